"""A one-line progress bar on stderr; silent unless stderr is a terminal."""

from __future__ import annotations

import sys
import time
from typing import TextIO

BAR_WIDTH = 30


def format_seconds(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    return f"{minutes} min {secs:02d} s"


class ProgressBar:
    """Call with (done, total) pixels; `close()` ends the line. Draws only on a terminal."""

    def __init__(self, label: str, stream: TextIO | None = None, enabled: bool | None = None):
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.label = label
        self.start = time.perf_counter()
        self.drawn = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        elapsed = time.perf_counter() - self.start
        fraction = done / total
        filled = int(BAR_WIDTH * fraction)
        eta = elapsed * (1.0 - fraction) / fraction if fraction > 0 else float("nan")
        eta_text = format_seconds(eta) if fraction > 0 else "?"
        bar = "#" * filled + "." * (BAR_WIDTH - filled)
        self.stream.write(
            f"\r{self.label} [{bar}] {100 * fraction:5.1f}% "
            f"{format_seconds(elapsed)} elapsed, ETA {eta_text}  "
        )
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False
