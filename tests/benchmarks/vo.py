"""The VO benchmark every VO change is judged by: all the real stereo frames and the whole-sequence renders.

    python tests/benchmarks/vo.py --data ../shared/data --renders runs/renders --out runs/vo

Rows (each VO variant on each set, measured in the same run, one after another on the same machine):
- real KITTI 06 frames 0–50 (urban), and 01 frames 0–50 (highway) as given and with its documented
  disparity offset (`vo.disparity_offset_px` 1.5 px; docs/vo.md): t_rel and r_rel over every start frame
  and the 10–50 m segments these 51 frames allow; also on the segments whose ground truth was measured
  (06's frames 0–11 are filled in with a constant motion: metrics.interpolated_steps, docs/vo.md);
- the renders of `--renders` (a KITTI root made by `hippo-nav render`; sequences 00, 02, 05, 06, 08 when
  present): VO alone, ATE 2-D and 3-D (SE(3) alignment), t_rel and r_rel over the devkit's 100–800 m
  segments (every 10th start frame, as the devkit).
Time per frame is the VO's own (`process`, images already decoded), the median of the run, as a ratio
against the first variant in the same run: absolute times on a shared machine are noise.

Variants: `frame_to_frame` (`vo.window.max_keyframes = 0`, the offset fixed, KLT's matches as they are: the VO
before the windowed refinement), `window_fixed` (`vo.window.max_keyframes = 8`, the disparity offset fixed as
configured: the VO before the self-calibration), `window_klt` (the window and the self-calibration on KLT's
matches: the VO before the warped-window refinement, `vo.refine_matches`) and `window` (the default);
`--variant NAME=JSON` adds or replaces one (a `vo` section's overrides). Where the self-calibration moved the
offset, `window_found_offset` drives the same frames with the offset it found, fixed from the first frame.

`--perturbations K` measures how far apart two equally good runs land: each variant also drives every set K
more times with the images perturbed by one gray level (each pixel +1, 0 or −1 at random, seeded by the
perturbation and the frame), which no VO should care about. The table then gives each error as the value of
the unperturbed run and the range over all K + 1 runs. A VO's whole-sequence ATE is a sum of small random
errors that a different rounding sends another way: a difference between two variants within that range is
not a difference (docs/vo.md, "How far apart equal runs land").

Writes `vo.md` (the tables of docs/vo.md) and `vo.json` under `--out`. Not a test (no assertions; pytest does
not collect it): a reproducible measurement on the shared data and the project's own renders.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from hippo_nav.datasets import KittiOdometry
from hippo_nav.datasets.base import StereoFrame
from hippo_nav.metrics import KITTI_SEGMENT_LENGTHS_M, ate_rmse, interpolated_steps, relative_errors_kitti
from hippo_nav.vo import StereoOdometry, VoParams

SHORT_LENGTHS_M = (10.0, 20.0, 30.0, 40.0, 50.0)
RENDERED = ("00", "02", "05", "06", "08")
VARIANTS = {
    "frame_to_frame": {
        "window": {"max_keyframes": 0},
        "disparity_self_calibration": False,
        "refine_matches": False,
    },
    "window_fixed": {
        "window": {"max_keyframes": 8},
        "disparity_self_calibration": False,
        "refine_matches": False,
    },
    "window_klt": {"refine_matches": False},
    "window": {},  # the default
}


class Perturbed:
    """`dataset` with each image changed by one gray level at random (+1, 0 or −1 per pixel, clipped to
    0–255), seeded by `seed` and the frame: the same perturbation on every call."""

    def __init__(self, dataset, seed: int) -> None:
        self.dataset, self.seed = dataset, seed
        self.calibration = dataset.calibration

    def __len__(self) -> int:
        return len(self.dataset)

    def ground_truth(self) -> np.ndarray:
        return self.dataset.ground_truth()

    def __getitem__(self, i: int) -> StereoFrame:
        frame = self.dataset[i]
        rng = np.random.default_rng([self.seed, i])

        def nudge(image: np.ndarray) -> np.ndarray:
            step = rng.integers(-1, 2, size=image.shape, dtype=np.int16)
            return np.clip(image.astype(np.int16) + step, 0, 255).astype(np.uint8)

        return StereoFrame(frame.index, frame.timestamp_s, nudge(frame.left), nudge(frame.right))


def run_vo(dataset, params: VoParams) -> tuple[np.ndarray, float, int, float]:
    """(world_from_camera (n, 4, 4), median ms per frame, frames not ok, the disparity offset in use at the
    end) of the VO over `dataset`."""
    vo = StereoOdometry(dataset.calibration, params)
    poses, times, not_ok = [], [], 0
    world_from_camera = np.eye(4)
    for i in range(len(dataset)):
        frame = dataset[i]
        start = time.perf_counter()
        step = vo.process(frame)
        times.append(time.perf_counter() - start)
        not_ok += step.status not in ("ok", "first")
        world_from_camera = world_from_camera @ step.camera_prev_from_camera_cur
        poses.append(world_from_camera)
    return np.stack(poses), 1e3 * float(np.median(times)), not_ok, vo.disparity_offset_px


def measure(dataset, params: VoParams, lengths, step: int, real: bool = False) -> dict:
    est, ms, not_ok, offset_px = run_vo(dataset, params)
    gt = dataset.ground_truth()
    gt = np.linalg.inv(gt[0]) @ gt
    rel = relative_errors_kitti(gt, est, lengths=lengths, step=step)
    # Real drives: also the errors on the segments whose ground truth was measured, not filled in with a
    # constant motion (KITTI 06 frames 0–11; metrics.interpolated_steps). Renders are exact everywhere.
    interpolated = interpolated_steps(gt) if real else np.zeros(len(gt) - 1, dtype=bool)
    measured = relative_errors_kitti(gt, est, lengths=lengths, step=step, exclude_steps=interpolated)
    length_m = float(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum())
    return {
        "frames": len(dataset),
        "length_m": round(length_m, 1),
        "ate_2d_m": ate_rmse(gt, est, planar=True),
        "ate_3d_m": ate_rmse(gt, est),
        "t_rel_percent": rel["t_rel_percent"],
        "r_rel_deg_per_100m": rel["r_rel_deg_per_100m"],
        "segments": rel["segments"],
        "interpolated_gt_steps": int(interpolated.sum()),
        "t_rel_measured_gt_percent": measured["t_rel_percent"],
        "r_rel_measured_gt_deg_per_100m": measured["r_rel_deg_per_100m"],
        "segments_measured_gt": measured["segments"],
        "ms_per_frame": ms,
        "frames_not_ok": not_ok,
        "disparity_offset_px": offset_px,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, help="the shared data folder (kitti_odometry/ inside)")
    parser.add_argument("--renders", type=Path, help="a KITTI root of whole-sequence renders")
    parser.add_argument("--sequences", nargs="+", default=list(RENDERED), help="rendered sequences to run")
    parser.add_argument("--variant", action="append", default=[], help="NAME=JSON of vo overrides")
    parser.add_argument("--only", nargs="+", help="run only these variants")
    parser.add_argument(
        "--perturbations", type=int, default=0, help="extra runs per variant with one-gray-level image noise"
    )
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.perturbations < 0:
        parser.error(f"--perturbations must be 0 or more, got {args.perturbations}")
    variants = dict(VARIANTS)
    for spec in args.variant:
        name, _, overrides = spec.partition("=")
        variants[name] = json.loads(overrides)
    if args.only:
        variants = {name: variants[name] for name in args.only}
    sets = []  # (label, dataset factory, extra vo overrides, segment lengths (None: the devkit's), step)
    if args.data is not None:
        kitti = args.data / "kitti_odometry"
        sets += [
            ("real 06, frames 0–50", lambda: KittiOdometry(kitti, "06"), {}, SHORT_LENGTHS_M, 1),
            ("real 01, frames 0–50, as given", lambda: KittiOdometry(kitti, "01"), {}, SHORT_LENGTHS_M, 1),
            (
                "real 01, frames 0–50, offset 1.5 px",
                lambda: KittiOdometry(kitti, "01"),
                {"disparity_offset_px": 1.5},
                SHORT_LENGTHS_M,
                1,
            ),
        ]
    if args.renders is not None:
        for seq in args.sequences:
            if (args.renders / "poses" / f"{seq}.txt").exists():
                sets.append((f"render {seq}", lambda s=seq: KittiOdometry(args.renders, s), {}, None, 10))
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict[str, dict]] = {}
    for label, factory, extra, lengths, step in sets:
        real = lengths is not None  # the real drives are the short ones, on 10–50 m segments
        dataset = factory()
        results[label] = {}
        for name, overrides in variants.items():
            params = VoParams(**{**extra, **overrides})
            row = measure(dataset, params, lengths or KITTI_SEGMENT_LENGTHS_M, step, real)
            if args.perturbations > 0:
                runs = [row] + [
                    measure(Perturbed(dataset, k), params, lengths or KITTI_SEGMENT_LENGTHS_M, step, real)
                    for k in range(1, args.perturbations + 1)
                ]
                row["perturbed"] = {
                    key: [run[key] for run in runs]
                    for key in ("ate_2d_m", "ate_3d_m", "t_rel_percent", "r_rel_deg_per_100m")
                }
            results[label][name] = row
            print(
                f"{label:38s} {name:16s} "
                + json.dumps(
                    {
                        k: round(v, 3) if isinstance(v, float) else v
                        for k, v in row.items()
                        if k != "perturbed"
                    }
                )
                + (f" perturbed {json.dumps(row['perturbed'])}" if "perturbed" in row else ""),
                flush=True,
            )
        # Where the self-calibration moved the offset: the same frames driven with the offset it found
        # from the first frame (what a longer drive runs most of its length with).
        found = results[label].get("window", {}).get("disparity_offset_px")
        configured = VoParams(**extra).disparity_offset_px
        if found is not None and found != configured:
            params = VoParams(**{**extra, "disparity_offset_px": found, "disparity_self_calibration": False})
            row = measure(dataset, params, lengths or KITTI_SEGMENT_LENGTHS_M, step, real)
            results[label]["window_found_offset"] = row
            print(f"{label:38s} window_found_offset {json.dumps(row)}", flush=True)
        (args.out / "vo.json").write_text(json.dumps(results, indent=1))
    names = [*variants, "window_found_offset"]
    (args.out / "vo.md").write_text(table(results, names))
    print(table(results, names))
    return 0


def table(results: dict, variants: list[str]) -> str:
    base = variants[0]
    lines = [
        "| data | VO | ATE 2-D / 3-D (m) | t_rel (%) | r_rel (°/100 m) | t_rel / r_rel, measured ground truth "
        "| disparity offset at the end (px) | time per frame (× " + base + ") |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for label, rows in results.items():
        for name in variants:
            if name not in rows:
                continue
            r = rows[name]
            ratio = r["ms_per_frame"] / rows[base]["ms_per_frame"] if base in rows else float("nan")
            measured = (
                f"{r['t_rel_measured_gt_percent']:.2f} / {r['r_rel_measured_gt_deg_per_100m']:.2f}"
                if r.get("interpolated_gt_steps")
                else "same"
            )
            ate_2d, ate_3d, t_rel, r_rel = (
                _with_range(r, key) for key in ("ate_2d_m", "ate_3d_m", "t_rel_percent", "r_rel_deg_per_100m")
            )
            lines.append(
                f"| {label} | {name} | {ate_2d} / {ate_3d} | {t_rel} | {r_rel} | {measured} | "
                f"{r['disparity_offset_px']:+.2f} | {ratio:.2f} |"
            )
    return "\n".join(lines) + "\n"


def _with_range(row: dict, key: str) -> str:
    """The unperturbed run's value, and with `--perturbations` the range over it and its repeats."""
    value = f"{row[key]:.2f}"
    runs = row.get("perturbed", {}).get(key)
    return value + (f" [{min(runs):.2f}–{max(runs):.2f}]" if runs else "")


if __name__ == "__main__":
    sys.exit(main())
