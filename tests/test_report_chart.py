"""The report's chart, read from the matplotlib figure it builds (not its pixels): a
legend in every panel naming exactly the series drawn there, and series that can be
told apart: no two share both colour and style (line style, marker and its fill), the
first seven differ in style alone (greyscale), and no point sits on another's."""

from __future__ import annotations

import itertools

import matplotlib.colors as mcolors
import matplotlib.pyplot as plt
import pytest
from matplotlib.container import ErrorbarContainer

from taskcam.sim.experiments.report import Cell
from taskcam.sim.experiments.report_chart import chart

TOLERANCES = (0.2, 0.1, 0.01)
DENSITIES = (0.05, 0.2, 0.35)


def _table(methods: list[str], missing: set[tuple[str, float]] = frozenset()) -> list[Cell]:
    """Every method equally successful everywhere (15 of 20), so that lines drawn
    plainly would lie on each other; none for the (method, tolerance) in ``missing``."""
    return [Cell(m, "rating", False, d, d, tol, 20, 15)
            for tol in TOLERANCES for m in methods for d in DENSITIES
            if (m, tol) not in missing]


def _series(ax) -> list[tuple[str, tuple, tuple, list[float]]]:
    """Each plotted series of ``ax``: its label, colour (RGBA), style (line style,
    marker, whether the marker is hollow) and its points' x."""
    out = []
    for container in ax.containers:
        assert isinstance(container, ErrorbarContainer)
        line = container.lines[0]
        colour = mcolors.to_rgba(line.get_color())
        hollow = mcolors.to_rgba(line.get_markerfacecolor()) != colour
        out.append((container.get_label(), colour,
                    (line.get_linestyle(), line.get_marker(), hollow),
                    list(line.get_xdata())))
    return out


@pytest.mark.parametrize("n", [2, 5, 10])
def test_every_panel_has_a_legend_of_the_series_it_draws(n):
    methods = [f"method_{k}" for k in range(n)]
    fig = chart(_table(methods, missing={(methods[-1], 0.01)}))
    try:
        assert len(fig.axes) == len(TOLERANCES)
        for ax, tol in zip(fig.axes, TOLERANCES, strict=True):
            series = _series(ax)
            drawn = [m for m in methods if (m, tol) != (methods[-1], 0.01)]
            assert [s[0] for s in series] == drawn
            legend = ax.get_legend()
            assert legend is not None, ax.get_title()
            assert [t.get_text() for t in legend.get_texts()] == drawn
            for a, b in itertools.combinations(series, 2):
                assert (a[1], a[2]) != (b[1], b[2]), (a[0], b[0])  # not both alike
                if len(series) <= 7:  # apart by colour, and by style alone in greyscale
                    assert a[1] != b[1] and a[2] != b[2], (a[0], b[0])
                assert not set(a[3]) & set(b[3]), (a[0], b[0])  # no point on another
    finally:
        plt.close(fig)
