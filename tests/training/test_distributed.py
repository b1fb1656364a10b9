"""Training across processes (`jaxsr.runtime.init_distributed`, JAX's multi-controller runtime): the options and
environment that start it and their refusals, fast; and, slow, two CPU processes on this machine training a tiny
DUF with the same loss curve as one process with two devices and the same global batch, process 0 alone writing
the run, which one process then resumes."""

import errno
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import jax
import pytest

from jaxsr import joining, runtime
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
    assert main(["train", "--output", str(tmp_path / "run"), "--num-processes", "2"]) == 2
    assert "jaxsr train: error: init_distributed: training across processes needs" in capsys.readouterr().err
    monkeypatch.setenv("JAXSR_PROCESS_ID", "5")
    assert main(["train", "--output", str(tmp_path / "run"), "--coordinator", "h:1", "--num-processes", "2"]) == 2
    assert "process id 5 is outside 0..1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["train", "--output", str(tmp_path / "run"), "--num-processes", "0"])
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


# Meeting before JAX's runtime starts (`jaxsr.joining`): in threads of this process, without JAX, each in a second.
def _in_thread(fn, *args):
    """Run fn(*args) in a thread; a function that returns what it returned or raise what it raised."""
    box = {}

    def work():
        try:
            box["value"] = fn(*args)
        except Exception as e:  # noqa: BLE001 - handed to the test
            box["error"] = e

    thread = threading.Thread(target=work, daemon=True)
    thread.start()

    def result(timeout=30):
        thread.join(timeout)
        assert not thread.is_alive(), "still waiting"
        if "error" in box:
            raise box["error"]
        return box.get("value")

    return result


def test_processes_meet_and_process_0_lets_the_port_go():
    address = f"127.0.0.1:{_free_port()}"
    lines = []
    others = [_in_thread(joining.meet, address, i, 3, 20.0, lines.append) for i in (2, 1)]
    joining.gather(address, 3, 20.0, lines.append)
    for other in others:
        other()
    assert f"process 0 of 3: waiting at {address} for process(es) 1, 2 to join (up to 20 s)" in lines
    assert f"process 1 of 3: waiting for process 0 at {address} (up to 20 s)" in lines
    with socket.socket() as s:  # free again, for JAX's coordinator
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(joining.split_address(address))


def _connect_when_listening(address: str, wait_s: float = 10.0) -> socket.socket:
    """A TCP connection to `address` once something listens there (within wait_s)."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return socket.create_connection(joining.split_address(address), timeout=1)
        except ConnectionRefusedError:
            assert time.monotonic() < deadline
            time.sleep(0.05)


def test_a_stray_connection_does_not_count_as_a_process():
    address = f"127.0.0.1:{_free_port()}"
    waiting = _in_thread(joining.gather, address, 2, 20.0)
    # once process 0 listens: a client that is not a process of the run, then process 1
    with _connect_when_listening(address) as stray:
        stray.sendall(b"GET / HTTP/1.0\r\n\r\n")
        joining.meet(address, 1, 2, 20.0)
    waiting()


def test_a_process_that_joined_and_left_is_waited_for_again():
    """Process 1 greets process 0 and is stopped (Ctrl-C) before the others came: it is missing again."""
    address = f"127.0.0.1:{_free_port()}"
    waiting = _in_thread(joining.gather, address, 3, 1.5)
    with _connect_when_listening(address) as left:
        left.sendall(b"jaxsr-join/1 1 3\n")
    with pytest.raises(joining.JoinError, match=r"process\(es\) 1, 2 of 3 did not join"):
        waiting()


@pytest.mark.parametrize("role", ["process 0", "process 1"])
def test_a_process_alone_gives_up_at_its_timeout_with_what_it_waited_for(role):
    address = f"127.0.0.1:{_free_port()}"
    start = time.monotonic()
    if role == "process 0":
        with pytest.raises(joining.JoinError, match=rf"process 0: process\(es\) 1, 2 of 3 did not join at "
                                                    rf"{address} within 0\.5 s"):
            joining.gather(address, 3, 0.5)
    else:
        with pytest.raises(joining.JoinError, match=rf"process 1: process 0 did not let this process join at "
                                                    rf"{address} within 0\.5 s"):
            joining.meet(address, 1, 3, 0.5)
    assert time.monotonic() - start < 5


def test_process_0_refuses_a_port_in_use_and_an_address_not_its_own():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(joining.JoinError, match=f"the coordinator's port {port} is in use on 127.0.0.1"):
            joining.gather(f"127.0.0.1:{port}", 2, 5.0)
    with pytest.raises(joining.JoinError, match="192.0.2.1 is not an address of this machine"):  # TEST-NET-1
        joining.gather(f"192.0.2.1:{port}", 2, 5.0)


@pytest.mark.parametrize("theirs,match", [
    ((1, 3), "process 1 was told 3 processes, process 0 2: give every process the same number"),
    ((2, 2), r"a process joined as process 2, outside 1\.\.1"),
])
def test_processes_told_different_things_are_refused_on_both_sides(theirs, match):
    address = f"127.0.0.1:{_free_port()}"
    other = _in_thread(joining.meet, address, *theirs, 20.0)
    with pytest.raises(joining.JoinError, match="process 0: " + match):
        joining.gather(address, 2, 20.0)
    with pytest.raises(joining.JoinError, match=rf"process {theirs[0]}: process 0 at {address} refused it: {match}"):
        other()


def test_two_processes_with_one_id_are_refused():
    address = f"127.0.0.1:{_free_port()}"
    others = [_in_thread(joining.meet, address, 1, 3, 20.0) for _ in range(2)]
    with pytest.raises(joining.JoinError, match="two processes joined as process 1: give each its own process id"):
        joining.gather(address, 3, 20.0)
    for other in others:
        with pytest.raises(joining.JoinError, match="refused it: two processes joined as process 1"):
            other()


def test_the_command_says_what_it_waits_for_and_gives_up_in_one_line(monkeypatch, tmp_path, capsys):
    """--join-timeout bounds the wait; the JAX backend this test process already runs is set aside (a real
    process joins first: the slow test below)."""
    for name in (*DISTRIBUTED_ENV, *SLURM):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(runtime, "_backend_started", lambda: False)
    address = f"127.0.0.1:{_free_port()}"
    args = ["train", "--output", str(tmp_path / "run"), "--coordinator", address, "--num-processes", "2"]
    assert main([*args, "--process-id", "1", "--join-timeout", "0.5"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"jaxsr train: process 1 of 2: waiting for process 0 at {address} (up to 0.5 s)",
                   f"jaxsr train: error: process 1: process 0 did not let this process join at {address} within "
                   f"0.5 s (the last attempt: {os.strerror(errno.ECONNREFUSED)}): start process 0 with the same "
                   "coordinator, on the host whose address that is (a name that resolves there to a loopback address "
                   "listens only there), or allow a longer timeout (--join-timeout)"]
    with socket.socket() as taken:
        taken.bind(joining.split_address(address))
        taken.listen()
        assert main([*args, "--process-id", "0"]) == 2
    assert "is in use on 127.0.0.1 (another run, or another program)" in capsys.readouterr().err
    for bad in ("0", "-1", "nan", "inf"):
        with pytest.raises(SystemExit) as e:
            main([*args, "--process-id", "0", "--join-timeout", bad])
        assert e.value.code == 2 and "--join-timeout" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("timeout", [0, -1.0, float("nan"), float("inf"), "60", True])
def test_init_distributed_refuses_a_timeout_that_is_not_seconds(timeout):
    with pytest.raises(ValueError, match="the timeout must be a positive number of seconds"):
        init_distributed("127.0.0.1:8476", 2, 1, timeout=timeout)


# A process that joins (JAX's runtime too) and holds on until its stdin closes: `python -c JOINER ID N TIMEOUT`.
JOINER = textwrap.dedent(
    """
    import sys
    from jaxsr.runtime import init_distributed
    print(init_distributed(None, int(sys.argv[2]), int(sys.argv[1]), timeout=float(sys.argv[3])), flush=True)
    sys.stdin.read()
    """
)


@pytest.mark.slow  # Python processes importing jaxsr and JAX on 2 shared cores: 10-30 s
def test_the_coordinator_listens_at_the_address_given_only(tmp_path):
    """JAX's default binds every interface ([::]); given 127.0.0.1, another loopback address (127.0.0.2) finds
    nothing."""
    port = _free_port()
    env = _env(XLA_FLAGS="--xla_force_host_platform_device_count=1", JAXSR_COORDINATOR=f"127.0.0.1:{port}")
    procs = [subprocess.Popen([sys.executable, "-c", JOINER, str(i), "2", "120"], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env)
             for i in (1, 0)]
    try:
        assert [p.stdout.readline().strip() for p in procs] == ["(1, 2)", "(0, 2)"]
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass  # JAX's coordinator listens there
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.2", port), timeout=5).close()
    finally:
        for p in procs:
            p.stdin.close()
        for p in procs:
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()


@pytest.mark.slow  # a Python process importing jaxsr on 2 shared cores: 5-15 s each
@pytest.mark.parametrize("process_id", [0, 1])
def test_a_process_alone_ends_in_one_line_or_at_ctrl_c(tmp_path, process_id):
    """No JAX abort ("Check failure", exit 134) at the timeout and no wait Ctrl-C cannot end: exit 2 after one
    line, and 130 at Ctrl-C, with nothing written."""
    command = [sys.executable, "-m", "jaxsr.cli", "train", "--output", str(tmp_path / "run"), "--coordinator",
               f"127.0.0.1:{_free_port()}", "--num-processes", "2", "--process-id", str(process_id)]
    alone = subprocess.run([*command, "--join-timeout", "1"], capture_output=True, text=True, timeout=120,
                           cwd=tmp_path, env=_env())
    assert alone.returncode == 2, alone.stderr[-3000:]
    assert alone.stderr.count("\n") == 2 and "jaxsr train: error: process" in alone.stderr
    waiting = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=_env())
    try:
        assert "waiting" in waiting.stderr.readline()
        waiting.send_signal(signal.SIGINT)
        assert waiting.wait(timeout=30) == 130
    finally:
        if waiting.poll() is None:
            waiting.kill()
    assert not (tmp_path / "run").exists()
