"""Presets: named settings laid under a config (`hippo_nav.system.presets`). The paper preset runs the system as
the paper describes it; a config's own settings win key by key; a run's config.json loads back to the same
config; a wrong or conflicting name is one clear line."""

from __future__ import annotations

import json

import pytest
from hippo_nav import HippoNavError
from hippo_nav.cli import main
from hippo_nav.map import ClosureMode, OnlineCorrection
from hippo_nav.pipeline import PipelineConfig, config_from_dict, load_config
from hippo_nav.system.config import resolved_config_dict
from hippo_nav.system.presets import PRESETS


def test_the_paper_preset_is_the_papers_system():
    config = config_from_dict({"preset": "paper"})
    assert config.parts.view_cells == "template"
    assert config.view_search.near_only is False
    assert config.injection.placement == "as_stored"
    assert config.map.closure == ClosureMode.RATSLAM
    assert config.map.online_correction == OnlineCorrection.RELAXATION
    assert config.correction.method == "relaxation"
    # Everything it does not name keeps today's default.
    assert config.engine == PipelineConfig().engine and config.output == PipelineConfig().output


def test_the_default_preset_changes_nothing():
    assert config_from_dict({"preset": "default"}) == PipelineConfig()
    assert PipelineConfig().preset == "default"


def test_a_configs_own_settings_win_key_by_key_inside_a_section():
    config = config_from_dict(
        {"preset": "paper", "map": {"closure": "Geometric"}, "injection": {"placement": "measured"}}
    )
    assert config.map.closure == ClosureMode.GEOMETRIC  # the file's
    assert config.map.online_correction == OnlineCorrection.RELAXATION  # the preset's, same section
    assert config.injection.placement == "measured"
    assert config.parts.view_cells == "template"


def test_a_presets_resolved_config_loads_back_to_the_same_config(tmp_path):
    for name in PRESETS:
        config = config_from_dict({"preset": name, "seed": 3})
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(resolved_config_dict(config)))
        assert load_config(path) == config
        assert json.loads(path.read_text())["preset"] == name


def test_an_unknown_preset_names_the_presets():
    with pytest.raises(HippoNavError, match=r"preset: unknown 'papr'; choose from default, paper"):
        config_from_dict({"preset": "papr"})


def test_preset_option_and_config_file_combine_and_a_conflict_is_refused(tmp_path):
    path = tmp_path / "mine.json"
    path.write_text(json.dumps({"view_search": {"near_only": True}}))
    config = load_config(path, "paper")
    assert config.preset == "paper" and config.view_search.near_only is True
    assert config.parts.view_cells == "template"
    path.write_text(json.dumps({"preset": "default"}))
    with pytest.raises(HippoNavError, match="names preset 'default', and --preset paper was given"):
        load_config(path, "paper")


def test_config_command_prints_a_preset_resolved(capsys):
    assert main(["config", "--preset", "paper"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["preset"] == "paper" and printed["parts"]["view_cells"] == "template"
    assert printed["map"]["closure"] == "RatSlam"


def test_a_sweep_varies_the_preset(tmp_path, capsys):
    code = main(["sweep", "--set", "preset=paper,default", "--dry-run", "--out", str(tmp_path / "s")])
    assert code == 0
    printed = capsys.readouterr().out
    assert "preset=paper" in printed and "preset=default" in printed and "2 runs" in printed


def test_run_with_the_paper_preset_runs_the_papers_system_on_the_demo_loop(tmp_path):
    """The demo loop with `--preset paper`: template cells, RatSLAM closures (no stereo keyframes are kept:
    nothing is measured), each true; the results folder's config names the preset and repeats the run."""
    out = tmp_path / "paper"
    assert main(["run", "--preset", "paper", "--out", str(out), "--no-progress", "--no-figures"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["closure_mode"] == "RatSlam"
    assert metrics["keyframes"] == 0
    # Measured: 121 template cells for 200 frames (the word cells make 52), 53 closures, all true.
    assert metrics["view_cells"] > 90
    quality = metrics["closure_quality"]
    assert quality["closures"] >= 20 and quality["precision"] >= 0.95, quality
    assert metrics["injected_frames"] > 0
    written = load_config(out / "config.json")
    assert written.preset == "paper" and written.parts == load_config(None, "paper").parts
    assert written.map == load_config(None, "paper").map
