"""Reports over many runs (`hippo-nav report DIR …`): sweep folders and plain `hippo-nav run` folders alike.

- `collect.py`: the runs as rows — what each varies and its numbers (`METRICS`, and three measured from
  its files: the place-bump width, the 1-D theory's width from its module widths, the path-integration error);
- `tables.py`: `table.csv`/`table.md` (one row per run), `groups.csv` and the statistics over seeds (mean,
  std, n, 95 % CI);
- `figures.py`: a metric per configuration with the seeds as points, the trajectories of one sequence
  overlaid, a metric against one swept key;
- `lesions.py`: `lesions.md`, the lesion conditions against the order the 1-D theory predicts.
- `neural.py`: one run's networks from its recording (`hippo-nav figures --run DIR`): rate maps on the true
  positions and folded onto each module's spacing, each module's decoded phase and its circular error.

A run whose files are malformed is left out with one warning and listed in `table.md` (`collect.py`'s module
doc); every file is written through `hippo_nav.io.atomic` (whole or not at all, never through a link planted
at its name).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hippo_nav._core import HippoNavError
from hippo_nav.io.atomic import output_folder, write_text
from hippo_nav.report.collect import RunFileError, RunRow, SkippedRun, collect, collect_runs
from hippo_nav.report.tables import axis_columns, stats, value_columns, write_tables

__all__ = [
    "Report",
    "RunFileError",
    "RunRow",
    "SkippedRun",
    "collect",
    "collect_runs",
    "stats",
    "write_report",
]


@dataclass(frozen=True)
class Report:
    runs: int
    files: list[Path]
    rows: list[RunRow]
    skipped: list[SkippedRun] = field(default_factory=list)
    """The runs left out because a file of theirs is malformed (each also logged as a warning)."""


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
    the figures into `out`. A run with a malformed file is skipped (`Report.skipped`, module doc); when no
    run is readable, a `HippoNavError` says why the first was not."""
    from hippo_nav.report import figures as plots
    from hippo_nav.report.lesions import lesion_comparison

    rows, skipped = collect(dirs)
    if not rows:
        raise HippoNavError(
            f"none of the {len(skipped)} runs found could be read; the first: {skipped[0].reason}"
        )
    keys = axis_columns(rows)
    if metric not in value_columns(rows):
        raise HippoNavError(f"--metric {metric}: no run has it; choose from {', '.join(value_columns(rows))}")
    if key is not None and key not in keys:
        raise HippoNavError(f"--key {key}: not a key the runs vary; they vary {', '.join(keys) or 'nothing'}")
    run_sequences = sorted({str(r.axes.get("sequence")) for r in rows if r.axes.get("sequence") is not None})
    if sequence is not None and sequence not in run_sequences:
        raise HippoNavError(
            f"--sequence {sequence}: no run is of it; the runs are of {', '.join(run_sequences) or 'the demo loop'}"
        )
    out = output_folder(out, "the report")
    files = write_tables(rows, out, skipped)
    lesions = lesion_comparison(rows, keys)
    if lesions is not None:
        files.append(write_text(out / "lesions.md", lesions))
    if figures:
        made = [
            plots.metric_by_configuration(rows, keys, metric, out),
            plots.trajectories(rows, keys, sequence, out),
        ]
        chosen = key or plots.swept_key(rows, keys)
        if chosen is not None:
            made.append(plots.response(rows, keys, metric, chosen, out))
        files += [p for p in made if p is not None]
    return Report(len(rows), files, rows, skipped)
