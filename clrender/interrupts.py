"""Signals that end a command the way Ctrl-C does.

Ctrl-C (SIGINT), SIGTERM (a job scheduler, `kill`) and SIGHUP (a closed terminal) raise
SignalInterrupt, a KeyboardInterrupt, in the main thread (unless the process started with them
ignored, as under `nohup` or in a shell's background: they stay ignored): a render stops
between device calls and the command writes the finished pixels (partial=1). The command then
exits with 128 + the number of the signal that interrupted it, as a shell reports a process the
signal ended (130 for Ctrl-C). Only the first one interrupts: one that comes while the render
finishes its work in flight and the images are written is reported and does not lose them
(SIGQUIT, Ctrl-\\, still quits at once).
From the moment the render's work is done (`work_done`, called by the render) to the command's
end every one of these signals is held (`held_once_done`; `signals_held` while the images are
written) and reported after the files are complete; one that comes after the command took its
status is delivered again as the command ends (`ending_signals_interrupt`), so that it is
never lost. Where the command is the whole process (`exiting`: the `clrender` script,
`python -m clrender`) the signals then take their default action, the output flushed first: one
that comes as the interpreter shuts down ends the process, no traceback; a program that runs
the command itself keeps its own handlers. While libraries load, the
runtime is set up and OpenCL programs build, the signals are blocked (`signals_blocked`): a
signal there interrupted an extension module's initialisation (an ImportError traceback) or a
system call inside the OpenCL compiler ("1 error generated."); blocked, it is delivered, and
ends the command in one line, right after that step.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator

# The signals that end a command with its finished work saved (SIGHUP is POSIX only).
ENDING_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


class SignalInterrupt(KeyboardInterrupt):
    """An ending signal arrived: handled wherever Ctrl-C is."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


# The ending signals this process received (a render catches the interrupt itself and only
# reports that it was interrupted: the command asks here which signal it was).
_received: list[int] = []


# A command's hold after its render (`held_once_done`): the list its signals go to while it
# waits for the render ([] outside), and the same list once the render's work is done (kept
# until ending_signals_interrupt ends, which delivers what the command did not take).
_asked: list[list[int]] = []
_holding: list[list[int]] = []
# Whether ending_signals_interrupt is on (its handler feeds the hold until it ends)
_interrupting: list[bool] = []


def _interrupt_once(signum: int, frame) -> None:
    """The first ending signal interrupts; a later one only says that the finished work is
    being saved (raised there, it would stop the saving and lose it). Once a render's work is
    done in a command that holds the signals from there (`held_once_done`), one is held."""
    _received.append(signum)
    if _holding:
        _holding[0].append(signum)
        return
    if len(_received) == 1:
        raise SignalInterrupt(signum)
    # (stderr may be a terminal that closed, the SIGHUP: the saving goes on)
    with contextlib.suppress(OSError):
        print(
            f"clrender: interrupted again ({signal.Signals(signum).name}): still finishing, "
            "finished pixels are saved (SIGQUIT, Ctrl-\\, quits at once)",
            file=sys.stderr,
        )


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
def ending_signals_interrupt(exiting: bool = False) -> Iterator[None]:
    """The first SIGINT, SIGTERM or SIGHUP raises SignalInterrupt while the block runs (main
    thread only), later ones are reported (`_interrupt_once`); signals the process was started
    with ignored (`nohup` ignores SIGHUP, a background job SIGINT) stay ignored. After the
    block the previous handlers come back, or with `exiting` (the block is the whole process)
    the default actions, stdout and stderr flushed first: a signal as the interpreter shuts
    down then ends the process, and the shell reports it (Python's own SIGINT handler printed
    a KeyboardInterrupt traceback, and a signal's default action drops unflushed output). A
    signal a command held after it took its status (`take_held`) is then delivered again."""
    _received.clear()
    signals = _not_ignored()
    previous = {signum: signal.signal(signum, _interrupt_once) for signum in signals}
    _interrupting[:] = [True]
    try:
        yield
    finally:
        if exiting:
            for stream in (sys.stdout, sys.stderr):
                with contextlib.suppress(OSError, ValueError, AttributeError):
                    stream.flush()
        for signum, old in previous.items():
            signal.signal(signum, signal.SIG_DFL if exiting else old)
        # (the handlers are replaced: nothing joins the hold from here)
        late = list(_holding[0]) if _holding else []
        _interrupting.clear()
        _asked.clear()
        _holding.clear()
        if late:
            with contextlib.suppress(OSError):
                print(
                    f"clrender: interrupted ({signal.Signals(late[-1]).name}) after the last "
                    "pixel: the images are complete",
                    file=sys.stderr,
                    flush=True,
                )
            signal.raise_signal(late[-1])


@contextlib.contextmanager
def held_once_done() -> Iterator[list[int]]:
    """For a command that renders, then saves and reports: from the moment its render's work
    is done (the render calls `work_done`) to the command's end, an ending signal does not
    interrupt (under ending_signals_interrupt): it is added to the list the block gets, for the
    command to take (`take_held`) and report once its files are written; one that comes
    after that is delivered as ending_signals_interrupt ends. Before that moment the first one
    interrupts the render, which returns its finished work."""
    held: list[int] = []
    _asked[:] = [held]
    try:
        yield held
    finally:
        _asked.clear()
        if not _interrupting:  # else the hold goes on to the end of ending_signals_interrupt
            _holding.clear()


def take_held(held: list[int]) -> list[int]:
    """The signals held so far, taken off the list (the command reports them; later ones stay
    and are delivered as the command ends)."""
    count = len(held)
    taken = held[:count]
    del held[:count]
    return taken


def work_done() -> None:
    """A render's interruptible work is done: called as its last step inside its own interrupt
    handling (an interrupt before the call is the render's), it starts the hold of a command
    that asked for one (`held_once_done`); elsewhere it does nothing."""
    _holding[:] = _asked  # one step: a signal finds the hold either not begun or begun


def _not_ignored() -> tuple[int, ...]:
    """The ending signals this process does not ignore."""
    return tuple(s for s in ENDING_SIGNALS if signal.getsignal(s) != signal.SIG_IGN)


@contextlib.contextmanager
def signals_held(received: list[int] | None = None) -> Iterator[list[int]]:
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs; the list (`received`, else a new
    one) gets those that came. Off the main thread (where handlers cannot be set, and a signal
    reaches the main thread anyway) nothing is held."""
    received = [] if received is None else received
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
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


def interrupting_signal() -> int:
    """The first ending signal received (the one that interrupted), else SIGINT (Python's own
    KeyboardInterrupt, outside ending_signals_interrupt)."""
    return _received[0] if _received else int(signal.SIGINT)


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
