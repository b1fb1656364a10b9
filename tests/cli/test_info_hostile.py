"""`jaxsr info` on damaged or hostile checkpoints: what the file says never reaches the terminal raw
(control characters and ANSI escapes escaped), and a deeply nested or huge card is refused with one line and exit
status 2, quickly, instead of a traceback or minutes of parsing. In-process (`jaxsr.cli.main`), tiny models."""

import json
import time

import jax
import numpy as np
import pytest
from hostile_files import claim_terabytes

from jaxsr import cli
from jaxsr.config import ModelConfig
from jaxsr.io.checkpoint import model_template, read_metadata, save_model
from jaxsr.io.formats import JSON_METADATA_MAX_BYTES
from jaxsr.nn import Model

TINY = ModelConfig(tr=0, base=4, growth=2, head=4, filter_hidden=4)
ESC = "\x1b[2J\x1b]0;owned\x07\u202e"  # clear the screen, set the window title, reverse the text


def tiny_model(path, card, compressed=False):
    """A tiny DUF checkpoint (zero weights, no compilation) with `card` as its training card."""
    params, state = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype), model_template(TINY))
    save_model(path, Model(params, state, TINY), card={})
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    arrays["__metadata__"] = np.array(json.dumps(dict(meta, card=card), ensure_ascii=False))
    (np.savez_compressed if compressed else np.savez)(path, **arrays)
    return path


def info(path, capsys, *flags):
    status = cli.main(["info", str(path), *flags])
    out, err = capsys.readouterr()
    return status, out, err


def test_control_characters_in_the_card_and_the_path_are_escaped(tmp_path, capsys):
    card = {f"note{ESC}": f"trained{ESC}", "nested": {ESC: [ESC]}, "purpose": f"a test{ESC}",
            "validation": {"psnr": 30.0, "frames": 4, "sequences": [ESC]}}
    path = tiny_model(tmp_path / f"m{ESC}.npz", card)
    status, out, err = info(path, capsys)
    assert status == 0 and err == ""
    assert "\x1b" not in out and "\x07" not in out and "\u202e" not in out
    # the path, the card's purpose and its validation sequences, as a Python literal writes them
    assert out.count("\\x1b[2J\\x1b]0;owned\\x07\\u202e") == 4  # the path twice: first line and "more: ... --json"
    assert len(out.splitlines()) == 6  # path, use, network, parameters, validation, more: no line broken
    status, out, err = info(path, capsys, "--json")
    assert status == 0 and out.isascii() and "\x1b" not in out
    assert json.loads(out)["card"][f"note{ESC}"] == f"trained{ESC}"  # escaped on screen, intact as data


def test_an_error_quoting_the_file_is_escaped_too(tmp_path, capsys):
    path = tiny_model(tmp_path / "m.npz", {})
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    arrays["__metadata__"] = np.array(json.dumps(dict(meta, format_version=f"9{ESC}", jaxsr_version=ESC)))
    np.savez(path, **arrays)
    status, out, err = info(path, capsys)
    assert status == 2 and out == "" and len(err.splitlines()) == 1
    assert err.startswith("jaxsr info: error: ") and "format version" in err and "\x1b" not in err


def test_a_long_card_entry_is_cut_in_text_and_whole_in_json(tmp_path, capsys):
    path = tiny_model(tmp_path / "m.npz", {"history": list(range(20_000)), "purpose": "x" * 20_000})
    status, out, _ = info(path, capsys)
    line = next(l for l in out.splitlines() if l.startswith("  use: "))
    assert status == 0 and len(line) < 1100 and line.endswith("more characters)")
    assert "history" not in out and len(out.splitlines()) == 5  # the card's entries are in --json only
    status, out, _ = info(path, capsys, "--json")
    assert status == 0 and json.loads(out)["card"]["history"] == list(range(20_000))


@pytest.mark.parametrize("depth", [100, 100_000])
def test_a_deeply_nested_card_is_refused_in_one_line(tmp_path, capsys, depth):
    """100 levels pass json.loads but not the printers; 100000 is a RecursionError in json.loads itself."""
    path = tmp_path / "m.npz"
    tiny_model(path, {})
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    text = str(arrays["__metadata__"])
    arrays["__metadata__"] = np.array(text[:-1] + ', "deep": ' + "[" * depth + "]" * depth + "}")
    np.savez(path, **arrays)
    status, out, err = info(path, capsys)
    assert status == 2 and out == "" and len(err.splitlines()) == 1, err
    assert "jaxsr info: error: " in err and "nested more than 64 levels" in err
    with pytest.raises(ValueError, match="nested more than 64 levels"):
        read_metadata(path)


def test_a_huge_card_is_refused_before_it_is_read(tmp_path, capsys):
    """A card of more than JSON_METADATA_MAX_BYTES (a compressed file says so in its zip directory: a few kB on
    disk, 17 MB read) is refused from the directory, before any of it is decompressed or parsed."""
    path = tiny_model(tmp_path / "m.npz", {"junk": "x" * (JSON_METADATA_MAX_BYTES // 4)}, compressed=True)
    t0 = time.perf_counter()
    status, out, err = info(path, capsys)
    assert time.perf_counter() - t0 < 1.0
    assert status == 2 and out == "" and len(err.splitlines()) == 1, err
    assert "MiB of metadata, more than the 16 MiB" in err


def test_an_error_quoting_a_huge_config_is_cut(tmp_path, capsys):
    """load_model's message quotes the config it cannot read: 10 MB of it would be one 10 MB line."""
    path = tiny_model(tmp_path / "m.npz", {})
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    config = dict(meta["config"], junk="\x1b[31m" + "x" * 10**6)
    arrays["__metadata__"] = np.array(json.dumps(dict(meta, config=config)))
    np.savez(path, **arrays)
    status, out, err = info(path, capsys)
    assert status == 2 and out == "" and len(err.splitlines()) == 1
    assert "unknown field(s) ['junk']" in err and len(err) < 2100 and "\x1b" not in err


@pytest.mark.parametrize("entry", ["__metadata__", "weights"])
def test_a_header_that_claims_terabytes_is_refused_in_one_line(tmp_path, capsys, entry):
    """An .npy header claiming 10^12 elements in an entry of a few bytes: one line naming the file, not NumPy's
    "Unable to allocate 3.64 TiB" traceback."""
    path = tiny_model(tmp_path / "m.npz", {})
    claim_terabytes(path, None if entry == "weights" else "__metadata__.npy")
    # the metadata is read by jaxsr info, the weights when the model loads
    command = ["info", str(path)] if entry == "__metadata__" else ["upscale", str(path), "-o", str(tmp_path / "o.npy"),
                                                                    "--model", str(path)]
    assert cli.main(command) == 2
    err = capsys.readouterr().err
    assert "claims 4e+12 bytes" in err and "a damaged or hostile file" in err and err.count("\n") == 1, err


def test_json_output_is_strict_json_with_nan_in_the_card(tmp_path, capsys):
    """Python's json reads NaN and Infinity in a card; --json printed them back, which jq and browsers refuse."""
    path = tiny_model(tmp_path / "m.npz", {"validation": {"psnr": float("nan"), "loss": float("inf"), "frames": 3}})
    status, out, _ = info(path, capsys, "--json")
    assert status == 0
    card = json.loads(out, parse_constant=lambda name: pytest.fail(f"{name} in --json"))["card"]
    assert card["validation"] == {"psnr": None, "loss": None, "frames": 3}
