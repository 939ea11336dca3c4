"""`python -m clrender` and the `clrender` command: set up the process, then run the CLI.

The host does no large linear algebra: one BLAS thread, so that idle OpenBLAS workers do not
spin on the cores the OpenCL CPU device works on (set before NumPy loads; the user's own
setting wins). Ctrl-C, SIGTERM and SIGHUP end the command alike (clrender.interrupts), from the
first moment: the signals are blocked while the libraries load, so that an interrupt there
ends the command in one line once they are loaded, never with a traceback. Only the first one
interrupts; a later one, while the finished pixels are saved, is reported.
"""

import os
import sys


def run(exiting: bool = False) -> int:
    """The command line's command; its exit status. exiting: the command is the whole process
    (the `clrender` script, `python -m clrender`), whose ending signals then take their
    default action (clrender.interrupts.ending_signals_interrupt); else the caller's handlers
    come back."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from clrender import interrupts

    with interrupts.ending_signals_interrupt(exiting):
        try:
            with interrupts.signals_blocked():  # NumPy, pyopencl, OpenEXR initialise whole
                from clrender.cli import main

            return main()
        except KeyboardInterrupt as interrupt:  # before the command's own handling
            return interrupts.report(interrupt)
        except BrokenPipeError:  # stdout's reader left (`... | head`): quietly, as cat does
            silence_stdout()
            return 141  # 128 + SIGPIPE, as a shell reports a writer the pipe ended
        except OSError as err:  # stdout cannot be written (a full disk, a closed terminal)?
            if stdout_writable():
                raise
            silence_stdout()
            print(f"clrender: error: cannot write standard output: {err.strerror}", file=sys.stderr)
            return 2


def stdout_writable() -> bool:
    """Whether stdout takes a line now (a probe: only after an OSError nothing else explains,
    which goes on as a traceback when stdout is fine)."""
    try:
        sys.stdout.write("\n")
        sys.stdout.flush()
    except OSError:
        return False
    return True


def silence_stdout() -> None:
    """stdout to the null device: Python's flush at exit must not fail too."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def entry() -> None:
    """The `clrender` script: the command is the whole process."""
    sys.exit(run(exiting=True))


def _run_by_python_m() -> bool:
    """Whether this process is `python [options] -m clrender` (IPython's `%run -m clrender`
    runs this module as __main__ too, inside a process that goes on)."""
    arguments = getattr(sys, "orig_argv", [])
    return any(
        argument == "-mclrender" or (argument == "-m" and following == "clrender")
        for argument, following in zip(arguments, [*arguments[1:], ""], strict=True)
    )


if __name__ == "__main__":
    sys.exit(run(exiting=_run_by_python_m()))
