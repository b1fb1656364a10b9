"""experiments/studies/accelerator_session.py: what a lease copies back, and that each planned fine-tune starts from
weights that exist."""

import os

import accelerator_session as session  # experiments/studies (pytest's pythonpath)

from jaxsr.io.checkpoint import resolve_model_path


def test_collect_copies_whole_files_and_only_when_changed(tmp_path):
    run, out = tmp_path / "run", tmp_path / "out"
    run.mkdir()
    out.mkdir()
    session.collect(run, out, "a")  # nothing written yet: nothing copied
    assert list(out.iterdir()) == []
    (run / "best.npz").write_bytes(b"epoch 1")
    session.collect(run, out, "a")
    assert (out / "a-best.npz").read_bytes() == b"epoch 1" and not (out / "a-metrics.jsonl").exists()
    os.utime(out / "a-best.npz", ns=(1, 1))  # a copy whose time stamp no longer matches the run's file is redone
    session.collect(run, out, "a")
    assert (out / "a-best.npz").stat().st_mtime_ns == (run / "best.npz").stat().st_mtime_ns
    (out / "a-best.npz").write_bytes(b"kept")  # same time stamp as the run's file: not copied again
    os.utime(out / "a-best.npz", ns=((run / "best.npz").stat().st_atime_ns, (run / "best.npz").stat().st_mtime_ns))
    session.collect(run, out, "a")
    assert (out / "a-best.npz").read_bytes() == b"kept"
    assert not list(out.glob("*.part"))


def test_every_fine_tune_starts_from_weights_that_exist():
    for name, args in session.FINETUNES.items():
        if "--init" in args:
            assert resolve_model_path(args[args.index("--init") + 1]).is_file(), name
