"""The experience map and pose-graph correctors through the Python face."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hippo_nav import HippoNavError
from hippo_nav.map import ExperienceMap, MapParams, PoseGraph, new_experience_map, read_g2o


def square_circuit(laps: int, yaw_bias_rad: float) -> list[tuple]:
    """A 20 m square at 1 m per frame seen by a perfect front end, with odometry yaw drift."""
    frames = []
    x = y = yaw = 0.0
    for step in range(laps * 80):
        s = step % 80
        turn = math.pi / 2 if s % 20 == 19 else 0.0
        odometry = (0.0, 0.0, 0.0) if step == 0 else (1.0, 0.0, turn + yaw_bias_rad)
        frames.append((s // 4, (x * 2 * math.pi / 100, y * 2 * math.pi / 100), yaw, odometry, 0.1))
        x, y = x + math.cos(yaw), y + math.sin(yaw)
        yaw = math.remainder(yaw + turn, 2 * math.pi)
    return frames


def test_python_defaults_are_the_rust_defaults() -> None:
    assert json.loads(MapParams().model_dump_json()) == json.loads(ExperienceMap.default_params_json())


def test_second_lap_closes_the_loop_and_both_correctors_reduce_the_cost() -> None:
    m = new_experience_map(MapParams(online_relaxation_passes=0))
    outcomes = [m.on_frame(*f) for f in square_circuit(2, 0.01)]
    closures = [k for k, o in enumerate(outcomes) if o["loop_closure"] is not None]
    assert closures and 80 <= closures[0] <= 84
    assert not any(o["loop_closure"] for o in outcomes[:80])
    graph = m.export()
    assert graph["poses"].shape == (len(m), 3)
    assert graph["links"].shape == (len(graph["link_is_loop"]), 2)
    assert graph["link_is_loop"].sum() == len(closures)
    before = m.pose_graph().chi2()
    relaxed = m.pose_graph()
    relaxation = relaxed.relax(passes=200)
    report = m.correct("least_squares")
    assert report["converged"]
    assert relaxation["final_chi2"] < 0.5 * before
    assert report["final_chi2"] <= relaxation["final_chi2"]
    np.testing.assert_allclose(m.poses()[0], [0.0, 0.0, 0.0], atol=1e-12)


def _loop_arrays(n: int = 40) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(0)
    step = np.array([1.0, 0.0, 2 * math.pi / n])
    poses = np.zeros((n, 3))
    edges = np.array([[i, (i + 1) % n] for i in range(n)], dtype=np.int64)
    measurements = np.tile(step, (n, 1)) + rng.normal(0, 0.01, (n, 3))
    information = np.tile(np.diag([100.0, 100.0, 1000.0]), (n, 1, 1))
    is_loop = np.zeros(n, dtype=bool)
    is_loop[-1] = True
    return poses, edges, measurements, information, is_loop


def test_pose_graph_accepts_any_numpy_layout() -> None:
    poses, edges, measurements, information, is_loop = _loop_arrays()
    reference = PoseGraph.from_arrays(poses, edges, measurements, information, is_loop)
    reference.initialize_from_odometry()
    reference.optimize(initialization="current")
    # Transposed (Fortran-ordered) and strided views of the same numbers.
    wide = np.zeros((measurements.shape[0], 6))
    wide[:, ::2] = measurements
    other = PoseGraph.from_arrays(
        np.asfortranarray(poses), edges.T.copy().T, wide[:, ::2], information.transpose(0, 2, 1), is_loop
    )
    other.initialize_from_odometry()
    other.optimize(initialization="current")
    np.testing.assert_array_equal(other.poses(), reference.poses())
    assert reference.chi2() < 1.0


def test_bad_arrays_and_parameters_raise_clear_errors() -> None:
    poses, edges, measurements, information, is_loop = _loop_arrays()
    bad = measurements.copy()
    bad[3, 1] = np.nan
    with pytest.raises(HippoNavError, match="NaN"):
        PoseGraph.from_arrays(poses, edges, bad, information, is_loop)
    with pytest.raises(HippoNavError, match="shape"):
        PoseGraph.from_arrays(poses[:, :2], edges, measurements, information, is_loop)
    with pytest.raises(HippoNavError, match="does not exist"):
        PoseGraph.from_arrays(poses[:10], edges, measurements, information, is_loop)
    graph = PoseGraph.from_arrays(poses, edges, measurements, information, is_loop)
    with pytest.raises(HippoNavError, match="robust_loss"):
        graph.optimize(robust_loss="tukey")
    m = new_experience_map()
    with pytest.raises(HippoNavError, match="finite"):
        m.on_frame(1, (0.0, float("inf")), 0.0, (0.0, 0.0, 0.0), 0.1)
    with pytest.raises(ValueError):
        MapParams(place_threshold_rad=-1.0)


def test_save_load_round_trip_and_corrupted_files(tmp_path) -> None:
    m = new_experience_map()
    frames = square_circuit(2, 0.01)
    for f in frames[:100]:
        m.on_frame(*f)
    path = tmp_path / "map.hnm"
    m.save(path)
    loaded = ExperienceMap.load(path)
    a, b = m.export(), loaded.export()
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert loaded.current_vertex == m.current_vertex
    for f in frames[100:]:
        assert loaded.on_frame(*f) == m.on_frame(*f)
    data = path.read_bytes()
    (tmp_path / "truncated.hnm").write_bytes(data[: len(data) // 2])
    with pytest.raises(HippoNavError, match="truncated"):
        ExperienceMap.load(tmp_path / "truncated.hnm")
    (tmp_path / "foreign.hnm").write_bytes(b"\x89PNG\r\n\x1a\n")
    with pytest.raises(HippoNavError, match="not a hippo_nav map file"):
        ExperienceMap.load(tmp_path / "foreign.hnm")
    flipped = bytearray(data)
    flipped[-20] ^= 0x01
    (tmp_path / "flipped.hnm").write_bytes(bytes(flipped))
    with pytest.raises(HippoNavError, match="checksum"):
        ExperienceMap.load(tmp_path / "flipped.hnm")


def test_g2o_write_read_round_trip(tmp_path) -> None:
    m = new_experience_map(MapParams(online_relaxation_passes=0))
    for f in square_circuit(2, 0.01):
        m.on_frame(*f)
    m.write_g2o(tmp_path / "map.g2o")
    graph = read_g2o(tmp_path / "map.g2o")
    np.testing.assert_array_equal(graph.poses(), m.poses())
    assert graph.chi2() == pytest.approx(m.pose_graph().chi2(), rel=1e-12)
    assert graph.is_loop().sum() == m.export()["link_is_loop"].sum()


@pytest.mark.data
def test_intel_benchmark_reaches_reference_optimum(shared_data) -> None:
    graph = read_g2o(shared_data / "posegraphs" / "intel.g2o")
    report = graph.optimize(initialization="chordal")
    assert report["converged"]
    assert report["final_chi2"] == pytest.approx(45.005, rel=1e-3)
