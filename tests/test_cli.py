"""The command line: exit codes, outputs, clear errors."""

from __future__ import annotations

import json

from hippo_nav.cli import main


def test_run_without_a_dataset_runs_the_demo_and_writes_results(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["run", "--out", str(out), "--no-progress"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["sequence"] == "synthetic demo loop"
    assert metrics["bump_counts_final"] == [1, 4, 16]
    assert metrics["place_code_final_error_pct_of_distance"] < 2.0
    assert metrics["heading_max_error_deg"] < 3.0
    for name in [
        "neural_estimate.kitti.txt",
        "neural_estimate.tum.txt",
        "engine_config.json",
        "neural_state.png",
    ]:
        assert (out / name).stat().st_size > 0, name
    assert len((out / "neural_estimate.kitti.txt").read_text().splitlines()) == metrics["frames"]
    assert "results written" in capsys.readouterr().out


def test_lesion_option_reaches_the_engine(tmp_path):
    out = tmp_path / "lesioned"
    assert main(["run", "--out", str(out), "--no-progress", "--lesion", "dorsal", "--stop", "30"]) == 0
    config = json.loads((out / "engine_config.json").read_text())
    assert config["lesioned"] == [False, False, True]


def test_bad_kitti_path_gives_one_clear_line_and_exit_2(tmp_path, capsys):
    code = main(["run", "--kitti", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x")])
    assert code == 2
    err = capsys.readouterr().err
    assert "no such folder" in err and "Traceback" not in err


def test_bad_config_file_gives_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"hd": {"n_theta": 0}}))
    assert main(["run", "--config", str(bad), "--out", str(tmp_path / "y"), "--no-progress"]) == 2
    assert "hd.n_theta" in capsys.readouterr().err


def test_kitti_sequence_runs_on_real_ground_truth(shared_data, tmp_path):
    out = tmp_path / "k06"
    root = shared_data / "kitti_odometry"
    assert (
        main(
            [
                "run",
                "--kitti",
                str(root),
                "--sequence",
                "06",
                "--stop",
                "300",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 300 and metrics["place_code_final_error_pct_of_distance"] < 2.0
