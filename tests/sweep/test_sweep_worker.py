"""One run of a sweep without Ray (`execute_run` in this process): the odometry axis, the manifest, the files
shipped back from a machine that cannot see the sweep folder."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hippo_nav.io import read_kitti_poses
from hippo_nav.sweep import build_space, plan
from hippo_nav.sweep.worker import SESSION_TOKEN, StopWhenAsked, execute_run
from hippo_nav.synthetic import demo_sequence

pytestmark = pytest.mark.usefixtures("thread_limits_restored")


def test_drift_and_a_replayed_file_run_and_their_manifest_says_what_ran(tmp_path):
    poses = demo_sequence() / "poses" / "00.txt"
    space = build_space(odometries=f"drift,{poses}", dataset={"stop": 12}, no_figures=True, seeds="3")
    out = tmp_path / "sweep"
    out.mkdir()
    (out / SESSION_TOKEN).write_text("s1\n")
    for spec in space.runs():
        outcome = execute_run(spec, str(out), "s1", cpus=1)
        assert outcome["files"] is None  # this process sees the sweep folder: written in place
        folder = out / "runs" / spec.run_id
        manifest = json.loads((folder / "manifest.json").read_text())
        assert (
            manifest == outcome["manifest"] and manifest["status"] == "done" and manifest["exit_status"] == 0
        )
        assert manifest["seed"] == 3 and manifest["config"]["seed"] == 3 and manifest["attempt"] == 1
        assert manifest["dataset"]["stop"] == 12 and manifest["dataset"]["checksum"]["frames"] == 12
        truth = read_kitti_poses(folder / "ground_truth.kitti.txt")
        odometry = read_kitti_poses(folder / "trajectory_vo.kitti.txt")
        step_truth = np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1).sum()
        step_odometry = np.linalg.norm(np.diff(odometry[:, :3, 3], axis=0), axis=1).sum()
        if spec.odometry.kind == "drift":  # every step 1 % too long
            assert abs(step_odometry / step_truth - 1.01) < 1e-6
        else:  # the ground truth replayed exactly
            assert spec.odometry.label == "00" and np.allclose(odometry, truth, atol=1e-6)
    # The same data gives the same checksum, whatever the odometry.
    checksums = {
        json.loads(p.read_text())["dataset"]["checksum"]["sha256"] for p in out.glob("runs/*/manifest.json")
    }
    assert len(checksums) == 1


def test_an_interrupted_rerun_of_a_whole_run_leaves_no_part_beside_it(tmp_path, monkeypatch):
    """A run done under another config is redone; stopped before its last frame, `run` keeps the whole earlier
    run and writes the part beside it. In a sweep that part would sit in runs/ as a run of its own: it goes,
    the manifest says interrupted, and the earlier run's files stay."""
    spec = build_space(dataset={"stop": 12}, no_figures=True).runs()[0]
    out = tmp_path / "sweep"
    out.mkdir()
    (out / SESSION_TOKEN).write_text("s1\n")
    assert execute_run(spec, str(out), "s1", cpus=1)["manifest"]["status"] == "done"
    folder = out / "runs" / spec.run_id
    before = (folder / "metrics.json").read_bytes()
    frames = []

    def stop_at_the_fifth_frame(self, event) -> None:
        frames.append(event)
        if len(frames) == 5:
            self.signal = "SIGINT"
            raise KeyboardInterrupt

    monkeypatch.setattr(StopWhenAsked, "on_frame", stop_at_the_fifth_frame)
    outcome = execute_run(spec, str(out), "s1", cpus=1, stop=object())
    assert outcome["manifest"]["status"] == "interrupted"
    assert [p.name for p in (out / "runs").iterdir()] == [spec.run_id]
    assert (folder / "metrics.json").read_bytes() == before


@pytest.mark.parametrize("damage", ["cut frames.csv", "lose the map", "cut a trajectory"])
def test_a_finished_run_whose_files_were_damaged_since_is_redone(tmp_path, damage):
    spec = build_space(dataset={"stop": 8}, no_figures=True).runs()[0]
    out = tmp_path / "sweep"
    out.mkdir()
    (out / SESSION_TOKEN).write_text("s1\n")
    manifest = execute_run(spec, str(out), "s1", cpus=1)["manifest"]
    assert {"frames.csv", "memory/map.bin", "trajectory_corrected.kitti.txt"} <= set(manifest["files"])
    assert [r.run_id for r in plan([spec], out).done] == [spec.run_id]
    folder = out / "runs" / spec.run_id
    if damage == "lose the map":
        (folder / "memory" / "map.bin").unlink()
    else:
        name = "frames.csv" if damage == "cut frames.csv" else "trajectory_corrected.kitti.txt"
        lines = (folder / name).read_text().splitlines(keepends=True)
        (folder / name).write_text("".join(lines[:-2]))  # cut at a line boundary: still parses
    assert [r.run_id for r in plan([spec], out).todo] == [spec.run_id]


def test_a_worker_that_cannot_see_the_sweep_folder_sends_the_files_back(tmp_path):
    spec = build_space(dataset={"stop": 6}, no_figures=True).runs()[0]
    outcome = execute_run(spec, str(tmp_path / "elsewhere"), "s2", cpus=1)
    files = outcome["files"]
    assert files is not None and json.loads(files["manifest.json"])["status"] == "done"
    assert {"metrics.json", "trajectory_corrected.kitti.txt", "run.log", "config.json"} <= set(files)
    assert not (tmp_path / "elsewhere").exists()


def test_a_bad_odometry_file_fails_the_run_with_a_one_line_error(tmp_path):
    short = tmp_path / "short.txt"
    short.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)  # 3 poses for a 200-frame sequence
    spec = build_space(odometries=str(short), dataset={"stop": 6}, no_figures=True).runs()[0]
    out = tmp_path / "sweep"
    out.mkdir()
    (out / SESSION_TOKEN).write_text("s3\n")
    manifest = execute_run(spec, str(out), "s3", cpus=1)["manifest"]
    assert manifest["status"] == "failed" and manifest["exit_status"] == 2
    assert "short.txt" in manifest["error"] and "\n" not in manifest["error"]
    assert "run failed" in (out / "runs" / spec.run_id / "run.log").read_text()
