"""The results folder survives what happens after the last frame: signals during the final correction, the
writing and the figures; a folder that stops taking files; links planted where files are written; names
that are not UTF-8."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import QUIET, Frames
from hippo_nav.cli import main
from hippo_nav.datasets.common import read_image_file
from hippo_nav.io import read_kitti_poses, write_kitti_poses
from hippo_nav.io.atomic import WriteError, open_atomic, write_image, write_text
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.pipeline import results as results_module
from hippo_nav.pipeline.observers import FrameEvent
from hippo_nav.pipeline.results import RESULT_FILES, ResultsNotWrittenError

FRAMES = 16
ESSENTIAL = ("config.json", "frames.csv", "metrics.json", "trajectory_corrected.kitti.txt", "map.bin")


def _kill_self(signame: str) -> None:
    os.kill(os.getpid(), getattr(signal, signame))
    time.sleep(0.05)  # the handler runs in the main thread at its next bytecode


def _complete(out: Path, frames: int) -> dict:
    """metrics.json, after checking every essential file is there and whole."""
    for name in ESSENTIAL:
        assert (out / name).is_file(), name
    assert len(read_kitti_poses(out / "trajectory_corrected.kitti.txt")) == frames
    assert not list(out.glob(".*.tmp")) and not list(out.glob(".*.png"))  # no temporary left behind
    return json.loads((out / "metrics.json").read_text())


# --- signals after the last frame ----------------------------------------------------------------------
@pytest.mark.parametrize("signame, code", [("SIGINT", 130), ("SIGTERM", 143)])
def test_a_signal_during_the_final_correction_stops_it_and_everything_is_written(
    demo, tmp_path, monkeypatch, disposition, signame, code
):
    disposition(signame, signal.SIG_DFL if signame != "SIGINT" else signal.default_int_handler)
    from hippo_nav.system.slam import SlamSystem

    def long_correction(self):
        _kill_self(signame)
        time.sleep(30)  # a correction that would take long: the signal must cut it short
        raise AssertionError("not interrupted")

    monkeypatch.setattr(SlamSystem, "correct", long_correction)
    monkeypatch.setattr("hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES))
    out = tmp_path / "out"
    started = time.perf_counter()
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out)]) == code
    assert time.perf_counter() - started < 25
    metrics = _complete(out, FRAMES)
    assert not metrics["interrupted"] and metrics["frames"] == FRAMES  # every frame was processed
    assert metrics["correction"]["interrupted_by"] == signame == metrics["interrupted_by"]


def test_a_double_ctrl_c_while_writing_leaves_every_file_whole(demo, tmp_path, monkeypatch, disposition):
    """Ctrl-C twice: the first stops the frames, the second comes while the trajectories are written."""
    disposition("SIGINT", signal.default_int_handler)
    real_write_tum = results_module.write_tum
    calls = []

    def write_tum_interrupted(path, times, poses):
        calls.append(path)
        if len(calls) == 1:
            _kill_self("SIGINT")  # arrives while the results are being written
        return real_write_tum(path, times, poses)

    monkeypatch.setattr(results_module, "write_tum", write_tum_interrupted)

    def ctrl_c_at_frame_8(i):
        if i == 8:
            _kill_self("SIGINT")

    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, 30, on_load=ctrl_c_at_frame_8)
    )
    out = tmp_path / "out"
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out)]) == 130
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["interrupted"] and metrics["interrupted_by"] == "SIGINT"
    _complete(out, metrics["frames"])
    for path in calls:  # every TUM file has a line per frame
        assert Path(path).read_text().count("\n") == metrics["frames"]


def test_ctrl_c_during_the_figures_keeps_those_drawn_and_says_so(demo, tmp_path, monkeypatch, disposition):
    disposition("SIGINT", signal.default_int_handler)
    from hippo_nav.pipeline import plots

    def rate_maps_interrupted(*args, **kwargs):
        _kill_self("SIGINT")
        raise AssertionError("not interrupted")

    monkeypatch.setattr(plots, "plot_rate_maps", rate_maps_interrupted)
    monkeypatch.setattr("hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES))
    out = tmp_path / "out"
    assert main(["run", "--no-progress", "--out", str(out)]) == 130
    metrics = _complete(out, FRAMES)
    assert "cognitive_map.png" in metrics["figures"] and "rate_maps.png" not in metrics["figures"]
    assert all((out / name).is_file() for name in metrics["figures"])
    assert metrics["unavailable"]["figures"] == "interrupted"


# --- a results folder that stops taking files ----------------------------------------------------------
class _FolderGoesAway:
    """At the last frame the results folder is moved away and a file takes its name: every later write
    there fails (as on a read-only or full disk, which a test cannot make as root)."""

    def __init__(self, out: Path, frames: int) -> None:
        self.out, self.frames = out, frames

    def on_frame(self, event: FrameEvent) -> None:
        if event.position == self.frames - 1:
            self.out.rename(self.out.with_name("moved"))
            self.out.write_text("not a folder any more\n")

    def on_finish(self, result) -> None:
        pass


def test_a_folder_that_stops_taking_files_names_the_file_and_where_the_results_went(
    demo, tmp_path, monkeypatch
):
    rescue_parent = tmp_path / "rescue"
    rescue_parent.mkdir()
    monkeypatch.setattr(results_module, "rescue_folder_candidates", lambda: [rescue_parent])
    out = tmp_path / "out"
    pipeline = Pipeline(
        Frames(demo, FRAMES), config_from_dict(QUIET), observers=[_FolderGoesAway(out, FRAMES)]
    )
    with pytest.raises(ResultsNotWrittenError) as caught:
        pipeline.run(out)
    error = caught.value
    message = str(error)
    assert f"cannot write {out}" in message and error.rescued_to is not None
    assert str(error.rescued_to) in message and error.rescued_to.parent == rescue_parent
    _complete(error.rescued_to, FRAMES)  # the whole results, elsewhere
    assert error.result.metrics["frames"] == FRAMES  # and in the exception, for a notebook
    assert not list((tmp_path / "moved").glob("trajectory_*"))  # nothing half-written in the old folder


def test_when_nothing_can_be_written_the_error_says_so_and_keeps_the_result(demo, tmp_path, monkeypatch):
    blocked = tmp_path / "a_file"
    blocked.write_text("x")
    monkeypatch.setattr(results_module, "rescue_folder_candidates", lambda: [blocked])
    out = tmp_path / "out"
    pipeline = Pipeline(
        Frames(demo, FRAMES), config_from_dict(QUIET), observers=[_FolderGoesAway(out, FRAMES)]
    )
    with pytest.raises(ResultsNotWrittenError, match="could not be written elsewhere either") as caught:
        pipeline.run(out)
    assert caught.value.rescued_to is None and len(caught.value.result.record) == FRAMES


def test_a_full_disk_mid_file_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "metrics.json"
    target.write_text("old\n")
    with pytest.raises(WriteError, match=r"metrics.json: the disk is full"), open_atomic(target) as f:
        f.write("new, partly")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert target.read_text() == "old\n" and os.listdir(tmp_path) == ["metrics.json"]


# --- links planted where files are written --------------------------------------------------------------
def test_a_link_at_a_written_file_is_replaced_never_written_through(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    out = tmp_path / "out"
    out.mkdir()
    for name in ("trajectory.kitti.txt", "metrics.json", "image.png"):
        (out / name).symlink_to(victim)
    write_kitti_poses(out / "trajectory.kitti.txt", np.tile(np.eye(4), (3, 1, 1)))
    write_text(out / "metrics.json", "{}\n")
    write_image(out / "image.png", np.zeros((8, 8), np.uint8))
    assert victim.read_text() == "precious\n"
    assert not any(
        (out / name).is_symlink() for name in ("trajectory.kitti.txt", "metrics.json", "image.png")
    )


def test_overwrite_does_not_follow_a_link_planted_at_the_maps_old_temporary_name(demo, tmp_path, monkeypatch):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    monkeypatch.setattr("hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES))
    out = tmp_path / "out"
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out)]) == 0
    (out / "map.bin.tmp").symlink_to(victim)
    (out / "map.g2o").unlink()
    (out / "map.g2o").symlink_to(victim)
    assert main(["run", "--no-progress", "--no-figures", "--overwrite", "--out", str(out)]) == 0
    assert victim.read_text() == "precious\n"
    assert (out / "map.bin").is_file() and not (out / "map.g2o").is_symlink()
    assert set(RESULT_FILES) & {p.name for p in out.iterdir()} >= {"map.bin", "map.g2o", "metrics.json"}


def test_render_replaces_links_in_its_output_never_writes_through_them(tmp_path):
    from hippo_nav.synthetic.render import render_sequence
    from hippo_nav.synthetic.trajectories import loop_trajectory

    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    poses = loop_trajectory(4, side_lengths_m=(60.0, 30.0), speed_m_per_frame=1.0)
    root = tmp_path / "kitti"
    render_sequence(poses, root, "00", image_size_px=(64, 32))
    sequence = root / "sequences" / "00"
    planted = [
        sequence / "times.txt",
        sequence / "calib.txt",
        root / "poses" / "00.txt",
        sequence / "image_0" / "000001.png",
        sequence / "image_1" / ".000002.partial.png",  # the temporary name renders used before
    ]
    for path in planted:
        path.unlink(missing_ok=True)
        path.symlink_to(victim)
    render_sequence(poses, root, "00", image_size_px=(64, 32))
    assert victim.read_text() == "precious\n"
    assert not any(p.is_symlink() for p in planted[:4])
    assert read_image_file(sequence / "image_0" / "000001.png").shape == (32, 64)


# --- names that are not UTF-8 ---------------------------------------------------------------------------
NON_UTF8_SCRIPT = r"""
import os, sys
from pathlib import Path
import numpy as np
from hippo_nav.cli import main
from hippo_nav.datasets.common import read_image_file
from hippo_nav.synthetic.render import render_sequence
from hippo_nav.synthetic.trajectories import loop_trajectory

base = Path(os.fsdecode(sys.argv[1].encode() + b"/caf\xe9"))  # Latin-1 'café': not UTF-8
poses = loop_trajectory(12, side_lengths_m=(60.0, 30.0), speed_m_per_frame=1.0)
render_sequence(poses, base / "kitti", "00", image_size_px=(160, 48))
assert read_image_file(base / "kitti" / "sequences" / "00" / "image_0" / "000011.png").shape == (48, 160)
code = main(["run", "--no-progress", "--video", "--video-every", "4", "--dataset", str(base / "kitti"),
             "--sequence", "00", "--out", str(base / "out")])
assert code == 0, code
assert (base / "out" / "mapping.mp4").stat().st_size > 0 and (base / "out" / "metrics.json").is_file()
print("ok")
"""


@pytest.mark.slow
def test_names_that_are_not_utf8_work_everywhere(tmp_path):
    """OpenCV crashed (exit 139, nothing written) on an image folder or a video path that is not UTF-8."""
    done = subprocess.run(
        [sys.executable, "-c", NON_UTF8_SCRIPT, str(tmp_path)],
        capture_output=True,
        check=False,
        timeout=600,
        env={**os.environ, "PYTHONUTF8": "0", "LC_ALL": "C.UTF-8"},
    )
    stdout, stderr = (out.decode("utf-8", "replace") for out in (done.stdout, done.stderr))
    assert done.returncode == 0 and stdout.strip().endswith("ok"), stderr[-2000:]


def test_written_files_get_the_permissions_a_plain_open_gives(tmp_path):
    """Exclusive temporaries must not make results private (mkstemp's 0600) to the people who share them."""
    umask = os.umask(0o022)
    try:
        path = write_text(tmp_path / "metrics.json", "{}\n")
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644
