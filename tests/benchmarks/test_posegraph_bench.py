"""Pose-graph solve against GTSAM's Levenberg–Marquardt (`make bench`; needs the optional `gtsam`).

The whole comparison (real graphs, 10³–10⁵ grid worlds, both starts, one table) is the script
`posegraph_vs_gtsam.py` beside this file; this runs its small cases under pytest-benchmark, one group per
graph and start (`posegraph_<graph>_<start>`: compare `hippo` with `gtsam` inside a group); each round
includes building the start (`PoseGraph.from_arrays` / `gtsam.Values`), which the script does not time. Without
`gtsam` the module is skipped. `test_same_optimum_as_gtsam` is not a benchmark: whenever gtsam is
installed it checks that both solvers end at the same χ² from the same start, the condition under which
their times may be compared.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gtsam")

# The sibling script; pytest puts this folder on sys.path.
import posegraph_vs_gtsam as bench
from conftest import shared_data_dir

TOLERANCE = 1e-6
CASES = [("grid1000", "chordal"), ("grid1000", "odometry"), ("intel", "chordal"), ("intel", "odometry")]


def _case(name: str, start: str) -> tuple[bench.Arrays, np.ndarray, object]:
    data: Path | None = shared_data_dir()
    arrays = bench.load_graph(name, data)
    if arrays is None:
        pytest.skip(f"{name} needs ../shared/data")
    return arrays, bench.start_poses(arrays, start), bench.gtsam_problem(arrays)


@pytest.mark.parametrize(("name", "start"), CASES)
def test_same_optimum_as_gtsam(name: str, start: str) -> None:
    arrays, initial, problem = _case(name, start)
    _, ours, our_poses = bench.solve_hippo(arrays, initial, TOLERANCE, nielsen=False)
    _, theirs, their_poses = bench.solve_gtsam(problem, initial, TOLERANCE)
    ours_chi2 = arrays.graph(our_poses).chi2()
    theirs_chi2 = arrays.graph(their_poses).chi2()
    assert ours["converged"]
    assert ours_chi2 == pytest.approx(theirs_chi2, rel=1e-5)
    # GTSAM needs no fewer Gauss–Newton steps: the undamped first step wastes none on damping.
    assert ours["iterations"] <= theirs["iterations"] + 1


@pytest.mark.parametrize("solver", ["hippo", "gtsam"])
@pytest.mark.parametrize(("name", "start"), CASES)
def test_solve(benchmark, name: str, start: str, solver: str) -> None:
    arrays, initial, problem = _case(name, start)
    benchmark.group = f"posegraph_{name}_{start}"
    if solver == "hippo":
        report = benchmark(lambda: bench.solve_hippo(arrays, initial, TOLERANCE, nielsen=False)[1])
    else:
        report = benchmark(lambda: bench.solve_gtsam(problem, initial, TOLERANCE)[1])
    assert report["iterations"] > 0
