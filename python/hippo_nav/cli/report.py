"""`hippo-nav report`: one table (CSV, Markdown), statistics over seeds and figures over sweeps and runs."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "one table (CSV, Markdown), statistics over seeds and figures from sweep and run folders"
DESCRIPTION = (
    "Reads sweep folders (OUT/runs/*/manifest.json) and plain `hippo-nav run` folders (any "
    "folder holding metrics.json, searched below each DIR) and writes into --out: table.csv and table.md "
    "(one row per run: what it varies, its metrics and timings), groups.csv and the grouped statistics "
    "over seeds in table.md (mean, std, n, 95 %% confidence interval), figures (ATE per configuration with "
    "the seeds as points, the trajectories of one sequence overlaid, a metric against one swept key) and, "
    "when the runs differ in lesions, lesions.md (place-bump width and path-integration error per lesion "
    "against the 1-D theory's order). A run whose files are malformed (metrics.json, manifest.json, "
    "config.json, bump_table.csv, trajectories) is left out with one warning naming the file and the field, "
    "and listed at the end of table.md; the report fails only when no run can be read."
)


def add_arguments(report: argparse.ArgumentParser) -> None:
    report.add_argument("dirs", nargs="+", metavar="DIR", help="sweep or run folders")
    report.add_argument(
        "--out", default=None, help="report folder (default: DIR/report for one DIR, else runs/report)"
    )
    report.add_argument(
        "--metric", default="ate_2d_corrected_m", help="the metric of the figures (a column of table.csv)"
    )
    report.add_argument(
        "--key",
        default=None,
        help="the swept key of the response figure (default: the first with several values)",
    )
    report.add_argument(
        "--sequence", default=None, help="the sequence whose trajectories are overlaid (default: the first)"
    )
    report.add_argument("--no-figures", action="store_true", help="tables only")


def command(args: argparse.Namespace) -> int:
    from hippo_nav._core import HippoNavError
    from hippo_nav.report import write_report

    out = args.out or (str(Path(args.dirs[0]) / "report") if len(args.dirs) == 1 else "runs/report")
    try:
        written = write_report(
            args.dirs,
            out,
            metric=args.metric,
            key=args.key,
            sequence=args.sequence,
            figures=not args.no_figures,
        )
    except OSError as err:  # the file and the reason, not the system's "[Errno …]"
        raise HippoNavError(f"{err.filename or out}: {err.strerror or err}") from None
    skipped = f" ({len(written.skipped)} skipped: see the warnings above)" if written.skipped else ""
    print(f"{written.runs} runs{skipped}; wrote {', '.join(p.name for p in written.files)} into {out}")
    return 0
