"""What the benches' charts share so that they read as a paper's figures: a caption that states
every parameter of a figure, the spread over seeds behind each error bar, log axes whose tick
labels cannot collide, and a legend beside the axes rather than on the data.

Captions are drawn at the top of the figure (a wrapped suptitle, which constrained layout
makes room for) and repeated under the figure in the report, from one string. Figures with
constrained layout are saved with save_figure: the layout already fits their captions, labels and
legends inside them (no bbox_inches="tight"), and each is drawn once.
"""

from __future__ import annotations

import math
import statistics
import textwrap
from unittest.mock import patch

import matplotlib

matplotlib.use("Agg")
from matplotlib.text import Text  # noqa: E402
from matplotlib.ticker import LogLocator, NullFormatter  # noqa: E402

CAPTION_WIDTH = 150  # characters per caption line in a figure
CAPTION_FONT_SIZE = 8


def caption(what: str, parameters: dict) -> str:
    """ "what. name value; name value; ..." with every parameter of a figure, in order (None
    values are left out)."""
    items = "; ".join(f"{name} {value}" for name, value in parameters.items() if value is not None)
    return f"{what}. {items}."


def draw_caption(fig, text: str, width: int = CAPTION_WIDTH) -> None:
    """The caption above the axes of a constrained-layout figure, wrapped to `width`."""
    fig.suptitle(textwrap.fill(text, width), fontsize=CAPTION_FONT_SIZE, x=0.01, ha="left")


def save_figure(fig, path, dpi: int) -> None:
    """Save a constrained-layout figure drawn once: its layout is computed at the saved dpi, then
    the engine is removed (None: the benches set no default layout in rcParams). savefig of a
    figure with any layout engine, even "none"'s placeholder, first walks every artist with
    drawing disabled, only to run the layout, then draws."""
    fig.set_dpi(dpi)
    fig.get_layout_engine().execute(fig)
    fig.set_layout_engine(None)
    fig.savefig(path, dpi=dpi)


def report_caption(text: str) -> str:
    """The caption as a report line under its figure."""
    return f"*{text}*"


def spread(values: list[float]) -> dict:
    """Mean, standard error (nan for one value), and the values themselves: what an error bar
    of a mean over seeds shows, and what it was computed from."""
    k = len(values)
    se = statistics.stdev(values) / math.sqrt(k) if k > 1 else float("nan")
    return {"mean": statistics.fmean(values), "se": se, "values": list(values), "count": k}


def decade_log_axis(axis, low: float, high: float) -> None:
    """A log axis from the decade at or below `low` to the one at or above `high`, labelled at
    the decades only (unlabelled ticks between): at least two labels, one per decade, so no two
    can overlap however narrow the data's range (the default labels minor ticks on spans under
    a decade, and those collide)."""
    low_decade = math.floor(math.log10(low))
    high_decade = max(math.ceil(math.log10(high)), low_decade + 1)
    axis.set_major_locator(LogLocator(base=10.0, numticks=high_decade - low_decade + 1))
    axis.set_minor_locator(LogLocator(base=10.0, subs=tuple(range(2, 10)), numticks=100))
    axis.set_minor_formatter(NullFormatter())
    set_limits = axis.axes.set_xlim if axis is axis.axes.xaxis else axis.axes.set_ylim
    set_limits(10.0**low_decade, 10.0**high_decade)


def legend_beside(fig, axes) -> None:
    """One legend for the figure, outside the axes on the right (constrained layout leaves it
    room), from the first axes' labelled artists."""
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize=7, frameon=False)


def drawn_texts(fig) -> list[tuple[str, object]]:
    """(text, window extent) of every text a draw of the figure puts on the canvas: tick
    labels in view, axis labels, titles, legend entries, the caption, annotations (texts that
    are hidden, empty, or belong to ticks outside the view are not drawn, so not listed)."""
    drawn = []
    draw = Text.draw

    def recording_draw(text, renderer):
        if text.get_visible() and text.get_text().strip():
            drawn.append(text)
        return draw(text, renderer)

    with patch.object(Text, "draw", recording_draw):
        fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    return [(t.get_text(), t.get_window_extent(renderer)) for t in dict.fromkeys(drawn)]


def overlapping_texts(fig, tolerance: float = 0.5) -> list[tuple[str, str]]:
    """Pairs of drawn texts of a figure whose boxes overlap by more than `tolerance` pixels
    both ways (empty for a readable figure)."""
    boxes = drawn_texts(fig)
    pairs = []
    for i, (a, box_a) in enumerate(boxes):
        for b, box_b in boxes[i + 1 :]:
            width = min(box_a.x1, box_b.x1) - max(box_a.x0, box_b.x0)
            height = min(box_a.y1, box_b.y1) - max(box_a.y0, box_b.y0)
            if width > tolerance and height > tolerance:
                pairs.append((a, b))
    return pairs
