"""Trajectory metrics: Umeyama, ATE, KITTI relative errors; equal to evo and to the devkit on real files."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from hippo_nav.io import DatasetError, read_kitti_poses, read_tum, write_kitti_poses, write_tum
from hippo_nav.metrics import (
    ate_rmse,
    interpolated_steps,
    relative_errors_kitti,
    relative_pose_errors,
    umeyama_alignment,
)
from hippo_nav.synthetic import loop_trajectory


def rotation_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def transformed(
    poses: np.ndarray, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0
) -> np.ndarray:
    out = poses.copy()
    out[:, :3, :3] = rotation @ poses[:, :3, :3]
    out[:, :3, 3] = scale * poses[:, :3, 3] @ rotation.T + translation
    return out


def test_umeyama_recovers_a_similarity_in_3d_and_2d() -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(50, 3))
    rotation = rotation_y(0.7) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    target = 2.5 * points @ rotation.T + [1.0, -2.0, 3.0]
    r, t, s = umeyama_alignment(points, target, with_scale=True)
    np.testing.assert_allclose(r, rotation, atol=1e-12)
    np.testing.assert_allclose(t, [1.0, -2.0, 3.0], atol=1e-12)
    assert s == pytest.approx(2.5)
    rotation_2d = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    r2, t2, s2 = umeyama_alignment(points[:, :2], points[:, :2] @ rotation_2d.T + [4.0, 5.0])
    np.testing.assert_allclose(r2, rotation_2d, atol=1e-12)
    np.testing.assert_allclose(t2, [4.0, 5.0], atol=1e-12)
    assert s2 == 1.0
    with pytest.raises(DatasetError, match="all the same point"):
        umeyama_alignment(np.zeros((5, 3)), points[:5])


def test_ate_is_invariant_to_the_alignment_it_fits() -> None:
    gt = loop_trajectory(120)
    moved = transformed(gt, rotation_y(1.1), np.array([5.0, 1.0, -3.0]))
    assert ate_rmse(gt, moved) == pytest.approx(0.0, abs=1e-9)
    assert ate_rmse(gt, moved, align="none") > 1.0
    scaled = transformed(gt, rotation_y(-0.4), np.array([2.0, 0.0, 1.0]), scale=0.8)
    assert ate_rmse(gt, scaled) > 1.0
    assert ate_rmse(gt, scaled, align="sim3") == pytest.approx(0.0, abs=1e-9)
    assert ate_rmse(gt, scaled, planar=True, align="sim3") == pytest.approx(0.0, abs=1e-9)
    # A known residual: every position off by 0.3 m in height (y) — invisible in the planar metric.
    lifted = gt.copy()
    lifted[::2, 1, 3] += 0.3
    lifted[1::2, 1, 3] -= 0.3
    assert ate_rmse(gt, lifted, align="none") == pytest.approx(0.3)
    assert ate_rmse(gt, lifted, planar=True, align="none") == pytest.approx(0.0, abs=1e-12)


def test_metrics_accept_any_layout_and_reject_bad_input() -> None:
    gt = loop_trajectory(60)
    est = transformed(gt, rotation_y(0.2), np.array([0.5, 0.0, 0.5]))
    est[:, 0, 3] += np.sin(np.arange(60))
    reference = ate_rmse(gt, est)
    assert ate_rmse(np.asfortranarray(gt), est[:, :3, :]) == pytest.approx(reference, abs=1e-12)
    assert ate_rmse(
        np.repeat(gt, 2, axis=0)[::2], est.transpose(0, 2, 1).transpose(0, 2, 1)
    ) == pytest.approx(reference)
    with pytest.raises(DatasetError, match="ground truth has 60 poses, the estimate 59"):
        ate_rmse(gt, est[:-1])
    bad = est.copy()
    bad[3, 0, 0] = np.nan
    with pytest.raises(DatasetError, match="estimate contains NaN"):
        ate_rmse(gt, bad)
    with pytest.raises(DatasetError, match="shape"):
        ate_rmse(gt, est[:, :, :3])
    with pytest.raises(DatasetError, match="align must be"):
        ate_rmse(gt, est, align="rigid")
    # Before: a zero length gave inf t_rel, a negative one a negative error, a fractional pair was truncated,
    # and NaN points ended in "SVD did not converge".
    for lengths in ([0.0], [-100.0]):
        with pytest.raises(DatasetError, match="segment lengths must be finite and > 0"):
            relative_errors_kitti(gt, est, lengths=lengths)
    with pytest.raises(DatasetError, match="whole frame indices"):
        relative_pose_errors(gt, est, [[0.5, 3.7]])
    with pytest.raises(DatasetError, match="every coordinate finite"):
        umeyama_alignment(np.full((4, 2), np.nan), np.zeros((4, 2)))


def devkit_relative_errors(
    gt: np.ndarray, est: np.ndarray, lengths, step: int = 10
) -> tuple[float, float, int]:
    """A line-by-line port of the KITTI devkit's calcSequenceErrors (evaluate_odometry.cpp)."""
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[-1] + float(np.linalg.norm(gt[i, :3, 3] - gt[i - 1, :3, 3])))
    t_sum = r_sum = 0.0
    count = 0
    for first in range(0, len(gt), step):
        for length in lengths:
            last = next((i for i in range(first, len(dist)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            delta_gt = np.linalg.inv(gt[first]) @ gt[last]
            delta_est = np.linalg.inv(est[first]) @ est[last]
            error = np.linalg.inv(delta_est) @ delta_gt
            d = 0.5 * (error[0, 0] + error[1, 1] + error[2, 2] - 1.0)
            r_sum += np.arccos(max(min(d, 1.0), -1.0)) / length
            t_sum += np.linalg.norm(error[:3, 3]) / length
            count += 1
    return t_sum / count * 100, np.degrees(r_sum / count) * 100, count


def test_relative_errors_match_a_port_of_the_devkit() -> None:
    gt = loop_trajectory(400, speed_m_per_frame=1.5)
    rng = np.random.default_rng(1)
    est = gt.copy()
    drift = np.cumsum(rng.normal(scale=0.002, size=400))
    for k in range(400):
        est[k, :3, :3] = rotation_y(drift[k]) @ gt[k, :3, :3]
        est[k, :3, 3] = 1.02 * gt[k, :3, 3] + rng.normal(scale=0.05, size=3)
    lengths = (50.0, 100.0, 200.0)
    ours = relative_errors_kitti(gt, est, lengths=lengths, step=7)
    t_ref, r_ref, count = devkit_relative_errors(gt, est, lengths, step=7)
    assert ours["segments"] == count > 100
    assert ours["t_rel_percent"] == pytest.approx(t_ref, rel=1e-12)
    # The port's arccos loses ~1e-8 rad near zero; our stable angle formula is exact there.
    assert ours["r_rel_deg_per_100m"] == pytest.approx(r_ref, rel=1e-6)
    assert set(ours["per_length"]) == set(lengths)
    assert sum(v["segments"] for v in ours["per_length"].values()) == count


def test_relative_errors_of_a_scaled_straight_drive() -> None:
    # Straight 1 m steps, estimate 3 % too long: every segment's error is 3 % of its (≥ L) chord.
    n = 1000
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 2, 3] = np.arange(n, dtype=float)
    est = gt.copy()
    est[:, 2, 3] *= 1.03
    result = relative_errors_kitti(gt, est)
    # The segment of length L spans L + 1 frames (first frame strictly beyond L).
    expected = np.mean(
        [
            3.0 * (length + 1) / length
            for length in range(100, 900, 100)
            for first in range(0, n, 10)
            if first + length + 1 < n
        ]
    )
    assert result["t_rel_percent"] == pytest.approx(expected, rel=1e-12)
    assert result["r_rel_deg_per_100m"] == pytest.approx(0.0, abs=1e-9)
    short = relative_errors_kitti(gt[:50], est[:50])
    assert short["segments"] == 0 and np.isnan(short["t_rel_percent"])


def wobbly_drive(n: int, seed: int = 2) -> np.ndarray:
    """1 m steps forward, each turning by a random small yaw (σ 0.1°, as measured KITTI steps differ)."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    for k in range(1, n):
        step = np.eye(4)
        step[:3, :3] = rotation_y(np.radians(rng.normal(scale=0.1)))
        step[2, 3] = 1.0
        poses[k] = poses[k - 1] @ step
    return poses


def test_interpolated_ground_truth_is_found_and_its_segments_left_out() -> None:
    """Steps 20–31 of a measured drive replaced by one constant motion, as KITTI's GPS gaps are: exactly
    those steps are flagged, and an estimate that drove what the car really did is judged without them."""
    truth = wobbly_drive(120)
    gt = truth.copy()
    constant = np.linalg.inv(truth[20]) @ truth[32]  # the gap's end points kept, the motion between made even
    twist = np.eye(4)
    twist[:3, :3] = rotation_y(np.arctan2(constant[0, 2], constant[2, 2]) / 12)
    twist[2, 3] = 1.0
    for k in range(21, 32):
        gt[k] = gt[k - 1] @ twist
    for k in range(32, 120):
        gt[k] = gt[31] @ twist @ np.linalg.inv(truth[32]) @ truth[k]
    flags = interpolated_steps(gt)
    assert np.flatnonzero(flags).tolist() == list(range(20, 32))
    assert not interpolated_steps(truth).any()
    assert not interpolated_steps(gt, min_steps=13).any()  # a run of 12 steps is shorter than 13

    est = truth  # what the car did: the interpolated ground truth disagrees with it only inside the gap
    lengths = (5.0, 10.0, 20.0)
    every = relative_errors_kitti(gt, est, lengths=lengths, step=1)
    measured = relative_errors_kitti(gt, est, lengths=lengths, step=1, exclude_steps=flags)
    assert measured["segments"] < every["segments"]
    assert measured["r_rel_deg_per_100m"] < 1e-6 < every["r_rel_deg_per_100m"]
    none = relative_errors_kitti(gt, est, lengths=lengths, step=1, exclude_steps=np.zeros(119, dtype=bool))
    assert none == every
    with pytest.raises(DatasetError, match="one flag per step"):
        relative_errors_kitti(gt, est, lengths=lengths, exclude_steps=flags[:-1])


@pytest.mark.data
def test_kitti_ground_truth_gaps(shared_data: Path) -> None:
    """The released KITTI poses: 06 frames 0–11 are a constant motion (docs/vo.md); 01 has none."""
    poses = shared_data / "kitti_odometry" / "poses"
    assert np.flatnonzero(interpolated_steps(read_kitti_poses(poses / "06.txt"))).tolist() == list(range(11))
    assert not interpolated_steps(read_kitti_poses(poses / "01.txt")).any()


@pytest.fixture(scope="module")
def peer(shared_data: Path) -> dict[str, np.ndarray]:
    folder = shared_data / "peer_trajectories"
    return {name: read_kitti_poses(folder / f"KITTI_00_{name}.txt") for name in ("gt", "ORB", "SPTAM")}


@pytest.mark.data
def test_orb_slam2_numbers_on_kitti_00(peer: dict[str, np.ndarray]) -> None:
    # ATE ≈ 1.30 m (evo's documented value); the ORB-SLAM2 paper reports t_rel 0.70 %, r_rel 0.25°/100 m.
    assert ate_rmse(peer["gt"], peer["ORB"]) == pytest.approx(1.30, abs=0.01)
    assert ate_rmse(peer["gt"], peer["SPTAM"]) == pytest.approx(3.74, abs=0.01)
    relative = relative_errors_kitti(peer["gt"], peer["ORB"])
    assert relative["t_rel_percent"] == pytest.approx(0.70, abs=0.01)
    assert relative["r_rel_deg_per_100m"] == pytest.approx(0.25, abs=0.01)


@pytest.mark.data
@pytest.mark.parametrize("name", ["ORB", "SPTAM"])
@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
def test_ate_equals_evo_on_the_same_files(
    tmp_path: Path, peer: dict[str, np.ndarray], name: str, align: str
) -> None:
    file_interface = pytest.importorskip("evo.tools.file_interface")
    from evo.core import metrics
    from evo.main_ape import ape

    # Both sides read the same files: the ground truth as TUM and the estimate as KITTI, written by us.
    stamps = np.arange(len(peer["gt"])) * 0.1
    gt_path = write_tum(tmp_path / "gt.tum", stamps, peer["gt"])
    est_path = write_kitti_poses(tmp_path / "est.txt", peer[name])
    ref = file_interface.read_tum_trajectory_file(str(gt_path))
    traj = file_interface.read_kitti_poses_file(str(est_path))
    theirs = ape(
        ref, traj, metrics.PoseRelation.translation_part, align=align != "none", correct_scale=align == "sim3"
    ).stats["rmse"]
    ours = ate_rmse(read_tum(gt_path)[1], read_kitti_poses(est_path), align=align)
    assert ours == pytest.approx(theirs, abs=1e-6)


@pytest.mark.data
@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_planar_ate_equals_evo_on_projected_trajectories(peer: dict[str, np.ndarray], align: str) -> None:
    trajectory = pytest.importorskip("evo.core.trajectory")
    from evo.core import metrics
    from evo.main_ape import ape

    gt, est = peer["gt"].copy(), peer["ORB"].copy()
    # Our planar ATE projects onto x–z first, then aligns; evo on the projected files must agree.
    for poses in (gt, est):
        poses[:, 1, 3] = 0.0
    ref = trajectory.PosePath3D(poses_se3=list(gt))
    traj = trajectory.PosePath3D(poses_se3=list(est))
    theirs = ape(
        ref, traj, metrics.PoseRelation.translation_part, align=True, correct_scale=align == "sim3"
    ).stats["rmse"]
    assert ate_rmse(peer["gt"], peer["ORB"], planar=True, align=align) == pytest.approx(theirs, abs=1e-6)


@pytest.mark.data
@pytest.mark.parametrize("delta", [1, 10, 100])
def test_relative_pose_errors_equal_evo_rpe(peer: dict[str, np.ndarray], delta: int) -> None:
    trajectory = pytest.importorskip("evo.core.trajectory")
    from evo.core import metrics

    gt, est = peer["gt"], peer["ORB"]
    pairs = np.stack([np.arange(0, len(gt), delta)[:-1], np.arange(0, len(gt), delta)[1:]], axis=1)
    t_err, r_err = relative_pose_errors(gt, est, pairs)
    data = (trajectory.PosePath3D(poses_se3=list(gt)), trajectory.PosePath3D(poses_se3=list(est)))
    for relation, ours in (
        (metrics.PoseRelation.translation_part, t_err),
        (metrics.PoseRelation.rotation_angle_rad, r_err),
    ):
        rpe = metrics.RPE(relation, delta=delta, delta_unit=metrics.Unit.frames, all_pairs=False)
        rpe.process_data(copy.deepcopy(data))
        np.testing.assert_allclose(ours, rpe.error, atol=1e-6)
