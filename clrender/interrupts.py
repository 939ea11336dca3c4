"""Signals that end a command the way Ctrl-C does.

SIGTERM (a job scheduler, `kill`) and SIGHUP (a closed terminal) raise SignalInterrupt, a
KeyboardInterrupt, in the main thread (unless the process started with them ignored, as under
`nohup`: they stay ignored): a render stops between device calls and the command
writes the finished pixels (partial=1), exactly as after Ctrl-C. The command then exits with
128 + the signal number, as a shell reports a process the signal ended (130 for Ctrl-C).
While the images are written every one of these signals is held (`signals_held`) and reported
after the files are complete. While libraries load, the runtime is set up and OpenCL programs
build, the signals are blocked (`signals_blocked`): a signal there interrupted an extension
module's initialisation (an ImportError traceback) or a system call inside the OpenCL
compiler ("1 error generated."); blocked, it is delivered, and ends the command in one line,
right after that step.
"""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator

# The signals that end a command with its finished work saved (SIGHUP is POSIX only).
ENDING_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


class SignalInterrupt(KeyboardInterrupt):
    """SIGTERM or SIGHUP arrived: handled wherever Ctrl-C is."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


# The SIGTERM and SIGHUP this process received (a render catches the interrupt itself and
# only reports that it was interrupted: the command asks here which signal it was).
_received: list[int] = []


def _raise(signum: int, frame) -> None:
    _received.append(signum)
    raise SignalInterrupt(signum)


@contextlib.contextmanager
def _handlers(signals: tuple[int, ...], handler) -> Iterator[None]:
    """`handler` for the signals while the block runs; the previous handlers after it."""
    previous = {signum: signal.signal(signum, handler) for signum in signals}
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


@contextlib.contextmanager
def ending_signals_interrupt() -> Iterator[None]:
    """SIGTERM and SIGHUP raise SignalInterrupt while the block runs (main thread only), unless
    the process was started with them ignored (`nohup` ignores SIGHUP): those stay ignored, as
    Python leaves an ignored SIGINT."""
    _received.clear()
    with _handlers(tuple(s for s in _not_ignored() if s != signal.SIGINT), _raise):
        yield


def _not_ignored() -> tuple[int, ...]:
    """The ending signals this process does not ignore."""
    return tuple(s for s in ENDING_SIGNALS if signal.getsignal(s) != signal.SIG_IGN)


@contextlib.contextmanager
def signals_held() -> Iterator[list[int]]:
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs; the list gets those that came."""
    received: list[int] = []
    with _handlers(_not_ignored(), lambda number, frame: received.append(number)):
        yield received


@contextlib.contextmanager
def signals_blocked() -> Iterator[None]:
    """Block SIGINT, SIGTERM and SIGHUP in this thread while the block runs (threads started
    inside it inherit the mask, so the signals reach this one); one that came is delivered,
    and its handler runs, when the block ends. A no-op where threads cannot mask signals."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, ENDING_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def last_signal() -> int:
    """The last SIGTERM or SIGHUP received, else SIGINT (Ctrl-C, Python's KeyboardInterrupt)."""
    return _received[-1] if _received else int(signal.SIGINT)


def exit_status(signum: int) -> int:
    return 128 + int(signum)


def report(interrupt: KeyboardInterrupt, written: bool | None = None) -> int:
    """Print the one line of an interrupted command (written=False: a command that writes
    files had written none, so it says so); its exit status."""
    signum = getattr(interrupt, "signum", int(signal.SIGINT))
    line = f"clrender: interrupted ({signal.Signals(signum).name})"
    if written is False:
        line += ": nothing written (a previous image there is kept)"
    print(line, file=sys.stderr)
    return exit_status(signum)
