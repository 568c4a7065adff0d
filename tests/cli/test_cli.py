"""The command line itself: exit codes, what it writes, clear errors, Ctrl-C."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest
from hippo_nav.cli import build_parser, main
from hippo_nav.io import read_kitti_poses


def test_run_without_a_dataset_runs_the_demo_and_writes_results(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["run", "--out", str(out), "--no-progress", "--stop", "30"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["sequence"] == "synthetic demo loop" and metrics["frames"] == 30
    assert metrics["errors"]["vo"]["ate_3d_m"] >= 0.0
    for name in ["config.json", "map.bin", "map.g2o", "frames.csv", "cognitive_map.png", "rate_maps.png"]:
        assert (out / name).stat().st_size > 0, name
    for name in ["vo", "online", "corrected"]:
        assert read_kitti_poses(out / f"trajectory_{name}.kitti.txt").shape == (30, 4, 4)
        assert (out / f"trajectory_{name}.tum.txt").stat().st_size > 0
    printed = capsys.readouterr().out
    assert "results written" in printed and '"loop_closures"' in printed


def test_lesion_and_seed_options_reach_the_resolved_config(tmp_path):
    out = tmp_path / "lesioned"
    args = ["run", "--out", str(out), "--no-progress", "--no-figures", "--stop", "8"]
    assert main([*args, "--lesion", "dorsal", "--lesion", "ventral", "--seed", "7"]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["lesions"] == {"ventral": True, "intermediate": False, "dorsal": True}
    assert config["seed"] == 7
    assert json.loads((out / "metrics.json").read_text())["lesioned"] == [True, False, True]
    assert not list(out.glob("*.png"))


def test_config_file_is_used_and_can_repeat_a_run(tmp_path):
    first = tmp_path / "first"
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"injection": {"initial_strength": 0.5}, "output": {"figures": False}}))
    assert main(["run", "--config", str(cfg), "--out", str(first), "--no-progress", "--stop", "8"]) == 0
    resolved = first / "config.json"
    assert json.loads(resolved.read_text())["injection"]["initial_strength"] == 0.5
    second = tmp_path / "second"
    assert main(["run", "--config", str(resolved), "--out", str(second), "--no-progress", "--stop", "8"]) == 0
    assert (first / "trajectory_corrected.kitti.txt").read_text() == (
        second / "trajectory_corrected.kitti.txt"
    ).read_text()


def test_bad_kitti_path_gives_one_clear_line_and_exit_2(tmp_path, capsys):
    code = main(["run", "--kitti", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x")])
    assert code == 2
    err = capsys.readouterr().err
    # --kitti is another name for --dataset; the message names the spelling typed.
    assert f"--kitti {tmp_path / 'nowhere'}: no such file or folder" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_a_folder_that_is_not_kitti_is_named_in_the_error(tmp_path, capsys):
    assert main(["run", "--kitti", str(tmp_path), "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "sequences" in err


def test_bad_config_file_gives_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"injection": {"decay_per_frame": -1}}))
    assert main(["run", "--config", str(bad), "--out", str(tmp_path / "y"), "--no-progress"]) == 2
    assert "injection.decay_per_frame" in capsys.readouterr().err
    assert main(["run", "--config", str(tmp_path / "missing.json"), "--out", str(tmp_path / "y")]) == 2
    assert "missing.json" in capsys.readouterr().err


def test_ctrl_c_exits_130_and_keeps_the_frames_processed(tmp_path, monkeypatch, capsys):
    from hippo_nav.pipeline import SlamSystem

    real = SlamSystem.step

    def interrupted_at_frame_5(self, *args, **kwargs):
        if self.frames == 5:
            raise KeyboardInterrupt
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SlamSystem, "step", interrupted_at_frame_5)
    out = tmp_path / "partial"
    assert main(["run", "--out", str(out), "--no-progress", "--no-figures"]) == 130
    assert json.loads((out / "metrics.json").read_text())["frames"] == 5
    assert read_kitti_poses(out / "trajectory_corrected.kitti.txt").shape == (5, 4, 4)
    assert "interrupted after 5 frames" in capsys.readouterr().out


def test_the_installed_command_runs_as_a_process(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "hippo_nav.cli", "run", "--kitti", str(tmp_path / "none")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 2 and "no such file or folder" in done.stderr


def test_run_and_sweep_take_the_same_input_flags():
    """One definition: the same dataset and loader flags with the same help; sweep's --sequence is its axis
    and its --stride has no default of its own (a sweep file's stands)."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))

    def inputs(command: str) -> dict[str, tuple]:
        parser = sub.choices[command]
        group = next(g for g in parser._action_groups if g.title and g.title.startswith("input"))
        loaders = [g for g in parser._action_groups if g.title == "loader options"]
        actions = [a for g in [group, *loaders] for a in g._group_actions]
        return {a.option_strings[0]: (a.dest, a.metavar, a.help, a.default) for a in actions}

    run, sweep = inputs("run"), inputs("sweep")
    assert "--sequence" in run and "--sequence" not in sweep
    assert run.pop("--stride")[3] == 1 and sweep.pop("--stride")[3] is None
    del run["--sequence"]
    assert run == sweep
    assert {
        "--dataset",
        "--dataset-kind",
        "--start",
        "--stop",
        "--cameras",
        "--left-topic",
        "--topics",
    } <= set(run)


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_two_dataset_paths_are_refused_naming_both_spellings(tmp_path, capsys, command):
    args = [command, "--dataset", str(tmp_path), "--kitti", str(tmp_path), "--out", str(tmp_path / "x")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "give one dataset path: --dataset and --kitti name the same option" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x").exists()


@pytest.mark.data
def test_kitti_sequence_option_runs_real_frames(shared_data, tmp_path):
    out = tmp_path / "k01"
    root = shared_data / "kitti_odometry"
    args = ["run", "--kitti", str(root), "--sequence", "01", "--stop", "20", "--stride", "2"]
    assert main([*args, "--out", str(out), "--no-progress", "--no-figures"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 10 and metrics["sequence"] == "kitti_01"
    assert len((out / "ground_truth.kitti.txt").read_text().splitlines()) == 10


def test_a_corrupt_frame_mid_run_keeps_what_was_written_and_names_the_file(tmp_path, capsys):
    import shutil

    from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence

    # A 20-frame copy of the demo in KITTI layout, with frame 12's left image corrupted.
    source, root = demo_sequence(), tmp_path / "kitti"
    seq = root / "sequences" / DEMO_SEQUENCE
    for cam in ("image_0", "image_1"):
        (seq / cam).mkdir(parents=True)
        for i in range(20):
            shutil.copy(
                source / "sequences" / DEMO_SEQUENCE / cam / f"{i:06d}.png", seq / cam / f"{i:06d}.png"
            )
    for name in ("calib.txt", "times.txt"):
        shutil.copy(source / "sequences" / DEMO_SEQUENCE / name, seq / name)
    shutil.copytree(source / "poses", root / "poses")
    (seq / "image_0" / "000012.png").write_bytes(b"\x89PNG not really")

    out = tmp_path / "out"
    args = ["run", "--kitti", str(root), "--sequence", DEMO_SEQUENCE, "--stop", "20", "--out", str(out)]
    assert main([*args, "--no-progress", "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert "000012.png" in err and "12 frames before it" in err and "Traceback" not in err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 12 and metrics["interrupted"] and "000012.png" in metrics["stopped_by_error"]
    assert read_kitti_poses(out / "trajectory_corrected.kitti.txt").shape == (12, 4, 4)
