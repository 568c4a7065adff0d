"""The loop-closing chain on real images: view cells on a real loop and on real streets without a revisit,
and the closure measurement against ground truth.

    python tests/benchmarks/real_images.py --data ../shared/data --out runs/real_images

Writes `real_images.md` (the tables of docs/results.md, "Real images"), `real_images.json` and
`precision_recall.png` under `--out`. Sections:

1. **Corridor loop** (`rtabmap_loop_samples`: 84 handheld images, images 41–84 revisit 1–40, ground truth
   of revisit pairs). The images are observed in order; a familiar view of a cell made 5 or more images
   earlier is a loop claim, correct when the ground truth says the two images show the same place.
   Precision = correct / claims, recall = revisit images with a correct claim / 44. Swept over each view
   descriptor's threshold: the paper's whole-image template (`novelty_threshold`) and the word view cells
   (`min_inliers`).
2. **Real streets without a revisit** (KITTI 00 left images 0–159, 06 and 01 frames 0–50): every claim is
   false. Cells made within the last 50 m of travel (ground truth) are the current passage, as the pipeline
   treats them; everything older is a candidate, with no odometry gate (harsher than the pipeline). Also the
   distribution of each frame's best evidence for an older cell against the threshold.
3. **Closure measurement** (KITTI 06 and 01 frames 0–50): a stereo keyframe of every second frame is
   measured from every other frame 1–20 m away; the relative pose (planar: forward, left, yaw) against the
   ground truth, by distance and by viewing-angle change; the share accepted, and the share of accepted
   measurements whose error is inside their own covariance at the map's χ² gate (16.27, 3 dof).

Not a test (no assertions; pytest does not collect it): a reproducible experiment on the shared real data.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import cv2
import numpy as np

CHI2_GATE = 16.27  # the map's max_loop_chi2 (χ², 3 dof, p = 0.999)
PASSAGE_M = 50.0  # the map's min_loop_separation_m: cells made within it are the current passage
CLAIM_GAP_IMAGES = 5


# ---------------------------------------------------------------------------------------------- corridor
def corridor_images(data: Path) -> tuple[list[np.ndarray], np.ndarray]:
    root = data / "rtabmap_loop_samples"
    files = sorted(root.glob("*.jpg"), key=lambda p: int(p.stem))
    truth = cv2.imread(str(root / "samples_GT.bmp"), cv2.IMREAD_GRAYSCALE) > 0
    return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files], truth


def corridor_claims(observe, images: list[np.ndarray], truth: np.ndarray) -> dict:
    """Run `observe(i, image, recent_cells) -> (status, cell, recent)` over the images in order."""
    created: dict[int, int] = {}
    claims = []
    for i, image in enumerate(images):
        recent = [c for c, at in created.items() if i - at < CLAIM_GAP_IMAGES]
        status, cell, is_recent = observe(image, recent)
        if status == "new":
            created[cell] = i
        elif status == "familiar" and not is_recent and i - created[cell] >= CLAIM_GAP_IMAGES:
            claims.append((i, created[cell], bool(truth[i, created[cell]])))
    revisits = int(truth.any(axis=1).sum())
    correct = sum(c[2] for c in claims)
    return {
        "claims": len(claims),
        "correct": correct,
        "precision": correct / len(claims) if claims else float("nan"),
        "recall": len({c[0] for c in claims if c[2]}) / revisits,
        "cells": len(created),
        "false": [(i + 1, j + 1) for i, j, ok in claims if not ok],
    }


def template_observer(threshold: float, crop=(0.1, 0.7)):
    from hippo_nav.view_cells import TemplateViewCells, TemplateViewConfig

    cells = TemplateViewCells(TemplateViewConfig(novelty_threshold=threshold, crop_rows_frac=crop))

    def observe(image, recent):
        obs = cells.observe(cells.template_from_image(image))
        return obs.status, obs.cell_id, obs.cell_id in recent

    return observe


def words_observer(min_inliers: int, camera_matrix=None):
    from hippo_nav.view_cells.words import WordViewCells, WordViewConfig

    config = WordViewConfig(
        min_inliers=min_inliers, keep_inliers=max(min_inliers, WordViewConfig().keep_inliers)
    )
    cells = WordViewCells(config, camera_matrix=camera_matrix)

    def observe(image, recent):
        obs = cells.observe(cells.describe_image(image), None, recent)
        return obs.status, obs.cell_id, obs.recent

    return observe


def corridor_section(data: Path) -> dict:
    from hippo_nav.view_cells import TemplateViewConfig
    from hippo_nav.view_cells.words import WordViewConfig

    images, truth = corridor_images(data)
    rows = []
    for threshold in (0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65):
        r = corridor_claims(template_observer(threshold), images, truth)
        rows.append({"descriptor": "template", "threshold": threshold, **r})
        print(f"corridor template {threshold}: {r}", file=sys.stderr)
    for min_inliers in (20, 25, 30, 35, 40, 50, 60, 80, 100):
        r = corridor_claims(words_observer(min_inliers), images, truth)
        rows.append({"descriptor": "words", "threshold": min_inliers, **r})
        print(f"corridor words {min_inliers}: {r}", file=sys.stderr)
    defaults = {"template": TemplateViewConfig().novelty_threshold, "words": WordViewConfig().min_inliers}
    return {"rows": rows, "defaults": defaults}


# ------------------------------------------------------------------------------------------ real streets
def street_frames(data: Path, sequence: str, stop: int):
    from hippo_nav.io import read_kitti_poses

    root = data / "kitti_odometry"
    files = sorted((root / "sequences" / sequence / "image_0").glob("*.png"))[:stop]
    gt = read_kitti_poses(root / "poses" / f"{sequence}.txt")[: len(files)]
    p0 = np.loadtxt(root / "sequences" / sequence / "calib.txt", usecols=range(1, 13))[0].reshape(3, 4)
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1))])
    return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files], travelled, p0[:, :3]


def street_section(data: Path) -> dict:
    from hippo_nav.view_cells import TemplateViewCells
    from hippo_nav.view_cells.words import WordViewCells

    out = {}
    for sequence, stop in (("00", 160), ("06", 51), ("01", 51)):
        images, travelled, K = street_frames(data, sequence, stop)
        # Words: claims at the defaults, and each frame's most verified older cell.
        words = WordViewCells(camera_matrix=K)
        created: dict[int, float] = {}
        claims, evidence = 0, []
        for i, image in enumerate(images):
            view = words.describe_image(image)
            older = [c for c, at in created.items() if travelled[i] - at >= PASSAGE_M]
            recent = [c for c, at in created.items() if travelled[i] - at < PASSAGE_M]
            if older:
                ranked = words.rank(view, older)
                evidence.append(max((inliers for _, _, inliers in ranked), default=0))
            obs = words.observe(view, None, recent)
            if obs.is_new:
                created[int(obs.cell_id)] = travelled[i]
            elif obs.status == "familiar" and not obs.recent:
                claims += 1
        # Templates at their default threshold, the same protocol.
        templates = TemplateViewCells()
        t_created: dict[int, float] = {}
        t_claims, t_evidence = 0, []
        for i, image in enumerate(images):
            t = templates.template_from_image(image)
            older = [c for c, at in t_created.items() if travelled[i] - at >= PASSAGE_M]
            if older:
                best = templates.best_match(t, older)
                if best is not None:
                    t_evidence.append(best[1])
            obs = templates.observe(t)
            if obs.is_new:
                t_created[int(obs.cell_id)] = travelled[i]
            elif obs.status == "familiar" and travelled[i] - t_created[int(obs.cell_id)] >= PASSAGE_M:
                t_claims += 1
        out[sequence] = {
            "frames": len(images),
            "path_m": float(travelled[-1]),
            "words": {
                "claims": claims,
                "cells": len(words),
                "frames_with_older_cells": len(evidence),
                "best_older_inliers": _quantiles(evidence),
            },
            "template": {
                "claims": t_claims,
                "cells": len(templates),
                "frames_with_older_cells": len(t_evidence),
                "best_older_difference": _quantiles(t_evidence, low=True),
            },
        }
        print(f"street {sequence}: {out[sequence]}", file=sys.stderr)
    return out


def _quantiles(values, low: bool = False) -> dict:
    if not values:
        return {}
    v = np.asarray(values, dtype=float)
    extreme = float(v.min() if low else v.max())
    return {
        "median": float(np.median(v)),
        "p99": float(np.percentile(v, 1 if low else 99)),
        "extreme": extreme,
    }


# ------------------------------------------------------------------------------------- closure measure
def closure_section(data: Path, descriptor: str = "sift") -> dict:
    from hippo_nav.closure import ClosureConfig, KeyframeExtractor, LoopMeasurer
    from hippo_nav.datasets import KittiOdometry
    from hippo_nav.geometry import planar_from_pose, wrap_angle

    out = {}
    for sequence, offset in (("06", 0.0), ("01", 0.0), ("01", 1.0)):
        dataset = KittiOdometry(data / "kitti_odometry", sequence, 0, 51)
        gt = np.asarray(dataset.ground_truth())
        config = ClosureConfig(descriptor=descriptor)
        extract = KeyframeExtractor(dataset.calibration, config, offset)
        measurer = LoopMeasurer(dataset.calibration, config)
        keyframes = [extract(f.left, f.right) for f in (dataset[i] for i in range(len(dataset)))]
        rows = []
        for k in range(0, len(keyframes), 2):
            for q in range(len(keyframes)):
                true = np.linalg.inv(gt[q]) @ gt[k]
                distance = float(np.linalg.norm(true[:3, 3]))
                if not 1.0 <= distance <= 20.0:
                    continue
                truth = planar_from_pose(true)
                measurement, why = measurer.measure(keyframes[k], keyframes[q])
                row = {"distance_m": distance, "angle_deg": abs(float(np.degrees(truth[2]))), "why": why}
                if measurement is not None:
                    error = np.array(measurement.agent_from_target) - truth
                    error[2] = wrap_angle(error[2])
                    row.update(
                        position_error_m=float(np.hypot(error[0], error[1])),
                        yaw_error_deg=abs(float(np.degrees(error[2]))),
                        chi2=float(error @ measurement.information @ error),
                    )
                rows.append(row)
        name = f"{sequence}" + (f" (disparity offset {offset:g} px)" if offset else "")
        out[name] = {
            "by_distance": _bins(rows, "distance_m", (1, 2, 3, 4, 6, 8, 10, 15, 20)),
            "by_angle": _bins(rows, "angle_deg", (0, 1, 2, 5, 10, 90)),
        }
        print(f"closure {name}: {out[name]['by_distance']}", file=sys.stderr)
    return out


def _bins(rows: list[dict], key: str, edges) -> list[dict]:
    table = []
    for lo, hi in itertools.pairwise(edges):
        sel = [r for r in rows if lo <= r[key] < hi]
        accepted = [r for r in sel if "position_error_m" in r]
        entry = {"range": f"{lo}–{hi}", "pairs": len(sel), "accepted": len(accepted)}
        if accepted:
            pos = np.array([r["position_error_m"] for r in accepted])
            yaw = np.array([r["yaw_error_deg"] for r in accepted])
            chi2 = np.array([r["chi2"] for r in accepted])
            entry.update(
                position_median_m=float(np.median(pos)),
                position_p95_m=float(np.percentile(pos, 95)),
                position_max_m=float(pos.max()),
                yaw_median_deg=float(np.median(yaw)),
                yaw_max_deg=float(yaw.max()),
                within_0_3m_1deg=int(((pos <= 0.3) & (yaw <= 1.0)).sum()),
                inside_gate=int((chi2 <= CHI2_GATE).sum()),
            )
        table.append(entry)
    return table


# ---------------------------------------------------------------------------------------------- report
def markdown(results: dict) -> str:
    lines = ["## Corridor loop: loop claims against the ground truth", ""]
    lines += [
        "| descriptor | threshold | claims | correct | precision | recall | cells |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results["corridor"]["rows"]:
        default = " (default)" if results["corridor"]["defaults"][r["descriptor"]] == r["threshold"] else ""
        lines.append(
            f"| {r['descriptor']} | {r['threshold']}{default} | {r['claims']} | {r['correct']} | "
            f"{r['precision']:.2f} | {r['recall']:.2f} | {r['cells']} |"
        )
    lines += ["", "## Real streets without a revisit: loop claims (all false)", ""]
    lines += [
        (
            "| sequence | frames | path | words: claims | words: best older-cell inliers (median / p99 / max) | "
            "template: claims | template: best older-cell difference (median / p1 / min) |"
        ),
        "|---|---|---|---|---|---|---|",
    ]
    for seq, r in results["streets"].items():
        w, t = r["words"]["best_older_inliers"], r["template"]["best_older_difference"]
        lines.append(
            f"| {seq} | {r['frames']} | {r['path_m']:.0f} m | {r['words']['claims']} | "
            + (f"{w['median']:.0f} / {w['p99']:.0f} / {w['extreme']:.0f}" if w else "–")
            + f" | {r['template']['claims']} | "
            + (f"{t['median']:.2f} / {t['p99']:.2f} / {t['extreme']:.2f}" if t else "–")
            + " |"
        )
    lines += ["", "## Closure measurement against the ground truth", ""]
    for name, r in results["closure"].items():
        for by in ("by_distance", "by_angle"):
            unit = "m" if by == "by_distance" else "°"
            lines += [
                f"**{name}, {by.replace('_', ' ')}**", "",
                (
                    f"| {unit} | pairs | accepted | position error median / p95 / max (m) | "
                    "yaw error median / max (°) | within 0.3 m and 1° | inside the χ² gate |"
                ),
                "|---|---|---|---|---|---|---|",
            ]  # fmt: skip
            for b in r[by]:
                if b["accepted"]:
                    lines.append(
                        f"| {b['range']} | {b['pairs']} | {b['accepted']} | {b['position_median_m']:.3f} / "
                        f"{b['position_p95_m']:.3f} / {b['position_max_m']:.3f} | {b['yaw_median_deg']:.3f} / "
                        f"{b['yaw_max_deg']:.3f} | {b['within_0_3m_1deg']} | {b['inside_gate']} |"
                    )
                else:
                    lines.append(f"| {b['range']} | {b['pairs']} | 0 | – | – | – | – |")
            lines.append("")
    return "\n".join(lines) + "\n"


def figure(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.5, 3.4), dpi=110)
    for descriptor, marker in (("template", "s"), ("words", "o")):
        rows = [r for r in results["corridor"]["rows"] if r["descriptor"] == descriptor and r["claims"]]
        ax.plot([r["recall"] for r in rows], [r["precision"] for r in rows], marker=marker, label=descriptor)
        default = results["corridor"]["defaults"][descriptor]
        for r in rows:
            if r["threshold"] == default:
                ax.plot(r["recall"], r["precision"], marker="*", markersize=14, color="k")
    ax.set_xlabel("recall (revisit images recognised)")
    ax.set_ylabel("precision (loop claims correct)")
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.05)
    ax.set_title("Corridor loop (84 real images)", fontsize=10)
    ax.legend(loc="lower left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, required=True, help="the shared data folder")
    parser.add_argument("--out", type=Path, default=Path("runs/real_images"))
    parser.add_argument("--sections", nargs="+", default=["corridor", "streets", "closure"])
    parser.add_argument(
        "--descriptor",
        choices=["orb", "sift"],
        default="sift",
        help="the closure keyframes' (closure.descriptor; the pipeline's default is sift)",
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    if "corridor" in args.sections:
        results["corridor"] = corridor_section(args.data)
    if "streets" in args.sections:
        results["streets"] = street_section(args.data)
    if "closure" in args.sections:
        results["closure"] = closure_section(args.data, args.descriptor)
    (args.out / "real_images.json").write_text(json.dumps(results, indent=1))
    if set(args.sections) >= {"corridor", "streets", "closure"}:
        (args.out / "real_images.md").write_text(markdown(results))
        figure(results, args.out / "precision_recall.png")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
