"""Checkpoints: round trip, atomic writes, and clear errors for corrupt or mismatched files."""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsr
from jaxsr.io.checkpoint import (
    FORMAT_VERSION,
    flatten_tree,
    load_model,
    load_tree,
    read_metadata,
    save_model,
    save_tree,
)
from jaxsr.config import ModelConfig
from jaxsr.nn import Model, init_model

CFG = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16)


@pytest.fixture(scope="module")
def model():
    return Model(*init_model(jax.random.key(0), CFG), CFG)


def test_round_trip(tmp_path, model):
    card = {"data": "toy", "steps": 3, "validation": {"psnr": 21.5}}
    path = save_model(tmp_path / "m.npz", model, card=card)
    assert sorted(os.listdir(tmp_path)) == ["m.npz"]  # no temporary file left behind
    loaded = load_model(path)
    assert loaded.config == CFG
    for a, b in zip(jax.tree_util.tree_leaves(model), jax.tree_util.tree_leaves(loaded)):
        np.testing.assert_array_equal(a, b)
    meta = read_metadata(path)
    assert meta["card"] == card and meta["format_version"] == FORMAT_VERSION and meta["kind"] == "model"
    assert load_model(tmp_path / "m").config == CFG  # ".npz" may be left out
    with np.load(path) as data:
        assert "params/blocks/0/conv2/w" in data.files and "state/head/bn/var" in data.files


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_model(tmp_path / "nothing.npz")


def test_truncated_file(tmp_path, model):
    path = save_model(tmp_path / "m.npz", model)
    raw = path.read_bytes()
    for cut in (len(raw) // 2, len(raw) - 10, 100):
        bad = tmp_path / f"cut{cut}.npz"
        bad.write_bytes(raw[:cut])
        with pytest.raises(ValueError, match="truncated or corrupt"):
            load_model(bad)


def test_corrupt_member(tmp_path, model):
    path = save_model(tmp_path / "m.npz", model)
    raw = bytearray(path.read_bytes())
    i = raw.find(b"params/blocks/0/conv2/w")
    raw[i + 200 : i + 260] = bytes(60)  # zero some array bytes: the zip CRC no longer matches
    bad = tmp_path / "crc.npz"
    bad.write_bytes(bytes(raw))
    with pytest.raises(ValueError):
        load_model(bad)


def _meta(cfg=CFG):
    import dataclasses

    return {"kind": "model", "config": dataclasses.asdict(cfg), "card": {}}


def test_missing_key(tmp_path, model):
    params = {k: v for k, v in model.params.items() if k != "residual"}
    tree = {"params": params, "state": model.state}
    save_tree(tmp_path / "m.npz", tree, _meta())
    with pytest.raises(ValueError, match="missing .*residual"):
        load_model(tmp_path / "m.npz")


def test_unexpected_key(tmp_path, model):
    tree = {"params": dict(model.params, extra={"w": jnp.zeros(2)}), "state": model.state}
    save_tree(tmp_path / "m.npz", tree, _meta())
    with pytest.raises(ValueError, match="unexpected .*extra"):
        load_model(tmp_path / "m.npz")


def test_shape_mismatch(tmp_path, model):
    # weights of a tr=1 model under the metadata of a tr=1 model with 16 base channels
    import dataclasses

    save_tree(tmp_path / "m.npz", {"params": model.params, "state": model.state},
              _meta(dataclasses.replace(CFG, base=16)))
    with pytest.raises(ValueError, match="shape"):
        load_model(tmp_path / "m.npz")


def test_dtype_mismatch(tmp_path, model):
    params = jax.tree_util.tree_map(lambda x: x.astype(jnp.float16), model.params)
    save_tree(tmp_path / "m.npz", {"params": params, "state": model.state}, _meta())
    with pytest.raises(ValueError, match="dtype"):
        load_model(tmp_path / "m.npz")


def test_version_mismatch(tmp_path, model):
    path = save_model(tmp_path / "m.npz", model)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    meta["format_version"] = FORMAT_VERSION + 1
    arrays["__metadata__"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "v.npz", **arrays)
    with pytest.raises(ValueError, match="format version"):
        load_model(tmp_path / "v.npz")


def test_not_a_checkpoint(tmp_path):
    np.savez(tmp_path / "x.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not a jaxsr checkpoint"):
        load_model(tmp_path / "x.npz")


def test_an_npy_file_is_not_a_checkpoint(tmp_path):
    """np.load gives an .npy's array itself (no archive); that is a clear ValueError, not a TypeError."""
    np.save(tmp_path / "x.npy", np.zeros(3))
    for read in (load_model, read_metadata, jaxsr.io.checkpoint.model_info):
        with pytest.raises(ValueError, match="single .npy array, not an .npz checkpoint"):
            read(tmp_path / "x.npy")


def test_failed_write_keeps_old_file(tmp_path, model):
    path = save_model(tmp_path / "m.npz", model)
    before = path.read_bytes()

    class Boom:
        def __array__(self, *a, **k):
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        save_tree(path, {"params": {"w": Boom()}}, _meta())
    assert path.read_bytes() == before and sorted(os.listdir(tmp_path)) == ["m.npz"]


def test_load_tree_generic(tmp_path):
    tree = {"a": [jnp.arange(3.0), {"b": jnp.ones((2, 2), jnp.int32)}]}
    save_tree(tmp_path / "t.npz", tree, {"kind": "test"})
    assert set(flatten_tree(tree)) == {"a/0", "a/1/b"}
    back, meta = load_tree(tmp_path / "t.npz", jax.eval_shape(lambda: tree))
    np.testing.assert_array_equal(back["a"][1]["b"], np.ones((2, 2)))
    assert meta["kind"] == "test"


def test_float16_storage_round_trip(tmp_path):
    cfg = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16)
    model = Model(*init_model(jax.random.key(0), cfg), cfg)
    save_model(tmp_path / "m32.npz", model)
    save_model(tmp_path / "m16.npz", model, storage_dtype="float16")
    # half the bytes per value; the zip entries and metadata of this tiny model add a fixed overhead
    assert (tmp_path / "m16.npz").stat().st_size < 0.65 * (tmp_path / "m32.npz").stat().st_size
    back = load_model(tmp_path / "m16.npz")
    for a, b in zip(jax.tree_util.tree_leaves(back), jax.tree_util.tree_leaves(model)):
        assert a.dtype == jnp.float32
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-4)  # float16: 11 significant bits
    big = Model(jax.tree_util.tree_map(lambda x: x + 1e5, model.params), model.state, cfg)
    with pytest.raises(ValueError, match="float16"):
        save_model(tmp_path / "big.npz", big, storage_dtype="float16")
    with pytest.raises(ValueError, match="storage_dtype"):
        save_model(tmp_path / "x.npz", model, storage_dtype="bfloat16")


def test_legacy_execution_field_is_dropped(tmp_path, model):
    """Checkpoints written while `conv3d_impl` was part of ModelConfig still load; any other unknown config field
    is still an error."""
    path = save_model(tmp_path / "m.npz", model)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    for extra, ok in (({"conv3d_impl": "native"}, True), ({"width": 3}, False)):
        arrays["__metadata__"] = np.array(json.dumps(dict(meta, config=dict(meta["config"], **extra))))
        np.savez(tmp_path / "old.npz", **arrays)
        if ok:
            loaded = load_model(tmp_path / "old.npz")
            assert loaded.config == CFG
            for a, b in zip(jax.tree_util.tree_leaves(model), jax.tree_util.tree_leaves(loaded)):
                np.testing.assert_array_equal(a, b)
        else:
            with pytest.raises(ValueError, match=r"unknown field\(s\) \['width'\]"):
                load_model(tmp_path / "old.npz")
    # the bundled window-form weights load whether or not they were written with the legacy field
    for tr in range(5):
        assert load_model(f"tr{tr}").config == ModelConfig(tr=tr)


def test_non_finite_weights_are_refused_naming_the_array(tmp_path, model):
    """NaN weights (a diverged run) would load and turn every output into NaN."""
    params = jax.tree_util.tree_map(np.asarray, model.params)
    params["head"]["conv"]["w"] = params["head"]["conv"]["w"].copy()
    params["head"]["conv"]["w"][0, 0, 0, 0, 0] = np.nan
    params["stem"]["b"] = np.full_like(params["stem"]["b"], np.inf)
    path = save_model(tmp_path / "m.npz", Model(params, model.state, CFG))
    with pytest.raises(ValueError, match=r"array 'params/head/conv/w' holds non-finite values .*and 1 more"):
        load_model(path)


def test_a_config_beyond_the_limits_is_refused_before_building_anything(tmp_path, model):
    """tr=100000 in a checkpoint's config would build 100003 blocks' templates (minutes, gigabytes)."""
    import time

    path = save_model(tmp_path / "m.npz", model)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    for field, value in (("tr", 100_000), ("base", 10**7), ("scale", 1000), ("filter_size", 101)):
        arrays["__metadata__"] = np.array(json.dumps(dict(meta, config=dict(meta["config"], **{field: value}))))
        np.savez(tmp_path / "big.npz", **arrays)
        t0 = time.perf_counter()
        with pytest.raises(ValueError, match=rf"ModelConfig: {field} must be .*got {value}"):
            load_model(tmp_path / "big.npz")
        assert time.perf_counter() - t0 < 1.0
    with pytest.raises(ValueError, match=r"tr must be an integer 0\.\.64"):
        ModelConfig(tr=65)


@pytest.mark.parametrize("kind, field, value", [
    ("histnet", "width", 10**6),
    ("histnet", "peak_half", -1),
    ("iseebetter", "base_filter", 10**6),
    ("iseebetter", "n_resblock", 10**6),
    ("iseebetter", "frames", 10**6),
    ("iseebetter", "disc_widths", [8] * 10**5),
])
def test_a_baseline_config_beyond_the_limits_is_refused_before_building_anything(tmp_path, kind, field, value):
    """HistNet's and iSeeBetter's configs are bounded like ModelConfig's: n_resblock=10^6 in a file would
    trace 3 x 10^6 residual blocks' templates (2000 took 10 s) before any shape is checked."""
    import time

    from jaxsr.baselines import HistNetConfig, RBPNConfig
    from jaxsr.io.checkpoint import model_template

    config = HistNetConfig(width=1) if kind == "histnet" else RBPNConfig(
        base_filter=2, feat=2, n_resblock=1, frames=3, disc_widths=(2,), disc_hidden=2)
    params, state = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype), model_template(config))
    path = save_model(tmp_path / "m.npz", Model(params, state, config))
    assert load_model(path).config == config
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    assert meta["architecture"] == kind
    arrays["__metadata__"] = np.array(json.dumps(dict(meta, config=dict(meta["config"], **{field: value}))))
    np.savez(tmp_path / "big.npz", **arrays)
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=rf"{type(config).__name__}: {field} must be .*got"):
        load_model(tmp_path / "big.npz")
    assert time.perf_counter() - t0 < 1.0


@pytest.mark.parametrize("field, value", [("tr", 0.0), ("tr", "0"), ("tr", None), ("scale", 4.0), ("bn_eps", "x")])
def test_a_config_field_of_the_wrong_type_is_refused_in_one_line(tmp_path, model, field, value):
    """`tr = 0.0` or `bn_eps = "x"` in a checkpoint's config ended in a TypeError traceback (issue 59): a
    ValueError naming the field."""
    path = save_model(tmp_path / "m.npz", model)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    arrays["__metadata__"] = np.array(json.dumps(dict(meta, config=dict(meta["config"], **{field: value}))))
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match=rf"ModelConfig: {field} must be .*got {value!r}"):
        load_model(tmp_path / "bad.npz")
