"""Signals that end a command the way Ctrl-C does.

SIGTERM (a job scheduler, `kill`) and SIGHUP (a closed terminal) raise SignalInterrupt, a
KeyboardInterrupt, in the main thread: a render stops between device calls and the command
writes the finished pixels (partial=1), exactly as after Ctrl-C. The command then exits with
128 + the signal number, as a shell reports a process the signal ended (130 for Ctrl-C).
While the images are written every one of these signals is held (`signals_held`) and reported
after the files are complete.
"""

from __future__ import annotations

import contextlib
import signal
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
def ending_signals_interrupt() -> Iterator[None]:
    """SIGTERM and SIGHUP raise SignalInterrupt while the block runs (main thread only)."""
    _received.clear()
    previous = {
        signum: signal.signal(signum, _raise)
        for signum in ENDING_SIGNALS
        if signum != signal.SIGINT
    }
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def signal_of(interrupt: KeyboardInterrupt) -> int:
    """The signal behind an interrupt: SIGINT for Python's own KeyboardInterrupt."""
    return getattr(interrupt, "signum", int(signal.SIGINT))


def last_signal() -> int:
    """The last SIGTERM or SIGHUP received, else SIGINT (Ctrl-C, Python's KeyboardInterrupt)."""
    return _received[-1] if _received else int(signal.SIGINT)


def exit_status(signum: int) -> int:
    return 128 + int(signum)


def signal_name(signum: int) -> str:
    return signal.Signals(signum).name


@contextlib.contextmanager
def signals_held() -> Iterator[list[int]]:
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs; the list gets those that came."""
    received: list[int] = []
    previous = {
        signum: signal.signal(signum, lambda number, frame: received.append(number))
        for signum in ENDING_SIGNALS
    }
    try:
        yield received
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
