"""The paper's schedule continued for TR0-TR4 within a wall-clock budget, resumable across slots and machines.

    python experiments/paper/converge_session.py --out OUT [--state DIR] [--minutes 9] [--tr 0 1 2 3 4] [--batch 16]
    python experiments/paper/converge_session.py --out OUT --quick --minutes 3   # a tiny network and scene, on a CPU

Each TR trains in its own process, all at once on the one device (`fit` of the `paper` preset: Adam, the rate
x0.1 every 10 epochs, early stopping after 5 epochs without a lower validation loss, up to 100 epochs), in its run
folder `--runs`/tr<N>: a new run starts from the bundled weights `jaxsr/weights/tr<N>.npz` (epoch 3 of the paper's
schedule; the schedule starts again at the first rate), a run already there resumes. `--batch` above the paper's
4 scales the rate by sqrt(batch / 4) (Adam's square-root rule) and keeps the 15,500 examples an epoch. Every
worker enables JAX's persistent compilation cache in `--runs`/xla, so that a slot whose cache came with it
skips the compilation (145-200 s a TR on an H200).

What a slot brings back is what fits the device's copy-back: at most 8 files of 16 MiB, 64 MiB in all. So every
30 s, and at the budget's end (the workers interrupted, each losing at most its last `--checkpoint-s` of steps),
the session packs into OUT: per TR its latest train state (`pack_state`: the weights and the best weights in
float16, Adam's second moment in bfloat16, its first moment left out: it restarts at zero, which Adam's 0.9
forgets within tens of steps) and its log, then the compilation cache's largest entries while they fit, as one
tar in parts `state.tar.000`... (`PART_BYTES` each, `MAX_PARTS` at most), beside `session.log`. `--state DIR` (a
folder holding such parts) restores them first: each run folder from its packed state unless the folder is
further on, and the cache entries it lacks. The five TRs' packed states take 46 MiB (TR0 6.1, TR4 13 MiB), the
rest of the 60 MiB goes to the cache. Calls on a machine still warm continue from `--runs` itself (an ignored
folder stays there between calls); a later machine needs the parts sent with the tree, whose 64 MiB the tracked
files nearly fill (60 MiB on 2026-11-29).
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # jaxsr from this checkout, installed or not (a lent machine's bare image)
sys.path.insert(0, str(ROOT / "experiments"))  # the shared harness
from harness.workers import epochs_of, stop, watch  # noqa: E402
PART_BYTES = 16 * 2**20 - 2**16  # each file that comes back: under 16 MiB
MAX_PARTS = 6  # 8 files may come back: the parts, session.log and one spare
MAX_BYTES = 60 * 2**20  # all parts together, under the 64 MiB that may come back
CACHE = "xla"  # the compilation cache's folder inside --runs
_META = "__metadata__"
# a train state's arrays by what they are (`jaxsr.training.run_state`): weights, Adam's moments
_WEIGHTS = ("params/", "best/params/")
_FIRST_MOMENT, _SECOND_MOMENT = "opt/mu/", "opt/nu/"


def train_config(batch: int, quick: bool, epochs: int = 100):
    """The `paper` preset at `batch` with the rate scaled by sqrt(batch / 4), up to `epochs` epochs (a resume may
    give more); `quick`: a few tiny steps and frames (the CPU smoke test)."""
    from jaxsr.config import PRESETS

    paper = PRESETS["paper"]
    cfg = dataclasses.replace(paper, batch_size=batch, lr=paper.lr * math.sqrt(batch / paper.batch_size),
                              epochs=epochs)
    if quick:
        cfg = dataclasses.replace(cfg, examples_per_epoch=2 * batch, patch=(8, 16), val_frames=2, val_sequences=())
    return cfg


def model_config(tr: int, quick: bool):
    """The paper's network at TR `tr`, or (`quick`) a tiny one of the same form."""
    from jaxsr.config import ModelConfig

    if quick:
        return ModelConfig(tr=tr, base=8, growth=4, head=16, filter_hidden=16)
    return ModelConfig(tr=tr)


def quick_data(tr: int, train_cfg):
    """The quick session's data, for want of compiling the scene renderer (minutes on a CPU): a wall and a box
    sliding before it (8 frames at the sensor's HR size, held in memory), as (make_batch, validation)."""
    import jax.numpy as jnp

    from jaxsr.config import Sensor
    from jaxsr.training import run_keys, sequence_batches, validation_set

    h, w = Sensor().hr_shape
    yy, xx = jnp.mgrid[:h, :w]
    depth = jnp.stack([jnp.where((abs(yy - h / 2) < h / 5) & (abs(xx - 20 - 8 * t) < w / 8), 12.0, 30.0 + yy / h)
                       for t in range(8)])
    intensity = jnp.full_like(depth, 0.5)
    sequences = {"box": {"depth": depth, "intensity": intensity, "snr": 2.0}}
    validation = validation_set(run_keys(train_cfg.seed)[2], tr, train_cfg, sequences=sequences)
    return sequence_batches(depth, intensity, tr, train_cfg), validation


def train_one(tr: int, runs: Path, batch: int, quick: bool, checkpoint_s: float, epochs: int) -> None:
    """The worker: `fit` of TR `tr` in runs/tr<N>, resumed if the folder holds a run, with the cache in runs/xla."""
    from jaxsr.runtime import enable_compilation_cache
    from jaxsr.training import RUN_FILES, fit

    enable_compilation_cache(path=runs / CACHE)
    out = runs / f"tr{tr}"
    resume = any((out / f).exists() for f in RUN_FILES if f != "metrics.jsonl")
    init = None if quick or resume else ROOT / "jaxsr" / "weights" / f"tr{tr}.npz"
    train_cfg = train_config(batch, quick, epochs)
    make_batch, validation = quick_data(tr, train_cfg) if quick else (None, None)
    fit(model_config(tr, quick), train_cfg, out=out, resume=resume, init=init, progress=False,
        make_batch=make_batch, validation=validation, checkpoint_every_s=checkpoint_s,
        card_extra={"session": "experiments/paper/converge_session.py"})


def latest_state(folder: Path) -> Path | None:
    """The run's latest train state file (`resume.npz` when ahead of `last.npz`), or None."""
    from jaxsr.training.folders import _latest_state

    return _latest_state(folder) if folder.is_dir() else None


def pack_state(path: Path) -> bytes:
    """A train state file (`last.npz` / `resume.npz`) made small: weights float16, Adam's second moment bfloat16
    (as uint16 bits), its first moment left out, everything else (BN statistics, key, counters, metadata) as it
    is. Returns the .npz's bytes; `unpack_state` makes the train state again."""
    import ml_dtypes

    small = {}
    with np.load(path, allow_pickle=False) as data:
        for key in data.files:
            a = data[key]
            if key.startswith(_FIRST_MOMENT):
                continue
            if key.startswith(_WEIGHTS) and a.dtype == np.float32:
                if np.any(np.abs(a) > np.finfo(np.float16).max):
                    raise ValueError(f"pack_state: {key} of {path} holds values beyond float16's range")
                a = a.astype(np.float16)
            elif key.startswith(_SECOND_MOMENT) and a.dtype == np.float32:
                a = a.astype(ml_dtypes.bfloat16).view(np.uint16)
                key = key + ".bf16"
            small[key] = a
    buf = io.BytesIO()
    np.savez(buf, **small)
    return buf.getvalue()


def unpack_state(packed: bytes) -> dict:
    """`pack_state`'s bytes back to a train state's arrays {name: float32 array ...} (the first moment zeros)."""
    import ml_dtypes

    arrays = {}
    with np.load(io.BytesIO(packed), allow_pickle=False) as data:
        for key in data.files:
            a = data[key]
            if key.endswith(".bf16"):
                key, a = key[: -len(".bf16")], a.view(ml_dtypes.bfloat16).astype(np.float32)
                arrays[_FIRST_MOMENT + key[len(_SECOND_MOMENT):]] = np.zeros_like(a)
            elif a.dtype == np.float16:
                a = a.astype(np.float32)
            arrays[key] = a
    return arrays


def _step_of(meta_entry) -> int:
    return int(json.loads(str(meta_entry))["run"]["step"])


def pack(runs: Path, trs, out: Path) -> dict:
    """Pack the runs' states and logs, then the cache's largest entries while they fit, into out/state.tar.NNN
    (written whole, then renamed; older parts removed). Returns {"states": {tr: step}, "cache": [entries packed,
    entries], "bytes": n}."""
    members, states = [], {}
    for tr in trs:
        state = latest_state(runs / f"tr{tr}")
        if state is None:
            continue
        packed = pack_state(state)
        with np.load(io.BytesIO(packed)) as data:
            states[tr] = _step_of(data[_META])
        members.append((f"tr{tr}/{state.name}", packed))
        log = runs / f"tr{tr}" / "metrics.jsonl"
        if log.is_file():
            members.append((f"tr{tr}/metrics.jsonl", log.read_bytes()))
    used = sum(len(b) + 1024 for _, b in members)
    cache = sorted((p for p in (runs / CACHE).glob("*") if p.is_file()), key=lambda p: -p.stat().st_size)
    packed_cache = 0
    for entry in cache:  # the steps' executables are the largest and the slowest to compile
        size = entry.stat().st_size + 1024
        if used + size <= MAX_BYTES:
            members.append((f"{CACHE}/{entry.name}", entry.read_bytes()))
            used += size
            packed_cache += 1
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for name, data in members:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    blob = buf.getvalue()
    parts = [blob[i : i + PART_BYTES] for i in range(0, len(blob), PART_BYTES)]
    if len(parts) > MAX_PARTS:
        raise ValueError(f"pack: the states alone take {len(blob)} bytes, more than {MAX_PARTS} parts can carry")
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / "packing"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for i, part in enumerate(parts):
        (tmp / f"state.tar.{i:03d}").write_bytes(part)
    for old in out.glob("state.tar.*"):
        old.unlink()
    for new in sorted(tmp.iterdir()):
        os.replace(new, out / new.name)
    tmp.rmdir()
    return {"states": states, "cache": [packed_cache, len(cache)], "bytes": len(blob)}


def restore(state_dir: Path, runs: Path, trs) -> dict:
    """Unpack `pack`'s parts from `state_dir` into the run folders: a TR's state (with its log and its best weights
    as best.npz) where its folder holds none further on, and the cache entries runs/xla lacks. Returns {tr: step
    restored}."""
    from jaxsr.config import ModelConfig
    from jaxsr.io.checkpoint import config_from_dict, save_model
    from jaxsr.nn.model import Model

    parts = sorted(state_dir.glob("state.tar.*"))
    if not parts:
        return {}
    restored = {}
    with tarfile.open(fileobj=io.BytesIO(b"".join(p.read_bytes() for p in parts))) as tar:
        members = {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}
    (runs / CACHE).mkdir(parents=True, exist_ok=True)
    for name, data in members.items():
        if name.startswith(CACHE + "/") and not (runs / name).exists():
            (runs / name).write_bytes(data)
    for tr in trs:
        states = [n for n in members if n.startswith(f"tr{tr}/") and n.endswith(".npz")]
        if not states:
            continue
        arrays = unpack_state(members[states[0]])
        meta = json.loads(str(arrays[_META]))
        here = latest_state(runs / f"tr{tr}")
        if here is not None and _step_of(np.load(here)[_META]) >= meta["run"]["step"]:
            continue  # the folder is as far or further on
        folder = runs / f"tr{tr}"
        folder.mkdir(parents=True, exist_ok=True)
        for f in ("last.npz", "resume.npz", "best.npz"):
            (folder / f).unlink(missing_ok=True)
        with open(folder / Path(states[0]).name, "wb") as f:
            np.savez(f, **arrays)
        if f"tr{tr}/metrics.jsonl" in members:
            (folder / "metrics.jsonl").write_bytes(members[f"tr{tr}/metrics.jsonl"])
        best = {k.split("/", 1)[1]: v for k, v in arrays.items() if k.startswith("best/")}
        tree = {"params": _nest(best, "params/"), "state": _nest(best, "state/")}
        save_model(folder / "best.npz", Model(tree["params"], tree["state"],
                                              config_from_dict(ModelConfig, meta["config"])), card=meta.get("card"))
        restored[tr] = meta["run"]["step"]
    return restored


def _nest(flat: dict, prefix: str) -> dict:
    """{"a/b/c": x} (the keys under `prefix`) as nested dicts {"a": {"b": {"c": x}}} (sequence indices too)."""
    tree = {}
    for key, value in flat.items():
        if not key.startswith(prefix):
            continue
        *path, leaf = key[len(prefix):].split("/")
        node = tree
        for p in path:
            node = node.setdefault(p, {})
        node[leaf] = value
    return _lists(tree)


def _lists(node):
    """Dicts whose keys are 0..n-1 as lists (a checkpoint's key paths keep sequence indices as digits)."""
    if not isinstance(node, dict):
        return node
    node = {k: _lists(v) for k, v in node.items()}
    if node and all(k.isdigit() for k in node) and sorted(map(int, node)) == list(range(len(node))):
        return [node[str(i)] for i in range(len(node))]
    return node


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="what comes back: state.tar.NNN parts, session.log")
    ap.add_argument("--state", type=Path, help="a folder of state.tar.NNN parts from an earlier slot, restored first")
    ap.add_argument("--runs", type=Path, default=ROOT / "runs" / "converge", help="the run folders and the cache")
    ap.add_argument("--minutes", type=float, default=9.0, help="wall-clock budget of the whole session")
    ap.add_argument("--tr", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--batch", type=int, default=16, help="examples a step (the paper's: 4); the rate scales by "
                    "sqrt(batch / 4)")
    ap.add_argument("--epochs", type=int, default=100, help="the epochs a run stops at (the paper's 100)")
    ap.add_argument("--checkpoint-s", type=float, default=30.0, help="seconds of training between saves in an epoch")
    ap.add_argument("--quick", action="store_true", help="a tiny network and a few steps an epoch (the CPU test)")
    ap.add_argument("--worker", type=int, help=argparse.SUPPRESS)  # one TR's training process
    args = ap.parse_args(argv)
    if args.worker is not None:
        train_one(args.worker, args.runs, args.batch, args.quick, args.checkpoint_s, args.epochs)
        return
    t_end = time.perf_counter() + 60 * args.minutes
    args.out.mkdir(parents=True, exist_ok=True)
    args.runs.mkdir(parents=True, exist_ok=True)
    log = open(args.out / "session.log", "a")

    def say(msg: str) -> None:
        line = f"[{time.strftime('%H:%M:%S')}] {msg}"
        print(line, flush=True)
        log.write(line + "\n")
        log.flush()

    if args.state is not None:
        say(f"restored {restore(args.state, args.runs, args.tr)} (TR: step) from {args.state}")
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false", PYTHONUNBUFFERED="1",
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    workers = {tr: subprocess.Popen(
        [sys.executable, __file__, "--worker", str(tr), "--out", str(args.out), "--runs", str(args.runs),
         "--batch", str(args.batch), "--epochs", str(args.epochs),
         "--checkpoint-s", str(args.checkpoint_s), *(["--quick"] if args.quick else [])],
        env=env, stdout=log, stderr=subprocess.STDOUT) for tr in args.tr}
    say(f"training TR {args.tr} at batch {args.batch}, {args.minutes} minutes")
    watch(workers, until=t_end - 30, refresh=lambda: say(f"packed {pack(args.runs, args.tr, args.out)}"))
    stop(workers)
    for tr, p in workers.items():
        epochs = epochs_of(args.runs / f"tr{tr}")
        best = min(epochs, key=lambda e: e["val_loss"]) if epochs else None
        say(f"TR{tr}: exit {p.returncode}, {len(epochs)} epochs"
            + (f", best val PSNR {best['val_psnr']:.2f} dB (epoch {best['epoch']})" if best else ""))
    say(f"packed {pack(args.runs, args.tr, args.out)}")


if __name__ == "__main__":
    main()
