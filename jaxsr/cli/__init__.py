"""The `jaxsr` command: argument parsing and the subcommand runners, nothing else (the work is done by the
library modules they call).

    jaxsr simulate --scene street --frames 20 --fps 25 --snr 1.3 --seed 0 -o DIR [-f]
    jaxsr simulate AIRSIM_FOLDER -o DIR [--snr 1.3]
    jaxsr train --tr 4 --preset cpu -o runs/tr4 [--resume | -f]
    jaxsr finetune --sensor my_sensor.toml -m tr4 -o my_tr4
    jaxsr upscale INPUT -o OUTPUT [-m tr4|auto|CHECKPOINT] [--sensor my_sensor.toml] [--preview strip.png]
    jaxsr info tr4 [--json]
    jaxsr models [--json]
    jaxsr --version

Each subcommand is a module here with `add_parser(subparsers)`, which registers its arguments and sets
`func=run`, and `run(args) -> exit status` (and may set `before_jax(args)`, run before JAX's backend starts). To
add one, write such a module and list it in `COMMANDS`.

Errors: a user's mistake (a bad argument, a missing or unreadable file, an existing output, a wrongly shaped
input, a damaged or hostile file) is one line on stderr, `jaxsr CMD: error: ...` (control characters escaped),
saying what was expected, and exit status 2, with no output or temporary file left behind; options and inputs
are checked before the long work starts. A traceback means a bug. A place the user chose that cannot be written
(no permission, a read-only file system: `jaxsr.io.NotWritableError`, or any OSError EROFS) is such a mistake too:
exit status 2, `jaxsr CMD: error: cannot write OUT: read-only file system; choose a folder you can write to`. A
write the system fails (a full disk, a quota, a failing device: any other OSError) is one line too, `jaxsr CMD:
error: no space left on device while writing OUT; nothing was written ...`, and exit status 1: the command was
right, the machine could not do it; atomic writes (`jaxsr.io.files`) have removed their temporary files by then.
Ctrl-C (SIGINT), SIGTERM and SIGHUP (the terminal closed) remove what the command had started to write and exit
with 130, 143 and 129 (128 + the signal number) after one line saying so (where the terminal is gone, the line
is lost); a signal ignored when the command starts stays ignored (`nohup jaxsr train ... &` outlives the
terminal). A Python warning is one line too, `jaxsr CMD: warning: ...`.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
import signal
import sys
import threading
import warnings

from ..joining import JoinError
from . import finetune, info, models, simulate, train, upscale
from ._text import printable, shortened

__all__ = ["COMMANDS", "USER_ERRORS", "Terminated", "build_parser", "main"]

COMMANDS = (simulate, train, finetune, upscale, info, models)
# Exceptions that mean the user asked for something impossible (the library raises these with a message).
USER_ERRORS = (FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError, PermissionError, ValueError,
               JoinError)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (`signum`), raised like Ctrl-C so that the same clean-up runs (temporary files and
    folders removed)."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(signum)
        self.signum = signal.Signals(signum)


# Signals that end a command as Ctrl-C does: SIGTERM (kill, a scheduler) and SIGHUP (the terminal closed).
TERMINATING = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad argument is one line on stderr (no usage block), exit status 2."""

    def error(self, message):
        if message.startswith("argument --") and message.endswith(": expected one argument"):
            flag = message.split()[1].split("/")[0].rstrip(":")  # argparse takes a value such as -5m for an option
            message += f" (one that begins with '-' is written {flag}=VALUE)"
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The `jaxsr` parser with every subcommand of `COMMANDS`; a subcommand is required."""
    from .. import __version__

    parser = _Parser(prog="jaxsr", description="Video super-resolution for single-photon lidar.")
    parser.add_argument("--version", action="version", version=f"jaxsr {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(subparsers)
    return parser


# An error line longer than this is cut: a message may quote a damaged file (megabytes of a config).
ERROR_LINE_CHARS = 2000


def _one_line(error: BaseException) -> str:
    """The error's message on one line, control characters escaped and cut at `ERROR_LINE_CHARS` (a message may
    quote a damaged file)."""
    return shortened(printable(" ".join(str(error).split())), ERROR_LINE_CHARS) or type(error).__name__


def _os_error_line(error: OSError) -> str:
    """An OSError as one line for people: `WriteError`'s own sentence, else the system's words and the file
    (no "[Errno N]" prefix)."""
    if error.strerror is None or type(error).__str__ is not OSError.__str__:
        return _one_line(error)
    where = f": {error.filename}" if error.filename is not None else ""
    return shortened(printable(" ".join(f"{error.strerror}{where}".split())), ERROR_LINE_CHARS)


def _raise_terminated(signum, frame):
    raise Terminated(signum)


def _handle_terminating_signals() -> dict:
    """Make each of `TERMINATING` end the command as Ctrl-C does (`Terminated`), except one that is ignored
    when the command starts: `nohup` ignores SIGHUP so that the command outlives the terminal, and it stays
    ignored. Returns {signal: the handler replaced}, to put back."""
    return {s: signal.signal(s, _raise_terminated) for s in TERMINATING if signal.getsignal(s) != signal.SIG_IGN}


def _redeliver_dropped_interruptions(previous):
    """A `sys.unraisablehook` that delivers again an interruption Python dropped: a signal handler's exception
    raised while a callback runs that Python cannot raise from (XLA's garbage-collection callback among them) is
    printed as "Exception ignored" and the command went on to exit 0 with its output written. Other exceptions
    go to `previous`."""

    def hook(unraisable):
        error = unraisable.exc_value
        if isinstance(error, KeyboardInterrupt):  # Terminated included
            signal.raise_signal(error.signum if isinstance(error, Terminated) else signal.SIGINT)
            return
        previous(unraisable)

    return hook


def _print_warning(command: str):
    """A `warnings.showwarning` that prints each warning as one line, `jaxsr COMMAND: warning: ...`."""

    def show(message, *args, **kwargs):
        print(f"jaxsr {command}: warning: {_one_line(message)}", file=sys.stderr)

    return show


def main(argv=None) -> int:
    """Entry point of the `jaxsr` console script.

    Args: argv (list of str, default sys.argv[1:]). Returns the exit status: 0 on success; 2 on a user error
    (see the module docstring; a place that cannot be written, read-only or without permission, among them),
    after printing the message to stderr; 1 when the system failed a write or a read (an OSError such as a full
    disk), after one line; 130 after Ctrl-C, 143 after SIGTERM, 129 after SIGHUP (unless SIGTERM or SIGHUP was
    ignored when `main` started: it stays ignored)."""
    args = build_parser().parse_args(argv)
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = _handle_terminating_signals() if in_main_thread else {}
    unraisable_hook = sys.unraisablehook
    if in_main_thread:
        sys.unraisablehook = _redeliver_dropped_interruptions(unraisable_hook)
    with warnings.catch_warnings():
        warnings.showwarning = _print_warning(args.command)
        for note in getattr(args, "old_spellings", ()):  # flags given in their old spelling (`_args.OldSpelling`)
            print(f"jaxsr {args.command}: warning: {note}", file=sys.stderr)
        try:
            status = _run(args, argv)
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
            sys.unraisablehook = unraisable_hook
    if argv is None:
        try:  # what is still buffered for a pipe: a reader that stopped reading ends the command quietly too
            sys.stdout.flush()
        except BrokenPipeError:
            _silence_stdout()
    if argv is None and status > 128:  # a program interrupted: its outputs are cleaned up by now
        _exit_now(status)
    return status


def _silence_stdout() -> None:
    """Point stdout at /dev/null: after a closed pipe, the interpreter's last flush would fail again."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _exit_now(status: int) -> None:
    """End the process at once with `status`, streams flushed: after an interruption XLA's threads may still be
    compiling or running, and the interpreter's shutdown under them crashed (SIGSEGV instead of 143, seen with a
    TR1 model stopped in its first batches)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # SIGHUP: the terminal may be gone
            stream.flush()
    os._exit(status)


def _run(args, argv) -> int:
    """Run the parsed command; the exit status, after one line for an error or an interruption (`main`)."""
    try:
        if getattr(args, "before_jax", None) is not None:  # first: e.g. joining a run across processes
            args.before_jax(args)
        if argv is None:  # run as a program (not called from Python, where the user owns JAX's devices)
            from ..runtime import use_cpu_cores

            use_cpu_cores()
        return args.func(args)
    except BrokenPipeError:  # the reader closed the pipe (jaxsr info tr4 | head -3): nothing more to say
        _silence_stdout()
        return 0
    except USER_ERRORS as e:
        print(f"jaxsr {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except OSError as e:  # after USER_ERRORS, which holds OSError's user-mistake subclasses
        print(f"jaxsr {args.command}: error: {_os_error_line(e)}", file=sys.stderr)
        return 2 if e.errno == errno.EROFS else 1  # a read-only file system: the user's choice of place, as EACCES
    except KeyboardInterrupt as e:
        what = f"terminated ({e.signum.name})" if isinstance(e, Terminated) else "interrupted"
        with contextlib.suppress(OSError):  # SIGHUP: the terminal may be gone, and the line with it
            print(f"jaxsr {args.command}: {what}; unfinished outputs removed", file=sys.stderr)
        return 128 + int(e.signum if isinstance(e, Terminated) else signal.SIGINT)
