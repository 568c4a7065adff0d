"""Recognising and closing a revisit against lateral offset, heading change and appearance change (renders).

    python tests/benchmarks/view_recognition.py --out runs/view_recognition [--levels same strong] \\
        [--offsets 0 1.5 3 4] [--headings 0 10 15 20]

A straight street (`hippo_nav.synthetic.revisit_street`) is driven twice, 30 stereo frames 2 m apart each
time, at 640×192 px (KITTI's field of view): the second pass `lateral_offset_m` to the left and yawed by
`heading_offset_deg`, rendered at an appearance level (`docs/render.md`: at `strong` another sun, shadows,
changed shop fronts and parked cars, noise, blur). For each view descriptor the first pass is observed in
order (its cells are the current passage), then the second (the first pass's cells are now older):

- **recognised**: the share of second-pass frames whose familiar cell is one of the first pass made within
  20 m of the true place (the views overlap); **false**: familiar cells of the first pass farther away.
- **closed** (word cells only, as the pipeline measures closures): the share of second-pass frames that are
  recognised *and* whose stereo measurement against the nearest first-pass keyframe (the vertex the odometry
  would predict) is accepted, and the largest position (m) and heading (°) errors of the accepted
  measurements against the ground truth.
- **proximity: closed**: the share of second-pass frames, recognised or not, whose measurement against that
  keyframe is accepted at the proximity bar (`closure.proximity.min_inliers`: the map's loop gate proposes
  the vertex nearest to where the odometry puts the agent, docs/map.md), and the largest errors.

Writes `view_recognition.md` and `view_recognition.json` under `--out` (renders are kept there and reused).
Not a test (no assertions; pytest does not collect it): a reproducible experiment.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

FRAMES_PER_PASS = 30
STEP_M = 2.0
IMAGE_SIZE_PX = (640, 192)
SEED = 3
PLACE_TOLERANCE_M = 20.0


def render(level: str, lateral_m: float, heading_deg: float, out: Path):
    """The KITTI root of one revisit (rendered once, then reused) and its `RevisitStreet`."""
    from hippo_nav.synthetic import render_sequence, revisit_street

    street = revisit_street(
        FRAMES_PER_PASS, step_m=STEP_M, lateral_offset_m=lateral_m, heading_offset_deg=heading_deg
    )
    root = out / "renders" / f"{level}_{lateral_m:g}m_{heading_deg:g}deg"
    render_sequence(
        street.world_from_camera, root, "00", IMAGE_SIZE_PX, seed=SEED, appearance=level,
        street_path_m=street.street_path_m, keep_existing=True,
    )  # fmt: skip
    return root, street


def observe_passes(cells, frames, street) -> list[tuple[int, int | None]]:
    """Observe the first pass, then the second; per second-pass frame (true place, claimed place or None).
    Places are first-pass frame indices."""
    made_at: dict[int, int] = {}
    first = set(street.first_pass.tolist())
    claims = []
    for i in range(len(street.world_from_camera)):
        on_first = i in first
        this_pass = [c for c, at in made_at.items() if (at in first) == on_first]
        obs = cells.observe(cells.describe(frames[i]), None, this_pass)
        if obs.cell_id is None:
            if not on_first:
                claims.append((int(street.revisit_of[i - len(first)]), None))
            continue
        if obs.is_new:
            made_at[obs.cell_id] = i
        if not on_first:
            origin = made_at[obs.cell_id]
            claimed = origin if (origin in first and not obs.is_new) else None
            claims.append((int(street.revisit_of[i - len(first)]), claimed))
    return claims


def closures(frames, street, claims, calibration, proximity: bool = False) -> list[dict]:
    """Stereo measurement of each recognised second-pass frame against the nearest first-pass keyframe; with
    `proximity`, of every second-pass frame, recognised or not, at the proximity bar (`closure.proximity`:
    the map's gate proposes the vertex nearest to where the odometry puts the agent)."""
    from hippo_nav.closure import ClosureConfig, KeyframeExtractor, LoopMeasurer
    from hippo_nav.geometry import planar_from_pose, wrap_angle

    config = ClosureConfig()
    extract = KeyframeExtractor(calibration, config)
    measurer = LoopMeasurer(calibration, config)
    keyframes: dict[int, object] = {}

    def keyframe(i: int):
        if i not in keyframes:
            keyframes[i] = extract(frames[i].left, frames[i].right)
        return keyframes[i]

    rows = []
    n_first = len(street.first_pass)
    for k, (place, claimed) in enumerate(claims):
        recognised = claimed is not None and abs(claimed - place) * STEP_M <= PLACE_TOLERANCE_M
        if not (recognised or proximity):
            rows.append({"closed": False})
            continue
        current = n_first + k
        bar = config.section("proximity").min_inliers if proximity else None
        measurement, why = measurer.measure(keyframe(place), keyframe(current), bar)
        if measurement is None:
            rows.append({"closed": False, "why": why})
            continue
        truth = planar_from_pose(
            np.linalg.inv(street.world_from_camera[current]) @ street.world_from_camera[place]
        )
        error = np.array(measurement.agent_from_target) - truth
        error[2] = wrap_angle(error[2])
        rows.append(
            {
                "closed": True,
                "position_error_m": float(np.hypot(error[0], error[1])),
                "yaw_error_deg": abs(float(np.degrees(error[2]))),
                "chi2": float(error @ measurement.information @ error),
            }
        )
    return rows


def one(level: str, lateral_m: float, heading_deg: float, out: Path) -> dict:
    from hippo_nav.datasets import KittiOdometry
    from hippo_nav.view_cells import TemplateViewCells, TemplateViewConfig, WordViewCells, WordViewConfig

    root, street = render(level, lateral_m, heading_deg, out)
    dataset = KittiOdometry(root, "00")
    frames = [dataset[i] for i in range(len(dataset))]
    row: dict = {"level": level, "lateral_m": lateral_m, "heading_deg": heading_deg}
    for name, cells in (
        ("words", WordViewCells.for_camera(WordViewConfig(), dataset.calibration)),
        ("template", TemplateViewCells.for_camera(TemplateViewConfig(), dataset.calibration)),
    ):
        claims = observe_passes(cells, frames, street)
        right = [c is not None and abs(c - p) * STEP_M <= PLACE_TOLERANCE_M for p, c in claims]
        wrong = [c is not None and abs(c - p) * STEP_M > PLACE_TOLERANCE_M for p, c in claims]
        row[name] = {"recognised": float(np.mean(right)), "false": int(np.sum(wrong)), "cells": len(cells)}
        if name == "words":
            measured = closures(frames, street, claims, dataset.calibration)
            accepted = [m for m in measured if m["closed"]]
            row[name]["closed"] = len(accepted) / len(measured)
            errors = [m["position_error_m"] for m in accepted]
            row[name]["median_position_error_m"] = float(np.median(errors)) if errors else None
            row[name]["max_position_error_m"] = max(errors, default=None)
            row[name]["max_yaw_error_deg"] = max((m["yaw_error_deg"] for m in accepted), default=None)
            row[name]["max_chi2"] = max((m["chi2"] for m in accepted), default=None)
            nearest = closures(frames, street, claims, dataset.calibration, proximity=True)
            accepted = [m for m in nearest if m["closed"]]
            row["proximity"] = {
                "closed": len(accepted) / len(nearest),
                "max_position_error_m": max((m["position_error_m"] for m in accepted), default=None),
                "max_yaw_error_deg": max((m["yaw_error_deg"] for m in accepted), default=None),
                "max_chi2": max((m["chi2"] for m in accepted), default=None),
            }
    print(json.dumps(row), file=sys.stderr, flush=True)
    return row


def markdown(rows: list[dict]) -> str:
    def fmt(v, spec=".2f"):
        return "–" if v is None else format(v, spec)

    lines = [
        (
            "| appearance | lateral offset (m) | heading change (°) | words: recognised / false | words: closed "
            "| words: median / max error (m), max (°) | proximity: closed | proximity: max error (m), (°) "
            "| template: recognised / false |"
        ),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        w, t, p = r["words"], r["template"], r["proximity"]
        lines.append(
            f"| {r['level']} | {r['lateral_m']:g} | {r['heading_deg']:g} | {w['recognised']:.2f} / {w['false']} "
            f"| {w['closed']:.2f} | {fmt(w.get('median_position_error_m'))} / {fmt(w['max_position_error_m'])}, "
            f"{fmt(w['max_yaw_error_deg'], '.1f')} "
            f"| {p['closed']:.2f} | {fmt(p['max_position_error_m'])}, {fmt(p['max_yaw_error_deg'], '.1f')} "
            f"| {t['recognised']:.2f} / {t['false']} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=Path("runs/view_recognition"))
    parser.add_argument("--levels", nargs="+", default=["same", "strong"])
    parser.add_argument("--offsets", nargs="+", type=float, default=[0.0, 1.5, 3.0, 4.0])
    parser.add_argument("--headings", nargs="+", type=float, default=[0.0, 10.0, 15.0, 20.0])
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = [one(*combo, args.out) for combo in itertools.product(args.levels, args.offsets, args.headings)]
    (args.out / "view_recognition.json").write_text(json.dumps(rows, indent=2) + "\n")
    table = markdown(rows)
    (args.out / "view_recognition.md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
