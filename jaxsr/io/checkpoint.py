"""Safe checkpoints: `.npz` files keyed by pytree key paths plus JSON metadata.

A file holds one array per leaf, named by its key path (`params/blocks/0/conv2/w`), and a `__metadata__`
entry with a JSON string (format version, jaxsr version, configs, training card). Writes go to a temporary
file in the same folder and are renamed over the target (`os.replace`), so a crash never leaves a
half-written checkpoint. Reads check every key, shape and dtype against a template (from `jax.eval_shape`)
and raise `ValueError` saying what is wrong.
"""

from __future__ import annotations

import dataclasses
import json
import os
import zipfile
from pathlib import Path

import jax
import numpy as np

from .files import atomic_path
from .formats import JSON_METADATA_MAX_BYTES, DamagedFile, _json_metadata, read_entry
from ..config import ModelConfig
from ..nn.duf import count_params
from ..nn.model import Architecture, Model, architecture

__all__ = [
    "FORMAT_VERSION",
    "flatten_tree",
    "save_tree",
    "load_tree",
    "read_metadata",
    "save_model",
    "load_model",
    "model_info",
    "model_template",
    "stored_architecture",
    "resolve_model_path",
    "config_to_dict",
    "config_from_dict",
    "drop_legacy_fields",
    "FORMS_CARD_KEY",
    "equivalent_forms",
]

FORMAT_VERSION = 1
_META = "__metadata__"
# Fields that older checkpoints carry in a config but the config no longer has: execution choices that used
# to live there (`conv3d_impl`, now an argument of `apply_model`). They say nothing about the weights, so
# reading drops them and those checkpoints still load and resume.
LEGACY_FIELDS = {ModelConfig: frozenset({"conv3d_impl"})}
# Fields added since take their defaults when a file lacks them (`config_from_dict`): `ModelConfig.temporal`
# is "window", the only form older versions trained.
# The card entry that records how the weights run in the temporal forms other than their own, measured:
# {form: {"equivalent": true or false, ...}} (`jaxsr.inference.measure_form_equivalence` writes one record).
FORMS_CARD_KEY = "forms"


def _version() -> str:
    import jaxsr  # late: jaxsr/__init__ imports this module

    return getattr(jaxsr, "__version__", "unknown")


def flatten_tree(tree) -> dict:
    """{key path "a/0/b": leaf} for every leaf of `tree` (dict keys, sequence indices, attribute names)."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path, simple=True, separator="/"): leaf for path, leaf in leaves}


def save_tree(path, tree, metadata: dict) -> Path:
    """Write the leaves of `tree` and the JSON-serialisable `metadata` to `path` (.npz) atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {k: np.asarray(v) for k, v in flatten_tree(tree).items()}
    if _META in arrays:
        raise ValueError(f"save_tree: key {_META!r} is reserved")
    meta = dict(metadata, format_version=FORMAT_VERSION, jaxsr_version=_version())
    arrays[_META] = np.array(json.dumps(meta, sort_keys=True))
    with atomic_path(path, overwrite=True, make_parents=True) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
        f.flush()
        os.fsync(f.fileno())
    return path


def _open(path):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {str(path)!r} does not exist")
    with open(path, "rb") as f:
        head = f.read(6)
    # neither an .npz (a zip archive) nor an .npy: numpy would take it for a pickle and suggest loading it unsafely
    if not head.startswith(b"PK") and head != b"\x93NUMPY":
        raise ValueError(f"checkpoint {str(path)!r} is not an .npz file (not a zip archive); a model is the .npz "
                         "that jaxsr.save_model or jaxsr train writes")
    try:
        data = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
        raise ValueError(f"checkpoint {str(path)!r} is not a readable .npz file (truncated or corrupt?): {e}") from e
    if not isinstance(data, np.lib.npyio.NpzFile):  # an .npy file: np.load gives the array itself
        raise ValueError(  # noqa: TRY004 - a wrong file (the user's mistake), not a wrong type in code
            f"checkpoint {str(path)!r} is a single .npy array, not an .npz checkpoint of jaxsr "
            "(save_model / jaxsr train write those)")
    return data


def _read_meta(data, path) -> dict:
    if _META not in data.files:
        raise ValueError(f"checkpoint {str(path)!r} has no {_META!r} entry: not a jaxsr checkpoint")
    names = data.zip.namelist()
    stored = data.zip.getinfo(_META + ".npy" if _META + ".npy" in names else _META).file_size
    if stored > JSON_METADATA_MAX_BYTES:  # refused before it is read: the zip's directory gives its size
        raise ValueError(f"checkpoint {str(path)!r}: {stored / 2**20:.0f} MiB of metadata, more than the "
                         f"{JSON_METADATA_MAX_BYTES // 2**20} MiB a jaxsr checkpoint's may hold: a damaged or "
                         "foreign file")
    try:
        entry = read_entry(data, _META, f"checkpoint {str(path)!r}")
    except DamagedFile:
        raise
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
        raise ValueError(f"checkpoint {str(path)!r}: unreadable metadata (truncated or corrupt?): {e}") from e
    meta = _json_metadata(entry, f"checkpoint {str(path)!r}")
    if not isinstance(meta, dict):
        raise ValueError(  # noqa: TRY004 - a foreign file, not a wrong type in code
            f"checkpoint {str(path)!r}: metadata is not a JSON object: not a jaxsr checkpoint")
    fv = meta.get("format_version")
    if fv != FORMAT_VERSION:
        raise ValueError(
            f"checkpoint {str(path)!r} has format version {fv} (written by jaxsr {meta.get('jaxsr_version')}); "
            f"this jaxsr ({_version()}) reads format version {FORMAT_VERSION}"
        )
    return meta


def read_metadata(path) -> dict:
    """The JSON metadata of a checkpoint (format and jaxsr versions, configs, training card).

    Reads only the metadata entry, not the arrays; returns a dict (no pytree of arrays).
    """
    with _open(path) as data:
        return _read_meta(data, path)


def load_tree(path, template, *, prefix: str = "", strict: bool = True):
    """Read a checkpoint into the structure of `template` (a pytree of arrays or `jax.ShapeDtypeStruct`s).

    Every leaf of the template must be present under `prefix + key path` with the same shape and dtype;
    with `strict`, no other arrays may be in the file. Returns (tree of numpy arrays, metadata dict).
    Raises `FileNotFoundError` for a missing file and `ValueError` for anything else wrong.
    """
    with _open(path) as data:
        meta = _read_meta(data, path)
        expected = {prefix + k: v for k, v in flatten_tree(template).items()}
        stored = set(data.files) - {_META}
        missing = sorted(set(expected) - stored)
        if missing:
            raise ValueError(f"checkpoint {str(path)!r} is missing {len(missing)} array(s), e.g. {missing[:3]}")
        if strict:
            extra = sorted(k for k in stored - set(expected) if k.startswith(prefix))
            if extra:
                raise ValueError(f"checkpoint {str(path)!r} has unexpected array(s) {extra[:3]} for this config")
        leaves = []
        for key, tmpl in expected.items():
            try:
                arr = read_entry(data, key, f"checkpoint {str(path)!r}")
            except DamagedFile:
                raise
            except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
                raise ValueError(
                    f"checkpoint {str(path)!r}: array {key!r} is unreadable (truncated or corrupt?): {e}"
                ) from e
            if arr.shape != tuple(tmpl.shape):
                raise ValueError(
                    f"checkpoint {str(path)!r}: array {key!r} has shape {arr.shape}, expected {tuple(tmpl.shape)}"
                )
            want = np.dtype(tmpl.dtype)
            if arr.dtype == np.float16 and want == np.float32 and meta.get("storage_dtype") == "float16":
                arr = arr.astype(np.float32)  # stored at half precision (`save_model(storage_dtype="float16")`)
            if arr.dtype != want:
                raise ValueError(
                    f"checkpoint {str(path)!r}: array {key!r} has dtype {arr.dtype}, expected {tmpl.dtype}"
                )
            leaves.append(arr)
    treedef = jax.tree_util.tree_structure(template)
    return jax.tree_util.tree_unflatten(treedef, leaves), meta


def config_to_dict(cfg) -> dict:
    """A frozen config dataclass as a JSON-ready dict."""
    return dataclasses.asdict(cfg)


def drop_legacy_fields(cls, d: dict) -> dict:
    """`d` (a config dict read from a checkpoint) without the fields `cls` no longer has (`LEGACY_FIELDS`)."""
    legacy = LEGACY_FIELDS.get(cls, frozenset())
    return {k: v for k, v in d.items() if k not in legacy}


def config_from_dict(cls, d: dict):
    """Rebuild a config dataclass from `config_to_dict`'s output (JSON lists become tuples); fields of
    older versions (`LEGACY_FIELDS`) are dropped, missing fields take their defaults, any other unknown field
    raises ValueError."""
    d = drop_legacy_fields(cls, d)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown field(s) {unknown} in checkpoint metadata")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def model_template(cfg):
    """Shapes and dtypes of (params, state) for `cfg` (a config of any registered architecture), without computing
    anything."""
    return architecture(cfg).template(cfg)


def save_model(path, model: Model, *, card: dict | None = None, storage_dtype: str = "float32") -> Path:
    """Save a `Model` of any architecture (a pytree of params and state) to `path` (.npz): arrays `params/...`,
    `state/...`, and metadata {kind: "model", architecture, config, card, storage_dtype}.

    `card` is the training card (JSON-ready dict: data, steps, wall time, hardware, validation PSNR, ...).
    storage_dtype: "float32", or "float16" to halve the file (`load_model` returns float32 either way);
    raises ValueError if a value does not fit float16 (|x| > 65504).
    """
    tree = {"params": model.params, "state": model.state}
    if storage_dtype == "float16":
        tree = jax.tree_util.tree_map(lambda x: np.asarray(x, np.float32), tree)
        too_big = [k for k, v in flatten_tree(tree).items() if np.any(np.abs(v) > np.finfo(np.float16).max)]
        if too_big:
            raise ValueError(f"save_model: {too_big[:3]} hold values beyond float16's range; store as float32")
        tree = jax.tree_util.tree_map(lambda x: x.astype(np.float16), tree)
    elif storage_dtype != "float32":
        raise ValueError(f"save_model: storage_dtype must be 'float32' or 'float16', got {storage_dtype!r}")
    meta = {"kind": "model", "architecture": model.kind, "config": config_to_dict(model.config), "card": card or {},
            "storage_dtype": storage_dtype}
    return save_tree(path, tree, meta)


# Names of bundled weights that stay fixed whatever the defaults become: "paper-tr4" is always the paper's TR4
# (depth in, trained on the paper's regime), which the reproduction scripts load.
BUNDLED_ALIASES = {f"paper-tr{tr}": f"tr{tr}" for tr in range(5)}


# The model of a training run's folder (`jaxsr.training.fit` writes it): a folder given as a model means this file.
RUN_MODEL_FILE = "best.npz"


def resolve_model_path(path) -> Path:
    """Where a model lives: `path` itself if it is a file, else the best model of a training run if it is a
    folder holding one (`path/best.npz`, as `jaxsr train` and `jaxsr finetune` write it), else `path` + ".npz",
    else the bundled weights of that name (`jaxsr/weights/tr4.npz` for "tr4"; "paper-tr0".."paper-tr4" name the
    paper's models, `BUNDLED_ALIASES`). Raises FileNotFoundError naming what was tried.

    Args: path (str or Path). Returns a Path to an existing file (not opened or checked).
    """
    if isinstance(path, str) and not path.strip():
        raise FileNotFoundError("no checkpoint named '': expected a file, a run folder or the name of bundled "
                                "weights (tr0 .. tr4, tr0-photons, tr4-photons, tr0-ambient, tr4-ambient, "
                                "paper-tr0 .. paper-tr4)")
    p = Path(path)
    if p.is_file():
        return p
    if p.is_dir() and (p / RUN_MODEL_FILE).is_file():
        return p / RUN_MODEL_FILE
    if p.name and p.suffix != ".npz" and p.with_name(p.name + ".npz").is_file():
        return p.with_name(p.name + ".npz")
    bundled = Path(__file__).parents[1] / "weights" / f"{BUNDLED_ALIASES.get(p.name, p.name)}.npz"
    if len(p.parts) == 1 and bundled.is_file():
        return bundled
    if p.is_dir():
        raise FileNotFoundError(f"no checkpoint at {str(path)!r}: a folder without {RUN_MODEL_FILE} (a training run "
                                "writes it at the end of its first epoch), nor bundled weights of that name")
    raise FileNotFoundError(f"no checkpoint at {str(path)!r} (nor {str(path)!r}.npz, nor bundled weights {p.name!r})")


def stored_architecture(meta: dict, path) -> Architecture:
    """The architecture a checkpoint's metadata names: "architecture" (files of jaxsr 0.2 on), "baseline" (learned
    baselines saved before, kind "baseline"), else the DUF network (every older model file). ValueError for a
    file that holds no model."""
    kind = meta.get("kind")
    if kind not in ("model", "train_state", "baseline") or "config" not in meta:
        raise ValueError(f"checkpoint {str(path)!r} does not hold a jaxsr model (kind {kind!r})")
    name = meta.get("architecture", meta.get("baseline", "duf"))
    try:
        return architecture(str(name))
    except ValueError as e:
        raise ValueError(f"checkpoint {str(path)!r}: {e}") from None


def equivalent_forms(card, arch: Architecture) -> tuple[str, ...]:
    """The temporal forms a card records as measured equivalent to the weights' own ({"forms": {form:
    {"equivalent": true, ...}}}, `FORMS_CARD_KEY`), among those `arch` runs in; () for a card without the record.
    A record that is not an object, or not `true`, counts as not measured."""
    records = card.get(FORMS_CARD_KEY) if isinstance(card, dict) else None
    if not isinstance(records, dict):
        return ()
    return tuple(f for f in arch.forms if isinstance(records.get(f), dict) and records[f].get("equivalent") is True)


def load_model(path, *, temporal: str | None = None) -> Model:
    """Load a `Model` of any registered architecture saved by `save_model` (or the model inside a training
    checkpoint of `jaxsr.training.fit`; or a learned baseline saved by jaxsr 0.1).

    `path` is a file, a file without its `.npz`, or the name of bundled weights ("tr4", "histnet"). Every
    array is checked against the shapes the architecture's init gives for the stored config; raises `ValueError`
    for a truncated file, a missing or unexpected key, a wrong shape or dtype, a non-finite value (NaN weights
    give NaN outputs), a config beyond `jaxsr.config`'s limits, or an unsupported format version.
    Returns the `Model` (params and state float32 in memory, config from the file, `Model.equivalent_forms` the
    forms its card records as measured equivalent, `equivalent_forms`). temporal (DUF models): None (the form the
    file records; "window" for files older than the field), or "window" / "sequence" to run the same weights in
    that form (both forms have the same parameters; e.g. `load_model("tr4", temporal="sequence")`).
    """
    path = resolve_model_path(path)
    meta = read_metadata(path)
    arch = stored_architecture(meta, path)
    try:
        cfg = config_from_dict(arch.config_type, meta["config"])
    except (TypeError, AttributeError, ValueError) as e:  # a config that is not a dict, or fields of the wrong type
        shown = repr(meta["config"])
        shown = shown if len(shown) <= 500 else f"{shown[:500]} ... ({len(shown) - 500:,} more characters)"
        raise ValueError(f"checkpoint {str(path)!r}: unreadable {arch.name} config {shown}: {e}") from e
    if temporal is not None:
        if not arch.forms:
            raise ValueError(f"load_model: temporal applies to DUF models; {str(path)!r} holds {arch.name}")
        if temporal not in arch.forms:
            raise ValueError(f"load_model: temporal must be one of {arch.forms}, got {temporal!r}")
        cfg = arch.with_form(cfg, temporal)
    params_t, state_t = model_template(cfg)
    template = {"params": params_t} if meta["kind"] == "baseline" else {"params": params_t, "state": state_t}
    tree, _ = load_tree(path, template, strict=meta["kind"] in ("model", "baseline"))
    bad = [k for k, v in flatten_tree(tree).items() if not np.isfinite(v).all()]
    if bad:  # such weights turn every output into NaN
        raise ValueError(f"checkpoint {str(path)!r}: array {bad[0]!r} holds non-finite values (NaN or inf)"
                         + (f", and {len(bad) - 1} more array(s)" if len(bad) > 1 else "")
                         + ": weights of a run that diverged, or a damaged file")
    tree = jax.tree_util.tree_map(jax.numpy.asarray, tree)
    return Model(tree["params"], tree.get("state", {}), cfg, equivalent_forms(meta.get("card"), arch))


def model_info(path, *, lr_shape=(32, 64)) -> dict:
    """Describe a model (see `resolve_model_path` for `path`): its file, architecture, config, what it reads
    ("histograms", or its channels per LR pixel such as ["depth"]), whether it marks no return, parameter count and
    training card, as a JSON-ready dict; for the DUF network also its temporal form, frames per window, input
    radius R (output t from frames t-R .. t+R) and GFLOP per frame at `lr_shape` (rows, cols) in its form."""
    path = resolve_model_path(path)
    model = load_model(path)
    meta = read_metadata(path)
    cfg = model.config
    return {
        "path": str(path),
        "architecture": model.kind,
        "config": config_to_dict(cfg),  # with the fields older files lack at their defaults
        **model.architecture.describe(cfg, lr_shape),
        "reads": "histograms" if model.reads_histograms else list(model.channels),
        "marks_no_return": model.has_no_return_head,
        "parameters": count_params(model.params),
        "lr_shape": list(lr_shape),
        "card": meta.get("card", {}),
    }
