"""The progress bar (tqdm): drawn on a terminal, a widget in Jupyter, nothing in a pipe."""

import fcntl
import io
import os
import pty
import struct
import subprocess
import sys
import termios

import pytest

from clrender.progress import ProgressBar

# A render of 64 pixels reported half done, then closed (the CLI's use of the bar).
HALF_DONE = """
from clrender.progress import ProgressBar
bar = ProgressBar("cornell 8x8")
bar(32, 64)
bar.close()
"""

# A Jupyter kernel as tqdm.auto detects one: ipykernel's shell module loaded, its shell running.
IN_JUPYTER = """
import sys, types
import IPython
class ZMQInteractiveShell:
    config = {"IPKernelApp": {}}
sys.modules["ipykernel.zmqshell"] = types.ModuleType("ipykernel.zmqshell")
IPython.get_ipython = ZMQInteractiveShell
import tqdm.notebook
from clrender.progress import ProgressBar
bar = ProgressBar("cornell 8x8")
bar(32, 64)
print("widget:", isinstance(bar.bar, tqdm.notebook.tqdm), "disabled:", bar.bar.disable)
bar.close()
"""


def run_python(code: str, **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run([sys.executable, "-c", code], env=env, check=True, **kwargs)


def test_nothing_is_drawn_in_a_pipe():
    child = run_python(HALF_DONE, capture_output=True, text=True)
    assert child.stderr == "" and child.stdout == ""


def open_terminal() -> tuple[int, int]:
    """A pseudo-terminal 80 columns wide (a new one has 0, where tqdm draws nothing)."""
    controller, terminal = pty.openpty()
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    return controller, terminal


def test_a_bar_is_drawn_on_a_terminal():
    controller, terminal = open_terminal()
    try:
        run_python(HALF_DONE, stderr=terminal, stdout=subprocess.DEVNULL)
        os.close(terminal)
        drawn = b""
        while chunk := read_or_eof(controller):
            drawn += chunk
    finally:
        os.close(controller)
    # The bar redrawn in place (\r), left on its line when closed (the terminal's \r\n)
    last = drawn.decode().removesuffix("\r\n").split("\r")[-1]
    assert last.startswith("cornell 8x8:  50%|") and "| 32/64 [" in last, drawn
    assert drawn.endswith(b"px/s]\r\n"), drawn


def read_or_eof(fd: int) -> bytes:
    try:
        return os.read(fd, 4096)
    except OSError:  # EIO: the writer is gone
        return b""


def test_a_widget_in_jupyter_though_stderr_is_no_terminal():
    pytest.importorskip("ipywidgets")
    child = run_python(IN_JUPYTER, capture_output=True, text=True)
    assert "widget: True disabled: False" in child.stdout.splitlines(), child.stdout + child.stderr


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize(
    "stream, enabled, drawn",
    [(io.StringIO, True, True), (Terminal, False, False), (Terminal, None, True)],
)
def test_enabled_overrides_the_terminal_check(stream, enabled, drawn):
    out = stream()
    bar = ProgressBar("x", stream=out, enabled=enabled)
    bar(4, 8)
    bar.close()
    assert ("50%|" in out.getvalue()) == drawn, out.getvalue()
