"""Appearance that changes between passes (`hippo_nav.synthetic.appearance`, docs/render.md): `same` is the
street as it always was, bit for bit; at `mild` and `strong` a place looks different on each pass, more so at
`strong`; passes, lane offsets and object states follow their documented rules; everything is deterministic."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from hippo_nav.cli import main
from hippo_nav.datasets import DatasetError
from hippo_nav.io import read_kitti_poses, write_kitti_poses
from hippo_nav.synthetic import (
    APPEARANCE_LEVELS,
    KITTI_FOCAL_RATIO,
    AppearanceModel,
    StreetWorld,
    loop_trajectory,
    pass_indices,
    planar_poses,
    render_cached,
    render_kitti,
    render_sequence,
    revisit_street,
    road_trajectory,
    stereo_projections,
)
from hippo_nav.synthetic.appearance import (
    LEVELS,
    PASS_RADIUS_M,
    FrameAppearance,
    Lighting,
    VisitHistory,
    smoothed_passes,
)

SIZE = (96, 32)

# sha256 (first 16 hex digits) of the decoded images, computed with the code as it was before appearances
# existed (commit f9ceea0): `same` must render exactly these. They hold for this project's NumPy/OpenBLAS;
# another BLAS may round the float32 texture products differently (then recompute them at that commit).
DIGEST_NOISELESS = (
    "f6d518786d564817"  # render_sequence(loop_trajectory(40), frames 0, 13, 26, 39; 96x32, seed 3)
)
DIGEST_NOISY = "ddc49a94020c8e9e"  # the same with noise_std=2
DIGEST_PITCHED = "8f5c8d593b2589e1"  # StreetWorld.render of frame 5 pitched by 0.05 rad (the per-ray path)
DIGEST_FRAMES = [0, 13, 26, 39]


def digest(images: list[np.ndarray]) -> str:
    h = hashlib.sha256()
    for image in images:
        h.update(np.ascontiguousarray(image).tobytes())
    return h.hexdigest()[:16]


def read_frames(root: Path, frames: list[int], cameras=("image_0", "image_1")) -> list[np.ndarray]:
    return [
        cv2.imread(str(root / "sequences" / "00" / camera / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        for i in frames
        for camera in cameras
    ]


@pytest.mark.parametrize("noise_std, expected", [(0.0, DIGEST_NOISELESS), (2.0, DIGEST_NOISY)])
def test_same_renders_exactly_what_it_rendered_before(tmp_path, noise_std, expected):
    poses = loop_trajectory(40)
    for name, extra in (("default", {}), ("same", {"appearance": "same"})):
        root = render_sequence(
            poses,
            tmp_path / name,
            "00",
            SIZE,
            seed=3,
            frames=np.array(DIGEST_FRAMES),
            noise_std=noise_std,
            workers=1,
            **extra,
        )
        assert digest(read_frames(root, DIGEST_FRAMES)) == expected


def test_same_is_the_plain_street_on_every_path():
    poses = loop_trajectory(40)
    world = StreetWorld(poses[:, :3, 3], seed=3)
    K = stereo_projections(SIZE, 0.537, KITTI_FOCAL_RATIO)[0][:, :3]
    pose = poses[5].copy()
    c, s = np.cos(0.05), np.sin(0.05)
    pose[:3, :3] = pose[:3, :3] @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # pitched: one ray per pixel
    assert digest([world.render(pose, K, SIZE)]) == DIGEST_PITCHED
    model = AppearanceModel(world, "same", seed=3, world_from_camera=poses)
    same = model.render(pose, K, SIZE, model.frame(20), noise_rng=np.random.default_rng(0))
    assert digest([same]) == DIGEST_PITCHED


def test_a_same_stamp_is_the_stamp_written_before(tmp_path):
    poses = loop_trajectory(6)
    render_cached(poses, tmp_path / "a", image_size_px=(32, 16), seed=1)
    render_cached(poses, tmp_path / "b", image_size_px=(32, 16), seed=1, appearance="same")
    stamps = [json.loads((tmp_path / r / "sequences" / "00" / "render.json").read_text()) for r in "ab"]
    assert stamps[0] == stamps[1] and "appearance" not in stamps[0]
    render_cached(poses, tmp_path / "c", image_size_px=(32, 16), seed=1, appearance="mild")
    assert (
        json.loads((tmp_path / "c" / "sequences" / "00" / "render.json").read_text())["appearance"] == "mild"
    )


@pytest.fixture(scope="module")
def street():
    """A 32 m street driven twice in the same lane: frame k of the second pass has the pose of frame k."""
    return revisit_street(33, step_m=1.0)


@pytest.fixture(scope="module")
def revisits(street, tmp_path_factory) -> dict[str, tuple[list[np.ndarray], list[np.ndarray]]]:
    """Left images of frames 6, 16, 26 on both passes, at every level."""
    places = [6, 16, 26]
    second = [int(street.second_pass[k]) for k in places]
    out = {}
    for level in APPEARANCE_LEVELS:
        root = render_sequence(
            street.world_from_camera,
            tmp_path_factory.mktemp(level),
            "00",
            SIZE,
            seed=2,
            frames=np.array(places + second),
            appearance=level,
            street_path_m=street.street_path_m,
            workers=1,
        )
        out[level] = (read_frames(root, places, ("image_0",)), read_frames(root, second, ("image_0",)))
    return out


def mean_abs_difference(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    return float(np.mean([np.abs(x.astype(float) - y).mean() for x, y in zip(a, b)]))


def test_a_place_looks_different_on_its_second_pass_more_so_at_strong(revisits):
    change = {level: mean_abs_difference(*revisits[level]) for level in APPEARANCE_LEVELS}
    assert change["same"] == 0.0  # the same pose on both passes: the same image
    # Measured 6.3 (mild) and 36 (strong) here; over seeds 0–5: mild 5.8–15.5, strong 22–54.
    assert 3.0 < change["mild"] < 12.0
    assert change["strong"] > 2.5 * change["mild"]


def test_first_passes_keep_the_street_recognisable(revisits):
    """Pass 0 at mild is still close to `same` (light, noise); strong has moved much further."""
    same = revisits["same"][0]
    assert mean_abs_difference(revisits["mild"][0], same) < mean_abs_difference(revisits["strong"][0], same)
    for level in ("mild", "strong"):
        for image in revisits[level][0] + revisits[level][1]:
            assert 40 < image.mean() < 200 and image.std() > 15  # not washed out, not black


def test_the_same_pose_at_pass_0_and_pass_1_differs_more_at_stronger_levels():
    poses = loop_trajectory(200)
    world = StreetWorld(poses[:, :3, 3], seed=0)
    K = stereo_projections(SIZE, 0.537, KITTI_FOCAL_RATIO)[0][:, :3]
    change = {}
    for level in APPEARANCE_LEVELS:
        model = AppearanceModel(world, level, seed=0)
        pair = [
            [
                model.render(poses[i], K, SIZE, model.at_pass(p), noise_rng=np.random.default_rng(i))
                for i in (60, 120)
            ]
            for p in (0, 1)
        ]
        change[level] = mean_abs_difference(*pair)
    assert change["same"] == 0.0 < change["mild"] < change["strong"]


def test_renders_are_deterministic_and_independent_of_the_workers(street, tmp_path):
    frames = np.array([3, 40, 41])
    roots = [
        render_sequence(
            street.world_from_camera,
            tmp_path / f"w{workers}_{k}",
            "00",
            SIZE,
            seed=5,
            frames=frames,
            appearance="strong",
            street_path_m=street.street_path_m,
            workers=workers,
        )
        for k, workers in enumerate((1, 2, 2))
    ]
    images = [read_frames(root, list(frames)) for root in roots]
    for other in images[1:]:
        assert all(np.array_equal(a, b) for a, b in zip(images[0], other))
    other_seed = render_sequence(
        street.world_from_camera,
        tmp_path / "seed6",
        "00",
        SIZE,
        seed=6,
        frames=frames,
        appearance="strong",
        street_path_m=street.street_path_m,
        workers=1,
    )
    assert not np.array_equal(read_frames(other_seed, list(frames))[0], images[0][0])


def reference_passes(xz: np.ndarray, radius_m: float) -> np.ndarray:
    """The rule, written out frame by frame: earlier separate visits, the current one not counted."""
    out = []
    for i in range(len(xz)):
        near = np.linalg.norm(xz[: i + 1] - xz[i], axis=1) < radius_m
        j = i
        while j >= 0 and near[j]:  # back over the current visit
            j -= 1
        earlier = near[: j + 1]
        out.append(int(np.sum(earlier & ~np.concatenate([[False], earlier[:-1]]))))
    return np.array(out)


def test_pass_index_counts_earlier_separate_visits():
    loop = loop_trajectory(400)  # ~2.9 laps of a 190 m loop
    passes = pass_indices(loop[:, :3, 3])
    np.testing.assert_array_equal(passes, reference_passes(loop[:, [0, 2], 3], PASS_RADIUS_M))
    lap = np.flatnonzero(passes == 1)[0]  # the first frame back at the start
    assert np.all(passes[:lap] == 0) and 120 < lap < 150
    assert np.linalg.norm(loop[lap, [0, 2], 3] - loop[0, [0, 2], 3]) < PASS_RADIUS_M + 1.5
    assert set(np.unique(passes)) == {0, 1, 2} and passes[-1] == 2
    assert np.all(np.diff(passes) >= 0)  # a loop driven round and round: each lap one pass more

    # Out and back on one street: the turn is one visit (pass 0); the way back, once clear of it, pass 1.
    x = np.concatenate([np.arange(0, 60, 2.0), np.arange(60, -2, -2.0)])
    yaw = np.concatenate([np.zeros(30), np.full(31, np.pi)])
    passes = pass_indices(planar_poses(x, np.zeros(len(x)), yaw)[:, :3, 3])
    np.testing.assert_array_equal(passes, (np.arange(len(x)) >= 30) & (x <= 60 - PASS_RADIUS_M))

    street = revisit_street(40, lateral_offset_m=3.0, heading_offset_deg=15.0)
    passes = pass_indices(street.world_from_camera[:, :3, 3])
    assert np.all(passes[street.first_pass] == 0) and np.all(passes[street.second_pass] == 1)


def test_objects_change_only_while_the_camera_is_away():
    loop = loop_trajectory(300)
    history = VisitHistory(loop[:, :3, 3], radius_m=15.0)
    place = loop[0, [0, 2], 3][None] + [[7.0, 3.0]]  # a facade point beside the start
    states = np.array([history.completed_visits(place, i)[0] for i in range(len(loop))])
    near = np.linalg.norm(loop[:, [0, 2], 3] - place, axis=1) < 15.0
    left = np.flatnonzero(near[:-1] & ~near[1:]) + 1  # the frames at which the camera had just left
    assert len(left) == 3  # 2.2 laps pass the place three times
    assert states[0] == 0 and states[-1] == 3 and np.all(np.diff(states) >= 0)
    np.testing.assert_array_equal(np.flatnonzero(np.diff(states)) + 1, left)  # it changes then, never in view


def out_and_back_kitti(root: Path) -> np.ndarray:
    """100 m east at 2 m per frame, a U-turn, and back: 101 frames, KITTI layout at `root`."""
    x = np.concatenate([np.arange(0, 100, 2.0), [100.0], np.arange(98, -2, -2.0)])
    yaw = np.concatenate([np.zeros(50), [np.pi / 2], np.full(50, np.pi)])
    poses = planar_poses(x, np.zeros(len(x)), yaw)
    write_kitti_poses(root / "poses" / "04.txt", poses)
    (root / "sequences" / "04").mkdir(parents=True)
    np.savetxt(root / "sequences" / "04" / "times.txt", 0.1 * np.arange(len(x)))
    return poses


@pytest.mark.parametrize("level", ["mild", "strong"])
def test_later_passes_drive_another_lane_and_the_poses_say_so(tmp_path, level):
    ground_truth = out_and_back_kitti(tmp_path / "kitti")
    out = render_kitti(
        tmp_path / "kitti", "04", tmp_path / "out", 0, 2, image_size_px=(32, 16), appearance=level
    )
    written = read_kitti_poses(out / "poses" / "04.txt")
    road = road_trajectory(ground_truth)
    offset = written[:, :3, 3] - road[:, :3, 3]
    sideways = np.einsum("ij,ij->i", offset, road[:, :3, 0])  # along each camera's x axis (its right)
    np.testing.assert_allclose(offset, sideways[:, None] * road[:, :3, 0], atol=1e-6)  # sideways only
    np.testing.assert_allclose(written[:, :3, :3], road[:, :3, :3], atol=1e-8)  # headings kept
    smooth = smoothed_passes(road[:, :3, 3], pass_indices(road[:, :3, 3]))
    first, later = smooth < 1e-7, smooth > 1 - 1e-7
    assert first.sum() >= 25 and later.sum() >= 15
    np.testing.assert_allclose(sideways[first], 0.0, atol=1e-6)
    np.testing.assert_allclose(np.abs(sideways[later]), LEVELS[level].lane_offset_m, atol=1e-6)
    assert len(np.unique(np.sign(sideways[later]))) == 1  # one lane for the whole pass
    assert np.all(np.abs(sideways) <= LEVELS[level].lane_offset_m + 1e-9)  # a ramp in between, no jump
    assert np.abs(np.diff(sideways)).max() < 0.5 * LEVELS[level].lane_offset_m
    stamp = json.loads((out / "sequences" / "04" / "render.json").read_text())
    assert stamp["appearance"] == level


def test_the_sun_casts_shadows_across_the_street():
    street = revisit_street(40)
    world = StreetWorld(street.street_path_m, seed=0)
    model = AppearanceModel(world, "strong", seed=0)
    size = (96, 48)
    K = stereo_projections(size, 0.537, KITTI_FOCAL_RATIO)[0][:, :3]
    pose = street.world_from_camera[5]  # looking along the street (world +z), facades at x = ±7 m

    def image(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
        light = Lighting(np.radians(azimuth_deg), np.radians(elevation_deg), 1.0, 1.0)
        return model.render(pose, K, size, FrameAppearance(0.0, light, None, 0)).astype(float)

    road = np.s_[40:, 30:66]
    # A low sun (20°) from the right (+x): the right-hand buildings (9–21 m) shade the whole 14 m wide road.
    # The same sun straight ahead lights it (the same n·s on the road: only the shadow differs).
    assert image(90, 20)[road].mean() < 0.8 * image(0, 20)[road].mean()
    # A high sun (60°) from the right clears the buildings: the left facade faces it, the right one has its
    # back to it. From the left, the other way round.
    facade_left, facade_right = np.s_[:20, :12], np.s_[:20, -12:]
    from_right, from_left = image(90, 60), image(-90, 60)
    assert from_right[facade_left].mean() > 1.3 * from_right[facade_right].mean()
    assert from_left[facade_right].mean() > 1.3 * from_left[facade_left].mean()


def test_revisit_street_pairs_each_second_pass_frame_with_its_place():
    street = revisit_street(40, step_m=1.0, lateral_offset_m=2.0, heading_offset_deg=15.0, along_offset_m=0.4)
    poses = street.world_from_camera
    assert poses.shape == (80, 4, 4) and street.street_path_m.shape == (40, 3)
    first, second = poses[street.first_pass], poses[street.second_pass]
    np.testing.assert_allclose(street.street_path_m, first[:, :3, 3])
    # 2 m to the left (world −x), 0.4 m further along (world +z), yawed 15° to the left.
    np.testing.assert_allclose(
        second[:, :3, 3] - first[:, :3, 3], np.tile([-2.0, 0.0, 0.4], (40, 1)), atol=1e-12
    )
    yaw = np.degrees(np.arctan2(-second[:, 0, 2], second[:, 2, 2]))
    np.testing.assert_allclose(yaw, 15.0)
    np.testing.assert_array_equal(street.revisit_of, np.arange(40))  # 0.4 m along: still the same frame
    assert revisit_street(40, along_offset_m=0.6).revisit_of[0] == 1
    with pytest.raises(DatasetError, match="at least 30 m"):
        revisit_street(20)
    with pytest.raises(DatasetError, match="lateral_offset_m"):
        revisit_street(40, lateral_offset_m=6.0)


def test_an_unknown_level_is_refused_with_the_levels_named(tmp_path):
    with pytest.raises(DatasetError, match="choose one of same, mild, strong"):
        render_sequence(loop_trajectory(4), tmp_path, image_size_px=(32, 16), appearance="foggy")
    assert not (tmp_path / "sequences").exists()  # refused before anything was written
    argv = ["render", "--kitti", str(tmp_path), "--sequence", "00", "--out", str(tmp_path)]
    assert main([*argv, "--appearance", "foggy"]) == 2


def test_the_render_command_records_its_appearance(tmp_path, capsys):
    out_and_back_kitti(tmp_path / "kitti")
    args = [
        "render",
        "--kitti",
        str(tmp_path / "kitti"),
        "--sequence",
        "04",
        "--size",
        "32x16",
        "--stop",
        "1",
        "--no-progress",
    ]
    assert main([*args, "--out", str(tmp_path / "plain")]) == 0
    stamp = json.loads((tmp_path / "plain" / "sequences" / "04" / "render.json").read_text())
    assert sorted(stamp) == ["image_size_px", "road_smoothing_m", "seed", "source_poses_sha"]  # as before
    assert main([*args, "--out", str(tmp_path / "strong"), "--appearance", "strong"]) == 0
    stamp = json.loads((tmp_path / "strong" / "sequences" / "04" / "render.json").read_text())
    assert stamp["appearance"] == "strong"
    capsys.readouterr()
    # A render at another level is not mixed into it.
    assert main([*args, "--out", str(tmp_path / "strong"), "--appearance", "mild"]) == 2
    assert "other settings" in capsys.readouterr().err


def test_the_figures_command_draws_the_levels(tmp_path, capsys):
    assert main(["figures", "--appearance", "--out", str(tmp_path)]) == 0
    path = tmp_path / "appearance_levels.png"
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image is not None and image.ndim == 2 and path.stat().st_size < 200_000
    assert not (tmp_path / "fig1_derivation.png").exists()  # only the figure asked for
