"""The report's tables: one row per run (`table.csv`, `table.md`) and statistics over seeds (`groups.csv`).

A *configuration* is a run's axes without its seed: the runs of one configuration with different seeds are
one group, summarised per number as mean, sample standard deviation (n − 1), n and the half-width of the
95 % confidence interval of the mean, `t(0.975, n − 1) · std / √n` (Student's t: a handful of seeds is not
a normal sample). A group of one run has no spread (std and CI empty).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav.io.atomic import open_atomic, write_text
from hippo_nav.report.collect import MEASURED, METRICS, TIMINGS, RunRow, SkippedRun

_T_975 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
          2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
          2.045, 2.042]  # fmt: skip
"""Student's t quantile 0.975 for 1 … 30 degrees of freedom."""


def t_975(dof: int) -> float:
    """Student's t quantile 0.975 (the table to 30 degrees of freedom; beyond, the Cornish–Fisher expansion
    around the normal quantile, within 0.001 of the exact value there)."""
    if dof < 1:
        raise ValueError("a t quantile needs at least one degree of freedom")
    if dof <= len(_T_975):
        return _T_975[dof - 1]
    z = 1.959964
    return z + (z**3 + z) / (4 * dof) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * dof**2)


@dataclass(frozen=True)
class Stats:
    mean: float | None
    std: float | None
    n: int
    ci95: float | None

    def text(self, digits: int = 3) -> str:
        if self.mean is None:
            return "–"
        if self.ci95 is None:
            return f"{self.mean:.{digits}f} (n {self.n})"
        return f"{self.mean:.{digits}f} ± {self.ci95:.{digits}f} (n {self.n})"


def stats(values: Sequence[float | None]) -> Stats:
    """Mean, std, n and 95 % CI half-width of the values that are numbers (module doc)."""
    numbers = np.array([v for v in values if v is not None], dtype=np.float64)
    n = len(numbers)
    if n == 0:
        return Stats(None, None, 0, None)
    if n == 1:
        return Stats(float(numbers[0]), None, 1, None)
    # In units of the largest: a number near the float's limit (a run that diverged) squares to infinity.
    scale = float(np.abs(numbers).max()) or 1.0
    unit = numbers / scale
    std = float(np.std(unit, ddof=1)) * scale
    return Stats(float(unit.mean()) * scale, std, n, t_975(n - 1) * std / math.sqrt(n))


def value_columns(rows: Sequence[RunRow]) -> list[str]:
    """The numbers of the runs, in the order of `METRICS`, the measured ones and the timings; a column no
    run has a value for is left out."""
    names = [name for name, _ in METRICS] + [*MEASURED, *TIMINGS]
    return [n for n in names if any(r.values.get(n) is not None for r in rows)]


def axis_columns(rows: Sequence[RunRow]) -> list[str]:
    """The axes that differ between runs (and the seed whenever a run has one), in first-seen order."""
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row.axes if k not in keys]
    varying = [k for k in keys if len({_key(r.axes.get(k)) for r in rows}) > 1 and k != "seed"]
    return varying + (["seed"] if any(r.axes.get("seed") is not None for r in rows) else [])


def _key(value: Any) -> str:
    return repr(value)


@dataclass
class Group:
    """The runs of one configuration (their axes but the seed equal)."""

    axes: dict[str, Any]
    rows: list[RunRow]

    def label(self) -> str:
        return ", ".join(f"{k}={_cell(v)}" for k, v in self.axes.items()) or "all runs"

    def stats(self, column: str) -> Stats:
        return stats([r.values.get(column) for r in self.rows if r.status == "done"])


def groups(rows: Sequence[RunRow], keys: Sequence[str]) -> list[Group]:
    """The runs by configuration (`keys` without the seed), in first-seen order."""
    config_keys = [k for k in keys if k != "seed"]
    found: dict[tuple[str, ...], Group] = {}
    for row in rows:
        ident = tuple(_key(row.axes.get(k)) for k in config_keys)
        found.setdefault(ident, Group({k: row.axes.get(k) for k in config_keys}, [])).rows.append(row)
    return list(found.values())


def _cell(value: Any, digits: int = 4) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def write_tables(rows: Sequence[RunRow], out: Path, skipped: Sequence[SkippedRun] = ()) -> list[Path]:
    """table.csv, groups.csv and table.md (runs, then the statistics over seeds, then the runs `skipped`)
    into `out`, each written atomically (`hippo_nav.io.atomic`)."""
    keys = axis_columns(rows)
    columns = value_columns(rows)
    table_csv = out / "table.csv"
    with open_atomic(table_csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["run_id", "sweep", "status", *keys, *columns, "error", "folder"])
        for r in rows:
            w.writerow(
                [r.run_id, r.sweep, r.status, *(_cell(r.axes.get(k), 12) for k in keys),
                 *(_cell(r.values.get(c), 12) for c in columns), r.error or "", str(r.folder)]
            )  # fmt: skip
    found = groups(rows, keys)
    groups_csv = out / "groups.csv"
    with open_atomic(groups_csv, "w", newline="") as f:
        w = csv.writer(f)
        config_keys = [k for k in keys if k != "seed"]
        stat_names = [f"{c}_{s}" for c in columns for s in ("mean", "std", "n", "ci95")]
        w.writerow([*config_keys, "runs", "failed", *stat_names])
        for g in found:
            cells: list[str] = []
            for c in columns:
                s = g.stats(c)
                cells += [_cell(s.mean, 12), _cell(s.std, 12), str(s.n), _cell(s.ci95, 12)]
            failed = sum(r.status != "done" for r in g.rows)
            w.writerow([*(_cell(g.axes.get(k), 12) for k in config_keys), len(g.rows), failed, *cells])
    table_md = out / "table.md"
    write_text(table_md, _markdown(rows, keys, columns, found, skipped))
    return [table_csv, groups_csv, table_md]


def _markdown(
    rows: Sequence[RunRow],
    keys: list[str],
    columns: list[str],
    found: list[Group],
    skipped: Sequence[SkippedRun] = (),
) -> str:
    lines = [f"# Runs ({len(rows)})", ""]
    head = ["run", "status", *keys, *columns]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r.run_id, r.status if not r.error else f"{r.status}: {r.error}"]
        cells += [_cell(r.axes.get(k)) for k in keys] + [_cell(r.values.get(c)) for c in columns]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    lines += [
        "",
        f"# Over seeds: mean ± 95 % confidence interval (n) of the runs done, {len(found)} configurations",
        "",
    ]
    head = ["configuration", "runs", *columns]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for g in found:
        cells = [g.label(), str(len(g.rows))] + [g.stats(c).text(_digits(c)) for c in columns]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    if skipped:
        # A report read later must say which runs it left out, not only the warnings of the day it was made.
        lines += ["", f"# Skipped runs ({len(skipped)}): a file is malformed; not in any table above", ""]
        lines += [f"- {s.reason}".replace("\n", " ") for s in skipped]
    return "\n".join(lines) + "\n"


def _digits(column: str) -> int:
    counts = ("frames", "loop_closures", "true_closures", "view_cells", "vertices")
    return 4 if column.endswith("_rad") else 1 if column in counts else 3
