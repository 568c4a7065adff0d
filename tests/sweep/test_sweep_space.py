"""The space of a sweep without Ray: parsing the axes, the run ids, sweep files, validation, the resume rule."""

from __future__ import annotations

import json
import sys

import pytest
from conftest import PROJECT_ROOT
from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.pipeline import config_from_dict
from hippo_nav.sweep import build_space, plan
from hippo_nav.sweep.manifest import read_manifest, write_json_atomic
from hippo_nav.sweep.space import config_hash, parse_seeds, parse_set, split_values


def test_values_are_json_where_they_parse_and_text_elsewhere():
    assert parse_set("views.novelty_threshold=0.40,0.45") == ("views.novelty_threshold", [0.4, 0.45])
    assert parse_set("lesions.dorsal=true,false") == ("lesions.dorsal", [True, False])
    assert parse_set("map.closure=RatSlam,Geometric") == ("map.closure", ["RatSlam", "Geometric"])
    assert parse_set("output.state_frames=[0,10],null") == ("output.state_frames", [[0, 10], None])
    assert split_values('a,"b,c",{"x": [1,2]}') == ["a", '"b,c"', '{"x": [1,2]}']
    assert parse_seeds("0-2,7") == [0, 1, 2, 7] and parse_seeds([3, 3, 1]) == [3, 1]
    for bad in ("0-x", "-1", [True]):
        with pytest.raises(HippoNavError, match="seed"):
            parse_seeds(bad)
    with pytest.raises(HippoNavError, match="--seeds"):
        parse_set("seed=1,2")


def test_the_cross_product_and_stable_distinct_ids():
    space = build_space(sets=["views.novelty_threshold=0.40,0.45"], lesions="none,dorsal", seeds="0-2")
    runs = space.runs()
    assert len(runs) == 2 * 2 * 3
    ids = [r.run_id for r in runs]
    assert len(set(ids)) == len(ids)
    again = build_space(seeds="0-2", lesions="none,dorsal", sets=["views.novelty_threshold=0.40,0.45"])
    assert [r.run_id for r in again.runs()] == ids  # the same space gives the same ids (resume)
    run = next(
        r
        for r in runs
        if r.lesion == "dorsal" and r.seed == 2 and r.overrides["views.novelty_threshold"] == 0.45
    )
    assert run.run_id.startswith("vo_no-dorsal_novelty_threshold=0.45_s2-")
    config = run.pipeline_config()
    assert config.seed == 2 and config.views.novelty_threshold == 0.45
    assert (config.lesions.ventral, config.lesions.intermediate, config.lesions.dorsal) == (
        False,
        False,
        True,
    )
    # `lesions.NAME` as a config key reaches the same section.
    by_key = build_space(sets=["lesions.dorsal=true"]).runs()[0].pipeline_config()
    assert by_key.lesions.dorsal and config_hash(by_key) != config_hash(
        build_space().runs()[0].pipeline_config()
    )


def test_a_key_given_twice_in_a_yaml_sweep_file_is_refused(tmp_path):
    twice = tmp_path / "twice.yaml"
    twice.write_text("seeds: 0-1\nseeds: 0-4\n")
    with pytest.raises(HippoNavError, match="key 'seeds' appears twice"):
        build_space(twice)


def test_a_frame_range_that_holds_no_frame_is_refused_before_any_run():
    with pytest.raises(HippoNavError, match="stop 10 is not after start 20"):
        build_space(dataset={"start": 20, "stop": 10})


def test_a_base_config_names_its_runs_and_figures_do_not(tmp_path):
    """A second sweep with another base config into the same folder makes runs of its own (other ids) instead
    of replacing the first's; what is output (--no-figures) changes no result and no id."""
    plain = [r.run_id for r in build_space(seeds="0-1").runs()]
    assert [r.run_id for r in build_space(seeds="0-1", no_figures=True).runs()] == plain
    base = tmp_path / "b.json"
    base.write_text(json.dumps({"views": {"novelty_threshold": 0.41}}))
    other = [r.run_id for r in build_space(seeds="0-1", config=str(base)).runs()]
    assert [i.rsplit("-", 1)[0] for i in other] == [i.rsplit("-", 1)[0] for i in plain]  # the same slugs
    assert not set(other) & set(plain)
    assert [r.run_id for r in build_space(seeds="0-1", config=str(base)).runs()] == other  # resumable


def test_a_bad_value_is_refused_before_anything_runs_with_the_config_files_message(tmp_path, capsys):
    with pytest.raises(HippoNavError, match=r"injection\.decay_per_frame.*got -1"):
        build_space(sets=["injection.decay_per_frame=0.5,-1"]).runs()
    with pytest.raises(HippoNavError, match="views.novelty_thresh"):
        build_space(sets=["views.novelty_thresh=0.4"]).runs()
    out = tmp_path / "sweep"
    assert main(["sweep", "--set", "vo.window.max_keyframes=-3", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "vo.window.max_keyframes" in err and len(err.strip().splitlines()) == 1 and not out.exists()
    with pytest.raises(HippoNavError, match="lesion 'frontal'"):
        build_space(lesions="none,frontal")
    with pytest.raises(HippoNavError, match="needs a dataset"):
        build_space(sequences="00,05")


def test_a_sweep_file_gives_a_union_of_cross_products_and_the_command_line_replaces_its_axes(tmp_path):
    odometry = tmp_path / "orb.txt"
    odometry.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    (tmp_path / "base.json").write_text(json.dumps({"injection": {"enabled": False}}))
    toml = tmp_path / "s.toml"
    toml.write_text(
        f"""
config_file = "{tmp_path / "base.json"}"
out = "runs/s"
seeds = "0-1"
[config.output]
figures = false
[set.views]
novelty_threshold = [0.4, 0.45]
[[space]]
odometry = ["vo", "drift"]
[[space]]
odometry = [{{ file = "{odometry}", align = "start" }}]
lesion = ["none", "ventral+dorsal"]
[space.set]
"map.closure" = "RatSlam"
"""
    )
    space = build_space(toml)
    runs = space.runs()
    assert space.out == "runs/s" and len(runs) == 2 * 2 * 2 + 2 * 2 * 2
    replayed = [r for r in runs if r.odometry.kind == "file"]
    assert {r.odometry.align for r in replayed} == {"start"} and replayed[0].odometry.label == "orb@start"
    config = replayed[0].pipeline_config()
    assert (
        not config.injection.enabled and not config.output.figures and config.map.closure.value == "RatSlam"
    )
    assert {r.lesion for r in replayed} == {"none", "ventral+dorsal"}
    # YAML reads the same; the command line's seeds replace the file's in every cross-product.
    yaml_file = tmp_path / "s.yaml"
    yaml_file.write_text(
        "seeds: [0, 1]\nspace:\n  - {odometry: [vo, drift]}\nset:\n  views.novelty_threshold: [0.4]\n"
    )
    assert len(build_space(yaml_file).runs()) == 4
    assert {r.seed for r in build_space(yaml_file, seeds="5").runs()} == {5}
    toml.write_text("sequences = ['00']\n")
    with pytest.raises(HippoNavError, match=r"unknown keys \['sequences'\]"):
        build_space(toml)


def test_resume_keeps_done_and_failed_runs_and_reruns_the_rest(tmp_path):
    runs = build_space(seeds="0-4", no_figures=True).runs()
    out = tmp_path / "sweep"

    def leave(spec, status, config=None, metrics=True):
        folder = out / "runs" / spec.run_id
        folder.mkdir(parents=True)
        write_json_atomic(
            folder / "manifest.json",
            {
                "run_id": spec.run_id,
                "status": status,
                "config_sha256": config or config_hash(spec.pipeline_config()),
            },
        )
        if metrics:  # what a finished run writes (the parts resume checks)
            (folder / "metrics.json").write_text(
                '{"frames": 200, "interrupted": false, "stopped_by_error": null}'
            )

    leave(runs[0], "done")
    leave(runs[1], "failed")
    leave(runs[2], "interrupted")
    leave(runs[3], "done", config="another")  # the package's defaults changed since
    found = plan(runs, out)
    assert [s.run_id for s in found.done] == [runs[0].run_id]
    assert [s.run_id for s in found.failed] == [runs[1].run_id]
    assert [s.run_id for s in found.todo] == [r.run_id for r in runs[2:]]
    assert [s.run_id for s in plan(runs, out, retry_failed=True).todo] == [r.run_id for r in runs[1:]]
    assert read_manifest(out / "runs" / runs[0].run_id)["status"] == "done"
    assert not list((out / "runs" / runs[0].run_id).glob(".*.tmp"))  # the atomic write left no temporary


def test_dry_run_lists_the_runs_without_ray(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    assert (
        main(["sweep", "--seeds", "0-1", "--lesion", "none,dorsal", "--dry-run", "--out", str(tmp_path)]) == 0
    )
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == "4 runs: 4 to run" and len(printed) == 5 and "lesion=dorsal" in printed[-1]


def test_without_ray_the_sweep_says_how_to_install_it_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    assert main(["sweep", "--stop", "5", "--out", str(tmp_path / "s"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err
        == "hippo-nav: error: hippo-nav sweep needs Ray: pip install 'hippo-nav[sweep]' (or pip install 'ray[default]')"
    )


def test_the_shipped_lesion_study_is_four_conditions_by_five_seeds():
    runs = build_space(PROJECT_ROOT / "docs" / "sweeps" / "lesions.toml").runs()
    assert len(runs) == 20 and {r.lesion for r in runs} == {"none", "ventral", "intermediate", "dorsal"}
    assert {r.seed for r in runs} == set(range(5))
    config = runs[0].pipeline_config()
    assert not config.injection.enabled and len(config.output.state_frames or []) == 20


@pytest.mark.data
def test_the_shipped_whole_sequence_benchmark_is_the_old_scripts_runs_and_the_papers_system(
    shared_data, tmp_path, monkeypatch
):
    monkeypatch.chdir(PROJECT_ROOT)  # the sweep file's paths are taken from the project root
    space = build_space(
        PROJECT_ROOT / "docs" / "sweeps" / "whole_sequences.toml", dataset={"dataset": str(tmp_path)}
    )
    runs = space.runs()
    assert len(runs) == 28 and space.out == "runs/whole"
    variants = {(r.sequence, r.odometry.kind, r.pipeline_config().map.closure.value) for r in runs}
    paper = [r for r in runs if r.pipeline_config().preset == "paper"]
    assert sorted(r.sequence for r in paper) == ["00", "02", "05", "06", "08"]
    for run in paper:
        config = run.pipeline_config()
        assert run.odometry.kind == "vo" and config.parts.view_cells == "template"
        assert config.map.closure.value == "RatSlam" and config.injection.placement == "as_stored"
    for sequence in ("00", "02", "05", "06", "08"):
        assert {
            (sequence, "vo", "Geometric"),
            (sequence, "drift", "Geometric"),
            (sequence, "vo", "RatSlam"),
        } <= variants
    # 07 and 09, whose loops end where the drive began: the VO and the drifting odometry only.
    for sequence in ("07", "09"):
        assert {(r.odometry.kind, r.pipeline_config().preset) for r in runs if r.sequence == sequence} == {
            ("vo", "default"),
            ("drift", "default"),
        }
    for sequence in ("00", "05"):
        assert {(sequence, "file", "Geometric"), (sequence, "file", "RatSlam")} <= variants
    assert {r.odometry.align for r in runs if r.sequence == "00" and r.odometry.kind == "file"} == {"start"}


def test_loader_options_reach_every_run(tmp_path):
    # A sweep that dropped `--cameras color` would run every sequence on the other camera pair.
    space = build_space(dataset={"dataset": str(tmp_path), "cameras": "color", "left_topic": "/cam0"})
    assert space.dataset.options == (("cameras", "color"), ("left_topic", "/cam0"))
    assert space.dataset.as_dict()["options"] == {"cameras": "color", "left_topic": "/cam0"}


def test_the_shipped_paper_ladder_adds_one_engineering_change_a_step(tmp_path, monkeypatch):
    monkeypatch.chdir(PROJECT_ROOT)
    space = build_space(
        PROJECT_ROOT / "docs" / "sweeps" / "paper_ladder.toml", dataset={"dataset": str(tmp_path)}
    )
    runs = space.runs()
    assert len(runs) == 15 and {r.sequence for r in runs} == {"00", "05", "06"}
    steps = []
    for run in runs[::3]:  # each step on 00, 05 and 06, in the file's order
        c = run.pipeline_config()
        steps.append(
            (c.parts.view_cells, c.view_search.near_only, c.map.closure.value, c.injection.placement)
        )
    assert steps == [
        ("template", False, "RatSlam", "as_stored"),  # the paper's system
        ("template", True, "RatSlam", "as_stored"),  # + the restricted search
        ("template", True, "Geometric", "measured"),  # + the geometric closure
        ("words", True, "Geometric", "measured"),  # + the word cells: the defaults
        ("words", True, "RatSlam", "as_stored"),  # the paper's closure with the word cells
    ]
    # Step 4 is today's defaults exactly (the sweep's runs write no figures).
    assert runs[9].pipeline_config() == config_from_dict({"output": {"figures": False}})
