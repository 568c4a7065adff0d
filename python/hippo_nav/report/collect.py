"""The runs a report reads, as rows: what each run varies (`axes`) and its numbers (`values`).

A run is a folder holding `metrics.json`: a sweep's `runs/<id>/` (with `manifest.json`: its axes, status,
wall time and peak memory) or a plain `hippo-nav run` folder, whose axes are read from what it wrote: the
sequence, the seed and the lesions from `metrics.json`, and every config value that differs from the
defaults (`config.json` against `PipelineConfig()`) as an override. A sweep run without `metrics.json`
(failed before its first frame, or never finished) is a row too, with its status and error.

`METRICS` is the one list of the numbers a row carries: the name of the column and where it comes from.
Three are measured from the run's files rather than read: `place_sigma_rad` (the CA3 place bump's width,
mean of its two axes, averaged over the snapshot frames of `bump_table.csv`), `theory_sigma_rad` (the
1-D theory's fused width, `(Σ_m 1/σ_m²)^(−1/2)`, from the same frames' grid-module widths, lesioned modules
absent) and `pi_error_2d_m` (path integration: the place code's trajectory against the odometry it
integrates, ATE on the ground plane after SE(3) alignment, so the odometry's own error drops out).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav._defaults import dotted
from hippo_nav.sweep.manifest import MANIFEST, RUNS_DIR, read_manifest

LESION_MODULES = ("ventral", "intermediate", "dorsal")


def _at(*path: str) -> Callable[[dict[str, Any]], Any]:
    def get(metrics: dict[str, Any]) -> Any:
        value: Any = metrics
        for key in path:
            if not isinstance(value, dict):
                return None
            value = value.get(key)
        return value

    return get


METRICS: list[tuple[str, Callable[[dict[str, Any]], Any]]] = [
    ("frames", _at("frames")),
    ("ate_2d_vo_m", _at("errors", "vo", "ate_2d_m")),
    ("ate_2d_online_m", _at("errors", "online", "ate_2d_m")),
    ("ate_2d_corrected_m", _at("errors", "corrected", "ate_2d_m")),
    ("ate_2d_neural_m", _at("errors", "neural", "ate_2d_m")),
    ("ate_3d_vo_m", _at("errors", "vo", "ate_3d_m")),
    ("ate_3d_corrected_m", _at("errors", "corrected", "ate_3d_m")),
    ("t_rel_corrected_percent", _at("errors", "corrected", "t_rel_percent")),
    ("loop_closures", _at("loop_closures")),
    ("true_closures", _at("closure_quality", "true_closures")),
    ("precision", _at("closure_quality", "precision")),
    ("recall", _at("closure_quality", "recall")),
    ("view_cells", _at("view_cells")),
    ("vertices", _at("vertices")),
    ("frames_per_s", _at("timing", "frames_per_s")),
]
"""Numbers read from `metrics.json`: (column, getter)."""
MEASURED = ("place_sigma_rad", "theory_sigma_rad", "pi_error_2d_m")
"""Numbers measured from a run's files (module doc)."""
TIMINGS = ("wall_s", "peak_rss_mb")
"""From the manifest (a plain run: `metrics.json`'s timing)."""


@dataclass
class RunRow:
    """One run: its folder, id, sweep, status, what it varies and its numbers."""

    folder: Path
    run_id: str
    sweep: str
    status: str
    error: str | None
    axes: dict[str, Any]
    values: dict[str, float | None] = field(default_factory=dict)


def find_run_folders(dirs: Sequence[str | Path]) -> list[tuple[Path, str]]:
    """(run folder, sweep or parent name) of every run under `dirs`: sweep folders, plain run folders and
    folders holding either, in a stable order; a folder is read once even when named twice."""
    found: dict[Path, str] = {}
    seen: set[Path] = set()
    for given in dirs:
        root = Path(given)
        if not root.is_dir():
            raise HippoNavError(f"{given}: no such folder (give sweep folders or hippo-nav run folders)")
        candidates = {p.parent for p in root.rglob("metrics.json")} | {p.parent for p in root.rglob(MANIFEST)}
        # A sweep's runs in the order of its space (the lesion conditions as given); other folders by name.
        ranks = {f.parent: _run_order(f.parent.parent) for f in candidates if f.parent.name == RUNS_DIR}
        for folder in sorted(
            candidates,
            key=lambda f: (
                str(f.parent),
                ranks.get(f.parent, {}).get(f.name, len(ranks.get(f.parent, {}))),
                f.name,
            ),
        ):
            if folder.resolve() in seen:
                continue
            seen.add(folder.resolve())
            sweep = folder.parent.parent.name if folder.parent.name == RUNS_DIR else folder.parent.name
            found[folder] = sweep or root.name
    if not found:
        raise HippoNavError(
            f"{', '.join(map(str, dirs))}: no runs found (no metrics.json or manifest.json below)"
        )
    return list(found.items())


def _run_order(sweep: Path) -> dict[str, int]:
    """A sweep's run ids in the order of its space (`sweep.json`)."""
    data = _read_json(sweep / "sweep.json") or {}
    runs = data.get("runs")
    return (
        {str(r.get("run_id")): i for i, r in enumerate(runs) if isinstance(r, dict)}
        if isinstance(runs, list)
        else {}
    )


def collect_runs(dirs: Sequence[str | Path]) -> list[RunRow]:
    """Every run under `dirs` as a row (module doc)."""
    return [_row(folder, sweep) for folder, sweep in find_run_folders(dirs)]


def _row(folder: Path, sweep: str) -> RunRow:
    manifest = read_manifest(folder)
    metrics = _read_json(folder / "metrics.json")
    if manifest is not None:
        axes = dict(manifest.get("axes") or {})
        status = str(manifest.get("status"))
        error = manifest.get("error")
        run_id = str(manifest.get("run_id", folder.name))
    else:
        axes = _plain_axes(folder, metrics or {})
        status = "interrupted" if (metrics or {}).get("interrupted") else "done"
        error = (metrics or {}).get("stopped_by_error")
        run_id = folder.name
    row = RunRow(folder, run_id, sweep, status, error, axes)
    timing = (metrics or {}).get("timing") or {}
    for name, get in METRICS:
        row.values[name] = _number(get(metrics)) if metrics is not None else None
    row.values.update(bump_widths(folder / "bump_table.csv"))
    row.values["pi_error_2d_m"] = path_integration_error_m(folder)
    row.values["wall_s"] = _number((manifest or {}).get("wall_s", timing.get("wall_s")))
    row.values["peak_rss_mb"] = _number((manifest or {}).get("peak_rss_mb", timing.get("peak_rss_mb")))
    return row


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def lesion_condition(lesioned: Sequence[bool]) -> str:
    """`[False, False, True]` (the engine's order: ventral, intermediate, dorsal) → `dorsal`; none → `none`."""
    names = [name for name, off in zip(LESION_MODULES, lesioned, strict=False) if off]
    return "+".join(names) or "none"


def _plain_axes(folder: Path, metrics: dict[str, Any]) -> dict[str, Any]:
    """A plain run's axes from its files: sequence, lesion, the config values that differ from the
    defaults, seed."""
    from hippo_nav.system.config import PipelineConfig, resolved_config_dict

    axes: dict[str, Any] = {
        "sequence": metrics.get("sequence"),
        "lesion": lesion_condition(metrics.get("lesioned") or []),
    }
    config = _read_json(folder / "config.json")
    if config is not None:
        defaults = dotted(resolved_config_dict(PipelineConfig()))
        for key, value in dotted(config).items():
            # The seed and the lesions are axes of their own (vo.seed follows the seed).
            own_axis = key in ("seed", "vo.seed") or key.startswith("lesions.")
            if key in defaults and value != defaults[key] and not own_axis:
                axes[key] = value
    axes["seed"] = metrics.get("seed")
    return axes


def bump_widths(path: Path) -> dict[str, float | None]:
    """`place_sigma_rad` and `theory_sigma_rad` of a run's `bump_table.csv` (module doc)."""
    from hippo_nav.theory import fused_sigma

    empty: dict[str, float | None] = {"place_sigma_rad": None, "theory_sigma_rad": None}
    try:
        with path.open(newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except OSError:
        return empty
    place: list[float] = []
    theory: list[float] = []
    for frame in sorted({r["frame"] for r in rows}):
        at = [r for r in rows if r["frame"] == frame]
        for r in at:
            if r["what"] == "place":
                place.append(0.5 * (float(r["sigma_x_rad"]) + float(r["sigma_y_rad"])))
        modules: dict[str, list[float]] = {}
        for r in at:
            if r["what"] == "grid":
                modules.setdefault(r["k"], []).append(
                    0.5 * (float(r["sigma_x_rad"]) + float(r["sigma_y_rad"]))
                )
        if modules:
            theory.append(fused_sigma([float(np.mean(widths)) for widths in modules.values()]))
    return {
        "place_sigma_rad": float(np.mean(place)) if place else None,
        "theory_sigma_rad": float(np.mean(theory)) if theory else None,
    }


def path_integration_error_m(folder: Path) -> float | None:
    """ATE 2-D of the place code's trajectory against the odometry's (module doc); None without them."""
    from hippo_nav.io import DatasetError, read_kitti_poses
    from hippo_nav.metrics import ate_rmse

    try:
        odometry = read_kitti_poses(folder / "trajectory_vo.kitti.txt")
        neural = read_kitti_poses(folder / "trajectory_neural.kitti.txt")
        return _number(ate_rmse(odometry, neural, planar=True, align="se3"))
    except (OSError, DatasetError, HippoNavError):
        return None
