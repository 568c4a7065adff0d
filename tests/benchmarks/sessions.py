"""Maps that outlive a run, measured on a whole rendered sequence (docs/memory.md, "Whole sequences").

Day 1 drives frames 0 … split−1 of a sequence and writes its memory. Day 2 sessions then start inside it with
no pose: from each frame of `--starts` to the end of the sequence, once more from `split` on a render whose
appearance changed (`--changed`, e.g. `render --appearance mild`), and once on another sequence the first day
never saw (`--unseen`, which must never relocalise). For each session: whether and when it relocalised (frames,
metres and seconds while lost), whether the relocalisation was correct (the joined vertex was made within 5 m
of the agent in truth), the closures after it, and the ATE (2-D, corrected) of the session against the same
frames of one run over the whole sequence (run here too). The merged map over the whole sequence (day 1's
trajectory as corrected at its end, then day 2 from `split`, in the same map frame) is compared with the one run.

    python tests/benchmarks/sessions.py --renders RENDERS [--changed RENDERS_MILD] [--sequence 00]
        [--split 2500] [--starts 2500,3000,3500] [--unseen 05:600] [--out runs/sessions]

Not a test (no assertions; pytest does not collect it): a reproducible measurement (~20 min on 2 cores for 00).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

CORRECT_WITHIN_M = 5.0


def _run(out: Path, dataset: Path, sequence: str, start: int | None, stop: int | None, memory: Path | None):
    from hippo_nav.pipeline import config_from_dict, run

    config = config_from_dict({"output": {"figures": False}})
    print(f"run {out.name}: {dataset} {sequence} [{start}, {stop}) map={memory}", flush=True)
    return run(
        out, dataset=dataset, sequence=sequence, start=start, stop=stop, config=config, progress=False,
        overwrite=True, memory_from=memory,
    )  # fmt: skip


def _vertex_frames(results: Path) -> dict[int, int]:
    """Vertex → the frame that made it, from a run's frames.csv."""
    out = {}
    with open(results / "frames.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["vertex_created"] == "1":
                out[int(row["vertex"])] = int(row["frame"])
    return out


def _ate_2d(gt: np.ndarray, est: np.ndarray) -> float:
    from hippo_nav.metrics import ate_rmse

    return ate_rmse(gt, est, planar=True, align="se3")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--renders", type=Path, required=True, help="KITTI-layout renders root")
    parser.add_argument(
        "--changed", type=Path, default=None, help="renders of the same sequence, changed look"
    )
    parser.add_argument("--sequence", default="00")
    parser.add_argument("--split", type=int, default=2500)
    parser.add_argument("--starts", default="2500,3000,3500")
    parser.add_argument("--unseen", default="05:600", help="SEQUENCE:FRAMES the first day never saw")
    parser.add_argument("--out", type=Path, default=Path("runs/sessions"))
    args = parser.parse_args(argv)
    from hippo_nav.datasets import KittiOdometry
    from hippo_nav.io.poses import read_kitti_poses

    args.out.mkdir(parents=True, exist_ok=True)
    seq = args.sequence
    gt = KittiOdometry(args.renders, seq).ground_truth()
    day1 = args.out / "day1"
    _run(day1, args.renders, seq, None, args.split, None)
    whole = _run(args.out / "whole", args.renders, seq, None, None, None)
    whole_corrected = read_kitti_poses(args.out / "whole" / "trajectory_corrected.kitti.txt")
    made_at = _vertex_frames(day1)
    sessions = [(f"start {s}", args.renders, seq, int(s)) for s in args.starts.split(",")]
    if args.changed is not None:
        sessions.append((f"start {args.split}, changed look", args.changed, seq, args.split))
    unseen_seq, unseen_frames = args.unseen.split(":")
    rows = []
    for label, root, sequence, start in [
        *sessions,
        (f"unseen ({unseen_seq})", args.renders, unseen_seq, None),
    ]:
        name = "day2_" + label.replace(" ", "_").replace(",", "").replace("(", "").replace(")", "")
        stop = int(unseen_frames) if start is None else None
        result = _run(args.out / name, root, sequence, start, stop, day1)
        loaded = result.metrics["loaded_map"]
        where = loaded["relocalisation"]
        row = {"session": label, "frames": result.metrics["frames"], "relocalised": loaded["relocalised"]}
        if where is not None:
            joined_frame, vertex = int(where["frame"]), int(where["vertex"])
            made = made_at.get(vertex)
            # On the unseen sequence every relocalisation is false (its truth is in another frame).
            off_m = (
                float(np.linalg.norm(gt[made][:3, 3] - gt[joined_frame][:3, 3]))
                if made is not None and start is not None
                else np.inf
            )
            row.update(
                frames_lost=where["frames_lost"],
                travelled_m=round(where["travelled_m"], 1),
                seconds_lost=round(where["frames_lost"] / 10.0, 1),
                joined_vertex_off_m=round(off_m, 2),
                correct=bool(off_m <= CORRECT_WITHIN_M),
                closures_after=result.metrics["loop_closures"],
            )
            if start is not None:
                est = read_kitti_poses(args.out / name / "trajectory_corrected.kitti.txt")
                row["ate_2d_m"] = round(_ate_2d(gt[start:], est), 2)
                row["ate_2d_m_one_run_same_frames"] = round(_ate_2d(gt[start:], whole_corrected[start:]), 2)
                if start == args.split and root == args.renders:
                    day1_est = read_kitti_poses(day1 / "trajectory_corrected.kitti.txt")
                    merged = np.concatenate([day1_est, est])
                    row["merged_ate_2d_m"] = round(_ate_2d(gt, merged), 2)
                    row["one_run_ate_2d_m"] = round(whole.metrics["errors"]["corrected"]["ate_2d_m"], 2)
        rows.append(row)
        print(json.dumps(row), flush=True)
    (args.out / "sessions.json").write_text(json.dumps(rows, indent=1) + "\n")
    keys = list(dict.fromkeys(k for r in rows for k in r))
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(str(r.get(k, "–")) for k in keys) + " |" for r in rows]
    (args.out / "sessions.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
