"""Maps that outlive a run, measured on a whole rendered sequence (docs/memory.md, "Whole sequences").

Day 1 drives frames 0 … split−1 of a sequence and writes its memory. Day 2 sessions then start inside it with
no pose: from each frame of `--starts` to the end of the sequence, once more from `split` on a render whose
appearance changed (`--changed`, e.g. `render --appearance mild`), and once on another sequence the first day
never saw (`--unseen`, which must never relocalise). For each session: whether and when it relocalised (frames,
metres and seconds while lost), whether the relocalisation was correct (the joined vertex was made within 5 m
of the agent in truth), the closures after it, and the ATE (2-D, corrected) of the session against the same
frames of one run over the whole sequence (run here too; for the changed look, one run over the whole changed
render, whose later passes lie up to 0.75 m aside: each session is scored against its own render's truth). The merged map (every frame of both days, day 1's
re-placed on the map as day 2 corrected it: the session's `trajectory_sessions.tum.txt`, docs/memory.md) is
compared with the one run over the same frames.

One run is one draw of the VO: a run started a frame later tracks other corners and its map over 00's last
thousand frames differs by up to 1.6x (docs/memory.md). So there are `--one-runs` of them (started at frames
0, 1, ...), and every error is taken over the frames all of them have (from frame `--one-runs` − 1 on); a
session is compared with their mean (`merged_over_one_runs`). `--session-config` (JSON) is merged into every day-2 session's
config (e.g. `'{"closure": {"relocalisation": {"retrace": {"max_links": 0}}}}'`: no retrace at the join).

    python tests/benchmarks/sessions.py --renders RENDERS [--changed RENDERS_MILD] [--sequence 00]
        [--split 2500] [--starts 2500,3000,3500] [--unseen 05:600] [--session-config JSON] [--one-runs 3]
        [--out runs/sessions] [--day1 EXISTING_DAY1_RESULTS] [--whole EXISTING_WHOLE_RESULTS]
        [--whole-changed EXISTING_WHOLE_RUN_ON_THE_CHANGED_RENDER]

Not a test (no assertions; pytest does not collect it): a reproducible measurement (~45 min on 2 cores for 00
with `--changed`, three one runs of each render).
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


def _by_frame(poses: np.ndarray, frames: np.ndarray, count: int) -> np.ndarray:
    """(count, 4, 4) poses indexed by frame, NaN where a run has no pose."""
    out = np.full((count, 4, 4), np.nan)
    out[frames] = poses
    return out


def _one_run(out: Path, dataset: Path, sequence: str, first: int, count: int) -> np.ndarray:
    """The corrected trajectory, by frame, of one run over the whole sequence from frame `first` (reused
    when `out` holds one)."""
    from hippo_nav.io.poses import read_kitti_poses

    if not (out / "trajectory_corrected.kitti.txt").is_file():
        _run(out, dataset, sequence, first or None, None, None)
    poses = read_kitti_poses(out / "trajectory_corrected.kitti.txt")
    return _by_frame(poses, np.arange(first, first + len(poses)), count)


def _merged(results: Path, split: int, start: int, count: int) -> np.ndarray:
    """Both days' frames as the session's final correction placed them (`trajectory_sessions.tum.txt`: day
    1's frames 0 … split−1, then the session's from `start`), by frame."""
    from hippo_nav.io.poses import read_tum

    _, poses = read_tum(results / "trajectory_sessions.tum.txt")
    frames = np.r_[0:split, start : start + len(poses) - split]
    return _by_frame(poses, frames, count)


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
        "--one-runs", type=int, default=3, help="one runs over the whole sequence, from frames 0, 1, ..."
    )
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
    count, draws = len(gt), max(1, args.one_runs)

    def one_runs(root: Path, first_dir: Path) -> list[np.ndarray]:
        dirs = [first_dir] + [first_dir.with_name(f"{first_dir.name}_from{k}") for k in range(1, draws)]
        return [_one_run(d, root, seq, k, count) for k, d in enumerate(dirs)]

    one_run = {args.renders: one_runs(args.renders, args.whole or args.out / "whole")}
    truths = {args.renders: gt}
    if args.changed is not None:
        changed_dir = args.whole_changed or args.out / "whole_changed"
        one_run[args.changed] = one_runs(args.changed, changed_dir)
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
                truth, wholes = truths[root], one_run[root]
                # The frames every one run has (from frame draws − 1 on).
                frames = np.arange(max(start, draws - 1), start + len(est))
                row["ate_2d_m"] = round(_ate_2d(truth[frames], est[frames - start]), 2)
                row["ate_2d_m_one_runs_same_frames"] = "/".join(
                    f"{_ate_2d(truth[frames], w[frames]):.2f}" for w in wholes
                )
                both = result.metrics.get("sessions", {})
                if "ate_2d_m" in both:
                    # Both days' frames: day 1's (0 … split−1) then this session's (start …).
                    merged = _merged(args.out / name, args.split, start, count)
                    frames = np.r_[draws - 1 : args.split, start : start + len(est)]
                    merged_m = _ate_2d(truth[frames], merged[frames])
                    ones = [_ate_2d(truth[frames], w[frames]) for w in wholes]
                    row["merged_ate_2d_m"] = round(merged_m, 2)
                    row["merged_day1_frames_ate_2d_m"] = round(both["ate_2d_m_earlier_sessions"], 2)
                    row["one_runs_ate_2d_m_same_frames"] = "/".join(f"{x:.2f}" for x in ones)
                    row["merged_over_one_runs"] = round(merged_m / float(np.mean(ones)), 2)
                offset = result.metrics.get("data", {}).get("disparity_offset_px")
                row["disparity_offset_px"] = None if offset is None else round(offset, 3)
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
