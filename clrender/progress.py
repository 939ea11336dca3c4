"""The render's progress bar, tqdm's: a bar on stderr when it is a terminal, a widget in
Jupyter (tqdm.auto; with ipywidgets installed), nothing in a pipe or a log file."""

from __future__ import annotations

from typing import TextIO

from tqdm.auto import tqdm


class ProgressBar:
    """Call with (done, total) pixels, the render's progress callback; `close()` ends the bar.
    enabled=None: tqdm decides (shown on a terminal or in Jupyter, hidden elsewhere)."""

    def __init__(self, label: str, stream: TextIO | None = None, enabled: bool | None = None):
        # Started now, so that its rate and ETA count the first tile too; total comes with it
        disable = None if enabled is None else not enabled
        self.bar = tqdm(desc=label, unit="px", file=stream, disable=disable)

    def __call__(self, done: int, total: int) -> None:
        if total <= 0:
            return
        if self.bar.total != total:
            self.bar.total = total
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        self.bar.close()
