"""The viewers: the mapping video, the Rerun observer (against a fake `rr` and, when installed, rerun itself),
the shared panels, and their command-line flags."""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import cv2
import hippo_nav.viewer.rerun as rerun_viewer
import hippo_nav.viewer.video as viewer_video
import numpy as np
import pytest
from hippo_nav import HippoNavError, SpatialMemory
from hippo_nav.cli import build_parser, main
from hippo_nav.datasets import KittiOdometry
from hippo_nav.pipeline import FrameEvent, NetworkActivity, Pipeline, config_from_dict
from hippo_nav.pipeline.frontend import tracked_pixels
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence
from hippo_nav.system.records import STAGES
from hippo_nav.viewer import RerunObserver, VideoObserver
from hippo_nav.viewer.panels import angles_to_pixels, colorize, neural_panels
from hippo_nav.viewer.rerun import BLOCK, _Blocks

FRAMES = 20


def demo(stop: int = FRAMES) -> KittiOdometry:
    return KittiOdometry(demo_sequence(), DEMO_SEQUENCE, stop=stop)


def decoded_frames(path) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, image = capture.read()
        if not ok:
            break
        frames.append(image)
    capture.release()
    return frames


# ------------------------------------------------------------------------------------------------
# A fake rerun: records what would be logged, at which frame.


class Logged:
    def __init__(self, kind: str, args: tuple, kwargs: dict) -> None:
        self.kind, self.args, self.kwargs = kind, args, kwargs


class _Factory:
    """`rr.Points2D(...)`, `rr.Points2D.from_fields(...)`: an archetype, recorded by name."""

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def __call__(self, *args, **kwargs) -> Logged:
        return Logged(self.kind, args, kwargs)

    def __getattr__(self, method: str) -> _Factory:
        return _Factory(f"{self.kind}.{method}")


class _Factories:
    """`rr.Points2D`, `rr.blueprint.Grid`, …: any archetype."""

    def __getattr__(self, kind: str) -> _Factory:
        return _Factory(kind)


class FakeRecording:
    def __init__(self, application_id: str) -> None:
        self.application_id = application_id
        self.time: dict[str, float] = {}
        self.logs: list[tuple[dict[str, float], str, Logged, bool]] = []
        self.sink: tuple | None = None
        self.blueprints: list[Logged] = []
        self.closed = False
        self.flush_timeouts_s: list[float] = []

    def save(self, path) -> None:
        self.sink = ("save", str(path))

    def spawn(self) -> None:
        self.sink = ("spawn",)

    def connect_grpc(self, url: str) -> None:
        self.sink = ("connect", url)

    def set_time(self, timeline: str, **value) -> None:
        (self.time[timeline],) = value.values()

    def log(self, entity: str, archetype: Logged, static: bool = False) -> None:
        self.logs.append((dict(self.time), entity, archetype, static))

    def send_blueprint(self, blueprint: Logged) -> None:
        self.blueprints.append(blueprint)

    def flush(self, timeout_sec: float = 1e38) -> None:
        self.flush_timeouts_s.append(timeout_sec)

    def disconnect(self) -> None:
        self.closed = True

    def at(self, entity: str) -> list[tuple[dict[str, float], Logged]]:
        return [(time, archetype) for time, name, archetype, _ in self.logs if name == entity]


class FakeRerun(_Factories):
    def __init__(self) -> None:
        self.blueprint = _Factories()
        self.recordings: list[FakeRecording] = []

    def RecordingStream(self, application_id: str) -> FakeRecording:
        recording = FakeRecording(application_id)
        self.recordings.append(recording)
        return recording


@pytest.fixture(scope="module")
def observed(tmp_path_factory):
    """One 20-frame demo run watched by the video observer and a Rerun observer on the fake `rr`."""
    video_path = tmp_path_factory.mktemp("video") / "mapping.mp4"
    video = VideoObserver(video_path, every=5)
    rr = FakeRerun()
    rrd = tmp_path_factory.mktemp("rerun") / "run.rrd"
    rerun = RerunObserver(rrd, rr=rr)
    pipeline = Pipeline(demo(), observers=[video, rerun])
    result = pipeline.run()
    rerun.close()
    return SimpleNamespace(
        pipeline=pipeline, result=result, video=video, rec=rr.recordings[0], rerun=rerun, rrd=rrd
    )


# ------------------------------------------------------------------------------------------------
# Video


def test_video_has_one_frame_every_n_frames_plus_one_after_the_final_correction(observed):
    frames = decoded_frames(observed.video.path)
    assert len(frames) == len(range(0, FRAMES, 5)) + 1 == observed.video.frames_written == 5
    assert all(f.shape == (720, 1280, 3) for f in frames)
    # The map grows: the right half (the cognitive map) changes from the first video frame to the last.
    map_half = (slice(40, 700), slice(660, 1270))
    changed = np.abs(frames[0][map_half].astype(int) - frames[-1][map_half].astype(int)) > 40
    assert changed.mean() > 0.002


def test_video_refuses_a_bad_frame_interval(tmp_path):
    with pytest.raises(ValueError, match="every=0"):
        VideoObserver(tmp_path / "x.mp4", every=0)


# ------------------------------------------------------------------------------------------------
# Rerun, against the fake


def test_rerun_observer_logs_every_frame_on_the_frame_timeline(observed):
    rec, pipeline = observed.rec, observed.pipeline
    # Recorded under a fresh hidden name beside the target, renamed to it when closed (never a half file
    # at the target's name, never a write through a link there).
    kind, recorded = rec.sink
    assert kind == "save" and Path(recorded).parent == observed.rrd.parent
    assert Path(recorded).name.startswith(".run.rrd.") and not Path(recorded).exists()
    assert observed.rrd.is_file() and rec.closed
    # Every flush is bounded: a viewer that stops taking data never holds a finished run.
    assert rec.flush_timeouts_s and max(rec.flush_timeouts_s) <= 60
    frames = [int(time["frame"]) for time, _ in rec.at("camera/left")]
    assert frames == [f.frame_index for f in pipeline.record.frames] == list(range(FRAMES))
    logged = {name for _, name, _, _ in rec.logs}
    expected = {
        "camera/left", "camera/left/features", "camera/left/view_cell",
        "neural/hd_ring", "neural/layer2_k1", "neural/layer2_k2", "neural/layer2_k4", "neural/place",
        "neural/place/bumps", "readout/heading_deg", "readout/speed_m_s", "readout/bump_table",
        "map/vertices/0", "map/links/0", "map/agent", "map/tracks/odometry/0", "map/tracks/online/0",
        "map/tracks/ground_truth/0", "map/tracks/corrected", "timing/stage_ms", "readout/yaw_rate_deg_s",
        "events",
    }  # fmt: skip
    assert expected <= logged, expected - logged
    assert len(rec.blueprints) == 1
    # Every frame's stage timings, each at its own frame (the last frame's logged by on_finish).
    timed = [(int(time["frame"]), a.args[0]) for time, a in rec.at("timing/stage_ms") if a.kind == "Scalars"]
    assert [frame for frame, _ in timed] == list(range(FRAMES))
    assert all(len(stages) == len(STAGES) for _, stages in timed)
    # The corrected map is logged at the last frame.
    assert int(rec.at("map/tracks/corrected")[-1][0]["frame"]) == FRAMES - 1


def test_rerun_images_are_the_camera_and_the_networks_at_their_own_size(observed):
    rec, pipeline = observed.rec, observed.pipeline
    (_, image), *_ = rec.at("camera/left")
    assert image.kind == "Image" and image.args[0].shape == pipeline.dataset[0].left.shape
    sizes = {
        name: rec.at(f"neural/{name}")[-1][1].args[0].shape for name in ("hd_ring", "layer2_k4", "place")
    }
    assert sizes == {"hd_ring": (15, 128, 3), "layer2_k4": (64, 64, 3), "place": (64, 64, 3)}
    assert len(rec.at("neural/layer2_k4/bumps")[-1][1].args[0]) == 16
    features = rec.at("camera/left/features")[-1][1].args[0]
    height, width = pipeline.dataset[0].left.shape
    assert len(features) > 20 and (features[:, 0] < width).all() and (features[:, 1] < height).all()
    label = rec.at("camera/left/view_cell")[-1][1].kwargs["labels"][0]
    assert label.startswith(f"view cell {pipeline.record.frames[-1].view_cell} ")


def test_rerun_map_ends_as_the_corrected_map_drawn_with_y_up(observed):
    rec, result = observed.rec, observed.result
    poses = result.map_export["poses"]
    assert len(poses) <= BLOCK  # one block in 20 frames
    points = rec.at("map/vertices/0")[-1][1].args[0]
    np.testing.assert_allclose(points, poses[:, :2] * [1, -1], atol=1e-4)
    # The vertices were logged when they changed, not on every frame.
    assert len(rec.at("map/vertices/0")) <= len(poses) + 1 < FRAMES


def test_blocks_relog_only_what_changed():
    rec = FakeRecording("test")
    style = ("LineStrips2D", {"colors": (1, 2, 3)})
    blocks = _Blocks(FakeRerun(), "track", lambda rows: Logged("Strip", (rows,), {}), style, overlap=1)
    rows = np.arange(2 * BLOCK + 10, dtype=float).reshape(-1, 1)
    assert blocks.update(rec, rows) == 3
    styles = [(name, a.kind) for _, name, a, static in rec.logs if static]
    assert styles == [(f"track/{b}", "LineStrips2D.from_fields") for b in range(3)]  # once per block, static
    assert blocks.update(rec, rows) == 0
    assert blocks.update(rec, np.vstack([rows, [[-1.0]]])) == 1  # a new row: the last block only
    rows = np.vstack([rows, [[-1.0]]])
    rows[3] = 99.0  # a moved early row (a loop closure's correction)
    assert blocks.update(rec, rows) == 1 and rec.logs[-1][1] == "track/0"
    assert sum(static for *_, static in rec.logs) == 3  # the style is not logged again
    # Blocks overlap by one row, so a polyline drawn block by block stays joined.
    first = rec.logs[-1][2].args[0]
    assert len(first) == BLOCK + 1 and first[-1, 0] == rows[BLOCK, 0]


def test_rerun_targets(monkeypatch):
    monkeypatch.setenv("DISPLAY", ":0")
    rr = FakeRerun()
    RerunObserver(rr=rr)
    RerunObserver("rerun+http://127.0.0.1:9876/proxy", rr=rr)
    assert [r.sink for r in rr.recordings] == [("spawn",), ("connect", "rerun+http://127.0.0.1:9876/proxy")]


def test_rerun_viewer_without_a_display_is_refused_before_the_run(monkeypatch):
    """Spawning the viewer on a machine without a display used to hang the finished run in its flush."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    with socket.socket() as s:  # a port where no viewer listens
        s.bind(("127.0.0.1", 0))
        free_port = s.getsockname()[1]
    monkeypatch.setattr(rerun_viewer, "VIEWER_PORT", free_port)
    rr = FakeRerun()
    with pytest.raises(HippoNavError, match="no display.*--rerun FILE.rrd"):
        RerunObserver(rr=rr)
    assert rr.recordings[0].sink is None  # nothing spawned
    # A viewer already listening (e.g. `rerun --serve-web`) is used even without a display.
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        monkeypatch.setattr(rerun_viewer, "VIEWER_PORT", server.getsockname()[1])
        RerunObserver(rr=rr)
    assert rr.recordings[1].sink == ("spawn",)


def test_rerun_flush_that_fails_does_not_stop_the_run(caplog):
    rr = FakeRerun()
    observer = RerunObserver("rerun+http://127.0.0.1:9/proxy", rr=rr)

    def refuse(timeout_sec: float = 1e38) -> None:
        raise RuntimeError("gRPC has been unable to connect")

    observer.rec.flush = refuse
    observer.close()
    assert "did not take the last data" in caplog.text and observer.rec.closed


def test_a_recording_rerun_could_not_finish_is_not_put_at_its_name(tmp_path):
    """Rerun could not write the rest of a recording (a full disk): the file is cut short, and a file at the
    target's name is always a whole recording, so nothing is put there and the close says so."""
    rr = FakeRerun()
    rrd = tmp_path / "run.rrd"
    observer = RerunObserver(rrd, rr=rr)
    Pipeline(demo(3), observers=[observer]).run()

    def refuse(timeout_sec: float = 1e38) -> None:
        raise RuntimeError("No space left on device (os error 28)")

    observer.rec.flush = refuse
    with pytest.raises(
        HippoNavError, match=r"run\.rrd could not be finished.*No space left.*is the disk full"
    ):
        observer.close()
    assert list(tmp_path.iterdir()) == []  # neither the target nor the partial file
    observer.close()  # a second close (the CLI closes every observer after an error) does nothing


def test_a_finished_recording_has_the_permissions_of_any_other_output(observed):
    umask = os.umask(0)
    os.umask(umask)
    assert observed.rrd.stat().st_mode & 0o777 == 0o666 & ~umask


def test_a_video_that_cannot_finish_does_not_hide_where_the_results_were_saved(
    tmp_path, monkeypatch, capsys, caplog
):
    """A full disk stops the results folder and the video alike: the message names the folder the results
    were rescued to (the video's failure is a warning), and --json says it too."""
    import hippo_nav.pipeline
    from hippo_nav.io.atomic import WriteError
    from hippo_nav.pipeline.results import ResultsNotWrittenError

    rescued = tmp_path / "rescued"
    out = tmp_path / "run"

    def full_disk(out_dir, **_):
        err = ResultsNotWrittenError(WriteError(Path(out_dir) / "frames.csv", "the disk is full"), rescued)
        err.result = SimpleNamespace(out_dir=rescued, metrics={}, record=[], interrupted=False)
        raise err

    def video_fails(self) -> None:
        raise HippoNavError(f"cannot write {out / 'mapping.mp4'}: the disk is full")

    monkeypatch.setattr(hippo_nav.pipeline, "run", full_disk)
    monkeypatch.setattr(VideoObserver, "close", video_fails)
    args = ["run", "--out", str(out), "--no-progress", "--video"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"written to {rescued} instead" in err and "Traceback" not in err
    assert "mapping.mp4: the disk is full" in caplog.text  # the video's failure, as a warning
    assert main([*args, "--json"]) == 2
    assert json.loads(capsys.readouterr().out)["results"] == str(rescued)


def test_a_video_that_cannot_finish_after_a_run_leaves_the_json_whole(tmp_path, monkeypatch, capsys):
    """The run finished and wrote its results; only the video's close failed (a full disk). A script reading
    --json still gets the results folder and the summary, with the video's error and exit 2."""

    def full_disk(path, mode):  # the video's last step, putting the finished file in place, fails
        raise HippoNavError("cannot write mapping.mp4: the disk is full")

    monkeypatch.setattr(viewer_video, "open_atomic", full_disk)
    out = tmp_path / "run"
    args = ["run", "--out", str(out), "--no-progress", "--no-figures", "--stop", "4", "--video"]
    assert main([*args, "--json"]) == 2
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert report["exit_reason"] == "viewer_not_written" and report["exit_code"] == 2
    assert report["results"] == str(out) and report["summary"]["frames"] == 4
    assert "the disk is full" in report["error"] and "results are written" in report["error"]
    assert "video" not in report and (out / "metrics.json").is_file()
    assert main([*args, "--overwrite"]) == 2  # without --json: the one line naming where the results are
    assert f"results are written to {out}" in capsys.readouterr().err


def test_a_program_on_the_viewers_port_that_never_answers_does_not_hold_the_run(monkeypatch, caplog):
    """Another program holding port 9876 takes the connection and never answers: the close (and Rerun's
    exit handler, which waits for the same connection) must not hold a finished run for ever."""
    monkeypatch.setattr(rerun_viewer, "FLUSH_TIMEOUT_S", 0.2)
    rr = FakeRerun()
    unregistered = []
    rr.unregister_shutdown = lambda: unregistered.append(True)
    observer = RerunObserver("rerun+http://127.0.0.1:9/proxy", rr=rr)
    never = threading.Event()
    observer.rec.disconnect = never.wait  # blocks for ever
    closed = threading.Thread(target=observer.close, daemon=True)
    closed.start()
    closed.join(10)
    never.set()
    assert not closed.is_alive(), "close() waited for the program on the port"
    assert unregistered == [True] and "did not close the connection" in caplog.text


# ------------------------------------------------------------------------------------------------
# The shared panels


def test_decoded_bumps_sit_on_the_activity_peaks():
    memory = SpatialMemory()
    memory.reset(1.0, (2.0, 4.5))
    for _ in range(5):
        readout = memory.step(0.3, 5.0, 0.1)
    raw = {
        "place": memory.place_activity(),
        "layer2_k4": memory.grid_layer2(2),
        "hd_ring": memory.hd_activity(),
    }
    for panel in neural_panels(NetworkActivity.of(memory), readout):
        if panel.name not in raw:
            continue
        activity = raw[panel.name]
        if panel.name == "hd_ring":  # the heading: the peak of the θ profile
            peak_x = np.argmax(activity.sum(axis=0)) + 0.5
            assert abs(panel.bumps_px[0, 0] - peak_x) <= 1.5
            continue
        row, column = np.unravel_index(np.argmax(activity), activity.shape)
        peak = np.array([column + 0.5, activity.shape[0] - row - 0.5])  # the image is flipped: θy up
        assert np.linalg.norm(panel.bumps_px - peak, axis=1).min() <= 1.5, panel.name


def test_colorize_keeps_the_row_axis_pointing_up():
    activity = np.zeros((4, 3))
    activity[0, 1] = 1.0
    image = colorize(activity)
    assert image.shape == (4, 3, 3) and image.dtype == np.uint8
    assert np.argmax(image.sum(axis=2)[:, 1]) == 3  # row 0 of the array is the bottom row of the image
    np.testing.assert_allclose(angles_to_pixels(np.array([[0.0, 0.0]]), (4, 3)), [[0.5, 3.5]])


def test_tracked_pixels_come_from_the_public_accessor_or_are_none():
    assert tracked_pixels(SimpleNamespace()) is None
    assert tracked_pixels(SimpleNamespace(tracked_pixels=lambda: np.zeros((3, 2)))).shape == (3, 2)
    assert tracked_pixels(SimpleNamespace(tracked_pixels=np.ones((5, 2), np.float32))).shape == (5, 2)


def test_the_viewer_draws_the_features_of_the_frame_it_shows_not_the_next_one():
    """The front end runs a frame ahead, so the features drawn with frame k must be the ones the
    odometry tracked in frame k, captured before it moved on to k+1."""
    from hippo_nav.vo import StereoOdometry

    demo_subset, seen = demo(12), []

    class Watch:
        def on_frame(self, event: FrameEvent) -> None:
            seen.append(event.features_px.copy())

        def on_finish(self, result) -> None:
            pass

    Pipeline(demo_subset, config_from_dict({"output": {"figures": False}}), observers=[Watch()]).run(None)
    alone = StereoOdometry(demo_subset.calibration)
    for k in range(len(demo_subset)):
        alone.process(demo_subset[k])
        np.testing.assert_array_equal(seen[k], alone.tracked_pixels)


# ------------------------------------------------------------------------------------------------
# Command line


def test_video_flag_writes_mapping_mp4_into_the_results_folder(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["run", "--out", str(out), "--no-progress", "--no-figures", "--stop", "9"]
    assert main([*args, "--video", "--video-every", "4"]) == 0
    assert len(decoded_frames(out / "mapping.mp4")) == len(range(0, 9, 4)) + 1
    assert "video written to" in capsys.readouterr().out


def test_missing_viewer_extra_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError
    out = tmp_path / "run"
    assert main(["run", "--rerun", "--out", str(out), "--no-progress", "--stop", "3"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'hippo-nav[viewer]'" in err and "Traceback" not in err
    assert not out.exists()  # nothing ran


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--video-every", "0"], "argument --video-every: '0' is out of range"),
        (["--rerun", "run.txt"], ".rrd"),
    ],
)
def test_bad_viewer_flags_are_one_line_and_exit_2(tmp_path, capsys, flags, says):
    assert main(["run", "--out", str(tmp_path / "x"), "--no-progress", "--stop", "3", *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err


def test_help_shows_every_options_default():
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert set(commands) == {"run", "render", "figures", "vocabulary", "sweep", "report", "record", "config"}
    for name, command in commands.items():
        formatter = command._get_formatter()
        for action in command._actions:
            if action.dest == "help":
                continue
            text = formatter._expand_help(action)
            assert re.search(r"default|required", text), f"{name} {action.option_strings}: {text!r}"
    run_help = commands["run"].format_help()
    assert "(default: 5)" in run_help and "(default: 1)" in run_help


# ------------------------------------------------------------------------------------------------
# Rerun itself (skipped when the viewer extra is not installed)


def test_rerun_flag_saves_a_recording_with_every_frame(tmp_path, capsys):
    rerun = pytest.importorskip("rerun")
    recording = tmp_path / "run" / "run.rrd"  # inside the results folder, which must be empty at the start
    args = ["run", "--out", str(tmp_path / "run"), "--no-progress", "--no-figures", "--stop", "6"]
    assert main([*args, "--rerun", str(recording)]) == 0
    assert f"rerun {recording}" in capsys.readouterr().out
    assert recording.stat().st_size > 20_000
    reader = getattr(getattr(rerun, "chunk", None), "RrdReader", None)
    if reader is None:  # an older rerun without the chunk reader: the file's existence is what can be checked
        return
    chunks = reader(recording).stream().to_chunks()
    entities = {chunk.entity_path for chunk in chunks}
    wanted = {"/camera/left", "/neural/place", "/map/vertices/0", "/readout/heading_deg", "/timing/stage_ms"}
    assert wanted <= entities, wanted - entities
    frames = set()
    for chunk in chunks:
        if chunk.entity_path == "/camera/left":
            frames |= set(chunk.to_record_batch().column("frame").to_pylist())
    assert frames == set(range(6))
