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


def run() -> int:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from clrender import interrupts

    with interrupts.ending_signals_interrupt():
        try:
            with interrupts.signals_blocked():  # NumPy, pyopencl, OpenEXR initialise whole
                from clrender.cli import main

            return main()
        except KeyboardInterrupt as interrupt:  # before the command's own handling
            return interrupts.report(interrupt)
        except BrokenPipeError:  # stdout's reader left (`... | head`): quietly, as cat does
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())  # Python's flush at exit must not fail too
            return 141  # 128 + SIGPIPE, as a shell reports a writer the pipe ended


if __name__ == "__main__":
    sys.exit(run())
