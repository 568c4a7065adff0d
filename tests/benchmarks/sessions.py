"""Maps that outlive a run, measured on a whole rendered sequence (docs/memory.md, "Whole sequences").

Day 1 drives frames 0 … split−1 of a sequence and writes its memory. Day 2 sessions then start inside it with
no pose: from each frame of `--starts` to the end of the sequence, once more from `split` on a render whose
appearance changed (`--changed`, e.g. `render --appearance mild`), and once on another sequence the first day
never saw (`--unseen`, which must never relocalise). For each session: whether and when it relocalised (frames,
metres and seconds while lost), whether the relocalisation was correct (the joined vertex was made within 5 m
of the agent in truth), the closures after it, and the ATE (2-D, corrected) of the session against the same
frames of one run over the whole sequence (run here too; for the changed look, one run over the whole changed
render, whose later passes lie up to 0.75 m aside: each session is scored against its own render's truth). The merged map (every frame of both days, day 1's
re-placed on the map as day 2 corrected it: the session's `metrics.json` `sessions`, docs/memory.md) is
compared with the one run over the same frames. `--session-config` (JSON) is merged into every day-2 session's
config (e.g. `'{"closure": {"relocalisation": {"retrace": {"max_links": 0}}}}'`: no retrace at the join).

    python tests/benchmarks/sessions.py --renders RENDERS [--changed RENDERS_MILD] [--sequence 00]
        [--split 2500] [--starts 2500,3000,3500] [--unseen 05:600] [--session-config JSON]
        [--out runs/sessions] [--day1 EXISTING_DAY1_RESULTS] [--whole EXISTING_WHOLE_RESULTS]
        [--whole-changed EXISTING_WHOLE_RUN_ON_THE_CHANGED_RENDER]

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


def _run(
    out: Path,
    dataset: Path,
    sequence: str,
    start: int | None,
    stop: int | None,
    memory: Path | None,
    extra: dict | None = None,
):
    from hippo_nav._defaults import merged
    from hippo_nav.pipeline import config_from_dict, run

    config = config_from_dict(merged({"output": {"figures": False}}, extra or {}))
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
    parser.add_argument("--session-config", type=json.loads, default=None, help="JSON merged into day 2's")
    parser.add_argument("--out", type=Path, default=Path("runs/sessions"))
    parser.add_argument("--day1", type=Path, default=None, help="reuse this day-1 results folder")
    parser.add_argument("--whole", type=Path, default=None, help="reuse this one-run results folder")
    parser.add_argument(
        "--whole-changed", type=Path, default=None, help="reuse this one run on the changed render"
    )
    args = parser.parse_args(argv)
    from hippo_nav.datasets import KittiOdometry
    from hippo_nav.io.poses import read_kitti_poses

    args.out.mkdir(parents=True, exist_ok=True)
    seq = args.sequence
    gt = KittiOdometry(args.renders, seq).ground_truth()
    day1 = args.day1 or args.out / "day1"
    if args.day1 is None:
        _run(day1, args.renders, seq, None, args.split, None)
    whole_dir = args.whole or args.out / "whole"
    if args.whole is None:
        _run(whole_dir, args.renders, seq, None, None, None)
    one_run = {args.renders: read_kitti_poses(whole_dir / "trajectory_corrected.kitti.txt")}
    truths = {args.renders: gt}
    if args.changed is not None:
        changed_dir = args.whole_changed or args.out / "whole_changed"
        if args.whole_changed is None:
            _run(changed_dir, args.changed, seq, None, None, None)
        one_run[args.changed] = read_kitti_poses(changed_dir / "trajectory_corrected.kitti.txt")
        truths[args.changed] = KittiOdometry(args.changed, seq).ground_truth()
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
        result = _run(args.out / name, root, sequence, start, stop, day1, args.session_config)
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
                truth, whole_corrected = truths[root], one_run[root]
                row["ate_2d_m"] = round(_ate_2d(truth[start:], est), 2)
                row["ate_2d_m_one_run_same_frames"] = round(
                    _ate_2d(truth[start:], whole_corrected[start:]), 2
                )
                both = result.metrics.get("sessions", {})
                if "ate_2d_m" in both:
                    # Both days' frames: day 1's (0 … split−1) then this session's (start …).
                    frames = np.r_[0 : args.split, start : len(gt)]
                    row["merged_ate_2d_m"] = round(both["ate_2d_m"], 2)
                    row["merged_day1_frames_ate_2d_m"] = round(both["ate_2d_m_earlier_sessions"], 2)
                    row["one_run_ate_2d_m_same_frames"] = round(
                        _ate_2d(truth[frames], whole_corrected[frames]), 2
                    )
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
