"""Per-frame test scores kept between scorings: a run is scored again only when something its scores depend on
changed (its weights file, the scored test data, the inference and scoring code, the JAX version), so that adding a
run to a table of runs scores that run only. Fingerprints are exact (bytes), so another machine or JAX build, whose
simulation differs in the last bits, scores again: the safe direction."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import jax
import numpy as np

import jaxsr
from harness.reports import machine, write_atomic

_PACKAGE = Path(jaxsr.__file__).parent
# What a score depends on beyond the weights and the test data: the network (every module of jaxsr.nn), its loading
# and compilation, inference (jaxsr.inference), the metrics and the scoring loop (harness/scoring.py)
SCORING_CODE = (*sorted((_PACKAGE / "nn").glob("*.py")), *sorted((_PACKAGE / "inference").glob("*.py")),
                *(_PACKAGE / name for name in ("config.py", "runtime.py", "io/checkpoint.py", "eval/metrics.py")),
                Path(__file__).with_name("scoring.py"))
KEY = ("weights", "data", "code")


def digest(*arrays) -> str:
    """A short content fingerprint (sha256) of byte strings and arrays; each part's dtype, shape and length go in,
    so that ("ab", "c") and ("a", "bc") differ."""
    h = hashlib.sha256()
    for part in arrays:
        raw = part if isinstance(part, bytes) else np.ascontiguousarray(part).tobytes()
        meta = b"bytes" if isinstance(part, bytes) else f"{np.asarray(part).dtype.str}{np.shape(part)}".encode()
        h.update(meta + len(raw).to_bytes(8, "little") + raw)
    return h.hexdigest()[:16]


def data_digest(clips: dict) -> str:
    """The fingerprint of scored test data (`harness.scoring.Clip`s): every frame's LR depth (the windows read
    them), the scored frames and their truth, so that a change of the scenes or the simulation scores every run
    again."""
    parts = []
    for name, clip in clips.items():
        scored = np.arange(len(clip.gt)) if clip.scored is None else np.asarray(clip.scored)
        parts += [name.encode(), scored, np.asarray(clip.lr), np.asarray(clip.gt)[scored]]
    return digest(*parts)


def code_digest() -> str:
    """The fingerprint of the code in `SCORING_CODE` and the JAX version."""
    return digest(jax.__version__.encode(), *(path.read_bytes() for path in SCORING_CODE))


def read_cache(path: Path) -> dict:
    """The cache at `path` (run name -> entry); {} when there is none or it cannot be read (said on stderr: it is
    only a cache, every run is then scored again)."""
    try:
        cache = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as err:
        print(f"warning: ignoring the unreadable score cache {path} ({err}); scoring every run", flush=True)
        return {}
    return {k: v for k, v in cache.items() if isinstance(v, dict)} if isinstance(cache, dict) else {}


def write_cache(path: Path, cache: dict) -> None:
    """Write the cache atomically, one run per line (readable diffs)."""
    lines = [f"{json.dumps(name)}: {json.dumps(entry)}" for name, entry in sorted(cache.items())]
    write_atomic(str(path), "{\n" + ",\n".join(lines) + "\n}\n")


def cached_frame_scores(cache: dict, name: str, key: dict, shape: tuple, compute) -> tuple[np.ndarray, bool]:
    """A run's per-frame PSNR of `shape` (scenes, frames), rounded to 1e-4 dB, and whether it was computed now:
    from `cache` (name -> entry, updated in place) when its entry has the same `key` (fingerprints: `KEY`) and
    shape, else `compute()`d and entered with the machine and date."""
    entry = cache.get(name, {})
    if all(entry.get(k) == key[k] for k in KEY) and np.shape(entry.get("psnr")) == tuple(shape):
        return np.asarray(entry["psnr"], np.float64), False
    frames = np.round(np.asarray(compute(), np.float64), 4)
    if frames.shape != tuple(shape):
        raise ValueError(f"{name}: expected per-frame scores of shape {tuple(shape)}, got {frames.shape}")
    cache[name] = {**{k: key[k] for k in KEY}, "psnr": frames.tolist(), "machine": machine(),
                   "date": time.strftime("%Y-%m-%d %H:%M")}
    return frames, True


def weights_digest(path: Path) -> str:
    """The fingerprint of a weights file."""
    return digest(path.read_bytes())
