"""The end of a run: final map correction, the three trajectories, metrics and the results folder.

Results folder (every file is written even when the run was interrupted, for the frames processed):

| file | what |
|---|---|
| `config.json` | the fully resolved config of the run (feed it back with `--config` to repeat the run) |
| `trajectory_vo.{kitti,tum}.txt` | the stereo VO alone, SE(3) |
| `trajectory_online.{kitti,tum}.txt` | the map's agent pose at each frame as the run went (planar) |
| `trajectory_corrected.{kitti,tum}.txt` | the final corrected map at every frame: vertex pose ∘ the frame's offset |
| `trajectory_neural.{kitti,tum}.txt` | the networks' own estimate: unwrapped place-bump position and HD heading |
| `ground_truth.kitti.txt` | the dataset's ground truth for the frames used, rebased to the first of them |
| `frames.csv` | per frame: VO status, motion given to the engine, view cell, injection, vertex, loop closures |
| `map.bin`, `map.g2o` | the corrected experience map (versioned save file; g2o pose graph) |
| `metrics.json` | sizes, loop closures, timing per stage and, with ground truth, ATE 2-D/3-D and t_rel/r_rel |
| `cognitive_map.png`, `neural_state_NNNNNN.png`, `rate_maps.png` | figures (see `plots.py`) |

Every trajectory is in the KITTI camera frame of the first processed frame (x right, y down, z forward);
planar estimates are level at height 0. Metrics use `hippo_nav.metrics`: ATE after rigid (SE(3)) Umeyama
alignment, in 3-D and projected on the ground plane (2-D); relative errors with the KITTI devkit protocol
over the devkit's lengths (100–800 m) that fit the trajectory, else over 1/4, 1/2 and 3/4 of its length
(the lengths used are written with the numbers).
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hippo_nav.io import write_kitti_poses, write_tum
from hippo_nav.metrics import KITTI_SEGMENT_LENGTHS_M, ate_rmse, relative_errors_kitti, trajectory_distances_m
from hippo_nav.pipeline.config import resolved_config_dict
from hippo_nav.pipeline.pipeline import STAGES, RunResult, se2_compose
from hippo_nav.synthetic import planar_poses

if TYPE_CHECKING:
    from hippo_nav.pipeline.pipeline import Pipeline

log = logging.getLogger("hippo_nav.pipeline")


def _poses_from_planar(xy_yaw: np.ndarray) -> np.ndarray:
    return planar_poses(xy_yaw[:, 0], xy_yaw[:, 1], xy_yaw[:, 2])


def correct_map(pipeline: Pipeline) -> dict[str, Any]:
    """Run the configured final correction; returns its report (empty when disabled or no loop)."""
    cfg = pipeline.config.correction
    export = pipeline.map.export()
    if cfg.method == "none" or not np.asarray(export["link_is_loop"]).any():
        return {"method": "none", "reason": "disabled" if cfg.method == "none" else "no loop closure"}
    if cfg.method == "relaxation":
        report = pipeline.map.correct("relaxation", passes=cfg.relaxation_passes, gain=cfg.relaxation_gain)
    else:
        report = pipeline.map.correct(
            "least_squares",
            initialization="current",
            robust_loss=cfg.robust_loss,
            robust_scale_chi2=cfg.robust_scale_chi2,
            max_iterations=cfg.max_iterations,
        )
    return {"method": cfg.method, **{k: v for k, v in report.items()}}


def corrected_track(record: Any, vertex_poses: np.ndarray) -> np.ndarray:
    """(n, 3) planar pose of every frame after correction: its vertex's corrected pose ∘ its offset.
    Frames without a vertex (never, unless relocalising) keep their online pose."""
    vertex = np.asarray(record.vertex)
    offset = np.asarray(record.vertex_from_agent)
    online = np.asarray(record.online_pose)
    track = online.copy()
    ok = (vertex >= 0) & np.isfinite(offset).all(axis=1)
    if ok.any():
        track[ok] = se2_compose(vertex_poses[vertex[ok]], offset[ok])
    return track


def _segment_lengths(gt: np.ndarray) -> tuple[float, ...]:
    total = float(trajectory_distances_m(gt)[-1])
    fitting = tuple(float(length) for length in KITTI_SEGMENT_LENGTHS_M if length < total)
    if fitting:
        return fitting
    # Too short for the devkit's lengths (e.g. the 51-frame KITTI excerpts): quarters of the path.
    return tuple(round(total * f, 1) for f in (0.25, 0.5, 0.75) if total * f > 1.0)


def _clean(value: Any) -> Any:
    """JSON-safe: NaN/inf → None, numpy scalars → Python."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def trajectory_errors(gt: np.ndarray, estimates: dict[str, np.ndarray]) -> dict[str, Any]:
    """ATE (3-D and 2-D, SE(3)-aligned) and KITTI relative errors of each estimate against `gt`."""
    lengths = _segment_lengths(gt)
    step = max(1, min(10, len(gt) // 20))
    out: dict[str, Any] = {"segment_lengths_m": list(lengths), "segment_step_frames": step}
    for name, est in estimates.items():
        entry: dict[str, Any] = {
            "ate_3d_m": ate_rmse(gt, est, planar=False, align="se3"),
            "ate_2d_m": ate_rmse(gt, est, planar=True, align="se3"),
        }
        if lengths:
            rel = relative_errors_kitti(gt, est, lengths=lengths, step=step)
            entry.update(
                t_rel_percent=rel["t_rel_percent"],
                r_rel_deg_per_100m=rel["r_rel_deg_per_100m"],
                segments=rel["segments"],
            )
        out[name] = entry
    return out


def _timing(record: Any, extra_s: dict[str, float]) -> dict[str, Any]:
    n = len(record)
    per_stage = {s: float(np.sum(record.stage_s[s])) for s in STAGES}
    frame_total = sum(per_stage.values())
    return {
        "frames": n,
        "per_frame_ms": {s: 1e3 * v / max(n, 1) for s, v in per_stage.items()},
        "share_of_frame": {s: v / frame_total if frame_total > 0 else None for s, v in per_stage.items()},
        "frames_per_s": n / frame_total if frame_total > 0 else None,
        "frames_per_s_without_image_loading": n / (frame_total - per_stage["load"])
        if frame_total > per_stage["load"]
        else None,
        **{f"{k}_s": v for k, v in extra_s.items()},
    }


def _write_frames_csv(path: Path, record: Any) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "frame", "timestamp_s", "vo_status", "motion_flag", "yaw_rate_rad_s", "speed_m_s",
                "view_cell", "view_status", "view_difference", "injection_strength", "heading_rad",
                "place_code_x_rad", "place_code_y_rad", "vertex", "vertex_created", "loop_closure",
            ]
        )  # fmt: skip
        for i in range(len(record)):
            loop = record.loop_closure[i]
            w.writerow(
                [
                    record.frame_index[i],
                    f"{record.timestamp_s[i]:.6f}",
                    record.vo_status[i],
                    record.motion_flag[i],
                    f"{record.yaw_rate_rad_s[i]:.6g}",
                    f"{record.speed_m_s[i]:.6g}",
                    record.view_cell[i],
                    record.view_status[i],
                    f"{record.view_difference[i]:.4f}",
                    f"{record.injection_strength[i]:.4g}",
                    f"{record.heading_rad[i]:.6f}",
                    f"{record.place_code_rad[i][0]:.6f}",
                    f"{record.place_code_rad[i][1]:.6f}",
                    record.vertex[i],
                    int(record.vertex_created[i]),
                    "" if loop is None else f"{loop[0]}->{loop[1]}",
                ]
            )


def finish_run(
    pipeline: Pipeline, out_dir: str | Path | None, interrupted: bool, stopped_by: str | None = None
) -> RunResult:
    """Correct the map, build the trajectories and metrics, and write the results folder."""
    record = pipeline.record
    n = len(record)
    clock = time.perf_counter()
    correction = correct_map(pipeline)
    correction_s = time.perf_counter() - clock

    export = {k: np.asarray(v) for k, v in pipeline.map.export().items()}
    vo = np.stack(record.vo_world_from_camera)
    online = _poses_from_planar(np.asarray(record.online_pose))
    corrected = _poses_from_planar(corrected_track(record, export["poses"]))
    place = np.asarray(record.place_position_m)
    neural = planar_poses(place[:, 0], place[:, 1], np.asarray(record.heading_rad))
    estimates = {"vo": vo, "online": online, "corrected": corrected, "neural": neural}

    gt = pipeline.dataset.ground_truth()
    if gt is not None:
        gt = np.asarray(gt)[:n]
        gt = np.linalg.inv(gt[0]) @ gt

    loops = [c for c in record.loop_closure if c is not None]
    statuses, counts = np.unique(record.vo_status, return_counts=True)
    metrics: dict[str, Any] = {
        "sequence": pipeline.dataset_name,
        "note": getattr(pipeline.dataset, "note", ""),
        "frames": n,
        "frames_requested": len(pipeline.dataset),
        "interrupted": interrupted,
        "stopped_by_error": stopped_by,
        "seed": pipeline.config.seed,
        "lesioned": list(pipeline.engine.config.lesioned),
        "distance_vo_m": float(trajectory_distances_m(vo)[-1]),
        "view_cells": len(pipeline.views),
        "familiar_view_frames": int(sum(s == "familiar" for s in record.view_status)),
        "injected_frames": int(sum(s > 0 for s in record.injection_strength)),
        "vertices": len(export["poses"]),
        "links": len(export["links"]),
        "loop_closures": len(loops),
        "loop_closure_frames": [
            record.frame_index[i] for i, c in enumerate(record.loop_closure) if c is not None
        ],
        "vo_status_counts": {str(s): int(c) for s, c in zip(statuses, counts)},
        "motion_flags": int(sum(f != "ok" for f in record.motion_flag)),
        "correction": correction,
    }
    if gt is not None:
        metrics["distance_gt_m"] = float(trajectory_distances_m(gt)[-1])
        metrics["errors"] = trajectory_errors(gt, estimates)

    result = RunResult(
        name=pipeline.dataset_name,
        record=record,
        metrics=metrics,
        vo_world_from_camera=vo,
        online_world_from_camera=online,
        corrected_world_from_camera=corrected,
        neural_world_from_camera=neural,
        ground_truth=gt,
        map_export=export,
        interrupted=interrupted,
    )
    if out_dir is None:
        metrics["timing"] = _timing(record, {"correction": correction_s})
        return result

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    clock = time.perf_counter()
    resolved = resolved_config_dict(pipeline.config)
    resolved.update(_frontend_resolved(pipeline))
    (out / "config.json").write_text(json.dumps(resolved, indent=2) + "\n")
    times = np.asarray(record.timestamp_s)
    for name, poses in estimates.items():
        write_kitti_poses(out / f"trajectory_{name}.kitti.txt", poses)
        write_tum(out / f"trajectory_{name}.tum.txt", times, poses)
    if gt is not None:
        write_kitti_poses(out / "ground_truth.kitti.txt", gt)
        write_tum(out / "ground_truth.tum.txt", times, gt)
    _write_frames_csv(out / "frames.csv", record)
    if pipeline.config.output.save_map:
        pipeline.map.save(out / "map.bin")
        pipeline.map.write_g2o(out / "map.g2o")
    write_s = time.perf_counter() - clock
    metrics["timing"] = _timing(record, {"correction": correction_s, "write": write_s})
    # Written before the figures too, so an interrupt while plotting still leaves the metrics.
    (out / "metrics.json").write_text(json.dumps(_clean(metrics), indent=2) + "\n")
    figures_s = 0.0
    if pipeline.config.output.figures:
        from hippo_nav.pipeline.plots import write_run_figures

        clock = time.perf_counter()
        try:
            written = write_run_figures(result, out, pipeline.config.output.rate_map_bin_m)
            metrics["figures"] = [p.name for p in written]
        except KeyboardInterrupt:
            log.warning("figures interrupted; the other results are written")
            metrics["figures"] = []
        figures_s = time.perf_counter() - clock
    metrics["timing"] = _timing(record, {"correction": correction_s, "write": write_s, "figures": figures_s})
    (out / "metrics.json").write_text(json.dumps(_clean(metrics), indent=2) + "\n")
    result.out_dir = out
    return result


def _frontend_resolved(pipeline: Pipeline) -> dict[str, Any]:
    from hippo_nav.pipeline.frontend import resolved_frontend_params

    return resolved_frontend_params(pipeline.odometry, pipeline.views)
