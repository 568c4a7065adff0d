"""The report's figures, each on its own `Figure` with an Agg canvas (no pyplot; as `pipeline/plots.py`).

- `<metric>_by_configuration.png`: the metric of every run, one column per configuration, the seeds as
  points, the mean and its 95 % confidence interval as a bar;
- `trajectories_<sequence>.png`: the corrected trajectories of one sequence, one per configuration (its
  first seed), over the ground truth, in the map frame (x forward, y left, metres; no alignment);
- `<metric>_vs_<key>.png`: the response of the metric to one swept key: mean ± 95 % CI against the key's
  values, one line per combination of the other axes, the seeds as faint points.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from hippo_nav.io.atomic import atomic_path
from hippo_nav.report.collect import RunRow
from hippo_nav.report.tables import Group, groups, stats

MAX_TRAJECTORIES = 10
DPI = 120


def _new_figure(width_in: float, height_in: float) -> Figure:
    figure = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=+-]+", "_", name)


def metric_by_configuration(
    rows: Sequence[RunRow], keys: Sequence[str], metric: str, out: Path
) -> Path | None:
    found = [g for g in groups(rows, keys) if any(r.values.get(metric) is not None for r in g.rows)]
    if not found:
        return None
    figure = _new_figure(max(5.0, 0.6 * len(found) + 2.0), 4.5)
    ax = figure.add_subplot()
    rng = np.random.default_rng(0)  # the points' sideways jitter only, fixed so figures are reproducible
    for i, group in enumerate(found):
        values = [
            r.values[metric] for r in group.rows if r.values.get(metric) is not None and r.status == "done"
        ]
        ax.scatter(
            i + rng.uniform(-0.12, 0.12, len(values)), values, s=14, color="tab:blue", alpha=0.7, zorder=3
        )
        s = group.stats(metric)
        if s.mean is not None:
            ax.errorbar(
                i, s.mean, yerr=s.ci95 or 0.0, fmt="_", color="black", markersize=18, capsize=4, zorder=4
            )
    ax.set_xticks(range(len(found)), [g.label() for g in found], rotation=30, ha="right", fontsize=7)
    ax.set_ylabel(metric)
    ax.set_title(f"{metric}: runs (points) and mean ± 95 % CI over seeds", fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    return _save(figure, out / f"{_safe(metric)}_by_configuration.png")


def trajectories(rows: Sequence[RunRow], keys: Sequence[str], sequence: str | None, out: Path) -> Path | None:
    from hippo_nav.geometry import planar_xy
    from hippo_nav.io import DatasetError, read_kitti_poses

    candidates = [r for r in rows if r.status in ("done", "interrupted")]
    sequences = [r.axes.get("sequence") for r in candidates]
    if sequence is None and sequences:
        sequence = sequences[0]
    chosen = [r for r in candidates if r.axes.get("sequence") == sequence]
    found = groups(chosen, keys)
    if not found:
        return None
    figure = _new_figure(6.5, 5.5)
    ax = figure.add_subplot()
    truth_drawn = False
    drawn = 0
    for group in found[:MAX_TRAJECTORIES]:
        row = group.rows[0]
        try:
            corrected = read_kitti_poses(row.folder / "trajectory_corrected.kitti.txt")
            truth = read_kitti_poses(row.folder / "ground_truth.kitti.txt") if not truth_drawn else None
        except (OSError, DatasetError):
            continue
        if truth is not None:
            xy = planar_xy(truth)
            ax.plot(xy[:, 0], xy[:, 1], color="black", linewidth=2.0, alpha=0.5, label="ground truth")
            truth_drawn = True
        xy = planar_xy(corrected)
        ax.plot(xy[:, 0], xy[:, 1], linewidth=1.0, label=group.label())
        drawn += 1
    if drawn == 0:  # no run has a readable trajectory: no figure (an empty one would be drawn with a warning)
        return None
    more = (
        f" (first {MAX_TRAJECTORIES} of {len(found)} configurations)" if len(found) > MAX_TRAJECTORIES else ""
    )
    name = "demo loop" if sequence is None else f"sequence {sequence}"
    ax.set_title(f"{name}: corrected trajectories, first seed of each configuration{more}", fontsize=9)
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("y left (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=6, loc="best")
    ax.grid(alpha=0.3)
    return _save(figure, out / f"trajectories_{_safe(str(sequence or 'demo'))}.png")


def swept_key(rows: Sequence[RunRow], keys: Sequence[str]) -> str | None:
    """The first swept key (not the seed) with several numeric values, else the first with several values."""
    swept = [k for k in keys if k != "seed"]
    numeric = [k for k in swept if all(_is_number(r.axes.get(k)) for r in rows)]
    chosen = numeric or swept
    return chosen[0] if chosen else None


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def response(rows: Sequence[RunRow], keys: Sequence[str], metric: str, key: str, out: Path) -> Path | None:
    others = [k for k in keys if k not in (key, "seed")]
    lines: dict[str, list[RunRow]] = {}
    for row in rows:
        if row.status == "done" and row.values.get(metric) is not None:
            label = Group({k: row.axes.get(k) for k in others}, []).label()
            lines.setdefault(label, []).append(row)
    if not lines:
        return None
    # By repr: an axis's values may be lists (`parts.closure`), which are not hashable.
    values = list({repr(v): v for v in (r.axes.get(key) for rs in lines.values() for r in rs)}.values())
    numeric = all(_is_number(v) for v in values)
    order: list[Any] = sorted(values) if numeric else values
    position = {repr(v): (float(v) if numeric else float(i)) for i, v in enumerate(order)}
    figure = _new_figure(6.5, 4.5)
    ax = figure.add_subplot()
    for label, line_rows in lines.items():
        xs, means, cis = [], [], []
        for v in order:
            at = [r.values[metric] for r in line_rows if repr(r.axes.get(key)) == repr(v)]
            if not at:
                continue
            s = stats(at)
            xs.append(position[repr(v)])
            means.append(s.mean)
            cis.append(s.ci95 or 0.0)
            ax.scatter([position[repr(v)]] * len(at), at, s=8, alpha=0.3)
        ax.errorbar(xs, means, yerr=cis, marker="o", capsize=3, label=label if len(lines) > 1 else None)
    if not numeric:
        ax.set_xticks([position[repr(v)] for v in order], [str(v) for v in order], rotation=20, fontsize=8)
    ax.set_xlabel(key)
    ax.set_ylabel(metric)
    ax.set_title(f"{metric} against {key}: mean ± 95 % CI over seeds", fontsize=9)
    if len(lines) > 1:
        ax.legend(fontsize=6)
    ax.grid(alpha=0.3)
    return _save(figure, out / f"{_safe(metric)}_vs_{_safe(key)}.png")


def _save(figure: Figure, path: Path) -> Path:
    # Through a temporary beside it (same suffix: matplotlib picks PNG by it), renamed over `path`.
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=DPI)
    return path
