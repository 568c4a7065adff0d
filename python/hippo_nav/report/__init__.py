"""Reports over many runs (`hippo-nav report DIR …`): sweep folders and plain `hippo-nav run` folders alike.

- `collect.py`: the runs as rows — what each varies and its numbers (`METRICS`, and three measured from
  its files: the place-bump width, the 1-D theory's width from its module widths, the path-integration error);
- `tables.py`: `table.csv`/`table.md` (one row per run), `groups.csv` and the statistics over seeds (mean,
  std, n, 95 % CI);
- `figures.py`: a metric per configuration with the seeds as points, the trajectories of one sequence
  overlaid, a metric against one swept key;
- `lesions.py`: `lesions.md`, the lesion conditions against the order the 1-D theory predicts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from hippo_nav._core import HippoNavError
from hippo_nav.report.collect import RunRow, collect_runs
from hippo_nav.report.tables import axis_columns, stats, value_columns, write_tables

__all__ = ["Report", "RunRow", "collect_runs", "stats", "write_report"]


@dataclass(frozen=True)
class Report:
    runs: int
    files: list[Path]
    rows: list[RunRow]


def write_report(
    dirs: Sequence[str | Path],
    out: str | Path,
    *,
    metric: str = "ate_2d_corrected_m",
    key: str | None = None,
    sequence: str | None = None,
    figures: bool = True,
) -> Report:
    """Read the runs under `dirs` and write the tables, `lesions.md` (when the runs differ in lesions) and
    the figures into `out`."""
    from hippo_nav.report import figures as plots
    from hippo_nav.report.lesions import lesion_comparison

    rows = collect_runs(dirs)
    keys = axis_columns(rows)
    if metric not in value_columns(rows):
        raise HippoNavError(f"--metric {metric}: no run has it; choose from {', '.join(value_columns(rows))}")
    if key is not None and key not in keys:
        raise HippoNavError(f"--key {key}: not a key the runs vary; they vary {', '.join(keys) or 'nothing'}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = write_tables(rows, out)
    lesions = lesion_comparison(rows, keys)
    if lesions is not None:
        (out / "lesions.md").write_text(lesions, encoding="utf-8")
        files.append(out / "lesions.md")
    if figures:
        made = [
            plots.metric_by_configuration(rows, keys, metric, out),
            plots.trajectories(rows, keys, sequence, out),
        ]
        chosen = key or plots.swept_key(rows, keys)
        if chosen is not None:
            made.append(plots.response(rows, keys, metric, chosen, out))
        files += [p for p in made if p is not None]
    return Report(len(rows), files, rows)
