"""Print the table of a `make bench` run: `python tests/benchmarks/table.py BENCH.json`.

BENCH.json is pytest-benchmark's `--benchmark-json` output. One row per benchmark: its median time and
the ratios its `extra_info` measured against a baseline in the same run (speed-ups, frames per second
against the 10 Hz camera), and for the whole pipeline each stage's share of a frame. Not a test.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

RATIOS = (
    "speedup",
    "frames_per_s",
    "frames_per_s_previous",
    "cpu_ratio",
    "cpu_ms_per_frame",
    "camera_period_ratio",
    "vo_over_read",
)


def _cell(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def table(report: dict) -> str:
    rows = ["| benchmark | median (ms) | ratios against the same run's baselines | stage shares of a frame |"]
    rows.append("|---|---|---|---|")
    for bench in report["benchmarks"]:
        info = bench.get("extra_info", {})
        ratios = ", ".join(f"{key} {_cell(info[key])}" for key in RATIOS if key in info)
        shares = info.get("share_of_frame") or {}
        share_text = ", ".join(f"{stage} {100 * share:.0f} %" for stage, share in shares.items() if share)
        rows.append(
            f"| {bench['fullname'].split('::')[-1]} | {1e3 * bench['stats']['median']:.2f} | "
            f"{ratios or '–'} | {share_text or '–'} |"
        )
    return "\n".join(rows)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(
            "usage: python tests/benchmarks/table.py BENCH.json (pytest --benchmark-json output)"
        )
    print(table(json.loads(Path(sys.argv[1]).read_text())))
