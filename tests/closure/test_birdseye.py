"""Bird's-eye closures: a street driven back the other way is registered from its stereo structure with the
right relative pose, a look-alike street elsewhere is refused, a submap with too few points never proposes,
and the pipeline closes the reverse revisit as a metric loop (docs/map.md, "Bird's-eye closures").

The route is rendered by the project itself (cached in the hippo_nav cache), with posts on the pavements
(`poles`, docs/render.md): east along a street, a left corner, north, a U-turn into the other lane, south, a
right corner and west back along the first street in its other lane. The first street is therefore seen in
both directions, with a corner at one end."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hippo_nav.closure import DEFAULT_PROPOSERS, ClosureConfig, KeyframeExtractor
from hippo_nav.closure.birdseye import (
    BirdsEyeConfig,
    Submap,
    _blurred_spectra,
    _correlations,
    _energy,
    _raster,
    register,
    self_similarity,
    structure_points,
    structure_weights,
    submap,
)
from hippo_nav.datasets import KittiOdometry
from hippo_nav.geometry import planar_from_pose, se2_between, wrap_angle
from hippo_nav.io import write_kitti_poses
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.synthetic import default_cache_dir, drifting_odometry, planar_poses, render_cached
from hippo_nav.vo.replay import ReplayOdometry

STEP_M = 1.5
# (length m, turn rad over it): east, left corner, north, U-turn into the other lane, south, right corner, west.
ROUTE = [(45.0, 0.0), (8.0 * np.pi / 2, np.pi / 2), (40.0, 0.0), (1.5 * np.pi, np.pi), (40.0, 0.0),
         (5.0 * np.pi / 2, -np.pi / 2), (45.0, 0.0)]  # fmt: skip


def _route_poses() -> np.ndarray:
    """(n, 3) planar poses every STEP_M along ROUTE (exact arcs)."""
    fine = [(0.0, 0.0, 0.0)]
    for length_m, turn_rad in ROUTE:
        steps = max(int(np.ceil(length_m / 0.05)), 1)
        ds, dyaw = length_m / steps, turn_rad / steps
        for _ in range(steps):
            x, y, yaw = fine[-1]
            mid = yaw + dyaw / 2
            fine.append((x + ds * np.cos(mid), y + ds * np.sin(mid), yaw + dyaw))
    fine_arr = np.array(fine)
    path = np.r_[0.0, np.cumsum(np.hypot(*np.diff(fine_arr[:, :2], axis=0).T))]
    at = np.searchsorted(path, np.arange(0.0, path[-1], STEP_M))
    return fine_arr[at]


def out_and_back_street() -> KittiOdometry:
    """The ROUTE rendered with posts (cached; also the bird's-eye benchmark's sequence)."""
    planar = _route_poses()
    poses = planar_poses(planar[:, 0], planar[:, 1], planar[:, 2])
    root = render_cached(poses, default_cache_dir() / "test_out_and_back_posts", "00", seed=5, poles=True)
    return KittiOdometry(root, "00")


@pytest.fixture(scope="module")
def out_and_back() -> KittiOdometry:
    return out_and_back_street()


@pytest.fixture(scope="module")
def structure(out_and_back):
    """Every frame's structure points and its ground-truth planar pose and path length."""
    extract = KeyframeExtractor(out_and_back.calibration, ClosureConfig())
    points = [structure_points(extract(f.left, f.right).points_m, BirdsEyeConfig()) for f in out_and_back]
    planar = planar_from_pose(out_and_back.ground_truth())
    path_m = np.r_[0.0, np.cumsum(np.hypot(*np.diff(planar[:, :2], axis=0).T))]
    return points, planar, path_m


def _submap(structure, centre: int, lo_m: float, hi_m: float) -> Submap:
    points, planar, path_m = structure
    members = np.flatnonzero((path_m >= path_m[centre] + lo_m) & (path_m <= path_m[centre] + hi_m))
    return submap(planar[centre], planar[members], [points[m] for m in members], 30.0)


def _frame_near(planar: np.ndarray, xy: tuple[float, float], heading_rad: float) -> int:
    """The frame nearest to `xy` among those heading within 45° of `heading_rad`."""
    along = np.abs(wrap_angle(planar[:, 2] - heading_rad)) < np.pi / 4
    distance = np.where(along, np.hypot(planar[:, 0] - xy[0], planar[:, 1] - xy[1]), np.inf)
    return int(np.argmin(distance))


def test_a_street_driven_back_the_other_way_registers_with_the_right_relative_pose(structure):
    _, planar, _ = structure
    cfg = BirdsEyeConfig()
    query_at = _frame_near(planar, (30.0, 3.0), np.pi)  # on the way back west, 15 m past the corner
    target_at = _frame_near(planar, (30.0, 0.0), 0.0)  # the same place on the way out, heading east
    query = _submap(structure, query_at, -cfg.submap_m, 0.0)
    target = _submap(structure, target_at, -cfg.submap_m / 2, cfg.submap_m / 2)
    truth = se2_between(planar[target_at], planar[query_at])
    assert abs(abs(truth[2]) - np.pi) < 0.1  # the two frames face opposite ways
    # The odometry's prediction, 6 m and 0.2 rad off, inside a gate of 20 m and 1 rad.
    prior = (truth + np.array([4.0, -4.5, 0.2]), 20.0, 1.0)
    registration, why = register(query, target, cfg, prior)
    assert registration is not None, why
    error = se2_between(truth, np.array(registration.target_from_query))
    assert np.hypot(error[0], error[1]) < 0.5, (registration, truth)
    assert abs(error[2]) < np.radians(2.0), (registration, truth)
    # Its information is finite and positive, and honest enough to keep the error inside a χ² gate.
    assert np.all(np.linalg.eigvalsh(registration.information) > 0)
    chi2 = float(error @ registration.information @ error)
    assert chi2 < 16.0, chi2
    # Without the prior (every heading, shifts up to 15 m) the same alignment is found.
    free, why = register(query, target, cfg)
    assert free is not None, why
    assert np.hypot(*se2_between(truth, np.array(free.target_from_query))[:2]) < 0.5


def test_a_look_alike_street_elsewhere_is_refused(structure):
    _, planar, _ = structure
    cfg = BirdsEyeConfig()
    query_at = _frame_near(planar, (30.0, 3.0), np.pi)
    query = _submap(structure, query_at, -cfg.submap_m, 0.0)

    # A straight street of walls alone (two noisy lines 14 m apart, as stereo sees them) slides along itself;
    # the first street with its posts does not slide.
    def walls(seed: int, half_length_m: float) -> Submap:
        rng = np.random.default_rng(seed)
        n = int(80 * half_length_m)
        along = rng.uniform(-half_length_m, half_length_m, n)
        side = np.where(rng.random(n) < 0.5, 7.0, -7.0) + rng.normal(0.0, 0.3, n)
        return Submap(np.stack([along, side], axis=1).astype(np.float32), half_length_m + 5.0)

    assert self_similarity(walls(0, 25.0), cfg) > 0.8
    straight_at = _frame_near(planar, (9.0, 0.0), 0.0)
    assert self_similarity(_submap(structure, straight_at, -9.0, 3.0), cfg) < 0.6
    # The search refuses such a street by itself (the featureless check is off by default): seen again, as
    # part of a longer street, it fits as well slid along as where it is.
    street = walls(1, 80.0)
    assert register(walls(0, 25.0), street, cfg, (np.zeros(3), 20.0, 0.35)) == (None, "birdseye_ambiguous")
    # The north street, 14 m wide like the first one, with the U-turn's end wall ahead: no alignment fits.
    elsewhere = _frame_near(planar, (53.0, 30.0), np.pi / 2)
    target = _submap(structure, elsewhere, -10.0, 10.0)
    wrong, why = register(query, target, cfg)
    assert wrong is None, (wrong, why)
    # The corner seen from the way out, placed by the odometry 60 m from where it is: the gate keeps the
    # search away from the true alignment, and what is left does not fit.
    target_at = _frame_near(planar, (30.0, 0.0), 0.0)
    target = _submap(structure, target_at, -cfg.submap_m / 2, cfg.submap_m / 2)
    truth = se2_between(planar[target_at], planar[query_at])
    far = (truth + np.array([60.0, 0.0, 0.0]), 20.0, 0.35)
    registration, _ = register(query, target, cfg, far)
    assert registration is None, registration


def test_a_submap_with_too_few_points_never_proposes(structure):
    cfg = BirdsEyeConfig()
    _, planar, _ = structure
    query_at = _frame_near(planar, (30.0, 3.0), np.pi)
    query = _submap(structure, query_at, -cfg.submap_m, 0.0)
    sparse = Submap(query.points_m[: cfg.min_points - 1], query.radius_m)
    assert register(sparse, query, cfg) == (None, "birdseye_few_points")
    assert register(query, sparse, cfg) == (None, "birdseye_few_points")
    empty = Submap(np.zeros((0, 2), np.float32), 30.0)
    assert register(empty, empty, cfg) == (None, "birdseye_few_points")


@pytest.mark.slow
def test_the_pipeline_closes_the_reverse_revisit(out_and_back, tmp_path):
    # A drifting odometry (1 % long, turning left), replayed: the map must close the way back onto the way
    # out from structure alone (no view is familiar the other way round) and pull the end back to the start.
    truth = out_and_back.ground_truth()
    drifted = drifting_odometry(truth, scale_error=0.03, yaw_bias_deg_per_frame=0.15)
    path = write_kitti_poses(tmp_path / "odometry.txt", drifted)
    base = {"output": {"figures": False, "save_map": False}}
    results = {}
    for on in (False, True):
        chain = [*DEFAULT_PROPOSERS, "birdseye"] if on else list(DEFAULT_PROPOSERS)
        config = config_from_dict({**base, "parts": {"closure": chain}})
        results[on] = Pipeline(out_and_back, config, odometry=ReplayOdometry(path, out_and_back)).run(None)
    metrics = {on: r.metrics for on, r in results.items()}
    notes = metrics[True]["closure_attempts"]
    assert notes.get("accepted_birdseye", 0) >= 1, notes
    assert metrics[False]["loop_closures"] == 0
    quality = metrics[True]["closure_quality"]
    assert quality["precision"] == 1.0, quality
    odometry_ate = metrics[True]["errors"]["vo"]["ate_2d_m"]
    corrected_ate = metrics[True]["errors"]["corrected"]["ate_2d_m"]
    assert corrected_ate < 0.5 * odometry_ate, (corrected_ate, odometry_ate)
    assert metrics[False]["errors"]["corrected"]["ate_2d_m"] > 0.9 * odometry_ate


def test_walls_weigh_little_and_posts_and_corners_fully() -> None:
    # A wall's points slide along the wall; a post and a corner pin a registration in every direction.
    rng = np.random.default_rng(1)
    wall = np.stack([rng.uniform(-25.0, 15.0, 600), np.full(600, 7.0)], axis=1)
    post = np.array([3.0, 2.0]) + np.zeros((15, 2))
    corner = np.concatenate(
        [
            np.stack([rng.uniform(-30.0, -20.0, 100), np.full(100, -3.0)], axis=1),
            np.stack([np.full(100, -20.0), rng.uniform(-13.0, -3.0, 100)], axis=1),
        ]
    )
    points = np.concatenate([wall, post, corner]) + rng.normal(0.0, 0.3, (815, 2))
    weights = structure_weights(points.astype(np.float32), 30.0)
    assert weights.shape == (815,) and np.all((weights >= 0) & (weights <= 1))
    assert np.median(weights[:600]) < 0.3
    assert np.median(weights[600:615]) > 0.9
    at_corner = np.hypot(points[615:, 0] + 20.0, points[615:, 1] + 3.0) < 2.0
    assert np.median(weights[615:][at_corner]) > 0.5


@pytest.mark.parametrize("size", [64, 100, 135, 288])
def test_the_packed_single_precision_correlation_is_numpys_double_precision_one(size) -> None:
    # The search correlates OpenCV's packed spectra in single precision (`_packed_layout` says where each
    # entry sits): the correlations and the images' energies must be those of numpy's rfft2 in double precision,
    # for even sizes and odd ones (their packing differs in the last column and row).
    rng = np.random.default_rng(size)
    points = rng.uniform(-0.45 * size * 0.5, 0.45 * size * 0.5, (3, 400, 2))
    half = size // 4
    query, target = (
        _blurred_spectra(points, None, half, size),
        _blurred_spectra(points[:1] + 1.3, None, half, size),
    )
    fy, fx = np.fft.fftfreq(size)[:, None], np.fft.rfftfreq(size)[None, :]
    blur = np.exp(-2 * (np.pi * 1.0) ** 2 * (fx**2 + fy**2))  # `_BLUR_M` over `_COARSE_CELL_M`: one cell
    image = np.minimum(_raster(points, 0.5, half, size, 3), 1.0).astype(np.float64)
    image_t = np.minimum(_raster(points[:1] + 1.3, 0.5, half, size, 1), 1.0).astype(np.float64)
    f_q, f_t = np.fft.rfft2(image) * blur, np.fft.rfft2(image_t) * blur
    expected = np.fft.irfft2(np.conj(f_q) * f_t, s=(size, size))
    np.testing.assert_allclose(_correlations(query, target[0]), expected, atol=2e-6 * np.abs(expected).max())
    blurred = np.fft.irfft2(f_q, s=(size, size))
    np.testing.assert_allclose(_energy(query), (blurred**2).sum(axis=(1, 2)), rtol=1e-5)


def test_structure_weights_are_the_structure_tensors_eigenvalues_as_opencv_computes_them() -> None:
    # The weights take the tensor's eigenvalues at the points' cells only: they must be those of OpenCV's
    # `cornerEigenValsAndVecs` over the whole image, bit for bit (a street, posts and noise).
    rng = np.random.default_rng(7)
    points = np.concatenate(
        [
            np.stack([rng.uniform(-25.0, 25.0, 500), rng.choice([-7.0, 7.0], 500)], axis=1),
            rng.uniform(-20.0, 20.0, (40, 2)).repeat(8, axis=0),
        ]
    )
    points = (points + rng.normal(0.0, 0.3, points.shape)).astype(np.float32)
    half = int(np.ceil(30.0 / 0.5)) + 9
    image = np.minimum(_raster(points[None], 0.5, half, 2 * half), 1.0)[0]
    eigen = cv2.cornerEigenValsAndVecs(cv2.GaussianBlur(image, (0, 0), 1.0), 9, 3)
    idx = np.clip(np.floor(points / 0.5).astype(np.int64) + half, 0, 2 * half - 1)
    e = eigen[idx[:, 0], idx[:, 1]]
    expected = np.clip(
        np.minimum(e[:, 0], e[:, 1]) / np.maximum(np.maximum(e[:, 0], e[:, 1]), 1e-12) / 0.5, 0, 1
    )
    np.testing.assert_array_equal(structure_weights(points, 30.0), expected.astype(np.float32))


def test_a_place_that_repeats_within_the_search_is_refused(structure):
    # The search covers everywhere the odometry may have put the agent: a place found twice there is no place.
    _, planar, _ = structure
    cfg = BirdsEyeConfig()
    query_at = _frame_near(planar, (30.0, 3.0), np.pi)
    target_at = _frame_near(planar, (30.0, 0.0), 0.0)
    query = _submap(structure, query_at, -cfg.submap_m, 0.0)
    target = _submap(structure, target_at, -cfg.submap_m / 2, cfg.submap_m / 2)
    truth = se2_between(planar[target_at], planar[query_at])
    prior = (truth, 80.0, 0.35)
    once = Submap(target.points_m, 100.0)
    registration, why = register(query, once, cfg, prior)
    assert registration is not None, why
    assert np.hypot(*se2_between(truth, np.array(registration.target_from_query))[:2]) < 0.5
    twice = Submap(np.concatenate([target.points_m, target.points_m + np.float32([0.0, 70.0])]), 100.0)
    assert register(query, twice, cfg, prior) == (None, "birdseye_ambiguous")


def test_a_failing_birdseye_attempt_costs_its_closure_not_the_run(out_and_back, monkeypatch, caplog):
    from hippo_nav.closure.birdseye import BirdsEyeSearch

    def broken(self, *args):
        raise np.linalg.LinAlgError("singular matrix")

    monkeypatch.setattr(BirdsEyeSearch, "propose", broken)
    config = config_from_dict(
        {
            "output": {"figures": False, "save_map": False},
            "parts": {"closure": [*DEFAULT_PROPOSERS, "birdseye"]},
        }
    )
    with caplog.at_level("WARNING", logger="hippo_nav.pipeline"):
        result = Pipeline(out_and_back, config).run(None)
    assert result.metrics["frames"] == len(out_and_back)
    assert "bird's-eye attempt failed" in caplog.text
    assert result.metrics["closure_attempts"].get("accepted_birdseye", 0) == 0
