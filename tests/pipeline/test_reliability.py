"""A run never throws away finished work, never hides a data problem, and says what to fix.

Each test is one failure a newcomer trial found (bad --out, short files, signals, gaps, unavailable
metrics, confusing messages, a seed without effect, engine arguments out of range)."""

from __future__ import annotations

import json
import os
import re
import signal

import cv2
import numpy as np
import pytest
from conftest import QUIET, Frames
from hippo_nav import HippoNavError
from hippo_nav.cli import main
from hippo_nav.datasets import KittiOdometry
from hippo_nav.engine import EngineConfig, SpatialMemory, ViewPatterns
from hippo_nav.io import DatasetError
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.pipeline.frontend import VO_AHEAD
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence, loop_trajectory
from hippo_nav.synthetic.render import render_cached
from hippo_nav.vo import ReplayOdometry, StereoOdometry


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


# --- results folder: checked before the first frame ----------------------------------------------------
def test_a_bad_results_folder_is_refused_before_any_frame(tmp_path, capsys):
    a_file = tmp_path / "file.txt"
    a_file.write_text("not a folder")
    base = ["run", "--no-progress", "--stop", "5"]
    for out, phrase in (
        (a_file, "is a file"),
        (a_file / "below", "a part of that path is a file"),
        ("", "empty"),
        (
            "/proc/hippo_nav_results",
            "results folder /proc/hippo_nav_results cannot be created",
        ),  # no folders there
    ):
        assert main([*base, "--out", str(out)]) == 2
        assert phrase in _one_line_error(capsys)
    assert main(["run", "--sequence", "05", "--no-progress"]) == 2
    assert "--sequence 05 needs --kitti" in _one_line_error(capsys)
    assert main([*base, "--seed", "-1", "--out", str(tmp_path / "s")]) == 2
    assert "argument --seed: '-1' is out of range" in _one_line_error(capsys)


def test_an_earlier_run_is_never_mixed_with_a_new_one(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "--no-progress", "--stop", "6", "--out", str(out)]) == 0
    (out / "neural_state_009999.png").write_bytes(b"an old figure")
    (out / "my_notes.txt").write_text("the user's own file")
    capsys.readouterr()
    assert main(["run", "--no-progress", "--stop", "4", "--no-figures", "--out", str(out)]) == 2
    assert "not empty" in _one_line_error(capsys) and "--overwrite" in capsys.readouterr().err + "--overwrite"
    assert (
        main(["run", "--no-progress", "--stop", "4", "--no-figures", "--out", str(out), "--overwrite"]) == 0
    )
    assert json.loads((out / "metrics.json").read_text())["frames"] == 4
    assert not list(out.glob("*.png")), "the old figures are gone with --overwrite"
    assert (out / "my_notes.txt").read_text() == "the user's own file"


def test_overwrite_never_clears_a_folder_no_run_made(tmp_path, capsys):
    """A folder of the user's own that happens to hold a config.json and a frames.csv is not a results folder:
    --overwrite refuses it and deletes nothing; a folder a run made (even one stopped before its first frame)
    carries the mark and is cleared."""
    theirs = tmp_path / "experiment"
    theirs.mkdir()
    (theirs / "config.json").write_text('{"mine": true}')
    (theirs / "frames.csv").write_text("my,own,table\n")
    assert main(["run", "--no-progress", "--stop", "3", "--out", str(theirs), "--overwrite"]) == 2
    assert "holds files no run made" in _one_line_error(capsys)
    assert (theirs / "config.json").read_text() == '{"mine": true}'
    assert (theirs / "frames.csv").read_text() == "my,own,table\n"
    assert sorted(p.name for p in theirs.iterdir()) == ["config.json", "frames.csv"]
    ours = tmp_path / "ours"
    assert main(["run", "--no-progress", "--stop", "3", "--no-figures", "--out", str(ours)]) == 0
    assert (ours / ".hippo_nav_results").is_file()
    assert (
        main(["run", "--no-progress", "--stop", "2", "--no-figures", "--out", str(ours), "--overwrite"]) == 0
    )
    assert json.loads((ours / "metrics.json").read_text())["frames"] == 2


def test_a_second_run_into_a_folder_being_written_is_refused(tmp_path, capsys):
    """Two runs started into the same new --out must not mix their files: the folder's mark is a lock."""
    from hippo_nav.pipeline.results import prepare_results_folder

    out = tmp_path / "shared"
    _, lock, _ = prepare_results_folder(out)  # the first run, still writing
    for extra in ([], ["--overwrite"]):
        assert main(["run", "--no-progress", "--stop", "2", "--no-figures", "--out", str(out), *extra]) == 2
        assert "another run is writing" in _one_line_error(capsys)
    assert sorted(p.name for p in out.iterdir()) == [".hippo_nav_results"]
    lock.close()  # the first run finished
    assert main(["run", "--no-progress", "--stop", "2", "--no-figures", "--out", str(out)]) == 0


def test_a_kitti_run_without_out_gets_its_own_folder(tmp_path, monkeypatch, demo):
    monkeypatch.chdir(tmp_path)
    root = demo.root
    assert (
        main(["run", "--kitti", str(root), "--sequence", DEMO_SEQUENCE, "--stop", "3", "--no-progress"]) == 0
    )
    assert (tmp_path / "runs" / f"kitti_{DEMO_SEQUENCE}" / "metrics.json").is_file()
    assert not (tmp_path / "runs" / "demo").exists()


# --- every result is written even when a metric cannot be computed -----------------------------------------
@pytest.mark.parametrize("how", ["one frame", "all modules lesioned"])
def test_results_are_written_when_a_metric_is_unavailable(demo, tmp_path, how):
    n = 1 if how == "one frame" else 12
    config = {**QUIET}
    if how != "one frame":
        config["lesions"] = {"ventral": True, "intermediate": True, "dorsal": True}
    Pipeline(Frames(demo, n), config_from_dict(config)).run(tmp_path / "out")
    out = tmp_path / "out"
    for name in ("vo", "online", "corrected", "neural"):
        assert (out / f"trajectory_{name}.kitti.txt").read_text().count("\n") == n
    assert (out / "map.bin").stat().st_size > 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == n
    if how == "one frame":
        assert "single frame" in metrics["unavailable"]["errors"]
    else:
        assert metrics["lesioned"] == [True, True, True]
        assert metrics["errors"]["vo"]["ate_2d_m"] >= 0.0  # scored, though the networks' estimate is not
        assert "same point" in metrics["errors"]["neural"]["unavailable"]


# --- signals --------------------------------------------------------------------------------------------
def _run_signalled_at_frame_8(demo, monkeypatch, out, signame: str, frames: int) -> int:
    """Exit code of `hippo-nav run` on `frames` demo frames, the process sending itself `signame` while
    frame 8 loads."""

    def signal_at_frame_8(i):
        if i == 8:
            os.kill(os.getpid(), getattr(signal, signame))

    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input",
        lambda *a, **k: Frames(demo, frames, on_load=signal_at_frame_8),
    )
    return main(["run", "--no-progress", "--no-figures", "--out", str(out)])


@pytest.mark.parametrize("signame, code", [("SIGTERM", 143), ("SIGHUP", 129)])
def test_sigterm_and_sighup_keep_the_frames_processed(
    demo, tmp_path, monkeypatch, disposition, signame, code
):
    disposition(signame, signal.SIG_DFL)
    out = tmp_path / "out"
    assert _run_signalled_at_frame_8(demo, monkeypatch, out, signame, frames=30) == code
    metrics = json.loads((out / "metrics.json").read_text())
    # The signal arrives while frame 8 loads, up to VO_AHEAD + 1 frames ahead of the networks (the odometry
    # runs VO_AHEAD ahead, the loader one more): 8 − (VO_AHEAD + 1) to 9 frames are done.
    assert metrics["interrupted"] and metrics["interrupted_by"] == signame
    assert 8 - (VO_AHEAD + 1) <= metrics["frames"] <= 9
    assert (out / "trajectory_corrected.kitti.txt").read_text().count("\n") == metrics["frames"]
    assert signal.getsignal(getattr(signal, signame)) is signal.SIG_DFL  # the handler is put back


@pytest.mark.parametrize("signame", ["SIGHUP", "SIGTERM"])
def test_a_signal_started_ignored_stays_ignored(demo, tmp_path, monkeypatch, disposition, signame):
    """`nohup hippo-nav run …` starts with SIGHUP ignored: a closed terminal must not stop the run."""
    disposition(signame, signal.SIG_IGN)
    out = tmp_path / "out"
    assert _run_signalled_at_frame_8(demo, monkeypatch, out, signame, frames=12) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert not metrics["interrupted"] and metrics["frames"] == 12
    assert signal.getsignal(getattr(signal, signame)) is signal.SIG_IGN


def test_ctrl_c_before_the_first_frame_exits_130(demo, tmp_path, monkeypatch, capsys):
    def interrupt(i):
        raise KeyboardInterrupt

    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, 30, on_load=interrupt)
    )
    assert main(["run", "--no-progress", "--out", str(tmp_path / "out")]) == 130


# --- data problems are flagged, not hidden ---------------------------------------------------------------
def test_a_time_gap_does_not_become_motion(demo, tmp_path):
    # 100 s pass between frames 10 and 11, and frame 11 has no texture: the VO's constant-velocity prior
    # must not carry the car on for 100 s (it did: 1 157 m).
    times = demo.timestamps_s[:20].copy()
    times[11:] += 100.0

    class BlankAt11(Frames):
        def __getitem__(self, i):
            frame = super().__getitem__(i)
            if i == 11:
                blank = np.full_like(frame.left, 128)
                return type(frame)(frame.index, frame.timestamp_s, blank, blank)
            return frame

    result = Pipeline(BlankAt11(demo, 20, times), config_from_dict(QUIET)).run(tmp_path / "out")
    vo = result.vo_world_from_camera
    assert np.linalg.norm(vo[11, :3, 3] - vo[10, :3, 3]) < 1.0
    assert result.record.frames[11].data_flags.startswith("time_gap:100")
    assert result.metrics["data"]["time_gaps"] == 1
    assert "time_gap" in (tmp_path / "out" / "frames.csv").read_text()


def test_a_hole_in_the_images_is_counted_and_flagged(demo, tmp_path):
    root = tmp_path / "kitti"
    sequence = root / "sequences" / DEMO_SEQUENCE
    for folder in ("image_0", "image_1"):
        (sequence / folder).mkdir(parents=True)
        for i in range(12):
            if not (folder == "image_1" and i == 6):
                source = demo.root / "sequences" / DEMO_SEQUENCE / folder / f"{i:06d}.png"
                (sequence / folder / source.name).write_bytes(source.read_bytes())
    for name in ("calib.txt", "times.txt"):
        (sequence / name).write_bytes((demo.root / "sequences" / DEMO_SEQUENCE / name).read_bytes())
    result = Pipeline(KittiOdometry(root, DEMO_SEQUENCE), config_from_dict(QUIET)).run(tmp_path / "out")
    assert result.metrics["data"]["missing_frames"] == 1
    assert result.metrics["data"]["frames_after_skipped_frames"] == 1
    assert [f.data_flags for f in result.record.frames].count("skipped_frames:1") == 1


def test_textureless_sequences_are_reported(demo, tmp_path, caplog):
    class Blank(Frames):
        def __getitem__(self, i):
            frame = super().__getitem__(i)
            blank = np.full_like(frame.left, 90)
            return type(frame)(frame.index, frame.timestamp_s, blank, blank)

    result = Pipeline(Blank(demo, 12), config_from_dict(QUIET)).run(None)
    assert result.metrics["data"]["low_texture_frames"] >= 10
    assert any("too little usable texture" in r.message for r in caplog.records)


def test_images_their_calibration_does_not_describe_stop_the_run_naming_the_sizes(demo):
    """A dataset made in Python gave images transposed against its calibration: every frame's odometry
    failed and the run ended with a trajectory of zeros and no error."""

    class Transposed(Frames):
        def __getitem__(self, i):
            frame = super().__getitem__(i)
            return type(frame)(frame.index, frame.timestamp_s, frame.left.T.copy(), frame.right.T.copy())

    width, height = demo.calibration.image_size_px
    with pytest.raises(
        DatasetError, match=f"frame 0: image is {height}×{width} px but the calibration is for"
    ):
        Pipeline(Transposed(demo, 5), config_from_dict(QUIET)).run(None)


def test_steps_rejected_as_too_fast_on_most_frames_are_reported(demo, caplog):
    """Timestamps a hundred times too close (still above the 1 ms floor) make every step too fast for the
    VO's limits: the run says to check the timestamps instead of ending on a trajectory of zeros silently."""
    frames = Frames(demo, 12, timestamps_s=demo.timestamps_s[:12] / 50.0)
    result = Pipeline(frames, config_from_dict(QUIET)).run(None)
    assert result.metrics["vo_status_counts"].get("rejected", 0) >= 10
    assert any(
        "rejected as too fast" in r.message and "timestamps' unit" in r.message for r in caplog.records
    )


def test_the_public_api_refuses_wrong_types_naming_the_argument(demo, tmp_path):
    """A path where a dataset belongs, a float frame range, a string for a lesion flag: a TypeError naming
    the argument, instead of an AttributeError deep inside or a silent coercion (stop=1.5 ran one frame,
    dorsal="no" lesioned the dorsal module)."""
    import hippo_nav

    with pytest.raises(TypeError, match="dataset must be a StereoDataset .*open_input"):
        Pipeline(str(tmp_path))
    with pytest.raises(TypeError, match="config must be a PipelineConfig or a dict"):
        Pipeline(Frames(demo, 3), 42)  # type: ignore[arg-type]
    # A dict of settings is checked as a config file is, and used.
    with pytest.raises(HippoNavError, match="seed"):
        Pipeline(Frames(demo, 3), {"seed": "one"})
    assert Pipeline(Frames(demo, 3), {**QUIET, "seed": 7}).config.seed == 7
    for kwargs, name in (
        ({"stop": 1.5}, "stop"),
        ({"start": True, "stop": 4}, "start"),
        ({"stride": 2.7}, "stride"),
    ):
        with pytest.raises(TypeError, match=f"{name} must be a whole frame number"):
            hippo_nav.run(tmp_path / "out", **kwargs)
    engine = SpatialMemory()
    with pytest.raises(TypeError, match="dorsal must be True or False, got 'no'"):
        engine.set_lesions(dorsal="no")  # type: ignore[arg-type]
    with pytest.raises(HippoNavError, match="grid module index 100000000000000000000 out of range"):
        engine.grid_activity(10**20)
    with pytest.raises(TypeError, match="module must be a grid module index"):
        engine.grid_layer2("1")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="config must be an EngineConfig, got dict.*load_config"):
        SpatialMemory({"tau_s": 0.01})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="lesioned"):
        EngineConfig().with_lesions(dorsal="maybe")  # type: ignore[arg-type]


def test_a_dataset_with_fewer_timestamps_than_frames_is_refused(demo):
    frames = Frames(demo, 6, timestamps_s=demo.timestamps_s[:4])
    with pytest.raises(DatasetError, match="timestamps_s holds 4 values for 6 frames"):
        Pipeline(frames, config_from_dict(QUIET))


def test_a_corrupt_file_in_a_render_cache_is_rendered_again(tmp_path):
    """The demo's cache (`render_cached`, under `demo_sequence`) renders a truncated image again; shown on a
    small render, as the demo's 200 frames would cost the test half a minute for the same check."""
    poses = loop_trajectory(12)
    root = render_cached(poses, tmp_path / "cache", DEMO_SEQUENCE, image_size_px=(64, 24))
    victim = root / "sequences" / DEMO_SEQUENCE / "image_0" / "000007.png"
    victim.write_bytes(victim.read_bytes()[:100])  # truncated
    assert cv2.imread(str(victim)) is None
    render_cached(poses, tmp_path / "cache", DEMO_SEQUENCE, image_size_px=(64, 24))
    assert cv2.imread(str(victim)) is not None


# --- messages --------------------------------------------------------------------------------------------
def test_config_errors_name_the_field_and_value(tmp_path, capsys):
    cfg = tmp_path / "c.json"
    for config, phrase in (
        ('{"engine": {"tau_s": NaN}}', "engine.tau_s: Input should be a finite number (got nan)"),
        (
            '{"output": {"rate_map_bin_m": 1e-6}}',
            "output.rate_map_bin_m: Input should be greater than or equal to 0.1",
        ),
        (
            '{"output": {"state_frames": [500]}}',
            "output.state_frames: [500] lie outside this run of 5 frames",
        ),
        (
            '{"vo": {"max_features": -3}}',
            "vo.max_features: Input should be greater than or equal to 8 (got -3)",
        ),
        # Absurd numbers that used to hang a run before frame 0 or silently turn a part off.
        (
            '{"engine": {"max_substep_s": 1e-9}}',
            "engine.max_substep_s: Input should be greater than or equal",
        ),
        ('{"engine": {"tau_s": 1e9}}', "engine.tau_s: Input should be less than or equal to 10"),
        (
            '{"engine": {"torus_period_m": 1e300}}',
            "engine.torus_period_m: Input should be less than or equal",
        ),
        (
            '{"closure": {"orb_features": 1000000000}}',
            "closure.orb_features: Input should be less than or equal",
        ),
    ):
        cfg.write_text(config)
        assert (
            main(["run", "--no-progress", "--stop", "5", "--config", str(cfg), "--out", str(tmp_path / "x")])
            == 2
        )
        assert phrase in _one_line_error(capsys)
    one_module = config_from_dict({"engine": {"grid": {"dorsal": {"nu_max": 0.1}}}})
    assert [g.nu_max for g in one_module.engine.grid][2] == 0.1
    assert one_module.engine.grid[0].nu_max == EngineConfig().grid[0].nu_max


def test_one_seed_reaches_every_random_choice(demo):
    def codes(seed: int) -> list:
        config = config_from_dict({"seed": seed, **QUIET})
        return Pipeline(Frames(demo, 8), config).run(None).record.column("place_code_rad")

    assert codes(3) == codes(3)
    assert codes(3) != codes(4)


def test_engine_arguments_out_of_range_are_named():
    sm = SpatialMemory()
    patterns = sm.view_patterns()
    with pytest.raises(HippoNavError, match="view strength"):
        sm.step(0.0, 1.0, 0.1, ViewPatterns(patterns.hd_profile, patterns.grid_layer2, strength=-1.0))
    with pytest.raises(ValueError, match="settle_s"):
        EngineConfig(settle_s=-0.1)
    with pytest.raises(HippoNavError, match="engine.settle_s = -0.1"):
        SpatialMemory(EngineConfig().model_copy(update={"settle_s": -0.1}))
    state = sm.state()
    state["place"] = -state["place"] - 1.0
    before = sm.place_activity()
    with pytest.raises(HippoNavError, match="place activity.*negative"):
        sm.set_state(state)
    np.testing.assert_array_equal(sm.place_activity(), before)
    with pytest.raises(HippoNavError, match="grid module index -1"):
        sm.grid_layer2(-1)


def test_the_vo_prior_does_not_extrapolate_over_a_gap(demo):
    vo = StereoOdometry(demo.calibration)
    frames = [demo[i] for i in range(4)]
    for frame in frames[:3]:
        vo.process(frame)
    blank = np.full_like(frames[3].left, 128)
    late = type(frames[3])(frames[3].index, frames[2].timestamp_s + 100.0, blank, blank)
    step = vo.process(late)
    assert step.status == "low_texture" and np.linalg.norm(step.camera_prev_from_camera_cur[:3, 3]) < 1e-9


@pytest.mark.parametrize("overlap", [True, False])
def test_a_failing_keyframe_extraction_costs_closures_not_the_run(demo, tmp_path, caplog, overlap):
    """A vertex's keyframe is extracted beside the next frame's odometry (or inline without the overlap);
    when extraction raises, the run still finishes and writes everything, and says which vertex lacks it."""
    from hippo_nav.closure import ClosureChain, KeyframeExtractor

    real, calls = KeyframeExtractor.__call__, []

    def fails_on_the_third(self, left, right, disparity_offset_px=None):
        calls.append(1)
        if len(calls) == 3:
            raise HippoNavError("simulated: keyframe extraction failed")
        return real(self, left, right, disparity_offset_px)

    config = config_from_dict({**QUIET, "overlap_front_end": overlap})
    pipeline = Pipeline(Frames(demo, 30), config)
    KeyframeExtractor.__call__ = fails_on_the_third  # type: ignore[method-assign]
    try:
        with caplog.at_level("WARNING", logger="hippo_nav.pipeline"):
            result = pipeline.run(tmp_path / "out")
    finally:
        KeyframeExtractor.__call__ = real  # type: ignore[method-assign]
    assert not result.interrupted and len(result.record) == 30
    closure = pipeline.system.closure
    assert isinstance(closure, ClosureChain)
    assert len(closure.store.keyframes) == result.metrics["keyframes"] == len(calls) - 1 >= 3
    assert "no stereo keyframe" in caplog.text
    assert (tmp_path / "out" / "metrics.json").is_file()


def test_a_text_input_that_is_not_utf8_is_one_line_naming_the_file(demo, tmp_path, capsys):
    """A config, calib.txt or times.txt holding a byte that is not UTF-8 (a Latin-1 comment, a binary file
    saved under the wrong name): one line naming the file and the line, exit 2, no traceback."""
    cfg = tmp_path / "config.json"
    cfg.write_bytes(b'{"seed": 1,\n "note": "caf\xe9"}')
    assert (
        main(["run", "--no-progress", "--stop", "2", "--config", str(cfg), "--out", str(tmp_path / "a")]) == 2
    )
    err = _one_line_error(capsys)
    assert str(cfg) in err and "not UTF-8" in err and ":2:" in err
    source = demo.root / "sequences" / DEMO_SEQUENCE
    for name in ("calib.txt", "times.txt"):
        root = tmp_path / f"kitti_{name}"
        sequence = root / "sequences" / DEMO_SEQUENCE
        sequence.mkdir(parents=True)
        for entry in source.iterdir():
            (sequence / entry.name).symlink_to(entry)
        (sequence / name).unlink()
        (sequence / name).write_bytes((source / name).read_bytes() + b"# r\xe9sum\xe9\n")
        args = ["run", "--kitti", str(root), "--sequence", DEMO_SEQUENCE, "--stop", "2", "--no-progress"]
        assert main([*args, "--out", str(tmp_path / f"out_{name}")]) == 2
        err = _one_line_error(capsys)
        assert str(sequence / name) in err and "not UTF-8" in err


def test_config_errors_name_the_setting_its_value_and_bound_not_a_json_column(tmp_path, capsys):
    """The engine's settings are checked in Python before the Rust engine sees them; every float refuses NaN
    (tests/pipeline/test_config_validation.py goes through every setting)."""
    cfg = tmp_path / "c.json"
    run = ["run", "--no-progress", "--stop", "3", "--config", str(cfg)]
    for config, phrases in (
        (
            '{"engine": {"hd": {"n_theta": -3}}}',
            ["engine.hd.n_theta:", "(got -3)", "greater than or equal to 4"],
        ),
        (
            '{"views": {"novelty_threshold": NaN}}',
            ["views.novelty_threshold: Input should be a finite number"],
        ),
        (
            '{"map": {"loop_gate_m": Infinity}}',
            ["map.loop_gate_m: Input should be a finite number (got inf)"],
        ),
        ('{"vo": {"max_features": "500"}}', ["vo.max_features: must be an integer, not str (got '500')"]),
        ('{"engine": {"grid": {"dorsal": {"n_theta": 32}}}}', ["grid[2] (dorsal).n_theta = 32 differs"]),
    ):
        cfg.write_text(config)
        assert main([*run, "--out", str(tmp_path / "x")]) == 2
        err = _one_line_error(capsys)
        assert str(cfg) in err and "line 1 column" not in err and all(p in err for p in phrases), err
    # The torus size given once for every grid module: the place torus follows, and the run goes on.
    cfg.write_text('{"engine": {"grid": {"n_theta": 32}}, "output": {"figures": false}}')
    assert main([*run, "--out", str(tmp_path / "torus")]) == 0
    resolved = json.loads((tmp_path / "torus" / "config.json").read_text())["engine"]
    assert [g["n_theta"] for g in resolved["grid"]] == [32, 32, 32] and resolved["place"]["n_theta"] == 32


# --- inputs of absurd size: refused from their size, before they are read ----------------------------------------
def _sparse(path, n_bytes: int, head: bytes = b"") -> None:
    """A file of `n_bytes` that takes no disk space (a hole after `head`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(n_bytes)


def _tiny_kitti(root) -> None:
    sequence = root / "sequences" / "00"
    for camera in ("image_0", "image_1"):
        (sequence / camera).mkdir(parents=True)
        for i in range(2):
            cv2.imwrite(str(sequence / camera / f"{i:06d}.png"), np.full((24, 64), 40 * i + 20, np.uint8))
    k = "40 0 31.5 {} 0 40 11.5 0 0 0 1 0"
    (sequence / "calib.txt").write_text(f"P0: {k.format(0)}\nP1: {k.format(-20)}\n")
    (sequence / "times.txt").write_text("0.0\n0.1\n")


def test_oversized_text_inputs_are_one_line_naming_file_and_size(tmp_path, capsys):
    from hippo_nav.io.errors import MAX_DATA_FILE_BYTES, MAX_SETTINGS_FILE_BYTES

    cfg = tmp_path / "big.json"
    _sparse(cfg, MAX_SETTINGS_FILE_BYTES + 1, b'{"seed": 1, ')
    assert main(["run", "--no-progress", "--config", str(cfg), "--out", str(tmp_path / "a")]) == 2
    err = _one_line_error(capsys)
    assert (
        f"{cfg}: the config file is 16.0 MiB ({MAX_SETTINGS_FILE_BYTES + 1} bytes)" in err
        and "at most" in err
    )
    for name, size in (("calib.txt", MAX_SETTINGS_FILE_BYTES + 1), ("times.txt", MAX_DATA_FILE_BYTES + 1)):
        root = tmp_path / f"kitti_{name}"
        _tiny_kitti(root)
        _sparse(root / "sequences" / "00" / name, size, b"0.0\n")
        args = ["run", "--kitti", str(root), "--sequence", "00", "--no-progress", "--out", str(root / "o")]
        assert main(args) == 2
        err = _one_line_error(capsys)
        assert str(root / "sequences" / "00" / name) in err and f"({size} bytes)" in err, err
    replayed = tmp_path / "poses.txt"
    _sparse(replayed, MAX_DATA_FILE_BYTES + 1)
    args = ["run", "--no-progress", "--stop", "3", "--odometry", str(replayed), "--out", str(tmp_path / "r")]
    assert main(args) == 2
    assert str(replayed) in _one_line_error(capsys)


def test_an_oversized_file_is_not_read_into_memory(tmp_path):
    import tracemalloc

    from hippo_nav.io.errors import DatasetError, read_text

    big = tmp_path / "times.txt"
    _sparse(big, 300 * 2**20, b"0.0\n")
    tracemalloc.start()
    try:
        with pytest.raises(DatasetError, match=r"times.txt: the timestamps file is 300.0 MiB"):
            read_text(big, "timestamps file")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 2**20
    # A device or pipe has no size to check: it is read up to the limit, never further.
    with pytest.raises(DatasetError, match=r"/dev/zero: the stream holds more than 64.0 KiB"):
        read_text("/dev/zero", "stream", 64 * 2**10)


def _png_header(width: int, height: int) -> bytes:
    """A PNG that declares width × height gray pixels and holds one compressed row: 100 bytes on disk."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    pixels = zlib.compress(b"\0" * (min(width, 4096) + 1))
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", pixels) + chunk(b"IEND", b"")


@pytest.mark.parametrize("side", [100_000, 9_000])
def test_an_image_declaring_an_absurd_size_is_refused_before_decoding(tmp_path, capsys, side):
    """A 100-byte PNG can declare 100 000 × 100 000 px (10 GB once decoded): refused from its header, in one
    line naming the file, whether OpenCV would have raised, allocated or given up."""
    from hippo_nav.datasets.common import decode_image_bytes
    from hippo_nav.io.errors import DatasetError

    root = tmp_path / "kitti"
    _tiny_kitti(root)
    bomb = root / "sequences" / "00" / "image_0" / "000000.png"
    bomb.write_bytes(_png_header(side, side))
    args = ["run", "--kitti", str(root), "--sequence", "00", "--no-progress", "--out", str(root / "o")]
    assert main(args) == 2
    err = _one_line_error(capsys)
    assert f"{bomb}: the image declares {side}x{side} px" in err, err
    # The same for an image inside a bag (a CompressedImage message).
    with pytest.raises(DatasetError, match=rf"bag /left: the image declares {side}x{side} px"):
        decode_image_bytes(_png_header(side, side), "bag /left")


@pytest.mark.parametrize(
    ("factor", "unit"), [(1e3, "milliseconds (divide them by 1,000)"), (1e9, "nanoseconds")]
)
def test_timestamps_in_another_unit_are_refused_before_any_frame(demo, factor, unit):
    # In milliseconds every frame was a 100 s "time gap": one warning per frame, and the networks lost the
    # motion across each (the place code's error grew fivefold on 20 real KITTI frames).
    frames = Frames(demo, 20, timestamps_s=demo.timestamps_s[:20] * factor)
    with pytest.raises(DatasetError, match="must be in seconds, and these look like " + re.escape(unit)):
        Pipeline(frames, config_from_dict(QUIET))
    assert frames.reads == []


def test_a_stride_is_not_taken_for_another_time_unit(demo):
    # Every 60th frame of a 10 Hz sequence: 6 s between the frames run, 0.1 s per sequence frame.
    strided = KittiOdometry(demo_sequence(), DEMO_SEQUENCE, stride=60)
    assert np.median(np.diff(strided.timestamps_s)) > 5.0
    Pipeline(strided, config_from_dict(QUIET))


def test_a_stride_longer_than_the_gap_limit_is_no_gap(tmp_path):
    # Every 20th frame of a 10 Hz sequence: 2 s between the frames run. `max_gap_s` (1 s) is per sequence
    # frame; unscaled, every frame was flagged as a time gap and its motion integrated over 1 s, not 2.
    # The ground truth is replayed as the odometry (the VO does not track 20 frames' motion at 96 rows).
    strided = KittiOdometry(demo_sequence(), DEMO_SEQUENCE, stop=121, stride=20)
    truth = strided.root / "poses" / f"{DEMO_SEQUENCE}.txt"
    result = Pipeline(strided, config_from_dict(QUIET), odometry=ReplayOdometry(truth, strided)).run(
        tmp_path / "out"
    )
    assert result.metrics["data"]["time_gaps"] == 0
    frames = result.record.frames
    assert all(f.data_flags == "" for f in frames)
    assert all(f.motion_flag == "ok" for f in frames[1:])
    # The engine's speed is the step over the 2 s between the frames run.
    vo = result.vo_world_from_camera
    for k, f in enumerate(frames[1:], start=1):
        step_m = np.linalg.norm(vo[k, [0, 2], 3] - vo[k - 1, [0, 2], 3])
        assert abs(f.speed_m_s) == pytest.approx(step_m / 2.0, rel=0.02)
