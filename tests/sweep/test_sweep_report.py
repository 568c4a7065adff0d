"""`hippo-nav report` on plain `hippo-nav run` folders (no Ray): the table is the runs' metrics.json, the
statistics over seeds are right, the lesion comparison and the figures are written."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from conftest import QUIET
from hippo_nav.cli import main
from hippo_nav.pipeline import config_from_dict, run
from hippo_nav.report.tables import stats, t_975


@pytest.fixture(scope="module")
def plain_runs(tmp_path_factory):
    """Four plain runs of 12 demo frames: intact and dorsal-lesioned, seeds 0 and 1."""
    root = tmp_path_factory.mktemp("plain")
    for lesion in ("none", "dorsal"):
        for seed in (0, 1):
            sections = {**QUIET, "seed": seed, "lesions": {"dorsal": lesion == "dorsal"}}
            run(root / f"{lesion}_{seed}", stop=12, progress=False, config=config_from_dict(sections))
    return root


def test_the_table_is_the_runs_metrics_and_the_groups_their_statistics(plain_runs, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", str(plain_runs), "--out", str(out)]) == 0
    assert "4 runs" in capsys.readouterr().out
    with (out / "table.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 and {r["lesion"] for r in rows} == {"none", "dorsal"}
    for row in rows:
        metrics = json.loads((plain_runs / row["run_id"] / "metrics.json").read_text())
        assert float(row["ate_2d_corrected_m"]) == pytest.approx(
            metrics["errors"]["corrected"]["ate_2d_m"], rel=1e-9
        )
        assert float(row["ate_2d_neural_m"]) == pytest.approx(
            metrics["errors"]["neural"]["ate_2d_m"], rel=1e-9
        )
        assert int(float(row["frames"])) == metrics["frames"] == 12 and int(row["seed"]) == metrics["seed"]
        assert float(row["peak_rss_mb"]) == pytest.approx(metrics["timing"]["peak_rss_mb"])
    with (out / "groups.csv").open() as f:
        groups = {g["lesion"]: g for g in csv.DictReader(f)}
    for lesion, group in groups.items():
        values = [float(r["place_sigma_rad"]) for r in rows if r["lesion"] == lesion]
        assert group["place_sigma_rad_n"] == "2"
        assert float(group["place_sigma_rad_mean"]) == pytest.approx(np.mean(values))
        assert float(group["place_sigma_rad_ci95"]) == pytest.approx(
            12.706 * np.std(values, ddof=1) / math.sqrt(2)
        )
    # The dorsal module is the sharpest: losing it widens the place bump, as the 1-D theory says.
    assert float(groups["dorsal"]["place_sigma_rad_mean"]) > float(groups["none"]["place_sigma_rad_mean"])
    lesions = (out / "lesions.md").read_text()
    assert "widest first: dorsal > none" in lesions and "matches the theory's" in lesions
    for name in ("table.md", "ate_2d_corrected_m_by_configuration.png", "ate_2d_corrected_m_vs_lesion.png"):
        assert (out / name).stat().st_size > 0, name
    assert [p.name for p in out.glob("trajectories_*.png")] == ["trajectories_synthetic_demo_loop.png"]


def test_statistics_over_seeds():
    s = stats([1.0, 2.0, 3.0, None])
    assert (s.mean, s.n) == (2.0, 3) and s.std == pytest.approx(1.0)
    assert s.ci95 == pytest.approx(4.303 / math.sqrt(3))
    assert stats([5.0]).ci95 is None and stats([None]).mean is None
    assert t_975(31) == pytest.approx(2.0395, abs=1e-3) and t_975(200) == pytest.approx(1.9719, abs=1e-3)
    # Numbers near the float's limit (a run that diverged) give finite statistics, without numpy's warning.
    with np.errstate(all="raise"):
        huge = stats([1e300, 3e300])
    assert huge.mean == pytest.approx(2e300) and huge.std == pytest.approx(math.sqrt(2) * 1e300)
    assert math.isfinite(huge.ci95)


def test_a_report_of_nothing_or_an_unknown_metric_is_one_clear_line(plain_runs, tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 2
    assert "no runs found" in capsys.readouterr().err
    assert main(["report", str(plain_runs), "--out", str(tmp_path / "r"), "--metric", "nope"]) == 2
    assert "--metric nope: no run has it" in capsys.readouterr().err
    assert main(["report", str(plain_runs), "--out", str(tmp_path / "r"), "--sequence", "99"]) == 2
    assert "--sequence 99: no run is of it" in capsys.readouterr().err
    (tmp_path / "a_file").write_text("x")
    assert main(["report", str(tmp_path / "a_file")]) == 2
    assert "a file, not a folder" in capsys.readouterr().err


def test_a_run_with_a_malformed_metrics_file_is_left_out_with_one_warning(
    plain_runs, tmp_path, caplog, capsys
):
    """Real runs, one of them spoilt (a field of the wrong type): the other three are reported, the spoilt one
    is named in one warning and in table.md, and the statistics are those of the three."""
    import logging
    import shutil

    runs = tmp_path / "runs"
    shutil.copytree(plain_runs, runs)
    spoilt = runs / "dorsal_1" / "metrics.json"
    metrics = json.loads(spoilt.read_text())
    metrics["errors"]["corrected"]["ate_2d_m"] = "0.1"
    spoilt.write_text(json.dumps(metrics))
    out = tmp_path / "report"
    with caplog.at_level(logging.WARNING):
        assert main(["report", str(runs), "--out", str(out), "--no-figures"]) == 0
    assert "3 runs (1 skipped" in capsys.readouterr().out
    (warning,) = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert f"{spoilt}: errors.corrected.ate_2d_m: expected a number or null, got text '0.1'" in warning
    with (out / "table.csv").open() as f:
        assert sorted(r["run_id"] for r in csv.DictReader(f)) == ["dorsal_0", "none_0", "none_1"]
    assert "# Skipped runs (1)" in (out / "table.md").read_text()
