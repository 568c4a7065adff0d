"""hippo_nav's pose-graph solver against GTSAM's Levenberg–Marquardt, in one run, from the same start.

    python tests/benchmarks/posegraph_vs_gtsam.py [--data ../shared/data] [--graphs intel grid1000 ...]
        [--starts chordal odometry] [--repeat 3] [--relative-tolerance 1e-6] [--json out.json]

Graphs: the standard 2-D benchmarks of the shared data (`posegraphs/*.g2o`: intel, city10000, kitti_00,
when present) and synthetic grid worlds of 10³, 10⁴ and 10⁵ vertices (`grid_world` below: a random walk on
a unit grid, noisy odometry, closures to earlier poses within 1 m; the generator of the Rust tests).
Starts: `chordal` (hippo_nav's chordal initialisation) and `odometry` (dead reckoning); both solvers start
from exactly these poses, so only the nonlinear solve is timed: `PoseGraph.optimize(initialization=
"current")` for hippo_nav, building `LevenbergMarquardtOptimizer` (its ordering) plus `optimize()` for
GTSAM. Graph construction is not timed. Both stop when an accepted step lowers the cost by less than
`--relative-tolerance` of it (GTSAM's `relativeErrorTol`; its absolute tolerance is set to 0); the gauge
is vertex 0 (fixed in hippo_nav, a prior of σ = 1e-6 in GTSAM). Solvers:
- `hippo`: the defaults (Gauss–Newton first, Levenberg–Marquardt when a step fails);
- `hippo-nielsen` (with `--nielsen`): the earlier damped schedule, λ₀ = 10⁻⁵·max diag(H), shrinking at
  most 3× per accepted step;
- `gtsam`: `LevenbergMarquardtOptimizer` with its default parameters otherwise (λ₀ = 10⁻⁵, ×10 / ÷10,
  multifrontal Cholesky, COLAMD). Both are single-threaded (the PyPI wheel has no TBB).
χ² is g2o's `Σ eᵀΩe`: GTSAM's error × 2, and, to compare the solutions themselves, hippo_nav's own χ² of
GTSAM's poses (`χ² at poses`). Each time is the best (wall clock) of `--repeat` runs, the solvers
interleaved; `CPU s` is that run's process time, less sensitive to other jobs on a shared machine.
Needs the optional `gtsam` dependency (`pip install -e '.[bench]'`); pytest does not collect this file
(`test_posegraph_bench.py` runs a small part of it as a pytest-benchmark).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from hippo_nav._core import PoseGraph

PROJECT_ROOT = Path(__file__).resolve().parents[2]
FILES = ("intel", "city10000", "kitti_00")
GRIDS = {"grid1000": 1_000, "grid10000": 10_000, "grid100000": 100_000}
PRIOR_SIGMA = 1e-6


@dataclass
class Arrays:
    """A pose graph as arrays (the arguments of `PoseGraph.from_arrays`)."""

    poses: np.ndarray
    edges: np.ndarray
    measurements: np.ndarray
    information: np.ndarray
    is_loop: np.ndarray

    @classmethod
    def of(cls, graph: PoseGraph) -> Arrays:
        return cls(graph.poses(), graph.edges(), graph.measurements(), graph.information(), graph.is_loop())

    def graph(self, poses: np.ndarray | None = None) -> PoseGraph:
        return PoseGraph.from_arrays(
            self.poses if poses is None else poses,
            self.edges,
            self.measurements,
            self.information,
            self.is_loop,
        )


@dataclass
class Result:
    graph: str
    start: str
    solver: str
    vertices: int
    edges: int
    iterations: int
    initial_chi2: float
    final_chi2: float
    chi2_at_poses: float
    seconds: float
    cpu_seconds: float
    speedup_vs_gtsam: float = math.nan


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`a⁻¹ ⊕ b` for rows of poses `(x, y, yaw)`."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, _wrap(b[:, 2] - a[:, 2])], axis=1)


def grid_world(
    n: int,
    seed: int = 11,
    closure_radius_m: float = 1.0,
    max_closures: int = 2,
    sigma_xy_m: float = 0.05,
    sigma_yaw_rad: float = 0.01,
) -> Arrays:
    """A Manhattan-world random walk on a unit grid (like M3500 / City10000), as in the Rust tests'
    `manhattan_world`: `n` poses, each step turns left or right with probability 1/10 each and stays in a
    square of side ≈ √n; noisy odometry; a closure from every pose to earlier poses (not its predecessor)
    in cells within `closure_radius_m`, at most `max_closures` a pose, all with the odometry's noise."""
    rng = np.random.default_rng(seed)
    half_side = math.ceil(math.sqrt(n) * 0.5) + 2
    directions = ((1, 0), (0, 1), (-1, 0), (0, -1))
    cells = np.zeros((n, 2), dtype=np.int64)
    headings = np.zeros(n, dtype=np.int64)
    turns = rng.integers(0, 10, size=n)
    x = y = heading = 0
    occupied: dict[tuple[int, int], list[int]] = {(0, 0): [0]}
    for i in range(1, n):
        h = heading + (1 if turns[i] == 0 else -1 if turns[i] == 1 else 0)
        while True:
            dx, dy = directions[h % 4]
            if abs(x + dx) <= half_side and abs(y + dy) <= half_side:
                break
            h += 1
        heading, x, y = h, x + dx, y + dy
        cells[i] = (x, y)
        headings[i] = heading
        occupied.setdefault((x, y), []).append(i)
    truth = np.column_stack([cells.astype(float), _wrap(headings * (np.pi / 2))])

    pairs = [(i - 1, i) for i in range(1, n)]
    reach = math.ceil(closure_radius_m)
    offsets = [
        (dx, dy)
        for dx in range(-reach, reach + 1)
        for dy in range(-reach, reach + 1)
        if math.hypot(dx, dy) <= closure_radius_m
    ]
    n_odometry = len(pairs)
    for i in range(n):
        added = 0
        for dx, dy in offsets:
            for j in occupied.get((int(cells[i, 0]) + dx, int(cells[i, 1]) + dy), ()):
                if added < max_closures and j + 1 < i:
                    pairs.append((j, i))
                    added += 1
    ends = np.array(pairs, dtype=np.int64)
    measured = _between(truth[ends[:, 0]], truth[ends[:, 1]])
    noise = rng.normal(size=measured.shape) * np.array([sigma_xy_m, sigma_xy_m, sigma_yaw_rad])
    information = np.diag([sigma_xy_m**-2, sigma_xy_m**-2, sigma_yaw_rad**-2])
    is_loop = np.arange(len(pairs)) >= n_odometry
    return Arrays(
        poses=np.zeros((n, 3)),
        edges=ends,
        measurements=measured + noise,
        information=np.broadcast_to(information, (len(pairs), 3, 3)).copy(),
        is_loop=is_loop,
    )


def load_graph(name: str, data: Path | None) -> Arrays | None:
    if name in GRIDS:
        return grid_world(GRIDS[name])
    path = None if data is None else data / "posegraphs" / f"{name}.g2o"
    if path is None or not path.is_file():
        return None
    return Arrays.of(PoseGraph.read_g2o(path))


def start_poses(arrays: Arrays, start: str) -> np.ndarray:
    """The initial estimate both solvers start from."""
    graph = arrays.graph()
    if start == "odometry":
        graph.initialize_from_odometry()
    elif start == "chordal":
        graph.optimize(initialization="chordal", max_iterations=0)
    else:
        raise SystemExit(f"unknown start {start!r}")
    return graph.poses()


def solve_hippo(
    arrays: Arrays, start: np.ndarray, tolerance: float, nielsen: bool
) -> tuple[float, dict[str, Any], np.ndarray]:
    graph = arrays.graph(start)
    # The earlier damped schedule, or None: the defaults.
    initial_lambda_scale, max_lambda_decrease = (1e-5, 3.0) if nielsen else (None, None)
    began, began_cpu = time.perf_counter(), time.process_time()
    solved = graph.optimize(
        initialization="current",
        relative_cost_tolerance=tolerance,
        max_iterations=200,
        initial_lambda_scale=initial_lambda_scale,
        max_lambda_decrease=max_lambda_decrease,
    )
    seconds = time.perf_counter() - began
    report = {**solved.as_dict(), "cpu_seconds": time.process_time() - began_cpu}
    return seconds, report, graph.poses()


def gtsam_problem(arrays: Arrays) -> Any:
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    graph.add(
        gtsam.PriorFactorPose2(
            0, gtsam.Pose2(*arrays.poses[0]), gtsam.noiseModel.Isotropic.Sigma(3, PRIOR_SIGMA)
        )
    )
    for (i, j), z, omega in zip(arrays.edges, arrays.measurements, arrays.information):
        graph.add(
            gtsam.BetweenFactorPose2(
                int(i), int(j), gtsam.Pose2(*z), gtsam.noiseModel.Gaussian.Information(omega)
            )
        )
    return graph


def solve_gtsam(
    problem: Any, start: np.ndarray, tolerance: float
) -> tuple[float, dict[str, Any], np.ndarray]:
    import gtsam

    initial = gtsam.Values()
    for k, pose in enumerate(start):
        initial.insert(k, gtsam.Pose2(*pose))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(tolerance)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(200)
    initial_error = problem.error(initial)
    began, began_cpu = time.perf_counter(), time.process_time()
    optimizer = gtsam.LevenbergMarquardtOptimizer(problem, initial, params)
    result = optimizer.optimize()
    seconds = time.perf_counter() - began
    cpu_seconds = time.process_time() - began_cpu
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (result.atPose2(k) for k in range(len(start)))])
    report = {
        "iterations": optimizer.iterations(),
        "initial_chi2": 2.0 * initial_error,
        "final_chi2": 2.0 * problem.error(result),
        "cpu_seconds": cpu_seconds,
    }
    return seconds, report, poses


def run(
    names: list[str], starts: list[str], data: Path | None, repeat: int, tolerance: float, nielsen: bool
) -> list[Result]:
    results: list[Result] = []
    for name in names:
        arrays = load_graph(name, data)
        if arrays is None:
            print(f"skipping {name}: not found under {data}", file=sys.stderr)
            continue
        problem = gtsam_problem(arrays)
        n, m = len(arrays.poses), len(arrays.edges)
        for start in starts:
            initial = start_poses(arrays, start)
            solvers = ["hippo", "hippo-nielsen", "gtsam"] if nielsen else ["hippo", "gtsam"]
            best: dict[str, tuple[float, dict[str, Any], np.ndarray]] = {}
            # 10⁵ vertices from dead reckoning takes GTSAM minutes: once is enough there.
            runs = 1 if n >= 100_000 else repeat
            for _ in range(runs):
                for solver in solvers:
                    if solver == "gtsam":
                        outcome = solve_gtsam(problem, initial, tolerance)
                    else:
                        outcome = solve_hippo(arrays, initial, tolerance, solver == "hippo-nielsen")
                    if solver not in best or outcome[0] < best[solver][0]:
                        best[solver] = outcome
            gtsam_seconds = best["gtsam"][0]
            for solver in solvers:
                seconds, report, poses = best[solver]
                results.append(
                    Result(
                        graph=name,
                        start=start,
                        solver=solver,
                        vertices=n,
                        edges=m,
                        iterations=int(report["iterations"]),
                        initial_chi2=float(report["initial_chi2"]),
                        final_chi2=float(report["final_chi2"]),
                        chi2_at_poses=arrays.graph(poses).chi2(),
                        seconds=seconds,
                        cpu_seconds=float(report["cpu_seconds"]),
                        speedup_vs_gtsam=gtsam_seconds / seconds,
                    )
                )
                print(format_row(results[-1]), flush=True)
    return results


HEADER = (
    "| graph | start | solver | vertices | edges | iterations | final χ² | χ² at poses | seconds | CPU s "
    "| GTSAM s / this s |\n|---|---|---|---|---|---|---|---|---|---|---|"
)


def format_row(r: Result) -> str:
    return (
        f"| {r.graph} | {r.start} | {r.solver} | {r.vertices} | {r.edges} | {r.iterations} | "
        f"{r.final_chi2:.6g} | {r.chi2_at_poses:.6g} | {r.seconds:.3f} | {r.cpu_seconds:.3f} | "
        f"{r.speedup_vs_gtsam:.2f} |"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=PROJECT_ROOT.parent / "shared" / "data")
    parser.add_argument("--graphs", nargs="+", default=[*FILES, *GRIDS])
    parser.add_argument("--starts", nargs="+", default=["chordal", "odometry"])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--relative-tolerance", type=float, default=1e-6)
    parser.add_argument("--nielsen", action="store_true", help="also run the earlier damped schedule")
    parser.add_argument("--json", type=Path, help="write every result here")
    args = parser.parse_args(argv)
    try:
        import gtsam  # noqa: F401
    except ImportError:
        print("gtsam is not installed: pip install -e '.[bench]'", file=sys.stderr)
        return 2
    print(f"relative cost tolerance {args.relative_tolerance:g} for both; best of {args.repeat}")
    print(HEADER, flush=True)
    results = run(args.graphs, args.starts, args.data, args.repeat, args.relative_tolerance, args.nielsen)
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in results], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
