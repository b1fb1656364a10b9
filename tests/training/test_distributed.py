"""Training across processes (`jaxsr.runtime.init_distributed`, JAX's multi-controller runtime): the options and
environment that start it and their refusals, fast; and, slow, two CPU processes on this machine training a tiny
DUF with the same loss curve as one process with two devices and the same global batch, process 0 alone writing
the run, which one process then resumes."""

import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import pytest

from jaxsr.cli import main
from jaxsr.config import ModelConfig, TrainConfig
from jaxsr.io.checkpoint import read_metadata
from jaxsr.runtime import DISTRIBUTED_ENV, distributed_settings, init_distributed
from jaxsr.training import choose_mesh, processes, run_state

SLURM = {"SLURM_JOB_ID": "4242", "SLURM_STEP_NODELIST": "gpu[07-08]", "SLURM_NTASKS": "8", "SLURM_PROCID": "3",
         "SLURM_LOCALID": "3"}


def test_one_process_unless_told_otherwise():
    assert distributed_settings(environ={}) is None
    assert distributed_settings(num_processes=1, environ={}) is None
    assert distributed_settings(environ={"JAXSR_NUM_PROCESSES": "1"}) is None
    assert distributed_settings(environ=dict(SLURM, SLURM_NTASKS="1")) is None  # srun -n 1: one process
    assert distributed_settings(num_processes=1, environ=SLURM) is None  # a count of 1 wins over Slurm's


def test_flags_win_over_the_environment():
    env = {"JAXSR_COORDINATOR": "10.0.0.1:8476", "JAXSR_NUM_PROCESSES": "4", "JAXSR_PROCESS_ID": "3"}
    assert distributed_settings(environ=env) == {"coordinator_address": "10.0.0.1:8476", "num_processes": 4,
                                                 "process_id": 3}
    assert distributed_settings("node1:1234", None, 0, environ=env) == {
        "coordinator_address": "node1:1234", "num_processes": 4, "process_id": 0}
    assert tuple(env) == DISTRIBUTED_ENV


def test_slurm_is_left_to_jax():
    """Under srun with several tasks and nothing given, JAX's own detection fills every field; given ones stay."""
    assert distributed_settings(environ=SLURM) == {"coordinator_address": None, "num_processes": None,
                                                   "process_id": None}
    assert distributed_settings(coordinator="gpu07:9000", environ=SLURM)["coordinator_address"] == "gpu07:9000"


@pytest.mark.parametrize("args,env,match", [
    (("localhost", 2, 0), {}, "HOST:PORT"),
    (("localhost:0", 2, 0), {}, "HOST:PORT"),
    (("localhost:99999", 2, 0), {}, "HOST:PORT"),
    (("h:1234", 0, 0), {}, "number of processes must be an integer >= 1"),
    (("h:1234", "two", 0), {}, "number of processes must be an integer >= 1"),
    (("h:1234", 2, -1), {}, "process id must be an integer >= 0"),
    (("h:1234", 2, 2), {}, r"process id 2 is outside 0\.\.1"),
    ((None, 1, 1), {}, r"process id 1 is outside 0\.\.0"),
    ((None, 2, None), {}, r"missing: coordinator \(\$JAXSR_COORDINATOR\), process_id \(\$JAXSR_PROCESS_ID\)"),
    ((None, None, None), {"JAXSR_COORDINATOR": "h:1234"}, "missing: num_processes"),
])
def test_bad_or_partial_settings_are_refused(args, env, match):
    with pytest.raises(ValueError, match=match):
        distributed_settings(*args, environ=env)


def test_init_distributed_after_jax_started_says_so(monkeypatch):
    for name in DISTRIBUTED_ENV:
        monkeypatch.delenv(name, raising=False)
    jax.devices()  # the backend runs
    assert init_distributed() == (0, 1)  # one process: nothing to start, whatever JAX did before
    with pytest.raises(RuntimeError, match="before any other JAX use"):
        init_distributed("127.0.0.1:1", 2, 0)


def test_the_command_refuses_a_partial_description(monkeypatch, tmp_path, capsys):
    for name in (*DISTRIBUTED_ENV, *SLURM):
        monkeypatch.delenv(name, raising=False)
    assert main(["train", "--out", str(tmp_path / "run"), "--num-processes", "2"]) == 2
    assert "jaxsr train: error: init_distributed: training across processes needs" in capsys.readouterr().err
    monkeypatch.setenv("JAXSR_PROCESS_ID", "5")
    assert main(["train", "--out", str(tmp_path / "run"), "--coordinator", "h:1", "--num-processes", "2"]) == 2
    assert "process id 5 is outside 0..1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["train", "--out", str(tmp_path / "run"), "--num-processes", "0"])
    assert e.value.code == 2 and "--num-processes" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_across_processes_the_batch_must_split_over_every_device(monkeypatch):
    monkeypatch.setattr(jax, "process_count", lambda: 2)
    monkeypatch.setattr(jax, "device_count", lambda: 4)
    with pytest.raises(ValueError, match="global batch of 6 .* does not split evenly over the 4 devices of 2 "
                                         "processes; choose a multiple of 4"):
        choose_mesh("auto", 6)
    with pytest.raises(ValueError, match="across 2 processes the batch is split over a mesh of all 4 devices"):
        choose_mesh(None, 8)


def test_a_resume_on_another_process_count_must_keep_the_global_batch(tmp_path):
    """The saved run's process count is checked with its settings: the global batch must be the same (then the
    run continues, with a warning), else the refusal says why."""
    cfg = ModelConfig(tr=0, base=8, growth=4, head=16, filter_hidden=16)
    saved = dict(run_state._settings(cfg, TrainConfig(batch_size=8), 0), kind="train_state", processes=2)
    run_state._check_resumable(tmp_path / "last.npz", saved, run_state._settings(cfg, TrainConfig(batch_size=8), 0))
    with pytest.raises(ValueError, match=r"train.batch_size 8 \(now 4\); a run begun on 2 process\(es\) continues "
                                         "on 1 only with the same global batch"):
        run_state._check_resumable(tmp_path / "last.npz", saved, run_state._settings(cfg, TrainConfig(batch_size=4), 0))


def test_one_process_shares_with_itself():
    def refuse():
        raise FileExistsError("held")

    assert processes._share({"a": [1.5, float("inf")]}) == {"a": [1.5, float("inf")]}
    assert processes._on_lead(lambda: 3) == 3
    with pytest.raises(FileExistsError, match="held"):
        processes._on_lead(refuse)


# A tiny DUF (TR0) on a toy source (a rectangle before a wall, jittable, the same on every process), one step per
# epoch so that each epoch's train loss is one step's: `python -c WORKER OUT EPOCHS [resume]` prints the history.
WORKER = textwrap.dedent(
    """
    import json, sys
    from jaxsr.runtime import init_distributed
    index, count = init_distributed()  # from $JAXSR_*: first, before any JAX use
    import jax, jax.numpy as jnp
    from jaxsr.config import ModelConfig, TrainConfig
    from jaxsr.training import fit

    def make_batch(key, batch=2):
        k = jax.random.split(key, 3 * batch).reshape(batch, 3)
        yy, xx = jnp.mgrid[:32, :32]
        def example(k):
            y0, x0 = jax.random.randint(k[0], (2,), 0, 20)
            hr = jnp.where((yy >= y0) & (yy < y0 + 12) & (xx >= x0) & (xx < x0 + 12),
                           jax.random.uniform(k[1], (), minval=0.1, maxval=0.6), 0.9)
            lr = hr.reshape(8, 4, 8, 4).mean(axis=(1, 3))
            return lr[None] + 0.05 * jax.random.normal(k[2], (1, 8, 8)), hr
        return jax.vmap(example)(k)

    windows, gt = make_batch(jax.random.key(99))
    cfg = ModelConfig(tr=0, base=8, growth=4, head=16, filter_hidden=16)
    train_cfg = TrainConfig(batch_size=2, examples_per_epoch=2, epochs=int(sys.argv[2]), patience=10, patch=(8, 8))
    _, history = fit(cfg, train_cfg, out=sys.argv[1], make_batch=make_batch,
                     validation={"windows": windows, "gt": gt}, progress=False, checkpoint_every_s=None,
                     resume=len(sys.argv) > 3)
    print(json.dumps({"index": index, "count": count, "devices": jax.device_count(),
                      "train_loss": [r["train_loss"] for r in history],
                      "val_loss": [r["val_loss"] for r in history]}))
    """
)
REPO = Path(__file__).resolve().parents[2]


def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in (*DISTRIBUTED_ENV, *SLURM)}
    env.update(JAX_PLATFORMS="cpu", JAXSR_CACHE_DIR="off", PYTHONPATH=str(REPO), **extra)
    return env


def _result(proc: subprocess.CompletedProcess) -> dict:
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # three Python processes compile the train step on 2 shared cores: about 1-2 minutes
def test_two_processes_train_as_one_with_the_same_global_batch(tmp_path):
    """2 processes x 1 CPU device == 1 process x 2 devices: the same mesh shape and global batch, so the same
    steps. Measured equal to the last bit (JAX 0.10.2, gloo); the stated tolerance, rtol 1e-5, allows for another
    float32 reduction order. Process 1, given an out folder of its own and a working folder of its own, writes
    nothing; process 0 writes the run, which one process resumes (warned: begun on 2), still on the curve."""
    epochs = 4
    one = subprocess.run([sys.executable, "-c", WORKER, str(tmp_path / "one"), str(epochs)], capture_output=True,
                         text=True, timeout=600, cwd=tmp_path,
                         env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=2"))
    reference = _result(one)
    assert (reference["count"], reference["devices"]) == (1, 2)

    port = _free_port()
    (tmp_path / "cwd0").mkdir()
    (tmp_path / "cwd1").mkdir()
    procs = [subprocess.Popen([sys.executable, "-c", WORKER, str(tmp_path / out), str(epochs - 1)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path / f"cwd{i}",
                              env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=1",
                                       JAXSR_COORDINATOR=f"127.0.0.1:{port}", JAXSR_NUM_PROCESSES="2",
                                       JAXSR_PROCESS_ID=str(i)))
             for i, out in enumerate(("two", "elsewhere"))]
    try:
        outputs = [p.communicate(timeout=600) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    results = [_result(subprocess.CompletedProcess(p.args, p.returncode, o, e)) for p, (o, e) in zip(procs, outputs)]
    assert [(r["index"], r["count"], r["devices"]) for r in results] == [(0, 2, 2), (1, 2, 2)]
    assert results[0] == dict(results[1], index=0)  # every process returns process 0's history
    for key in ("train_loss", "val_loss"):
        assert results[0][key] == pytest.approx(reference[key][: epochs - 1], rel=1e-5), key

    # process 0 alone wrote: its run folder holds the run (no lock left); process 1's folders hold nothing
    assert sorted(os.listdir(tmp_path / "two")) == ["best.npz", "last.npz", "metrics.jsonl"]
    assert not (tmp_path / "elsewhere").exists() and not os.listdir(tmp_path / "cwd1")
    meta = read_metadata(tmp_path / "two" / "last.npz")
    assert meta["processes"] == 2 and meta["card"]["hardware"]["processes"] == 2
    assert len((tmp_path / "two" / "metrics.jsonl").read_text().splitlines()) == epochs - 1

    # one process (2 devices) continues the 2-process run: the same global batch, so allowed, and on the curve
    resumed = subprocess.run([sys.executable, "-c", WORKER, str(tmp_path / "two"), str(epochs), "resume"],
                             capture_output=True, text=True, timeout=600, cwd=tmp_path,
                             env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=2"))
    continued = _result(resumed)
    assert "begun on 2 process(es), on 1: the global batch of 2 is unchanged" in resumed.stderr
    for key in ("train_loss", "val_loss"):
        assert continued[key] == pytest.approx(reference[key], rel=1e-5), key
    assert read_metadata(tmp_path / "two" / "last.npz")["processes"] == 1
