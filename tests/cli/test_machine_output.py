"""Output for scripts: `hippo-nav run --json` prints one JSON object on stdout and nothing else (done,
interrupted, stopped by an unreadable frame, bad input), and `hippo-nav config` prints the default config,
checks a config file without running and shows one resolved."""

from __future__ import annotations

import json

import pytest
from conftest import Frames
from hippo_nav.cli import main
from hippo_nav.io.errors import DatasetError
from hippo_nav.pipeline import PipelineConfig, load_config
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence
from hippo_nav.system.config import resolved_config_dict

TRAJECTORIES = {"vo", "online", "corrected", "neural"}


def _one_object(capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:
    """(the JSON object that is all of stdout, stderr); `json.loads` refuses anything before or after it."""
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert isinstance(report, dict), captured.out
    return report, captured.err


# --- run --json ---------------------------------------------------------------------------------------
def test_run_json_is_one_object_with_the_results_metrics_and_exit(tmp_path, capsys):
    out = tmp_path / "out"
    replayed = demo_sequence() / "poses" / f"{DEMO_SEQUENCE}.txt"  # the --odometry note is printed too
    args = ["run", "--stop", "4", "--no-figures", "--json", "--out", str(out), "--odometry", str(replayed)]
    assert main(args) == 0  # with the progress bar on: it must stay on stderr
    report, err = _one_object(capsys)
    assert report["exit_code"] == 0 and report["exit_reason"] == "done" and "error" not in report
    assert report["results"] == str(out)
    metrics = json.loads((out / "metrics.json").read_text())
    summary = report["summary"]
    assert summary["frames"] == 4 and summary["sequence"] == metrics["sequence"]
    for key in [
        "view_cells",
        "vertices",
        "loop_closures",
        "interrupted",
        "frames_per_s",
        "ate_2d_m_corrected",
    ]:
        assert key in summary, key
    assert set(report["errors"]) == TRAJECTORIES
    for name in TRAJECTORIES:
        assert report["errors"][name] == metrics["errors"][name]
    assert "odometry replayed from" in err  # what used to be printed on stdout went to stderr


def test_run_json_on_bad_input_is_an_error_object_and_the_one_line_on_stderr(tmp_path, capsys):
    out = tmp_path / "never"
    args = ["run", "--json", "--config", str(tmp_path / "missing.json"), "--out", str(out), "--no-progress"]
    assert main(args) == 2
    report, err = _one_object(capsys)
    assert report["exit_code"] == 2 and report["exit_reason"] == "error"
    assert "missing.json" in report["error"]
    assert err.strip().splitlines() == [f"hippo-nav: error: {report['error']}"]
    assert not out.exists()  # nothing processed


def test_run_json_when_interrupted_names_the_signal_and_exits_130(tmp_path, monkeypatch, capsys):
    from hippo_nav.pipeline import SlamSystem

    real = SlamSystem.step

    def interrupted_at_frame_3(self, *args, **kwargs):
        if self.frames == 3:
            raise KeyboardInterrupt
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SlamSystem, "step", interrupted_at_frame_3)
    out = tmp_path / "partial"
    assert main(["run", "--stop", "10", "--no-figures", "--no-progress", "--json", "--out", str(out)]) == 130
    report, _ = _one_object(capsys)
    assert report["exit_code"] == 130 and report["exit_reason"] == "interrupted"
    assert report["signal"] == "SIGINT" and report["results"] == str(out)
    assert report["summary"]["frames"] == 3 and report["summary"]["interrupted"] is True


def test_run_json_when_a_frame_cannot_be_read_keeps_the_results(demo, tmp_path, monkeypatch, capsys):
    def unreadable(i: int) -> None:  # a corrupt frame mid-sequence, as a loader reports it
        if i == 5:
            raise DatasetError("000005.png: not an image")

    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, 8, on_load=unreadable)
    )
    out = tmp_path / "out"
    assert main(["run", "--no-figures", "--no-progress", "--json", "--out", str(out)]) == 2
    report, err = _one_object(capsys)
    assert report["exit_code"] == 2 and report["exit_reason"] == "stopped_by_error"
    assert "000005.png" in report["error"] and report["results"] == str(out)
    assert report["summary"]["frames"] == 5
    assert err.strip().splitlines()[-1] == f"hippo-nav: error: {report['error']}"
    assert json.loads((out / "metrics.json").read_text())["frames"] == 5


# --- config -------------------------------------------------------------------------------------------
def _defaults(tmp_path, capsys) -> tuple[dict, str]:
    assert main(["config", "--defaults"]) == 0
    report, _ = _one_object(capsys)
    path = tmp_path / "defaults.json"
    path.write_text(json.dumps(report))
    return report, str(path)


def test_config_defaults_is_every_section_and_loads_back_to_the_defaults(tmp_path, capsys):
    printed, path = _defaults(tmp_path, capsys)
    sections = set(PipelineConfig.model_fields) | set(PipelineConfig.part_sections())
    assert sections <= set(printed) and {"vo", "views", "view_words"} <= set(printed)
    assert load_config(path) == PipelineConfig()
    assert resolved_config_dict(load_config(path)) == printed


def test_config_defaults_given_to_run_is_the_resolved_config_of_the_run(tmp_path, capsys):
    printed, path = _defaults(tmp_path, capsys)
    out = tmp_path / "out"
    args = ["run", "--config", path, "--stop", "3", "--no-figures", "--no-progress", "--out", str(out)]
    assert main(args) == 0
    written = json.loads((out / "config.json").read_text())
    assert written == {**printed, "output": {**printed["output"], "figures": False}}  # --no-figures


def test_config_check_a_valid_file(tmp_path, capsys):
    _, path = _defaults(tmp_path, capsys)
    assert main(["config", "--check", path]) == 0
    captured = capsys.readouterr()
    assert captured.out == f"{path}: valid\n" and captured.err == ""


def test_config_check_an_old_spelling_is_valid_with_a_warning(tmp_path, capsys, caplog):
    old = tmp_path / "old.json"
    old.write_text('{"closure": {"proximity_min_inliers": 20}}')
    assert main(["config", "--check", str(old)]) == 0
    assert capsys.readouterr().out == f"{old}: valid\n"
    assert "closure.proximity_min_inliers → closure.proximity.min_inliers" in caplog.text


def test_config_check_a_bad_file_is_one_line_and_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"injection": {"decay_per_frame": 3}}')
    assert main(["config", "--check", str(bad)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hippo-nav: error: ")
    assert "bad.json" in lines[0] and "injection.decay_per_frame" in lines[0]


def test_config_check_reads_the_vocabulary_the_config_names(tmp_path, capsys):
    """`run` would refuse a missing or unreadable vocabulary file: `--check` must not call it valid."""
    for vocabulary, phrase in (
        (tmp_path / "none.voc", "none.voc: cannot read the vocabulary"),
        (tmp_path, ""),
    ):
        config = tmp_path / "words.json"
        config.write_text(json.dumps({"view_words": {"vocabulary": str(vocabulary)}}))
        assert main(["config", "--check", str(config)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and phrase in err and "valid" not in err


def test_config_show_fills_in_the_defaults(tmp_path, capsys):
    partial = tmp_path / "partial.json"
    partial.write_text('{"seed": 5, "lesions": {"dorsal": true}}')
    assert main(["config", "--show", str(partial)]) == 0
    shown, _ = _one_object(capsys)
    assert shown == resolved_config_dict(load_config(partial))
    assert shown["seed"] == 5 and shown["lesions"]["dorsal"] is True
    assert shown["injection"] == resolved_config_dict(PipelineConfig())["injection"]
