"""`hippo-nav report` on files it did not write well: every file it writes goes through the atomic writer (a
link planted at an output name is replaced, never written through), and every file it reads back is checked
field by field. A run with a malformed file is left out with one warning naming the file and the field
(and listed in table.md); when no run is readable, the command fails with one line. Never a traceback.

The runs here are made by hand (metrics.json and config.json as `hippo-nav run` writes them, without
running the pipeline): the report reads files, so files are what is tested.
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.report import write_report
from hippo_nav.report.collect import collect
from hippo_nav.report.tables import axis_columns
from hippo_nav.report.tables import groups as report_groups
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


def _metrics(seed: int, ate: float, dorsal: bool = False) -> dict[str, Any]:
    """The fields of a `hippo-nav run` metrics.json the report reads."""
    return {
        "sequence": "synthetic demo loop",
        "frames": 12,
        "interrupted": False,
        "stopped_by_error": None,
        "seed": seed,
        "lesioned": [False, False, dorsal],
        "view_cells": 3,
        "vertices": 5,
        "loop_closures": 0,
        "errors": {
            "vo": {"ate_2d_m": ate, "ate_3d_m": ate},
            "corrected": {"ate_2d_m": ate, "ate_3d_m": ate, "t_rel_percent": 0.25},
        },
        "closure_quality": {"true_closures": 0, "precision": None, "recall": None},
        "timing": {"wall_s": 0.6, "peak_rss_mb": 200.0, "frames_per_s": 20.0},
    }


def _make_runs(root: Path, n: int = 2, lesions: bool = False) -> list[Path]:
    folders = []
    for i in range(n):
        folder = root / f"run_{i}"
        folder.mkdir(parents=True)
        metrics = _metrics(i % 2, 0.1 + 0.01 * i, dorsal=lesions and i >= n // 2)
        (folder / "metrics.json").write_text(json.dumps(metrics), encoding="utf-8")
        (folder / "config.json").write_text(json.dumps({"seed": i % 2}), encoding="utf-8")
        folders.append(folder)
    return folders


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hippo-nav: error:"), err
    assert "Traceback" not in err and "[Errno" not in err, err
    return lines[0]


def test_a_link_planted_at_a_report_file_is_replaced_not_written_through(tmp_path):
    runs = tmp_path / "runs"
    _make_runs(runs, 4, lesions=True)
    out = tmp_path / "report"
    out.mkdir()
    names = ["table.csv", "groups.csv", "table.md", "lesions.md", "ate_2d_corrected_m_by_configuration.png"]
    victims = {}
    for name in names:
        victim = tmp_path / f"victim_{name}"
        victim.write_text("precious\n", encoding="utf-8")
        (out / name).symlink_to(victim)
        victims[name] = victim
    assert main(["report", str(runs), "--out", str(out)]) == 0
    for name, victim in victims.items():
        assert victim.read_text(encoding="utf-8") == "precious\n", f"{name} was written through its link"
        assert not (out / name).is_symlink() and (out / name).stat().st_size > 0, name
    # Nothing but the report's own files is left behind (no temporaries).
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]


MALFORMED = [
    # (what is done to metrics.json, the field the warning must name)
    (lambda m: m.update(timing="fast"), "timing"),
    (lambda m: m["timing"].update(wall_s="0.6"), "timing.wall_s"),
    (lambda m: m["errors"].update(corrected=[1, 2]), "errors.corrected"),
    (lambda m: m["errors"]["corrected"].update(ate_2d_m=-1.0), "errors.corrected.ate_2d_m"),
    (lambda m: m["errors"]["corrected"].update(ate_2d_m=math.nan), "errors.corrected.ate_2d_m"),
    (lambda m: m["errors"]["corrected"].update(ate_2d_m=10**400), "errors.corrected.ate_2d_m"),
    (lambda m: m.update(frames=12.5), "frames"),
    (lambda m: m.update(frames=True), "frames"),
    (lambda m: m["closure_quality"].update(precision=1.5), "closure_quality.precision"),
    (lambda m: m.update(lesioned=5), "lesioned"),
    (lambda m: m.update(lesioned="abc"), "lesioned"),
    (lambda m: m.update(seed=-3), "seed"),
    (lambda m: m.update(seed="0"), "seed"),
    (lambda m: m.update(sequence={"a": 1}), "sequence"),
    (lambda m: m.update(interrupted="yes"), "interrupted"),
    (lambda m: m.update(stopped_by_error=5), "stopped_by_error"),
]


@pytest.mark.parametrize(("spoil", "field"), MALFORMED, ids=[f for _, f in MALFORMED])
def test_a_malformed_metrics_field_skips_the_run_with_one_warning_naming_file_and_field(
    tmp_path, caplog, capsys, spoil, field
):
    runs = tmp_path / "runs"
    good, bad = _make_runs(runs, 2)
    metrics = json.loads((bad / "metrics.json").read_text(encoding="utf-8"))
    spoil(metrics)
    (bad / "metrics.json").write_text(json.dumps(metrics), encoding="utf-8")
    out = tmp_path / "report"
    with caplog.at_level(logging.WARNING):
        assert main(["report", str(runs), "--out", str(out), "--no-figures"]) == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1, warnings
    assert f"{bad / 'metrics.json'}: {field}:" in warnings[0] and "\n" not in warnings[0]
    assert "1 runs (1 skipped" in capsys.readouterr().out
    table = (out / "table.csv").read_text(encoding="utf-8")
    assert str(good) in table and str(bad) not in table
    assert "# Skipped runs (1)" in (out / "table.md").read_text(encoding="utf-8")


def test_an_unreadable_metrics_file_skips_the_run(tmp_path, caplog):
    """Truncated, not JSON, not an object, nested absurdly deep, a folder: each one warning, no traceback."""
    runs = tmp_path / "runs"
    folders = _make_runs(runs, 6)
    text = (folders[0] / "metrics.json").read_text(encoding="utf-8")
    (folders[1] / "metrics.json").write_text(text[: len(text) // 2], encoding="utf-8")
    (folders[2] / "metrics.json").write_text("[1, 2, 3]", encoding="utf-8")
    (folders[3] / "metrics.json").write_text("[" * 100_000 + "]" * 100_000, encoding="utf-8")
    (folders[4] / "metrics.json").write_bytes(b"\xff\xfe{}")
    (folders[5] / "metrics.json").unlink()
    (folders[5] / "metrics.json").mkdir()
    with caplog.at_level(logging.WARNING):
        rows, skipped = collect([runs])
    assert [r.folder for r in rows] == [folders[0]]
    assert sorted(s.folder for s in skipped) == folders[1:]
    for s in skipped:
        assert str(s.folder / "metrics.json") in s.reason and "\n" not in s.reason, s.reason
    assert len([r for r in caplog.records if r.levelno >= logging.WARNING]) == 5


def test_malformed_sweep_manifests_config_and_bump_tables_skip_the_run(tmp_path, caplog):
    runs = tmp_path / "runs"
    folders = _make_runs(runs, 5)
    (folders[1] / "manifest.json").write_text(json.dumps({"status": "done", "axes": "abc"}), encoding="utf-8")
    (folders[2] / "manifest.json").write_text(
        json.dumps({"status": "finished", "axes": {}}), encoding="utf-8"
    )
    (folders[3] / "config.json").write_text(
        json.dumps({"views": {"novelty_threshold": 10**400}}), encoding="utf-8"
    )
    (folders[4] / "bump_table.csv").write_text(
        "frame,what,k,bump,mu_x_rad,mu_y_rad,sigma_x_rad,sigma_y_rad\n0,grid,1,0,0,0,abc,0.2\n",
        encoding="utf-8",
    )
    with caplog.at_level(logging.WARNING):
        rows, skipped = collect([runs])
    assert [r.folder for r in rows] == [folders[0]]
    reasons = {s.folder.name: s.reason for s in skipped}
    assert "manifest.json: axes: expected an object" in reasons["run_1"]
    assert "manifest.json: status: expected one of" in reasons["run_2"]
    assert "config.json: views.novelty_threshold: out of range" in reasons["run_3"]
    assert "bump_table.csv: line 2, column sigma_x_rad: 'abc' is not a number" in reasons["run_4"]


def _sweep_run(runs: Path, name: str, seed: int, ate: float, novelty: float, stop: int) -> None:
    """A done sweep run with the manifest a sweep writes (axes: only what the sweep varied)."""
    folder = runs / name
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text(json.dumps(_metrics(seed, ate)), encoding="utf-8")
    manifest = {
        "run_id": name,
        "status": "done",
        "axes": {"sequence": None, "odometry": "vo", "lesion": "none", "seed": seed},
        "dataset": {"path": None, "kind": None, "start": None, "stop": stop, "stride": 1, "checksum": "x"},
        "config": {"seed": seed, "vo": {"seed": seed}, "views": {"novelty_threshold": novelty}},
    }
    (folder / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")


def test_sweeps_of_other_base_configs_or_frame_ranges_are_not_pooled(tmp_path):
    """Two sweeps into one folder, or reported together, whose runs vary the same axes (the seed) but were
    set up otherwise: each setting that differs is a column, and the statistics are per setting."""
    runs = tmp_path / "sweep" / "runs"
    _sweep_run(runs, "a0", 0, 0.10, 0.45, 40)
    _sweep_run(runs, "a1", 1, 0.12, 0.45, 40)
    _sweep_run(runs, "b0", 0, 0.50, 0.41, 40)
    _sweep_run(runs, "b1", 1, 0.52, 0.41, 40)
    _sweep_run(runs, "c0", 0, 0.90, 0.45, 15)
    rows, _ = collect([tmp_path / "sweep"])
    assert {r.run_id: (r.axes["views.novelty_threshold"], r.axes["stop"]) for r in rows} == {
        "a0": (0.45, 40), "a1": (0.45, 40), "b0": (0.41, 40), "b1": (0.41, 40), "c0": (0.45, 15),
    }  # fmt: skip
    assert not any("vo.seed" in r.axes for r in rows)  # the seed is an axis of its own
    groups = report_groups(rows, axis_columns(rows))
    means = sorted(round(g.stats("ate_2d_corrected_m").mean, 3) for g in groups)
    assert means == [0.11, 0.51, 0.9]
    # One sweep's runs, set up alike, get no extra column.
    alone, _ = collect([runs / "a0", runs / "a1"])
    assert all(set(r.axes) == {"sequence", "odometry", "lesion", "seed"} for r in alone)


def test_a_trajectory_cut_at_a_line_is_left_out_not_scored(tmp_path):
    runs = tmp_path / "runs"
    good, cut = _make_runs(runs, 2)
    pose = "1 0 0 {x} 0 1 0 0 0 0 1 {z}\n"
    for folder, kept in ((good, 10), (cut, 6)):
        (folder / "trajectory_vo.kitti.txt").write_text("".join(pose.format(x=i, z=0) for i in range(10)))
        neural = "".join(pose.format(x=i, z=0.1 * i) for i in range(10)).splitlines(keepends=True)[:kept]
        (folder / "trajectory_neural.kitti.txt").write_text("".join(neural))
    rows, skipped = collect([runs])
    assert [r.folder for r in rows] == [good] and rows[0].values["pi_error_2d_m"] is not None
    assert [s.folder for s in skipped] == [cut] and "6 poses against 10" in skipped[0].reason


def test_an_earlier_run_set_aside_by_overwrite_is_not_a_run_of_its_own(tmp_path):
    runs = tmp_path / "runs"
    (run,) = _make_runs(runs, 1)
    aside = run / ".hippo_nav_previous"  # what a killed `--overwrite` leaves
    aside.mkdir()
    (aside / "metrics.json").write_text(json.dumps(_metrics(0, 0.3)), encoding="utf-8")
    rows, skipped = collect([runs])
    assert [r.folder for r in rows] == [run] and skipped == []


def test_no_readable_run_and_an_out_that_is_a_file_are_one_line(tmp_path, capsys):
    runs = tmp_path / "runs"
    (bad,) = _make_runs(runs, 1)
    (bad / "metrics.json").write_text("{", encoding="utf-8")
    assert main(["report", str(runs), "--out", str(tmp_path / "r")]) == 2
    line = _one_line_error(capsys)
    assert "none of the 1 runs" in line and str(bad / "metrics.json") in line and "not valid JSON" in line
    (bad / "metrics.json").write_text(json.dumps(_metrics(0, 0.1)), encoding="utf-8")
    a_file = tmp_path / "a_file"
    a_file.write_text("x", encoding="utf-8")
    assert main(["report", str(runs), "--out", str(a_file)]) == 2
    assert "not a folder" in _one_line_error(capsys)
    assert main(["report", str(runs), "--out", str(a_file / "below")]) == 2
    assert "cannot create the folder" in _one_line_error(capsys)


# ------------------------------------------------------------------------------------ property-based
JSON_SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(10**30), max_value=10**30)
    | st.sampled_from([10**400, -(10**400), 2**53 + 1])
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8)
)
JSON_VALUES = st.recursive(
    JSON_SCALARS,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=8,
)
FIELDS = [
    ("frames",), ("seed",), ("sequence",), ("lesioned",), ("interrupted",), ("stopped_by_error",),
    ("timing",), ("timing", "wall_s"), ("timing", "peak_rss_mb"), ("timing", "frames_per_s"),
    ("errors",), ("errors", "corrected"), ("errors", "corrected", "ate_2d_m"), ("errors", "vo", "ate_3d_m"),
    ("closure_quality",), ("closure_quality", "precision"), ("loop_closures",), ("view_cells",),
]  # fmt: skip


def _set(data: dict[str, Any], path: tuple[str, ...], value: Any) -> None:
    for key in path[:-1]:
        if not isinstance(data.get(key), dict):
            data[key] = {}
        data = data[key]
    data[path[-1]] = value


def _drop(data: dict[str, Any], path: tuple[str, ...]) -> None:
    for key in path[:-1]:
        data = data.get(key)
        if not isinstance(data, dict):
            return
    data.pop(path[-1], None)


@st.composite
def malformed_metrics(draw: st.DrawFn) -> bytes:
    """metrics.json spoilt one way: a field given another value, fields dropped, another top-level value,
    deep nesting, or the text cut short."""
    metrics = _metrics(0, 0.1)
    how = draw(st.sampled_from(["field", "drop", "top", "deep", "truncate"]))
    if how == "field":
        for _ in range(draw(st.integers(1, 3))):
            _set(metrics, draw(st.sampled_from(FIELDS)), draw(JSON_VALUES))
    elif how == "drop":
        for path in draw(st.lists(st.sampled_from(FIELDS), min_size=1, max_size=5)):
            _drop(metrics, path)
    elif how == "top":
        return json.dumps(draw(JSON_VALUES.filter(lambda v: not isinstance(v, dict)))).encode()
    elif how == "deep":
        depth = draw(st.sampled_from([33, 100, 5000, 200_000]))
        _set(
            metrics, draw(st.sampled_from(FIELDS)), json.loads("[" * min(depth, 900) + "]" * min(depth, 900))
        )
        if depth > 900:  # beyond what json.loads makes; written as text
            return ("{" + '"frames": ' + "[" * depth + "]" * depth + "}").encode()
    text = json.dumps(metrics).encode()
    if how == "truncate":
        return text[: draw(st.integers(0, len(text) - 1))]
    return text


@pytest.fixture(scope="module")
def fuzz_root(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=malformed_metrics())
def test_any_malformed_metrics_file_is_a_skipped_run_or_a_checked_row(fuzz_root, data):
    with tempfile.TemporaryDirectory(dir=fuzz_root) as where:
        runs = Path(where) / "runs"
        (folder,) = _make_runs(runs, 1)
        (folder / "metrics.json").write_bytes(data)
        logging.disable(logging.WARNING)  # the warnings are checked above; here they would flood the log
        try:
            rows, skipped = collect([runs])
        finally:
            logging.disable(logging.NOTSET)
        if skipped:
            (s,) = skipped
            assert str(folder / "metrics.json") in s.reason and "\n" not in s.reason, s.reason
            with pytest.raises(HippoNavError, match="none of the 1 runs"):
                write_report([runs], Path(where) / "report", figures=False)
        else:
            (row,) = rows
            for name, value in row.values.items():
                assert value is None or (isinstance(value, float) and math.isfinite(value) and value >= 0), (
                    name
                )
            metric = next((c for c, v in row.values.items() if v is not None), None)
            if metric is None:
                with pytest.raises(HippoNavError, match="no run has it"):
                    write_report([runs], Path(where) / "report", figures=False)
            else:
                write_report([runs], Path(where) / "report", figures=False, metric=metric)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=malformed_metrics())
def test_the_command_on_a_malformed_metrics_file_is_one_line_never_a_traceback(fuzz_root, capsys, data):
    """Through the command line: 0 (the run read, or skipped beside a good one), or 2 and one line."""
    with tempfile.TemporaryDirectory(dir=fuzz_root) as where:
        runs = Path(where) / "runs"
        folders = _make_runs(runs, 2)
        (folders[1] / "metrics.json").write_bytes(data)
        capsys.readouterr()
        logging.disable(logging.WARNING)
        try:
            code = main(["report", str(runs), "--out", os.path.join(where, "report"), "--no-figures"])
            assert code == 0
            folders[0].joinpath("metrics.json").unlink()  # the spoilt run alone
            code = main(["report", str(runs), "--out", os.path.join(where, "report"), "--no-figures"])
        finally:
            logging.disable(logging.NOTSET)
        if code == 2:  # the file and the field, or (read well) a metric it does not hold
            line = _one_line_error(capsys)
            assert "metrics.json" in line or "no run has it" in line, line
        else:
            assert code == 0


def test_an_axis_whose_values_are_lists_is_plotted_not_a_type_error(tmp_path):
    """A sweep over `parts.closure` gives list-valued axes (unhashable): the report's figures take them."""
    from hippo_nav.report import figures
    from hippo_nav.report.collect import RunRow

    chains = [["view_cell", "proximity"], ["view_cell", "proximity", "sequence"]]
    rows = [
        RunRow(
            tmp_path / f"r{i}",
            f"r{i}",
            "s",
            "done",
            None,
            {"parts.closure": chains[i % 2], "seed": i // 2},
            {"ate_2d_corrected_m": 1.0 + i},
        )
        for i in range(4)
    ]
    keys = ["parts.closure", "seed"]
    assert figures.swept_key(rows, keys) == "parts.closure"
    made = figures.response(rows, keys, "ate_2d_corrected_m", "parts.closure", tmp_path)
    assert made is not None and made.stat().st_size > 0
    assert figures.metric_by_configuration(rows, keys, "ate_2d_corrected_m", tmp_path) is not None
