"""The warped-window refinement of KLT matches (`VoParams.refine_matches`, Rust `hippo_vo::tracks`): on a
rendered road, whose true correspondences the renderer gives exactly, KLT's square window is biased and the
refinement is not; bad input is refused with a clear error. (The warp's own convergence is tested in
crates/hippo_vo/src/tracks/; what it does to the odometry is measured by tests/benchmarks/vo.py.)"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hippo_nav import HippoNavError
from hippo_nav._core import _refine_matches
from hippo_nav.datasets import KittiOdometry
from hippo_nav.synthetic import DEMO_SEQUENCE, StreetWorld, demo_sequence
from hippo_nav.vo import StereoOdometry, VoParams

# KLT as the VO runs it on the demo's 320×96 images (a 13 px window; `VoParams.klt_window_px`).
KLT = {
    "winSize": (13, 13),
    "maxLevel": 3,
    "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
}
HALF_WINDOW_PX = 6


@pytest.fixture(scope="module")
def road_matches():
    """Errors (px) of KLT's matches and of the refined ones against the truth, for corners on the road of
    the demo loop (every 12th frame) matched into the right image and into the next left image; the truth
    ray cast into the renderer's street, KLT started at it."""
    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    gt = dataset.ground_truth()
    calibration = dataset.calibration
    K = np.asarray(calibration.K, np.float64)
    # The street the demo was rendered in (`render_sequence`'s defaults).
    world = StreetWorld(gt[:, :3, 3], street_half_width_m=7.0, camera_height_m=1.65, seed=0)
    right_from_left = np.eye(4)
    right_from_left[0, 3] = calibration.baseline_m

    def project(world_from_camera: np.ndarray, points: np.ndarray) -> np.ndarray:
        c = (points - world_from_camera[:3, 3]) @ world_from_camera[:3, :3]
        return np.column_stack([K[0, 0] * c[:, 0] / c[:, 2] + K[0, 2], K[1, 1] * c[:, 1] / c[:, 2] + K[1, 2]])

    out: dict[str, list[np.ndarray]] = {
        "stereo_klt": [],
        "stereo_refined": [],
        "track_klt": [],
        "track_refined": [],
    }
    for i in range(10, len(dataset) - 1, 12):
        frame, following = dataset[i], dataset[i + 1]
        corners = cv2.goodFeaturesToTrack(frame.left, 400, 0.005, 5).reshape(-1, 2).astype(np.float32)
        rays = np.column_stack(
            [(corners[:, 0] - K[0, 2]) / K[0, 0], (corners[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(corners))]
        )
        hits = world.cast(gt[i][:3, 3], rays @ gt[i][:3, :3].T)
        road = hits["kind"] == 1
        corners, points = corners[road], hits["points"][road]
        for name, second, pose, model in (
            ("stereo", frame.right, gt[i] @ right_from_left, "row_shear"),
            ("track", following.left, gt[i + 1], "affine"),
        ):
            truth = project(pose, points)
            klt, status, _ = cv2.calcOpticalFlowPyrLK(
                frame.left,
                second,
                corners,
                truth.astype(np.float32),
                flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
                **KLT,
            )
            ok = (status.ravel() == 1) & (np.linalg.norm(klt - truth, axis=1) < 1.0)
            refined, done = _refine_matches(
                frame.left,
                second,
                corners[ok].astype(np.float64),
                klt[ok].astype(np.float64),
                model,
                HALF_WINDOW_PX,
            )
            # Compared where the refinement ran (a window that leaves the image keeps KLT's match).
            out[f"{name}_klt"].append((klt[ok] - truth[ok])[done])
            out[f"{name}_refined"].append((refined - truth[ok])[done])
    return {name: np.concatenate(errors) for name, errors in out.items()}


def test_a_stereo_match_on_the_road_is_biased_under_klt_and_not_after_refinement(road_matches):
    """The road's disparity grows down the image by baseline / camera height (0.33 px a row): KLT's square
    window finds the disparity of its gradient-weighted middle, a tenth of a pixel off with one sign; the
    row-shear window finds the centre's."""
    klt = np.median(road_matches["stereo_klt"][:, 0])
    refined = np.median(road_matches["stereo_refined"][:, 0])
    assert len(road_matches["stereo_klt"]) >= 200
    assert abs(klt) > 0.08, f"KLT's stereo bias on the road: {klt:+.3f} px"
    assert abs(refined) < 0.04, f"refined: {refined:+.3f} px (KLT {klt:+.3f} px)"
    # A rectified match stays on its row (KLT's may wander off it by a fraction of a pixel).
    np.testing.assert_allclose(road_matches["stereo_refined"][:, 1], 0.0, atol=1e-3)


def test_a_road_track_from_frame_to_frame_is_less_biased_after_refinement(road_matches):
    """Forward motion stretches the road's image downwards (its flow grows with the square of the row):
    the affine window takes out most of KLT's bias. (Not all: the road's flow is not affine across a
    window; the stereo shear, which is, goes to zero.)"""
    klt = np.linalg.norm(np.median(road_matches["track_klt"], axis=0))
    refined = np.linalg.norm(np.median(road_matches["track_refined"], axis=0))
    assert klt > 0.05, f"KLT's track bias on the road: {klt:.3f} px"
    assert refined < 0.75 * klt, f"refined {refined:.3f} px against KLT's {klt:.3f} px"


def test_refinement_keeps_the_match_it_cannot_refine_and_refuses_bad_input():
    flat = np.full((40, 60), 100, np.uint8)
    points = np.array([[30.0, 20.0], [1.0, 20.0]])
    refined, ok = _refine_matches(flat, flat, points, points + 0.25, "affine", 6)
    assert not ok.any()
    np.testing.assert_array_equal(refined, points + 0.25)
    with pytest.raises(HippoNavError, match="unknown warp model"):
        _refine_matches(flat, flat, points, points, "projective", 6)
    with pytest.raises(HippoNavError, match="one row per match"):
        _refine_matches(flat, flat, points, points[:1], "affine", 6)
    with pytest.raises(HippoNavError, match="C-contiguous"):
        _refine_matches(np.asfortranarray(np.zeros((40, 60), np.uint8)), flat, points, points, "affine", 6)
    with pytest.raises(HippoNavError, match="NaN"):
        _refine_matches(flat, flat, np.array([[np.nan, 1.0]]), points[:1], "affine", 6)


def test_the_odometry_uses_the_refined_matches_only_when_asked(monkeypatch):
    """`refine_matches=False` gives KLT's matches as they are (the refinement is never called); the default
    refines both the tracks (affine) and the stereo matches (row shear)."""
    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    calls: list[str] = []
    from hippo_nav.vo import matching

    real = matching._refine_matches

    def spy(*args, **kwargs):
        calls.append(args[4])
        return real(*args, **kwargs)

    monkeypatch.setattr(matching, "_refine_matches", spy)
    for params, expected in ((VoParams(refine_matches=False), set()), (VoParams(), {"affine", "row_shear"})):
        calls.clear()
        vo = StereoOdometry(dataset.calibration, params)
        for i in range(4):
            vo.process(dataset[i])
        assert set(calls) == expected


@pytest.mark.data
def test_real_kitti_06_drifts_less_on_refined_matches(shared_data):
    """Real KITTI 06 frames 0–50 (60 m of urban street): the default VO, on refined matches, meets the
    issue's t_rel goal of 1 % in the run itself, beats the same VO on KLT's matches in t_rel and is no worse
    in r_rel (measured when written: 1.08 → 0.89 %, 1.54 → 1.43°/100 m). On the segments whose ground truth was measured
    (frames 0–11 are a constant motion filled in, `interpolated_steps`) it meets the r_rel goal of 1°/100 m
    too (measured 0.63)."""
    from hippo_nav.metrics import interpolated_steps, relative_errors_kitti
    from hippo_nav.vo import run_odometry

    data = KittiOdometry(shared_data / "kitti_odometry", "06")
    gt = data.ground_truth()
    gt = np.linalg.inv(gt[0]) @ gt
    errors = {}
    for name, params in (("klt", VoParams(refine_matches=False)), ("refined", VoParams())):
        est, _ = run_odometry(data, params)
        errors[name] = relative_errors_kitti(gt, est, lengths=(10.0, 20.0, 30.0, 40.0, 50.0), step=1)
    # Beats KLT by at least 5 %: the margin, not KLT's side of 1 %, is the claim. KLT's own t_rel depends on the
    # CPU (OpenCV's kernels round differently): 1.08 % when written, 0.998 % on an AMD EPYC without AVX-512,
    # where the refined matches gave 0.871 % (0.87×).
    assert errors["refined"]["t_rel_percent"] < 1.0
    assert errors["refined"]["t_rel_percent"] < 0.95 * errors["klt"]["t_rel_percent"], errors
    # r_rel: no worse (within 1 %). When written the refined matches were better (1.54 → 1.43°/100 m); with
    # OpenCV 5.0.0.93 the two are equal (1.538 and 1.542), so only "no worse" holds with both.
    assert errors["refined"]["r_rel_deg_per_100m"] < 1.01 * errors["klt"]["r_rel_deg_per_100m"]
    measured = relative_errors_kitti(
        gt, est, lengths=(10.0, 20.0, 30.0, 40.0, 50.0), step=1, exclude_steps=interpolated_steps(gt)
    )
    assert measured["segments"] > 50
    assert measured["r_rel_deg_per_100m"] < 1.0 < errors["refined"]["r_rel_deg_per_100m"]
