"""Closure keyframes' depths against the renderer's truth: the stereo matches refined with a row-sheared
window (`ClosureConfig.refine_stereo`) are not biased on the road as KLT's square window is."""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.closure import ClosureConfig, KeyframeExtractor
from hippo_nav.datasets import KittiOdometry
from hippo_nav.synthetic import DEMO_SEQUENCE, StreetWorld, demo_sequence

ROAD, FACADE = 1, 2  # `StreetWorld.cast` hit kinds


@pytest.fixture(scope="module")
def depth_errors() -> dict[bool, dict[int, np.ndarray]]:
    """Relative depth errors (Z / true Z − 1) of keyframe points on every 3rd frame of the demo loop, by hit
    kind, with and without the refinement; the truth ray cast into the street the demo was rendered in. ORB
    corners, as the bias was measured on (SIFT's blob centres sit on the road less often: +2.8 % with KLT)."""
    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    gt = dataset.ground_truth()
    K = np.asarray(dataset.calibration.K, dtype=np.float64)
    world = StreetWorld(gt[:, :3, 3], street_half_width_m=7.0, camera_height_m=1.65, seed=0)
    out = {}
    for refine in (False, True):
        extract = KeyframeExtractor(
            dataset.calibration, ClosureConfig(descriptor="orb", refine_stereo=refine)
        )
        errors: dict[int, list[float]] = {ROAD: [], FACADE: []}
        for i in range(2, len(dataset), 3):
            frame = dataset[i]
            keyframe = extract(frame.left, frame.right)
            px = keyframe.pixels_px.astype(np.float64)
            rays = np.column_stack(
                [(px[:, 0] - K[0, 2]) / K[0, 0], (px[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(px))]
            )
            hits = world.cast(gt[i][:3, 3], rays @ gt[i][:3, :3].T)
            true_z = ((hits["points"] - gt[i][:3, 3]) @ gt[i][:3, :3])[:, 2]
            relative = keyframe.points_m[:, 2] / true_z - 1.0
            for kind in errors:
                errors[kind] += relative[hits["kind"] == kind].tolist()
        out[refine] = {kind: np.array(v) for kind, v in errors.items()}
    return out


def test_refined_stereo_removes_most_of_the_road_bias(depth_errors) -> None:
    klt, refined = depth_errors[False][ROAD], depth_errors[True][ROAD]
    assert len(klt) >= 30 and len(refined) >= 30
    # KLT's square window on a slanted road: depths a few percent long (measured +4.8 %, refined +1.4 %).
    assert np.median(klt) > 0.03
    assert abs(np.median(refined)) < 0.5 * np.median(klt)


def test_refined_stereo_is_no_worse_on_facades(depth_errors) -> None:
    klt, refined = depth_errors[False][FACADE], depth_errors[True][FACADE]
    assert len(refined) > 0.95 * len(klt) > 1000
    assert abs(np.median(refined)) < 0.005
    assert np.median(np.abs(refined)) < np.median(np.abs(klt))


def _strong_revisit_measurements(descriptor: str) -> list[tuple[float, float] | None]:
    """(position error m, heading error °) of each second-pass frame's measurement against its first-pass
    keyframe (None: refused), at the proximity bar of 15 inliers, on a street driven twice at 320×96: the
    second pass 3 m aside under `strong` change (another sun, hard shadows, changed shop fronts and cars,
    noise, blur)."""
    from hippo_nav.closure import LoopMeasurer
    from hippo_nav.datasets.base import StereoCalibration
    from hippo_nav.geometry import planar_from_pose, se2_between
    from hippo_nav.synthetic import revisit_street, stereo_projections
    from hippo_nav.synthetic.appearance import AppearanceModel

    size, baseline = (320, 96), 0.537
    p0, p1 = stereo_projections(size, baseline, 718.856 / 1241.0)
    K = p0[:, :3]
    street = revisit_street(24, step_m=2.0, lateral_offset_m=3.0)
    model = AppearanceModel(StreetWorld(street.street_path_m, seed=3), "strong", 3, street.world_from_camera)
    right_from_left = np.eye(4)
    right_from_left[0, 3] = baseline
    Calibration = StereoCalibration(p0, p1, None, None, size)
    config = ClosureConfig(descriptor=descriptor)
    extract, measurer = KeyframeExtractor(Calibration, config), LoopMeasurer(Calibration, config)
    poses = street.world_from_camera

    def keyframe(i: int):
        look, rng = model.frame(i), np.random.default_rng([3, i])
        left = model.render(poses[i], K, size, look, noise_rng=rng)
        return extract(left, model.render(poses[i] @ right_from_left, K, size, look, noise_rng=rng))

    out: list[tuple[float, float] | None] = []
    for i, place in zip(street.second_pass, street.revisit_of):
        measurement, _ = measurer.measure(keyframe(int(place)), keyframe(int(i)), 15)
        if measurement is None:
            out.append(None)
            continue
        truth = se2_between(planar_from_pose(poses[i]), planar_from_pose(poses[int(place)]))
        error = np.asarray(measurement.agent_from_target) - truth
        out.append((float(np.hypot(error[0], error[1])), float(np.degrees(abs(error[2])))))
    return out


@pytest.mark.slow
def test_the_default_sift_keyframes_measure_revisits_under_strong_change_that_orb_misses() -> None:
    # Measured once: SIFT 24 of 24 (errors ≤ 0.3 m, 0.8°), ORB 9 of 24. ORB's corners survive the change of
    # light, but their descriptors do not: the Hamming distance between a corner and itself on the other pass
    # was 68-91 of 256 bits on the 06 render at `strong` (38-46 at `same`), near chance. The default is what
    # is measured first: with ORB as the default this fails.
    sift = _strong_revisit_measurements(ClosureConfig().descriptor)
    orb = _strong_revisit_measurements("orb")
    accepted = [m for m in sift if m is not None]
    assert len(accepted) >= 20 and sum(m is not None for m in orb) <= 12, (sift, orb)
    assert max(m[0] for m in accepted) < 0.5 and max(m[1] for m in accepted) < 1.5, accepted
    extract = KeyframeExtractor(
        KittiOdometry(demo_sequence(), DEMO_SEQUENCE).calibration, ClosureConfig(descriptor="sift")
    )
    frame = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)[10]
    keyframe = extract(frame.left, frame.right)
    assert keyframe.descriptors.dtype == np.uint8 and keyframe.descriptors.shape == (len(keyframe), 128)


def test_a_map_continued_with_another_descriptor_is_refused_clearly() -> None:
    from hippo_nav._core import HippoNavError
    from hippo_nav.closure import KeyframeStore

    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    orb = KeyframeStore(dataset.calibration, ClosureConfig(descriptor="orb"))
    frame = dataset[10]
    orb.keyframes[0] = orb.extract(frame.left, frame.right)
    saved = orb.export_state()
    assert saved["descriptors"].shape[1] == 32
    sift = KeyframeStore(dataset.calibration, ClosureConfig(descriptor="sift"))
    with pytest.raises(HippoNavError, match="continue a map with the descriptor it was made with"):
        sift.restore_state(saved)
    restored = KeyframeStore(dataset.calibration, ClosureConfig(descriptor="orb"))
    restored.restore_state(saved)
    np.testing.assert_array_equal(restored.keyframes[0].descriptors, orb.keyframes[0].descriptors)


def _keyframe_matching_every_feature(extract: KeyframeExtractor, left: np.ndarray, right: np.ndarray):
    """(pixels, disparities before refinement) of the features a keyframe keeps, found the plain way: every
    detected feature tracked into the right image and back, the strongest `keyframe_features` of those
    that pass (demo-sized images: no shrinking for SIFT)."""
    import cv2

    cfg = extract.config
    keypoints, _ = extract._detector.detectAndCompute(left, None)
    pixels = np.array([k.pt for k in keypoints], np.float32)
    response = np.array([k.response for k in keypoints], np.float32)
    guess = pixels.copy()
    guess[:, 0] -= extract.fx * extract.baseline_m / cfg.stereo_guess_depth_m
    flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    in_right, ok, _ = cv2.calcOpticalFlowPyrLK(left, right, pixels, guess, flags=flags, **extract._klt)
    back, ok_back, _ = cv2.calcOpticalFlowPyrLK(
        right, left, in_right, pixels.copy(), flags=flags, **extract._klt
    )
    disparity = pixels[:, 0] - in_right[:, 0]
    keep = (
        (ok.ravel() == 1)
        & (ok_back.ravel() == 1)
        & (np.linalg.norm(back - pixels, axis=1) < cfg.forward_backward_px)
        & (np.abs(in_right[:, 1] - pixels[:, 1]) < cfg.stereo_row_tolerance_px)
        & (disparity > 0.5)
    )
    index = np.flatnonzero(keep)
    index = index[np.argsort(-response[index], kind="stable")[: cfg.keyframe_features]]
    return pixels[index], disparity[index]


@pytest.mark.parametrize("descriptor", ["sift", "orb"])
@pytest.mark.parametrize("features", [40, 150, 300])
def test_matching_the_strongest_first_keeps_the_features_matching_every_one_would(
    descriptor, features
) -> None:
    # The extractor tracks the strongest features into the right image in batches and tracks back only
    # those that passed the forward checks (less work: docs/results.md, "Cost"); the keyframe must hold
    # exactly the features, in the same order, that matching every detected feature selects.
    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    config = ClosureConfig(descriptor=descriptor, keyframe_features=features, refine_stereo=False)
    extract = KeyframeExtractor(dataset.calibration, config)
    compared = 0
    for i in range(0, len(dataset), 25):
        frame = dataset[i]
        keyframe = extract(frame.left, frame.right)
        pixels, disparity = _keyframe_matching_every_feature(extract, frame.left, frame.right)
        np.testing.assert_array_equal(keyframe.pixels_px, pixels)
        depth_m = extract.fx * extract.baseline_m / disparity.astype(np.float64)
        np.testing.assert_array_equal(keyframe.points_m[:, 2], depth_m.astype(np.float32))
        compared += len(pixels)
    assert compared >= 4 * features  # a real comparison: most frames give a full keyframe
