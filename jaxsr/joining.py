"""How the processes of a run across processes meet before JAX's multi-controller runtime starts
(`jaxsr.runtime.init_distributed`).

JAX's own wait (`jax.distributed.initialize`) cannot be interrupted (Ctrl-C waits for it), says nothing while it
waits, and ends the process with a C++ abort when a process is missing at its timeout, or a segmentation fault
when the coordinator's port is taken. So every process first meets process 0 here, in Python, at the
coordinator's own address: process 0 listens there (which checks that the port is free and that the host is
one of its own), the others connect and say which process they are and how many take part, and process 0 answers
"go" once all of them are there. A missing process, a port in use or two processes told different counts is then
one line (`JoinError`) after a timeout the user sets, and Ctrl-C ends the wait; JAX's runtime starts only when
every process is present, and binds the port once process 0 has let it go.
"""

from __future__ import annotations

import contextlib
import errno
import selectors
import socket
import time

__all__ = ["JoinError", "split_address", "gather", "meet"]

# The first word of every message, so that something else at the port (a stray connection, another program) is
# told apart from a process of this run.
_GREETING = "jaxsr-join/1"
# How often a waiting process looks again (seconds): short enough that the wait ends soon after its deadline.
_POLL_S = 0.5


class JoinError(RuntimeError):
    """The processes of a run could not meet: one missing at the timeout, the coordinator's port in use or not
    this host's, or processes told different things."""


def split_address(address: str) -> tuple[str, int]:
    """("HOST", PORT) of "HOST:PORT"; an IPv6 address may be bracketed ("[::1]:8476")."""
    host, _, port = address.rpartition(":")
    return host.removeprefix("[").removesuffix("]"), int(port)


def _listen(address: str) -> socket.socket:
    """A socket listening at `address`: the port must be free and the host one of this machine's addresses."""
    host, port = split_address(address)
    try:
        family, kind, proto, _, where = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as e:
        raise JoinError(f"process 0: the coordinator's host {host!r} is not known here ({e.strerror})") from None
    sock = socket.socket(family, kind, proto)
    try:
        # as JAX's server does: a port left in TIME_WAIT by an earlier run is free, one a program listens on is not
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(where)
        sock.listen(64)
    except OSError as e:
        sock.close()
        if e.errno == errno.EADDRINUSE:
            raise JoinError(f"process 0: the coordinator's port {port} is in use on {host} (another run, or another "
                            "program): choose a free port for --coordinator") from None
        if e.errno == errno.EADDRNOTAVAIL:
            named = host if where[0] == host else f"{host} ({where[0]})"
            raise JoinError(f"process 0: {named} is not an address of this machine: the coordinator is process 0's "
                            "own host and a port on it") from None
        raise JoinError(f"process 0: cannot listen at {address}: {e.strerror}") from None
    return sock


def _send(conn: socket.socket, text: str) -> None:
    try:
        conn.setblocking(True)
        conn.settimeout(_POLL_S)
        conn.sendall(f"{_GREETING} {text}\n".encode())
    except OSError:  # it left: its own wait says so
        pass


def _hello(line: bytes) -> tuple[int, int] | None:
    """(process id, number of processes) of a process's greeting, None for anything else."""
    words = line.decode("ascii", "replace").split()
    if len(words) != 3 or words[0] != _GREETING or not (words[1].isdigit() and words[2].isdigit()):
        return None
    return int(words[1]), int(words[2])


def gather(address: str, num_processes: int, timeout: float, say=None) -> None:
    """Process 0: listen at `address` ("HOST:PORT") until processes 1..num_processes-1 have all connected, then tell
    them to go and let the port go (JAX's coordinator binds it next). Waits at most `timeout` seconds; say(line)
    is told what it waits for. JoinError for the port in use, a host not this machine's, a missing process at the
    timeout, a process told another count or an id out of range, or two processes with the same id (these are
    told why too)."""
    deadline = time.monotonic() + timeout
    listener = _listen(address)
    waiting = selectors.DefaultSelector()  # not select.select: it takes no more than 1024 connections
    waiting.register(listener, selectors.EVENT_READ)
    received: dict[socket.socket, bytes] = {}  # connected, greeting not read whole yet
    joined: dict[int, socket.socket] = {}

    def drop(conn):
        waiting.unregister(conn)
        received.pop(conn, None)
        conn.close()

    try:
        if say is not None:
            say(f"process 0 of {num_processes}: waiting at {address} for process(es) "
                f"{_ids(range(1, num_processes))} to join (up to {timeout:g} s)")
        while len(joined) < num_processes - 1:
            left = deadline - time.monotonic()
            if left <= 0:
                missing = sorted(set(range(1, num_processes)) - set(joined))
                raise JoinError(f"process 0: process(es) {_ids(missing)} of {num_processes} did not join at {address} "
                                f"within {timeout:g} s: start each with the same coordinator and number of processes "
                                "and its own process id, or allow a longer timeout (--join-timeout)")
            for key, _ in waiting.select(min(left, _POLL_S)):
                conn = key.fileobj
                if conn is listener:
                    peer, _ = listener.accept()
                    peer.setblocking(False)
                    received[peer] = b""
                    waiting.register(peer, selectors.EVENT_READ)
                    continue
                try:
                    data = conn.recv(256)
                except OSError:
                    data = b""
                if conn not in received or not data:  # a process that joined and left, or a stray that closed
                    for i in [i for i, c in joined.items() if c is conn]:
                        del joined[i]
                    drop(conn)
                    continue
                received[conn] += data
                if b"\n" not in received[conn]:
                    if len(received[conn]) > 256:  # not one of ours
                        drop(conn)
                    continue
                hello = _hello(received.pop(conn).split(b"\n", 1)[0])
                if hello is None:
                    drop(conn)
                    continue
                i, n = hello
                problem = None
                if n != num_processes:
                    problem = (f"process {i} was told {n} processes, process 0 {num_processes}: give every process "
                               "the same number of processes")
                elif not 0 < i < num_processes:
                    problem = f"a process joined as process {i}, outside 1..{num_processes - 1}"
                elif i in joined:
                    problem = f"two processes joined as process {i}: give each its own process id"
                if problem is not None:
                    for c in (conn, joined.get(i)):
                        if c is not None:
                            _send(c, f"refused {problem}")
                    raise JoinError(f"process 0: {problem}")
                joined[i] = conn
        for conn in joined.values():
            _send(conn, "go")
        _until_closed(list(joined.values()))
    finally:
        waiting.close()
        for conn in (*received, *joined.values(), listener):
            conn.close()


def _until_closed(conns, seconds: float = 2.0) -> None:
    """Wait (at most `seconds`) for the processes told to go to close their side first: the side that closes
    first holds the port in TIME_WAIT, and JAX's coordinator binds it next."""
    deadline = time.monotonic() + seconds
    for conn in conns:
        with contextlib.suppress(OSError):
            conn.settimeout(max(deadline - time.monotonic(), 0.0) or 1e-3)
            while conn.recv(256):
                pass


def meet(address: str, process_id: int, num_processes: int, timeout: float, say=None) -> None:
    """Process `process_id` > 0: connect to process 0 at `address` until it answers "go" (every process is there),
    trying again while nothing listens. Waits at most `timeout` seconds; say(line) is told what it waits for.
    JoinError when process 0 has not answered by then, or refused this process (it says why)."""
    deadline = time.monotonic() + timeout
    host, port = split_address(address)
    if say is not None:
        say(f"process {process_id} of {num_processes}: waiting for process 0 at {address} (up to {timeout:g} s)")
    last = "nothing answered"  # what the last attempt met, for the message at the timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise JoinError(f"process {process_id}: process 0 did not let this process join at {address} within "
                            f"{timeout:g} s ({last}): start process 0 with the same coordinator, on the host whose "
                            "address that is (a name that resolves there to a loopback address listens only there), "
                            "or allow a longer timeout (--join-timeout)")
        try:
            conn = socket.create_connection((host, port), timeout=min(left, 2.0))
        except OSError as e:  # nobody listens yet (refused), no route yet, a name not known (yet)
            last = f"the last attempt: {e.strerror or type(e).__name__}"
            time.sleep(min(_POLL_S, max(left, 0.0)))
            continue
        with conn:
            reply = _ask(conn, f"{process_id} {num_processes}", deadline)
        if reply == "go":
            return
        if reply is not None and reply.startswith("refused "):
            raise JoinError(f"process {process_id}: process 0 at {address} refused it: {reply.removeprefix('refused ')}")
        last = "something answered there, not process 0 of a jaxsr run"
        time.sleep(min(_POLL_S, max(deadline - time.monotonic(), 0.0)))  # closed without an answer: try again


def _ask(conn: socket.socket, text: str, deadline: float) -> str | None:
    """Send our greeting with `text`; process 0's answer (the words after its greeting), None when the connection
    closes or the deadline passes without one."""
    try:
        conn.sendall(f"{_GREETING} {text}\n".encode())
        received = b""
        while b"\n" not in received:
            left = deadline - time.monotonic()
            if left <= 0 or len(received) > 4096:
                return None
            conn.settimeout(min(left, _POLL_S))
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            if not data:
                return None
            received += data
    except OSError:
        return None
    line = received.split(b"\n", 1)[0].decode("utf-8", "replace")
    greeting, _, answer = line.partition(" ")
    return answer if greeting == _GREETING else None


def _ids(ids) -> str:
    """Process ids for a message: "1, 2, 3", or "1..7" for a long run of them."""
    ids = list(ids)
    if len(ids) > 4 and ids == list(range(ids[0], ids[-1] + 1)):
        return f"{ids[0]}..{ids[-1]}"
    return ", ".join(map(str, ids))
