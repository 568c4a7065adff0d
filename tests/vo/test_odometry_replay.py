"""Replaying another system's odometry file (`hippo_nav.vo.replay`, `hippo-nav run --odometry`) and the
drifting-odometry generator (`hippo_nav.synthetic.drifting_odometry`)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from hippo_nav.cli import main
from hippo_nav.datasets import DatasetError, KittiOdometry
from hippo_nav.io import matrix_from_quaternion, read_kitti_poses, write_kitti_poses, write_tum
from hippo_nav.synthetic import drifting_odometry, loop_trajectory, path_length_m
from hippo_nav.vo import planar_step
from hippo_nav.vo.replay import (
    ReplayOdometry,
    frame_interval_s,
    pair_by_timestamp,
    read_pose_file,
    replay_odometry,
)

SEQUENCE = "04"
N_FRAMES = 12
DT_S = 0.1
CALIB = "P0: 100 0 63.5 0 0 100 23.5 0 0 0 1 0\nP1: 100 0 63.5 -50 0 100 23.5 0 0 0 1 0\n"


def random_trajectory(n: int, seed: int = 0) -> np.ndarray:
    """A 3-D (not planar) trajectory: steps of ~1 m forward with small random rotations about all axes."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    for k in range(1, n):
        step = np.eye(4)
        step[:3, :3] = matrix_from_quaternion(np.r_[rng.normal(0, 0.03, 3), 1.0])
        step[:3, 3] = rng.normal(0, 0.1, 3) + [0.0, 0.0, 1.0]
        poses[k] = poses[k - 1] @ step
    return poses


def make_sequence(root: Path, n_frames: int = N_FRAMES, times_s: np.ndarray | None = None) -> Path:
    """A tiny KITTI root whose images are blank (replay ignores pixels): every frame in stereo."""
    seq = root / "sequences" / SEQUENCE
    blank = np.zeros((48, 128), dtype=np.uint8)  # the view-cell template needs ≥ 64×40 px
    for cam in ("image_0", "image_1"):
        (seq / cam).mkdir(parents=True)
        for i in range(n_frames):
            cv2.imwrite(str(seq / cam / f"{i:06d}.png"), blank)
    (seq / "calib.txt").write_text(CALIB)
    times_s = np.arange(n_frames) * DT_S if times_s is None else times_s
    np.savetxt(seq / "times.txt", times_s, fmt="%.6f")
    write_kitti_poses(root / "poses" / f"{SEQUENCE}.txt", random_trajectory(n_frames, seed=1))
    return root


@pytest.fixture(scope="module")
def kitti_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sequence(tmp_path_factory.mktemp("replay") / "kitti")


def chained(replay: ReplayOdometry, dataset) -> tuple[np.ndarray, list]:
    """world_from_camera from the identity, by chaining the replay's steps over the dataset's frames."""
    steps = [replay.process(frame) for frame in dataset]
    poses = [np.eye(4)]
    for step in steps[1:]:
        poses.append(poses[-1] @ step.camera_prev_from_camera_cur)
    return np.stack(poses), steps


def rebased(poses: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[0]) @ poses


# --------------------------------------------------------------------------------------------------
# KITTI files: reproduction and alignment


@pytest.mark.parametrize("start, stop, stride", [(None, None, 1), (2, 11, 3), (1, None, 2)])
def test_replay_reproduces_the_file_trajectory(kitti_root, tmp_path, start, stop, stride):
    file_poses = random_trajectory(N_FRAMES, seed=7)
    path = write_kitti_poses(tmp_path / "other.txt", file_poses)
    dataset = KittiOdometry(kitti_root, SEQUENCE, start, stop, stride)
    replay = ReplayOdometry(path, dataset)
    poses, steps = chained(replay, dataset)
    expected = rebased(read_kitti_poses(path)[dataset.frame_indices])
    np.testing.assert_allclose(poses, expected, atol=1e-9)
    assert [s.status for s in steps] == ["first"] + ["ok"] * (len(dataset) - 1)
    np.testing.assert_allclose([s.dt_s for s in steps[1:]], np.diff(dataset.timestamps_s))
    assert steps[0].dt_s == 0.0 and steps[1].n_features == 0 and np.isnan(steps[1].reprojection_rmse_px)
    replay.reset()
    assert replay.process(dataset[1]).status == "first"


@pytest.mark.parametrize("n_lines", [N_FRAMES + 3, N_FRAMES - 2])
def test_exact_rejects_a_file_of_another_length_naming_both_counts_and_the_flag(
    kitti_root, tmp_path, n_lines
):
    path = write_kitti_poses(tmp_path / "other.txt", random_trajectory(n_lines))
    dataset = KittiOdometry(kitti_root, SEQUENCE)
    with pytest.raises(DatasetError) as err:
        ReplayOdometry(path, dataset)
    message = str(err.value)
    assert f"{n_lines} poses" in message and f"{N_FRAMES} frames" in message
    assert "--odometry-align start" in message and "--odometry-align end" in message
    assert str(path) in message and "\n" not in message


def test_start_ignores_extra_poses_at_the_end_but_not_missing_ones(kitti_root, tmp_path):
    file_poses = random_trajectory(N_FRAMES + 3, seed=3)
    path = write_kitti_poses(tmp_path / "longer.txt", file_poses)
    dataset = KittiOdometry(kitti_root, SEQUENCE, stride=2)
    replay = ReplayOdometry(path, dataset, align="start")
    np.testing.assert_allclose(
        chained(replay, dataset)[0], rebased(file_poses[dataset.frame_indices]), atol=1e-9
    )
    assert "6 of the file's 15 poses used" in replay.note  # stride 2: frames 0, 2, …, 10

    short = write_kitti_poses(tmp_path / "short.txt", random_trajectory(N_FRAMES - 4))
    # The file covers frames 0..7: a run that stops there is fine, the whole sequence is not.
    ReplayOdometry(short, KittiOdometry(kitti_root, SEQUENCE, stop=8), align="start")
    with pytest.raises(
        DatasetError, match=r"4 of the 12 processed frames have no line \(the first: frame 8\)"
    ):
        ReplayOdometry(short, KittiOdometry(kitti_root, SEQUENCE), align="start")


def test_end_aligns_the_last_line_with_the_last_frame(kitti_root, tmp_path):
    truth = random_trajectory(N_FRAMES, seed=5)
    late = write_kitti_poses(tmp_path / "late.txt", truth[3:])  # a system that started at frame 3
    dataset = KittiOdometry(kitti_root, SEQUENCE, start=3)
    replay = ReplayOdometry(late, dataset, align="end")
    np.testing.assert_allclose(chained(replay, dataset)[0], rebased(truth[3:]), atol=1e-9)
    with pytest.raises(DatasetError, match=r"frames 3\.\.11 .* 3 of the 12 processed frames have no line"):
        ReplayOdometry(late, KittiOdometry(kitti_root, SEQUENCE), align="end")

    extra_first = write_kitti_poses(tmp_path / "early.txt", np.concatenate([random_trajectory(2, 9), truth]))
    dataset = KittiOdometry(kitti_root, SEQUENCE, stride=3)
    replay = ReplayOdometry(extra_first, dataset, align="end")
    np.testing.assert_allclose(chained(replay, dataset)[0], rebased(truth[dataset.frame_indices]), atol=1e-9)


def test_a_dataset_without_a_sequence_length_needs_the_processed_frames_covered(tmp_path):
    path = write_kitti_poses(tmp_path / "poses.txt", random_trajectory(10))
    dataset = SimpleNamespace(frame_indices=np.array([4, 6, 8]), timestamps_s=np.array([0.4, 0.6, 0.8]))
    replay = ReplayOdometry(path, dataset)  # exact: no sequence length known, lines 4, 6, 8 exist
    np.testing.assert_array_equal(replay.world_from_camera, read_kitti_poses(path)[[4, 6, 8]])
    beyond = SimpleNamespace(frame_indices=np.array([8, 10, 12]), timestamps_s=np.array([0.8, 1.0, 1.2]))
    with pytest.raises(
        DatasetError, match=r"2 of the 3 processed frames have no line \(the first: frame 10\)"
    ):
        ReplayOdometry(path, beyond)
    # `end` without a sequence length: the last processed frame is the file's last line.
    replay = ReplayOdometry(path, beyond, align="end")
    np.testing.assert_array_equal(replay.world_from_camera, read_kitti_poses(path)[[5, 7, 9]])


def test_a_frame_outside_the_aligned_range_is_a_clear_error(kitti_root, tmp_path):
    path = write_kitti_poses(tmp_path / "other.txt", random_trajectory(N_FRAMES))
    replay = ReplayOdometry(path, KittiOdometry(kitti_root, SEQUENCE, stop=5))
    with pytest.raises(DatasetError, match="frame 7 has no pose in the replay"):
        replay.process(KittiOdometry(kitti_root, SEQUENCE)[7])


def test_a_replay_given_to_a_run_is_checked_and_started_afresh(kitti_root, tmp_path):
    """A replay aligned for other frames is refused before the first frame (its frames were "failed" one by
    one, two thirds of a run made up), and one given to a second run starts a new trajectory (its first
    step jumped from the last run's end back to the start)."""
    from hippo_nav.pipeline import Pipeline, config_from_dict

    quiet = config_from_dict({"output": {"figures": False}})
    path = write_kitti_poses(tmp_path / "other.txt", random_trajectory(N_FRAMES, seed=3))
    built_for = KittiOdometry(kitti_root, SEQUENCE, stop=6)
    with pytest.raises(DatasetError, match="frame 6 has no pose in the replay"):
        Pipeline(
            KittiOdometry(kitti_root, SEQUENCE, start=2), quiet, odometry=ReplayOdometry(path, built_for)
        )
    replay = ReplayOdometry(path, built_for)
    first, second = (Pipeline(built_for, quiet, odometry=replay).run(None) for _ in range(2))
    np.testing.assert_array_equal(first.vo_world_from_camera, second.vo_world_from_camera)
    assert second.metrics["vo_status_counts"] == {"first": 1, "ok": 5}


def test_bad_files_and_options_are_one_line_errors(tmp_path, kitti_root):
    one = write_kitti_poses(tmp_path / "one.txt", np.eye(4)[None])
    with pytest.raises(DatasetError, match="holds 1 pose; replaying odometry needs at least 2"):
        read_pose_file(one)
    seven = tmp_path / "seven.txt"
    seven.write_text("# comment\n1 2 3 4 5 6 7\n")
    with pytest.raises(DatasetError, match=r"seven\.txt:2: cannot tell the trajectory format from 7 numbers"):
        read_pose_file(seven)
    with pytest.raises(DatasetError, match="pose file not found"):
        read_pose_file(tmp_path / "missing.txt")
    kitti = write_kitti_poses(tmp_path / "k.txt", random_trajectory(N_FRAMES))
    with pytest.raises(DatasetError, match="expected 8 numbers"):
        read_pose_file(kitti, "tum")  # a wrong explicit format: the reader names the line
    with pytest.raises(DatasetError, match="unknown alignment 'middle'"):
        replay_odometry(kitti, align="middle")
    tum = write_tum(tmp_path / "t.txt", np.arange(N_FRAMES) * DT_S, random_trajectory(N_FRAMES))
    with pytest.raises(DatasetError, match="--odometry-align start applies to KITTI files"):
        replay_odometry(tum, align="start")


# --------------------------------------------------------------------------------------------------
# TUM files: pairing by timestamp


def test_tum_poses_pair_with_frames_by_timestamp(kitti_root, tmp_path):
    rng = np.random.default_rng(2)
    truth = random_trajectory(N_FRAMES + 4, seed=11)
    # Poses stamped a little off the frame times (±20 ms at 10 Hz), and two extra before and after.
    stamps = (np.arange(N_FRAMES + 4) - 2) * DT_S + rng.uniform(-0.02, 0.02, N_FRAMES + 4)
    path = write_tum(tmp_path / "traj.tum", stamps, truth)
    assert read_pose_file(path).file_format == "tum"
    for stride in (1, 2):
        dataset = KittiOdometry(kitti_root, SEQUENCE, start=1, stride=stride)
        replay = ReplayOdometry(path, dataset)
        expected = rebased(truth[dataset.frame_indices + 2])
        np.testing.assert_allclose(chained(replay, dataset)[0], expected, atol=1e-9)
    assert "paired by timestamp" in replay.note


def test_a_tum_file_missing_a_frame_is_an_error(kitti_root, tmp_path):
    keep = np.r_[0:5, 6:N_FRAMES]  # no pose for frame 5
    path = write_tum(tmp_path / "gap.tum", keep * DT_S, random_trajectory(N_FRAMES)[keep])
    with pytest.raises(DatasetError) as err:
        ReplayOdometry(path, KittiOdometry(kitti_root, SEQUENCE))
    message = str(err.value)
    assert "1 of the 12 processed frames (the first: frame 5 at t = 0.500 s)" in message
    assert "±50.0 ms" in message and "\n" not in message
    # A run over the frames it does cover is fine.
    ReplayOdometry(path, KittiOdometry(kitti_root, SEQUENCE, start=6))


def test_pairing_gives_each_pose_to_one_frame_and_the_interval_ignores_the_stride():
    stamps = np.array([0.0, 0.1, 0.2, 0.3])
    np.testing.assert_array_equal(pair_by_timestamp(stamps, [0.01, 0.19, 0.5], 0.05), [0, 2, -1])
    # Two frames near the same pose (uneven timing): the nearer one keeps it.
    np.testing.assert_array_equal(pair_by_timestamp(stamps, [0.09, 0.12], 0.05), [1, -1])
    assert frame_interval_s(np.array([0, 3, 6]), np.array([0.0, 0.3, 0.6])) == pytest.approx(0.1)
    assert frame_interval_s(np.array([5]), np.array([0.5])) is None


# --------------------------------------------------------------------------------------------------
# The command line


def _trajectory_files(out: Path) -> list[Path]:
    return sorted(out.glob("trajectory_*")) if out.exists() else []


def test_cli_runs_the_back_end_on_a_replayed_drifting_odometry(kitti_root, tmp_path, capsys):
    truth = read_kitti_poses(kitti_root / "poses" / f"{SEQUENCE}.txt")
    drifted = drifting_odometry(truth, scale_error=0.05, yaw_bias_deg_per_frame=0.5)
    path = write_kitti_poses(tmp_path / "drifted.txt", drifted)
    out = tmp_path / "out"
    args = ["run", "--kitti", str(kitti_root), "--sequence", SEQUENCE, "--odometry", str(path)]
    assert (
        main([*args, "--start", "1", "--stride", "2", "--out", str(out), "--no-progress", "--no-figures"])
        == 0
    )
    assert f"odometry replayed from {path}" in capsys.readouterr().out
    frames = np.arange(1, N_FRAMES, 2)
    vo = read_kitti_poses(out / "trajectory_vo.kitti.txt")
    np.testing.assert_allclose(vo, rebased(drifted[frames]), atol=1e-6)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == len(frames) and metrics["errors"]["vo"]["ate_3d_m"] > 0.0


def test_cli_rejects_a_misaligned_file_before_any_frame(kitti_root, tmp_path, capsys):
    path = write_kitti_poses(tmp_path / "long.txt", random_trajectory(N_FRAMES + 3))
    out = tmp_path / "out"
    args = ["run", "--kitti", str(kitti_root), "--sequence", SEQUENCE, "--odometry", str(path)]
    assert main([*args, "--out", str(out), "--no-progress", "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "15 poses" in err and "--odometry-align start" in err
    assert _trajectory_files(out) == []
    assert main([*args, "--odometry-align", "start", "--out", str(out), "--no-progress", "--no-figures"]) == 0
    assert read_kitti_poses(out / "trajectory_vo.kitti.txt").shape == (N_FRAMES, 4, 4)


@pytest.mark.parametrize(
    "bad_line, problem",
    [("1 0 0 nan 0 1 0 0 0 0 1 0", "NaN or infinity"), ("1 0 0 0 0 1 0 0 0 0 1", "expected 12 numbers")],
)
def test_cli_names_file_and_line_of_a_malformed_file(kitti_root, tmp_path, capsys, bad_line, problem):
    path = write_kitti_poses(tmp_path / "bad.txt", random_trajectory(N_FRAMES))
    lines = path.read_text().splitlines()
    lines[4] = bad_line
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    args = ["run", "--kitti", str(kitti_root), "--sequence", SEQUENCE, "--odometry", str(path)]
    assert main([*args, "--odometry-format", "kitti", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and f"{path}:5:" in err and problem in err
    assert "Traceback" not in err and _trajectory_files(out) == []


def test_cli_odometry_options_need_a_file(tmp_path, capsys):
    assert main(["run", "--odometry-align", "start", "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    assert "--odometry-align needs --odometry FILE" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


# --------------------------------------------------------------------------------------------------
# The drifting-odometry generator


def test_drift_without_errors_is_the_ground_truth():
    truth = random_trajectory(30, seed=4)
    same = drifting_odometry(truth, scale_error=0.0, yaw_bias_deg_per_frame=0.0)
    np.testing.assert_allclose(same, truth, atol=1e-9)


def test_scale_error_lengthens_the_path_by_that_fraction():
    truth = random_trajectory(50, seed=6)
    drifted = drifting_odometry(truth, scale_error=0.01, yaw_bias_deg_per_frame=0.3)
    assert path_length_m(drifted) == pytest.approx(1.01 * path_length_m(truth), rel=1e-9)


def test_yaw_bias_turns_the_final_heading_by_n_times_the_bias():
    truth = loop_trajectory(120)  # level, with left turns
    bias_deg = 0.05
    drifted = drifting_odometry(truth, scale_error=0.0, yaw_bias_deg_per_frame=bias_deg)
    _, _, heading_error_rad = planar_step(np.linalg.inv(truth[-1]) @ drifted[-1])
    assert heading_error_rad == pytest.approx(np.deg2rad(bias_deg) * (len(truth) - 1), abs=1e-9)
    # Positive bias = extra left turns: the drifted camera ends up left of the truth's heading.
    assert heading_error_rad > 0
    np.testing.assert_allclose(drifted[0], truth[0])


def test_noise_is_seeded_and_zero_mean():
    truth = loop_trajectory(200)
    noisy = {
        "scale_error": 0.0,
        "yaw_bias_deg_per_frame": 0.0,
        "translation_noise_m": 0.05,
        "yaw_noise_deg": 0.1,
    }
    a = drifting_odometry(truth, seed=1, **noisy)
    np.testing.assert_array_equal(a, drifting_odometry(truth, seed=1, **noisy))
    assert not np.allclose(a, drifting_odometry(truth, seed=2, **noisy))
    steps = np.linalg.inv(a[:-1]) @ a[1:]
    true_steps = np.linalg.inv(truth[:-1]) @ truth[1:]
    translation_error = steps[:, :3, 3] - true_steps[:, :3, 3]
    assert abs(translation_error.mean()) < 4 * 0.05 / np.sqrt(translation_error.size)
    assert translation_error.std() == pytest.approx(0.05, rel=0.2)
    with pytest.raises(DatasetError, match="standard deviations"):
        drifting_odometry(truth, translation_noise_m=-1.0)


# --------------------------------------------------------------------------------------------------
# Real files (../shared/data): alignment only; the real 00 folder has no right images to run on


@pytest.mark.data
def test_orbslam3_file_for_kitti_00_needs_align_start(shared_data):
    sequence_dir = shared_data / "kitti_odometry" / "sequences" / "00"
    path = shared_data / "peer_trajectories" / "hybrid_neuroslam_orbslam3" / "kitti00_ORBSLAM.txt"
    if not path.is_file() or not sequence_dir.is_dir():
        pytest.skip("the ORB-SLAM3 trajectory or KITTI 00 is not in the shared data")
    times_s = np.loadtxt(sequence_dir / "times.txt")
    dataset = SimpleNamespace(
        frame_indices=np.arange(len(times_s)), timestamps_s=times_s, sequence_dir=sequence_dir, sequence="00"
    )
    pose_file = read_pose_file(path)
    assert pose_file.file_format == "kitti" and len(pose_file) == 4544 and len(times_s) == 4541
    with pytest.raises(DatasetError) as err:
        ReplayOdometry(pose_file, dataset)
    assert "4544 poses" in str(err.value) and "4541 frames" in str(err.value)
    assert "--odometry-align start" in str(err.value)
    replay = ReplayOdometry(pose_file, dataset, align="start")
    np.testing.assert_array_equal(replay.world_from_camera, pose_file.world_from_camera[:4541])
    frames = [SimpleNamespace(index=i, timestamp_s=times_s[i]) for i in (0, 1, 2)]
    steps = [replay.process(f) for f in frames]
    assert steps[0].status == "first" and steps[2].status == "ok"
    # KITTI 00 starts driving forward at ~0.7 m per frame (camera z).
    assert 0.3 < steps[1].camera_prev_from_camera_cur[2, 3] < 1.5


@pytest.mark.data
def test_orbslam3_file_for_kitti_05_matches_exactly(shared_data):
    sequence_dir = shared_data / "kitti_odometry" / "sequences" / "05"
    path = shared_data / "peer_trajectories" / "hybrid_neuroslam_orbslam3" / "kitti05_ORBSLAM.txt"
    if not path.is_file() or not sequence_dir.is_dir():
        pytest.skip("the ORB-SLAM3 trajectory or KITTI 05 is not in the shared data")
    times_s = np.loadtxt(sequence_dir / "times.txt")
    dataset = SimpleNamespace(
        frame_indices=np.arange(0, len(times_s), 5), timestamps_s=times_s[::5], sequence_dir=sequence_dir
    )
    replay = ReplayOdometry(path, dataset)
    assert len(replay.world_from_camera) == len(dataset.frame_indices)
