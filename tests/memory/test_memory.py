"""Maps that outlive a run: a saved memory continues exactly, relocalises a later session on a revisit and
not on an unseen street, and a damaged or incompatible one is one clear error that overwrites nothing."""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from conftest import QUIET, Frames
from hippo_nav.geometry import planar_from_pose, se2_between
from hippo_nav.memory import SavedMemoryError, read_memory, write_memory
from hippo_nav.pipeline import SlamSystem, config_from_dict, run
from hippo_nav.vo import StereoOdometry

LAP = 140  # frames of one lap of the demo loop (1.4 laps in 200 frames)


class Slice:
    """Frames `start` … `stop − 1` of a dataset as a dataset of their own (frame indices kept)."""

    def __init__(self, dataset, start: int, stop: int) -> None:
        self.d, self.start, self.stop = dataset, start, stop
        self.name, self.calibration = dataset.name, dataset.calibration
        self.frame_indices = dataset.frame_indices[start:stop]
        self.timestamps_s = dataset.timestamps_s[start:stop]

    def __len__(self) -> int:
        return self.stop - self.start

    def __getitem__(self, i: int):
        return self.d[self.start + i]

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def ground_truth(self):
        gt = self.d.ground_truth()
        return None if gt is None else gt[self.start : self.stop]


@pytest.fixture(scope="module")
def steps(demo):
    """The demo's frames with their VO steps, measured once."""
    odometry = StereoOdometry(demo.calibration, config_from_dict(QUIET).vo)
    out = []
    for frame in Frames(demo, 195):
        step = odometry.process(frame)
        out.append((frame, step.camera_prev_from_camera_cur, step.status))
    return out


def _records(system: SlamSystem, steps) -> list:
    return [system.step(frame, step, status).record for frame, step, status in steps]


def _assert_same_records(a: list, b: list) -> None:
    assert len(a) == len(b)
    for ra, rb in zip(a, b):
        for f in fields(ra):
            # assert_equal: exact, NaN equal to NaN (a frame with no vertex offset), tuples and arrays alike.
            np.testing.assert_equal(
                getattr(ra, f.name), getattr(rb, f.name), err_msg=f"frame {ra.frame_index}: {f.name}"
            )


@pytest.mark.slow
@pytest.mark.parametrize("keyframe_spacing_m", [0.0, 5.0])
def test_a_saved_session_continues_bit_identically(demo, steps, tmp_path, keyframe_spacing_m):
    """Stopped after frame 90, saved, loaded, and given the same frames, a session decides exactly what one
    that never stopped decides (view cells, closures, map, networks, which vertices keep a keyframe), through
    the loop's closures."""
    config = config_from_dict({**QUIET, "closure": {"keyframe_spacing_m": keyframe_spacing_m}})
    never_stopped = SlamSystem(demo.calibration, config)
    reference = _records(never_stopped, steps[:170])
    first = SlamSystem(demo.calibration, config)
    _records(first, steps[:90])
    first.finish()
    write_memory(first.save_memory(), tmp_path / "memory")
    resumed = SlamSystem(demo.calibration, config, memory=read_memory(tmp_path), resume=True)
    continued = _records(resumed, steps[90:170])
    _assert_same_records(continued, reference[90:])
    assert any(r.loop_closure is not None for r in continued), "the test must pass through loop closures"
    for key, value in never_stopped.map.export().items():
        np.testing.assert_array_equal(np.asarray(value), np.asarray(resumed.map.export()[key]), err_msg=key)
    np.testing.assert_array_equal(never_stopped.engine.place_activity(), resumed.engine.place_activity())
    never_stopped.finish()
    resumed.finish()
    kept = sorted(never_stopped.closure.store.keyframes)
    assert sorted(resumed.closure.store.keyframes) == kept
    if keyframe_spacing_m > 0:
        assert len(kept) < 0.7 * len(never_stopped.map), (len(kept), len(never_stopped.map))


@pytest.fixture(scope="module")
def first_lap(demo, tmp_path_factory) -> Path:
    """The results folder of a run over the demo's first lap (it holds memory/)."""
    out = tmp_path_factory.mktemp("first_lap") / "run"
    run(out, config=config_from_dict(QUIET), progress=False, dataset=None, stop=LAP)
    return out


@pytest.mark.slow
def test_a_session_saved_before_it_joined_resumes_and_joins_as_if_it_never_stopped(
    demo, steps, first_lap, tmp_path
):
    """A session inside a loaded map, saved while still lost and resumed, joins at the same frame with the
    same records as one that never stopped (its unconfirmed hypotheses and where it began are kept)."""
    config = config_from_dict(QUIET)
    session = [
        (frame, np.eye(4) if k == 0 else step, status)
        for k, (frame, step, status) in enumerate(steps[LAP + 5 :])
    ]
    never_stopped = SlamSystem(demo.calibration, config, memory=read_memory(first_lap))
    reference = _records(never_stopped, session)
    assert never_stopped.relocalisation is not None and never_stopped.relocalisation["frames_lost"] >= 2
    lost = SlamSystem(demo.calibration, config, memory=read_memory(first_lap))
    _records(lost, session[:2])
    assert lost.map.unjoined_from is not None
    lost.finish()
    write_memory(lost.save_memory(), tmp_path / "memory")
    resumed = SlamSystem(demo.calibration, config, memory=read_memory(tmp_path), resume=True)
    _assert_same_records(_records(resumed, session[2:]), reference[2:])
    assert resumed.relocalisation == never_stopped.relocalisation


@pytest.mark.slow
def test_a_later_session_relocalises_on_a_revisit_and_extends_the_map(demo, first_lap, tmp_path):
    """Started without its pose on the second lap, a session is lost until a familiar view is confirmed, then
    stands where the truth puts it in the first run's map, and the map holds both sessions."""
    saved = json.loads((first_lap / "metrics.json").read_text())
    data = Slice(demo, LAP + 5, 195)
    from hippo_nav.pipeline import Pipeline

    memory = read_memory(first_lap)
    pipeline = Pipeline(data, config_from_dict(QUIET), memory=memory)
    result = pipeline.run(tmp_path / "second")
    metrics = result.metrics
    loaded = metrics["loaded_map"]
    assert loaded["relocalised"], metrics
    where = loaded["relocalisation"]
    assert where["frames_lost"] <= 15 and where["networks_set"], where
    notes = result.record.column("closure_note")
    assert notes.count("relocalised") == 1
    # After the join the agent stands where the truth puts it in the first run's map frame (the map's origin
    # is the first run's first pose).
    gt = demo.ground_truth()
    origin = planar_from_pose(gt[0])
    online = np.stack(result.record.column("online_pose"))
    joined = notes.index("relocalised")
    truth = se2_between(origin, planar_from_pose(gt[LAP + 5 : 195]))
    error_m = np.hypot(*(online[joined:, :2] - truth[joined:, :2]).T)
    assert error_m.max() < 2.0, error_m.max()
    # One map: the first run's vertices, then the session's; closures after the join are ordinary ones.
    assert metrics["vertices"] > saved["vertices"]
    assert (tmp_path / "second" / "memory" / "memory.json").is_file()
    again = read_memory(tmp_path / "second")
    assert again.info["counts"]["vertices"] == metrics["vertices"]


@pytest.mark.slow
def test_an_unseen_street_never_relocalises(first_lap, tmp_path):
    """A session on a street the first run never saw stays unjoined: no relocalisation, no closure onto the
    loaded map, and its own map is written whole."""
    from hippo_nav.datasets import KittiOdometry
    from hippo_nav.synthetic import loop_trajectory, render_sequence

    root = render_sequence(
        loop_trajectory(60, side_lengths_m=(60.0, 40.0)), tmp_path / "elsewhere", "00", seed=11
    )
    result = run(
        tmp_path / "second", dataset=root, sequence="00", config=config_from_dict(QUIET), progress=False,
        memory_from=first_lap,
    )  # fmt: skip
    loaded = result.metrics["loaded_map"]
    assert not loaded["relocalised"] and loaded["relocalisation"] is None
    assert "relocalised" not in result.record.column("closure_note")
    assert all(c is None for c in result.record.column("loop_closure"))
    assert result.metrics["correction"]["method"] == "none"
    assert len(KittiOdometry(root, "00")) == result.metrics["frames"]


def _damage(folder: Path, how: str) -> None:
    memory = folder / "memory"
    if how == "truncated views":
        data = (memory / "views.npz").read_bytes()
        (memory / "views.npz").write_bytes(data[: len(data) // 2])
    elif how == "flipped keyframes":
        data = bytearray((memory / "keyframes.npz").read_bytes())
        data[len(data) // 2] ^= 0xFF
        (memory / "keyframes.npz").write_bytes(bytes(data))
    elif how == "truncated manifest":
        text = (memory / "memory.json").read_text()
        (memory / "memory.json").write_text(text[: len(text) // 2])
    elif how == "no memory":
        for path in memory.iterdir():
            path.unlink()
        memory.rmdir()


@pytest.mark.parametrize(
    ("how", "says"),
    [
        ("truncated views", "views.npz holds"),
        ("flipped keyframes", "keyframes.npz does not match its checksum"),
        ("truncated manifest", "memory.json cannot be read"),
        ("no memory", "there is no memory.json"),
    ],
)
def test_a_damaged_memory_is_one_clear_error_and_overwrites_nothing(first_lap, tmp_path, how, says):
    import shutil

    damaged = tmp_path / "damaged"
    shutil.copytree(first_lap, damaged)
    _damage(damaged, how)
    before = {p: p.read_bytes() for p in damaged.rglob("*") if p.is_file()}
    with pytest.raises(SavedMemoryError, match=says):
        run(
            damaged,
            config=config_from_dict(QUIET),
            progress=False,
            stop=5,
            overwrite=True,
            memory_from=damaged,
        )
    assert {p: p.read_bytes() for p in damaged.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize(
    ("file", "key", "says"),
    [
        ("views", "recall.offset", "view recall's offset holds NaN"),
        ("keyframes", "points_m", "keyframes' points_m holds NaN"),
    ],
)
def test_a_memory_edited_to_hold_nan_is_refused_naming_it(first_lap, tmp_path, file, key, says):
    # Checksums recomputed (a hand-edited or foreign memory): the NaN is named as the memory's, not met later
    # as input the networks refuse, blamed on the odometry, or copied into the next memory.
    memory = read_memory(first_lap)
    arrays = getattr(memory, file)
    arrays[key] = np.asarray(arrays[key]).astype(np.float64 if file == "views" else np.float32)
    arrays[key].flat[0] = np.nan
    write_memory(memory, tmp_path / "edited" / "memory")
    with pytest.raises(SavedMemoryError, match=says):
        run(
            tmp_path / "out",
            config=config_from_dict(QUIET),
            progress=False,
            stop=5,
            memory_from=tmp_path / "edited",
        )


@pytest.mark.parametrize(
    ("override", "names"),
    [
        ({"view_words": {"orb_features": 400}}, "view_cells.orb_features"),
        ({"engine": {"torus_period_m": 120.0}}, "engine.torus_period_m"),
        ({"parts": {"view_cells": "template"}}, "parts.view_cells"),
        ({"lesions": {"dorsal": True}}, "lesions.dorsal"),
        ({"closure": {"descriptor": "orb"}}, "closure.descriptor"),
    ],
)
def test_a_memory_made_with_other_settings_is_refused_naming_the_setting(
    first_lap, tmp_path, override, names
):
    config = config_from_dict({**QUIET, **override})
    with pytest.raises(SavedMemoryError, match=rf"made with {names.replace('.', '[.]')} ="):
        run(tmp_path / "x", config=config, progress=False, stop=5, memory_from=first_lap)
    assert not (tmp_path / "x").exists()


def test_a_memory_from_before_the_keyframe_descriptor_was_recorded_is_taken_as_orb(first_lap, tmp_path):
    """Memories saved before `closure.descriptor` was recorded hold ORB keyframes (the default then): a run
    with SIFT keyframes (the default now) refuses one, naming the setting to change."""
    import shutil

    old = tmp_path / "old"
    shutil.copytree(first_lap, old)
    manifest = old / "memory" / "memory.json"
    info = json.loads(manifest.read_text())
    assert info["depends_on"].pop("closure") == {"descriptor": "sift"}
    manifest.write_text(json.dumps(info))
    with pytest.raises(
        SavedMemoryError,
        match='made with closure[.]descriptor = "orb", this run has "sift"',
    ):
        run(tmp_path / "x", config=config_from_dict(QUIET), progress=False, stop=5, memory_from=old)
    assert not (tmp_path / "x").exists()


def test_a_setting_this_run_has_no_part_for_is_named_as_missing_not_as_a_placeholder(first_lap, tmp_path):
    """The paper's preset has no stereo keyframes: the memory's `closure.descriptor` has nothing to compare
    with (before: 'this run has "<absent>"')."""
    config = config_from_dict({**QUIET, "preset": "paper"})
    with pytest.raises(SavedMemoryError, match=r"this run has no \S+ \(no such part that sets it\)") as err:
        run(tmp_path / "x", config=config, progress=False, stop=5, memory_from=first_lap)
    assert "<absent>" not in str(err.value)


class _RightShifted(Frames):
    """The first `n` frames with every right image moved a pixel to the right (a disparity shortfall)."""

    def __getitem__(self, i: int):
        import dataclasses

        import cv2

        frame = super().__getitem__(i)
        h, w = frame.right.shape
        shift = np.float32([[1, 0, 1.0], [0, 1, 0]])
        moved = cv2.warpAffine(frame.right, shift, (w, h), borderMode=cv2.BORDER_REPLICATE)
        return dataclasses.replace(frame, right=moved)


def test_a_later_session_starts_from_the_stereo_offset_the_first_found(demo, tmp_path):
    """A run on a rig whose right image is a pixel off finds the offset from the motion and saves it with
    its memory, and the estimates behind it; a session started in that memory starts its VO there, with
    those estimates as its prior evidence (its first frames do not overturn the offset), unless its config
    sets the offset."""
    from hippo_nav.pipeline import Pipeline

    pipeline = Pipeline(_RightShifted(demo, 90), config_from_dict(QUIET))
    first = pipeline.run(tmp_path / "first")
    found_px = first.metrics["data"]["disparity_offset_px"]
    assert found_px > 0.3  # it moved (the demo's 1 px reads about 0.6 after the first 10 frames)
    memory = read_memory(tmp_path / "first")
    assert memory.info["odometry"]["disparity_offset_px"] == found_px
    behind = memory.info["odometry"]["disparity_offset_frames"]
    assert behind == pipeline.odometry.disparity_offset_frames > 0  # type: ignore[attr-defined]

    later = Pipeline(_RightShifted(demo, 5), config_from_dict(QUIET), memory=memory)
    assert later.odometry.disparity_offset_px == found_px  # type: ignore[attr-defined]
    assert later.odometry.params.disparity_calibration_prior_frames == behind  # type: ignore[attr-defined]
    assert later.odometry.disparity_offset_frames == behind  # type: ignore[attr-defined]
    config = json.loads(json.dumps(QUIET))
    config.setdefault("vo", {})["disparity_offset_px"] = 0.25
    told = Pipeline(_RightShifted(demo, 5), config_from_dict(config), memory=memory)
    assert told.odometry.disparity_offset_px == 0.25  # type: ignore[attr-defined]
    assert told.odometry.disparity_offset_frames == 0  # type: ignore[attr-defined]
    fresh = Pipeline(_RightShifted(demo, 5), config_from_dict(QUIET))
    assert fresh.odometry.disparity_offset_px == 0.0  # type: ignore[attr-defined]
    assert fresh.odometry.disparity_offset_frames == 0  # type: ignore[attr-defined]
    # A memory written before the estimates were kept starts from the offset with no prior evidence.
    del memory.info["odometry"]["disparity_offset_frames"]
    older = Pipeline(_RightShifted(demo, 5), config_from_dict(QUIET), memory=memory)
    assert older.odometry.disparity_offset_px == found_px  # type: ignore[attr-defined]
    assert older.odometry.disparity_offset_frames == 0  # type: ignore[attr-defined]
