"""How a finished map's correction depends on how stiff the odometry links hold heading (docs/results.md, 02).

For each results folder (a run with a ground truth; its `memory/path.npz` anchors every frame to a vertex), the
final pose graph (`map.bin`: the odometry and loop links the run found) is solved again with the odometry links'
heading information scaled by each factor, every frame is placed on the solved map (vertex ∘ offset), and the
ATE (2-D) is printed, with the error by eighths of the sequence for the first folder. Factor 1 reproduces the
run's own corrected map. The links the run found are kept: what an online run with other weights would have
found is not measured here.

    python tests/benchmarks/heading_weight_scan.py RESULTS [RESULTS ...] [--factors 1,0.1,0.01]
    python tests/benchmarks/heading_weight_scan.py RESULTS [RESULTS ...] --per-rad 0,0.02,0.1

`--per-rad` instead lets each odometry link's heading deviation grow by K rad per radian the link turns, and
first prints, for each folder, the odometry's heading error over 20-frame windows (`trajectory_vo` against the
ground truth) on straight road and in turns (a window turning more than 0.2 rad): whether the VO's heading
error is a share of its turns, as such a model assumes.

Not a test (no assertions; pytest does not collect it).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def _load(results: Path):
    from hippo_nav.io.poses import read_kitti_poses
    from hippo_nav.map import ExperienceMap
    from hippo_nav.memory import read_memory

    path = read_memory(results).path
    if not path:
        raise SystemExit(f"{results}: its memory has no path.npz (run it with this hippo_nav)")
    graph = ExperienceMap.load(results / "map.bin").pose_graph()
    arrays = [np.asarray(a) for a in (graph.poses(), graph.edges(), graph.measurements())]
    arrays += [np.asarray(graph.information()), np.asarray(graph.is_loop())]
    return path, arrays, read_kitti_poses(results / "ground_truth.kitti.txt")


def _errors_m(path, truth: np.ndarray, poses: np.ndarray) -> np.ndarray:
    from hippo_nav.geometry import lift_planar, se2_compose
    from hippo_nav.metrics import ate_errors

    placed = se2_compose(poses[path["vertex"]], path["vertex_from_agent"])
    return ate_errors(truth, lift_planar(placed, np.eye(4)), planar=True, align="se3")


def _headings_rad(kitti_poses: Path) -> np.ndarray:
    """Each frame's heading in the ground plane (the camera's z axis on x–z), unwrapped."""
    z = np.loadtxt(kitti_poses).reshape(-1, 3, 4)[:, :, 2]
    return np.unwrap(np.arctan2(z[:, 0], z[:, 2]))


def _turn_errors(results: Path, frames: int = 20) -> str:
    """The odometry's heading error over `frames`-frame windows, straight and turning (module doc)."""
    vo, truth = (_headings_rad(results / f) for f in ("trajectory_vo.kitti.txt", "ground_truth.kitti.txt"))
    turn = truth[frames::frames] - truth[:-frames:frames]
    error = (vo[frames::frames] - vo[:-frames:frames]) - turn
    turning = np.abs(turn) > 0.2
    return (
        f"{results.name}: heading error over {frames} frames, std {1e3 * np.std(error[~turning]):.1f} mrad on "
        f"straight road ({np.sum(~turning)} windows), {1e3 * np.std(error[turning]):.1f} mrad in turns "
        f"({np.sum(turning)}); median |error| / |turn| in turns {100 * np.median(np.abs(error / turn)[turning]):.2f} %"
    )


def main(argv: list[str] | None = None) -> int:
    from hippo_nav.map import PoseGraph

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path, nargs="+")
    parser.add_argument("--factors", default="1,0.3,0.1,0.03,0.01,0.005,0.003,0.001")
    parser.add_argument("--per-rad", help="heading deviation added per radian of a link's turn, K,K,...")
    args = parser.parse_args(argv)
    runs = {r: _load(r) for r in args.results}
    per_rad = args.per_rad is not None
    if per_rad:
        for r in args.results:
            print(_turn_errors(r))
    for factor in [float(f) for f in (args.per_rad if per_rad else args.factors).split(",")]:
        cells = []
        for k, (name, (path, (poses, edges, measured, information, is_loop), truth)) in enumerate(
            runs.items()
        ):
            scaled = information.copy()
            odometry = ~is_loop
            if per_rad:
                sigma_rad = 1.0 / np.sqrt(information[odometry, 2, 2]) + factor * np.abs(
                    measured[odometry, 2]
                )
                scaled[odometry, 2, 2] = 1.0 / sigma_rad**2
            else:
                scaled[odometry, 2, 2] *= factor
            graph = PoseGraph.from_arrays(poses, edges, measured, scaled, is_loop)
            graph.optimize(initialization="chordal")
            errors = _errors_m(path, truth, np.asarray(graph.poses()))
            cells.append(f"{name.name} {np.sqrt(np.mean(errors**2)):6.2f}")
            if k == 0:
                eighths = np.array_split(errors, 8)
                cells.append("(" + " ".join(f"{np.sqrt(np.mean(e**2)):.1f}" for e in eighths) + ")")
        label = f"heading deviation +{factor:g} rad/rad" if per_rad else f"heading information x{factor:<6g}"
        print(label, "  ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
