"""The report's chart: success rate against density, a panel per tolerance, a line per
method with its Wilson interval, the methods told apart by colour, line style and
marker (greyscale too)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol


class Rate(Protocol):
    """One cell of the table as the chart reads it (sim/experiments/report.py's Cell)."""

    @property
    def method(self) -> str: ...
    @property
    def tolerance(self) -> float: ...
    @property
    def density(self) -> float: ...
    @property
    def rate(self) -> float: ...
    @property
    def interval(self) -> tuple[float, float]: ...


# A series' look: its colour (Okabe and Ito's, told apart by colour-blind readers), its
# line style and its marker, so that series stay apart in greyscale too.
COLOURS = ("#000000", "#E69F00", "#0072B2", "#009E73", "#CC79A7", "#D55E00", "#56B4E9")
DASHES: tuple[Any, ...] = ("-", "--", ":", "-.", (0, (5, 1.5, 1, 1.5, 1, 1.5)),
                           (0, (8, 2)), (0, (1, 1)))
MARKERS = ("o", "s", "^", "D", "v", "P", "X")
DODGE_PCT = 0.7  # points of series at one density set apart, in density's percent


def series_style(k: int) -> dict[str, Any]:
    """The ``k``-th series' colour, line style and marker (matplotlib keywords): no two
    of the first 49 share both colour and line style; odd ones have hollow markers."""
    n = len(COLOURS)
    colour = COLOURS[k % n]
    return {"color": colour, "linestyle": DASHES[(k + k // n) % n],
            "marker": MARKERS[(k + 2 * (k // n)) % n],
            "markerfacecolor": colour if k % 2 == 0 else "white"}


def chart(table: Sequence[Rate], difficulty: Mapping[float, str] | None = None) -> Any:
    """Success rate against density, a panel per tolerance, a line per method with the
    Wilson intervals as error bars; each method styled as :func:`series_style` says, its
    points set a little apart from the others' so that none hides another; a legend
    below every panel; a panel's title names its tolerance's ``difficulty``. Returns the
    matplotlib figure (close it when done)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tolerances = sorted({c.tolerance for c in table}, reverse=True)
    fig, axes = plt.subplots(1, len(tolerances), figsize=(4.4 * len(tolerances), 4.3),
                             sharey=True, squeeze=False)
    series: dict[str, list[Rate]] = defaultdict(list)
    for c in table:
        series[c.method].append(c)
    for ax, tol in zip(axes[0], tolerances, strict=True):
        for k, (method, cs) in enumerate(series.items()):
            pts = sorted((c for c in cs if c.tolerance == tol), key=lambda c: c.density)
            if not pts:
                continue
            shift = (k - (len(series) - 1) / 2) * DODGE_PCT
            x = [100 * c.density + shift for c in pts]
            y = [100 * c.rate for c in pts]
            err = [[100 * (c.rate - c.interval[0]) for c in pts],
                   [100 * (c.interval[1] - c.rate) for c in pts]]
            ax.errorbar(x, y, yerr=err, capsize=3, linewidth=1.4, markersize=5,
                        label=method, **series_style(k))
        ax.set_title(f"tolerance {100 * tol:g} % ({(difficulty or {}).get(tol, '')})")
        ax.set_xlabel("occlusion density (%)")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.17),
                  ncol=min(3, len(series)), frameon=False)  # below: it hides no point
    axes[0][0].set_ylabel("task success (%)")
    fig.tight_layout()
    return fig


def write_chart(table: Sequence[Rate], path: Path,
                difficulty: Mapping[float, str] | None = None) -> None:
    """:func:`chart` as a PNG at ``path``."""
    fig = chart(table, difficulty)
    import matplotlib.pyplot as plt

    try:
        fig.savefig(path, dpi=120)
    finally:
        plt.close(fig)
