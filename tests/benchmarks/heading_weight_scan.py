"""How a finished map's correction depends on how stiff the odometry links hold heading (docs/results.md, 02).

For each results folder (a run with a ground truth; its `memory/path.npz` anchors every frame to a vertex), the
final pose graph (`map.bin`: the odometry and loop links the run found) is solved again with the odometry links'
heading information scaled by each factor, every frame is placed on the solved map (vertex ∘ offset), and the
ATE (2-D) is printed, with the error by eighths of the sequence for the first folder. Factor 1 reproduces the
run's own corrected map. The links the run found are kept: what an online run with other weights would have
found is not measured here.

    python tests/benchmarks/heading_weight_scan.py RESULTS [RESULTS ...] [--factors 1,0.1,0.01]

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


def main(argv: list[str] | None = None) -> int:
    from hippo_nav.map import PoseGraph

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path, nargs="+")
    parser.add_argument("--factors", default="1,0.3,0.1,0.03,0.01,0.005,0.003,0.001")
    args = parser.parse_args(argv)
    runs = {r: _load(r) for r in args.results}
    for factor in [float(f) for f in args.factors.split(",")]:
        cells = []
        for k, (name, (path, (poses, edges, measured, information, is_loop), truth)) in enumerate(
            runs.items()
        ):
            scaled = information.copy()
            scaled[~is_loop, 2, 2] *= factor
            graph = PoseGraph.from_arrays(poses, edges, measured, scaled, is_loop)
            graph.optimize(initialization="chordal")
            errors = _errors_m(path, truth, np.asarray(graph.poses()))
            cells.append(f"{name.name} {np.sqrt(np.mean(errors**2)):6.2f}")
            if k == 0:
                eighths = np.array_split(errors, 8)
                cells.append("(" + " ".join(f"{np.sqrt(np.mean(e**2)):.1f}" for e in eighths) + ")")
        print(f"heading information x{factor:<6g}", "  ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
