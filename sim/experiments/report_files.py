"""A results database's report files, side by side: the Table 1 cells with the evidence
behind them (sim/experiments/report.py) and the paper's orderings tested on those cells
(sim/experiments/orderings.py, which reads the cells' module: this one stands above
both)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from taskcam.sim.experiments import orderings as claims
from taskcam.sim.experiments.report import (
    DIFFICULTY,
    bands_markdown,
    camera_views,
    cells,
    elevation_bands,
    failed_markdown,
    failed_trials,
    markdown,
    radius_markdown,
    radius_shares,
    step_limit,
    step_limit_markdown,
    views_markdown,
    write_csv,
)
from taskcam.sim.experiments.report_chart import write_chart


def write_report(db: str | Path, out: str | Path | None = None) -> dict[str, Any]:
    """Write ``<db stem>.md``, ``.csv`` and ``.png`` into ``out`` (default: beside the
    database), and the paper's orderings tested (sim/experiments/orderings.py) as
    ``<db stem>-orderings.md`` and ``.csv``; returns both Markdown texts and the paths."""
    db = Path(db)
    table = cells(db)
    tested = claims.orderings_in(db)
    folder = Path(out) if out is not None else db.parent
    folder.mkdir(parents=True, exist_ok=True)
    text = markdown(table)
    for extra in (failed_markdown(failed_trials(db)), step_limit_markdown(step_limit(db)),
                  radius_markdown(radius_shares(db)), bands_markdown(elevation_bands(db)),
                  views_markdown(camera_views(db))):
        if extra:
            text += "\n" + extra
    ordered = claims.markdown(tested)
    paths = {ext: folder / f"{db.stem}.{ext}" for ext in ("md", "csv", "png")}
    paths |= {f"orderings {ext}": folder / f"{db.stem}-orderings.{ext}" for ext in ("md", "csv")}
    paths["md"].write_text(text)
    write_csv(table, paths["csv"])
    write_chart(table, paths["png"], DIFFICULTY)
    paths["orderings md"].write_text(ordered)
    claims.write_csv(tested, paths["orderings csv"])
    return {"markdown": text, "orderings": ordered, "paths": paths}
