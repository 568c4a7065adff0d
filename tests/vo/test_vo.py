"""Stereo VO: accuracy on the project's synthetic sequences and on real KITTI frames, and robustness."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hippo_nav import HippoNavError
from hippo_nav.datasets import KittiOdometry, StereoFrame
from hippo_nav.metrics import relative_errors_kitti
from hippo_nav.synthetic import planar_poses
from hippo_nav.vo import StereoOdometry, VoParams, WindowConfig, planar_step, run_odometry
from hippo_nav.vo.matching import ImageMatcher

SHORT_LENGTHS_M = (10.0, 20.0, 30.0, 40.0, 50.0)


def _rebased(poses: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[0]) @ poses


def _velocity_errors(dataset, steps) -> tuple[float, float]:
    """RMS errors of the VO's yaw rate (rad/s) and speed (m/s) against the ground truth."""
    gt = dataset.ground_truth()
    yaw_err, speed_err = [], []
    for i in range(1, len(gt)):
        dt = dataset.timestamps_s[i] - dataset.timestamps_s[i - 1]
        forward, left, yaw = planar_step(np.linalg.inv(gt[i - 1]) @ gt[i])
        yaw_rate, speed = steps[i].planar_velocities()
        yaw_err.append(yaw_rate - yaw / dt)
        speed_err.append(speed - np.copysign(np.hypot(forward, left), forward) / dt)
    return float(np.sqrt(np.mean(np.square(yaw_err)))), float(np.sqrt(np.mean(np.square(speed_err))))


def _evaluate(name: str, dataset, est, steps, lengths) -> tuple[dict, float, float]:
    """KITTI relative errors over `lengths` (every start frame) and the velocity RMS errors, printed."""
    gt = _rebased(dataset.ground_truth())
    errors = relative_errors_kitti(gt, est, lengths=lengths, step=1)
    yaw_rms, speed_rms = _velocity_errors(dataset, steps)
    per_length = {k: round(v["t_rel_percent"], 2) for k, v in errors["per_length"].items()}
    print(
        f"{name}: t_rel {errors['t_rel_percent']:.3f} % (by length {per_length}), "
        f"r_rel {errors['r_rel_deg_per_100m']:.2f} deg/100 m, yaw rate RMS {yaw_rms:.4f} rad/s, "
        f"speed RMS {speed_rms:.3f} m/s"
    )
    return errors, yaw_rms, speed_rms


def test_planar_velocities_follow_the_camera_conventions():
    # 1.5 m forward, 0.2 m left, 0.1 rad left turn in 0.1 s.
    start, end = planar_poses([0.0, 1.5], [0.0, 0.2], [0.0, 0.1])
    from hippo_nav.vo import VoStep

    step = VoStep(np.linalg.inv(start) @ end, "ok", 0.1, 0, 0, 0, 0.0)
    yaw_rate, speed = step.planar_velocities()
    assert yaw_rate == pytest.approx(1.0) and speed == pytest.approx(np.hypot(1.5, 0.2) / 0.1)
    backwards = VoStep(np.linalg.inv(end) @ start, "ok", 0.1, 0, 0, 0, 0.0)
    assert backwards.planar_velocities()[1] < 0
    assert VoStep(np.eye(4), "first", 0.0, 0, 0, 0, 0.0).planar_velocities() == (0.0, 0.0)


@pytest.mark.slow
def test_synthetic_loop_within_one_percent(demo):
    """The demo loop (279 m, corners of 1.7 rad/s): KITTI t_rel over 100 and 200 m segments ≤ 1 %."""
    est, steps = run_odometry(demo)
    assert all(s.status == "ok" for s in steps[1:]), [s.status for s in steps]
    errors, yaw_rms, speed_rms = _evaluate("demo", demo, est, steps, (100.0, 200.0))
    assert errors["segments"] > 100
    assert errors["t_rel_percent"] <= 1.0
    assert errors["r_rel_deg_per_100m"] <= 3.0
    assert yaw_rms < 0.1 and speed_rms < 1.0  # at 10 Hz: < 0.6° and < 10 cm per frame


def test_same_input_gives_the_same_trajectory(demo):
    first, _ = run_odometry(_Frames(demo, range(12)))
    second, _ = run_odometry(_Frames(demo, range(12)))
    np.testing.assert_array_equal(first, second)


class _Frames:
    """Chosen frames of a dataset, optionally altered (same protocol)."""

    def __init__(self, dataset, indices, alter=None):
        self._d, self._idx, self._alter = dataset, list(indices), alter or {}
        self.name, self.calibration = dataset.name, dataset.calibration
        self.timestamps_s = dataset.timestamps_s[self._idx]

    def __len__(self) -> int:
        return len(self._idx)

    def __getitem__(self, i: int) -> StereoFrame:
        frame = self._d[self._idx[i]]
        return self._alter[i](frame) if i in self._alter else frame

    def ground_truth(self):
        return self._d.ground_truth()[self._idx]


def _blank(frame: StereoFrame) -> StereoFrame:
    flat = np.full_like(frame.left, 90)
    return dataclasses.replace(frame, left=flat, right=flat.copy())


def test_low_texture_frames_are_flagged_and_bridged_by_the_prior(demo):
    """A covered lens for three frames: flagged, the constant-velocity prior stands in, tracking resumes."""
    data = _Frames(demo, range(30), alter={12: _blank, 13: _blank, 14: _blank})
    est, steps = run_odometry(data)
    statuses = [s.status for s in steps]
    assert statuses[12:16] == ["low_texture"] * 4  # frame 15 has no tracked points from blank frame 14
    assert statuses[16:] == ["ok"] * 14
    for i in range(12, 16):
        np.testing.assert_allclose(
            steps[i].camera_prev_from_camera_cur, steps[11].camera_prev_from_camera_cur, atol=1e-12
        )
    gt = _rebased(data.ground_truth())
    # The demo drives straight there, so the prior is nearly right: no jump, the end error stays small.
    assert np.linalg.norm(est[-1, :3, 3] - gt[-1, :3, 3]) < 0.02 * 30 * 1.6


def test_blurred_frame_does_not_make_a_jump(demo):
    import cv2

    def blur(frame):
        return dataclasses.replace(
            frame,
            left=cv2.GaussianBlur(frame.left, (0, 0), 2.5),
            right=cv2.GaussianBlur(frame.right, (0, 0), 2.5),
        )

    data = _Frames(demo, range(10), alter={5: blur})
    _, steps = run_odometry(data)
    gt = data.ground_truth()
    true_step = np.linalg.norm((np.linalg.inv(gt[5]) @ gt[6])[:3, 3])
    for i in (5, 6):
        assert steps[i].status in ("ok", "low_texture")
        assert abs(np.linalg.norm(steps[i].camera_prev_from_camera_cur[:3, 3]) - true_step) < 0.1 * true_step


def test_bad_frames_and_calibrations_give_clear_errors(demo):
    vo = StereoOdometry(demo.calibration)
    frame = demo[0]
    with pytest.raises(HippoNavError, match="sizes differ"):
        vo.process(dataclasses.replace(frame, right=frame.right[:, :-8]))
    with pytest.raises(HippoNavError, match="calibration is for 320×96"):
        vo.process(dataclasses.replace(frame, left=frame.left[:-8], right=frame.right[:-8]))
    with pytest.raises(HippoNavError, match="8-bit gray"):
        vo.process(dataclasses.replace(frame, left=frame.left.astype(np.float32)))
    # A failed frame leaves the odometry usable.
    assert vo.process(frame).status == "first"
    p1 = demo.calibration.P1.copy()
    p1[0, 3] = 0.0
    with pytest.raises(HippoNavError, match="baseline"):
        StereoOdometry(dataclasses.replace(demo.calibration, P1=p1))
    with pytest.raises(ValueError, match="min_inliers"):
        VoParams(min_inliers=2)


# --- real KITTI frames ---------------------------------------------------------------------------------
@pytest.mark.data
def test_real_kitti_06_urban(shared_data):
    """Sequence 06, frames 0–50 (60 m): t_rel over every segment length the data allows ≤ 2.5 %."""
    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    est, steps = run_odometry(data)
    errors, yaw_rms, speed_rms = _evaluate("KITTI 06", data, est, steps, SHORT_LENGTHS_M)
    assert sum(s.ok for s in steps) == len(steps) - 1
    assert errors["segments"] > 100
    assert errors["t_rel_percent"] <= 2.5
    assert yaw_rms < 0.02 and speed_rms < 0.4


@pytest.mark.data
def test_real_kitti_01_highway_scale_follows_the_right_camera_baseline(shared_data):
    """Sequence 01, frames 0–50 (52 m, a highway ramp).

    These images' right camera is not camera 1: with calib.txt's camera-1 baseline (0.537 m) every step
    comes out 14–15 % too long while the rotations match the ground truth to 0.03°/frame, which is what
    the 0.469 m camera-0 → camera-3 baseline predicts (0.537 / 0.469 = 1.145). So the test checks that
    the scale follows the stated baseline, then measures accuracy with the camera-3 baseline taken from
    the same calib.txt (P3), not fitted to the ground truth.

    On KLT's matches as they are (`refine_matches=False`): the refined stereo matches of this highway, most
    of them on the road, have larger disparities, and the steps come out 9.4 % long instead of 14.5 %, so
    part of what the camera-3 baseline explains here is KLT's bias on the road (docs/vo.md)."""
    data = KittiOdometry(shared_data / "kitti_odometry", "01")
    gt = _rebased(data.ground_truth())
    klt = {"refine_matches": False}
    # The frame-to-frame steps: their scale is the stereo pair's alone (the window adds temporal parallax,
    # which pulls a biased pair's scale part of the way back: 1.118 here).
    est, _ = run_odometry(
        data, VoParams(window=WindowConfig(max_keyframes=0), disparity_self_calibration=False, **klt)
    )
    true_steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    ratio = np.median(np.linalg.norm(np.diff(est[:, :3, 3], axis=0), axis=1) / true_steps)
    baseline_cam3_m = -data.calibration.P3[0, 3] / data.calibration.P3[0, 0]
    assert ratio == pytest.approx(data.calibration.baseline_m / baseline_cam3_m, rel=0.02)

    p1 = data.calibration.P1.copy()
    p1[0, 3] = -data.calibration.fx * baseline_cam3_m
    data.calibration = dataclasses.replace(data.calibration, P1=p1)
    # Without the self-calibration: it reads the depth-dependent error the baseline does not explain
    # (tests/vo/test_disparity.py) and would correct the scale a second time.
    est, steps = run_odometry(data, VoParams(disparity_self_calibration=False, **klt))
    errors, yaw_rms, speed_rms = _evaluate("KITTI 01 (camera-3 baseline)", data, est, steps, SHORT_LENGTHS_M)
    assert errors["segments"] > 100
    assert errors["t_rel_percent"] <= 2.5
    assert yaw_rms < 0.02 and speed_rms < 0.8


def _right_shifted(frame: StereoFrame, shift_px: float) -> StereoFrame:
    """The frame with its right image moved `shift_px` to the right (a disparity shortfall)."""
    import cv2

    h, w = frame.right.shape
    moved = cv2.warpAffine(
        frame.right, np.float32([[1, 0, shift_px], [0, 1, 0]]), (w, h), borderMode=cv2.BORDER_REPLICATE
    )
    return dataclasses.replace(frame, right=moved)


@pytest.mark.slow
def test_a_shifted_right_image_is_reported_and_the_disparity_offset_corrects_it(demo, caplog):
    """A right image shifted by a pixel against its calibration (what KITTI 01's shared frames show)
    makes depths wrong in a way no rigid step explains: with the self-calibration off (tests/vo/
    test_disparity.py has it on) the VO warns once, and `disparity_offset_px` puts the pixel back."""
    gt = _rebased(demo.ground_truth())
    frames = [demo[i] for i in range(len(demo))]

    def run(params: VoParams, shift_px: float) -> tuple[StereoOdometry, float]:
        vo, pose, poses = StereoOdometry(demo.calibration, params), np.eye(4), []
        for frame in frames:
            pose = pose @ vo.process(_right_shifted(frame, shift_px)).camera_prev_from_camera_cur
            poses.append(pose)
        errors = relative_errors_kitti(gt, np.stack(poses), lengths=(100.0, 200.0), step=1)
        return vo, errors["t_rel_percent"]

    fixed = VoParams(disparity_self_calibration=False)
    consistent, t_rel_consistent = run(fixed, 0.0)
    assert consistent.warnings == [] and abs(consistent.stereo_bias_px) < 0.03
    with caplog.at_level("WARNING", logger="hippo_nav.vo"):
        shifted, t_rel_shifted = run(fixed, 1.0)
    assert len(shifted.warnings) == 1 and "disparity_offset_px" in shifted.warnings[0]
    assert shifted.stereo_bias_px < -0.03 and "looks biased" in caplog.text
    corrected, t_rel_corrected = run(VoParams(disparity_offset_px=1.0, disparity_self_calibration=False), 1.0)
    assert corrected.warnings == []
    assert t_rel_shifted > 2 * t_rel_consistent
    assert t_rel_corrected < 1.5 * t_rel_consistent + 0.2


@pytest.mark.data
def test_real_kitti_01_disparity_offset_and_the_bias_warning(shared_data):
    """KITTI 01's shared frames with calib.txt as given and the self-calibration off: the VO warns that
    the stereo pair looks biased (t_rel 8–15 %); `disparity_offset_px = 1.1`, about what the self-calibration
    finds, brings t_rel to about 1 % (fixed at 0.9, 1.0, 1.1, 1.2, 1.3 and 1.5 px: 1.99, 1.33, 1.04, 1.17,
    1.38 and 2.54 %; with the full check window from 1.0 px: 1.70, 1.14, 1.11, 1.28 and 2.26 %; docs/vo.md).
    The camera-3 baseline of the test above gives ~2.3 %."""
    data = KittiOdometry(shared_data / "kitti_odometry", "01")
    frames = [data[i] for i in range(len(data))]
    gt = _rebased(data.ground_truth())
    t_rel = {}
    for offset_px in (0.0, 1.1):
        vo, pose, poses = (
            StereoOdometry(
                data.calibration, VoParams(disparity_offset_px=offset_px, disparity_self_calibration=False)
            ),
            np.eye(4),
            [],
        )
        for frame in frames:
            pose = pose @ vo.process(frame).camera_prev_from_camera_cur
            poses.append(pose)
        t_rel[offset_px] = relative_errors_kitti(gt, np.stack(poses), lengths=SHORT_LENGTHS_M, step=1)[
            "t_rel_percent"
        ]
        if offset_px == 0.0:
            assert len(vo.warnings) == 1 and vo.stereo_bias_px < -0.03
    assert t_rel[0.0] > 8.0
    assert t_rel[1.1] <= 1.5


@pytest.mark.parametrize("check_window_px, expected_px", [(None, 13), ("full", 13), (9, 9)])
def test_the_backward_checks_take_their_own_window_and_reject_a_wrong_track(
    demo, monkeypatch, check_window_px, expected_px
):
    """`klt_check_window_px` sizes the forward–backward checks alone (None at 320 px and 'full': KLT's
    window, 13 px there); at either size a consistent track passes and a track moved 4 px along its row fails."""
    import cv2

    real = cv2.calcOpticalFlowPyrLK
    a, b = demo[10].left, demo[11].left
    pts = cv2.goodFeaturesToTrack(a, 200, 0.01, 7).reshape(-1, 2)
    tracked, ok, _ = real(a, b, pts, None, winSize=(13, 13), maxLevel=3)
    tracked, pts = tracked[ok.ravel() == 1], pts[ok.ravel() == 1]
    wrong = tracked.copy()
    wrong[:, 0] += 4.0
    windows: list[tuple[int, int]] = []

    def spy(*args, **kwargs):
        windows.append(tuple(kwargs["winSize"]))
        return real(*args, **kwargs)

    match = ImageMatcher(demo.calibration, VoParams(klt_check_window_px=check_window_px))
    monkeypatch.setattr(cv2, "calcOpticalFlowPyrLK", spy)
    assert len(pts) > 50
    assert match.track_back(b, a, tracked, pts).mean() > 0.8
    assert match.track_back(b, a, wrong, pts).mean() < 0.1
    assert windows == [(expected_px, expected_px)] * 2


def test_the_backward_checks_take_nine_pixels_on_images_from_640_px_wide(demo):
    """The default check window (`klt_check_window_px` None) is 9 px on KITTI-size images, KLT's full window on
    smaller ones; 'full' or a size overrides it."""
    import dataclasses

    def check_px(width_px, check_window_px):
        calibration = dataclasses.replace(demo.calibration, image_size_px=(width_px, width_px * 3 // 10))
        match = ImageMatcher(calibration, VoParams(klt_check_window_px=check_window_px))
        return match.klt_check["winSize"][0], match.klt_short["winSize"][0]

    assert check_px(320, None) == (13, 13)
    assert check_px(639, None) == (15, 15)
    assert check_px(640, None) == (9, 15)
    assert check_px(1241, None) == (9, 15)
    assert check_px(1241, "full") == (15, 15)
    assert check_px(1241, 11) == (11, 15)


def test_new_corners_are_spread_over_buckets_when_there_is_no_room_for_all(demo):
    """`corner_bucket_px`: with more corners than room, every square gets its strongest corner before any gets
    a second (the strongest overall crowd into the most contrasted part of the image); with room for all, the
    corners are the same as without buckets."""
    image = demo[5].left
    none = np.zeros((0, 2), np.float32)
    plain = ImageMatcher(demo.calibration, VoParams(corner_bucket_px=0))
    spread = ImageMatcher(demo.calibration, VoParams(corner_bucket_px=32))
    everything = plain.detect(image, 10_000, none)
    np.testing.assert_array_equal(spread.detect(image, 10_000, none), everything)

    def buckets(xy):
        return set(zip((xy[:, 0] // 32).astype(int), (xy[:, 1] // 32).astype(int), strict=True))

    occupied = buckets(everything)
    wanted = len(occupied)
    chosen = spread.detect(image, wanted, none)
    strongest = plain.detect(image, wanted, none)
    assert len(chosen) == wanted and buckets(chosen) == occupied  # one corner in every square
    assert len(buckets(strongest)) < len(occupied)  # the strongest overall leave squares empty
    # Within each square the one chosen is its strongest.
    for x, y in chosen:
        same = everything[(everything[:, 0] // 32 == x // 32) & (everything[:, 1] // 32 == y // 32)]
        assert (x, y) == tuple(same[0])  # `everything` is ordered by score, strongest first
