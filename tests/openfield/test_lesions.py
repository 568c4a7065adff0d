"""The open-field lesion study: the place field widens when a module is switched off, most when the dorsal
(sharpest) one is, as the 1-D theory predicts from the intact modules' widths; mean and 95 % interval over
seeds; one figure."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("opexebo")
pytest.importorskip("ratinabox")

from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.openfield import OpenFieldConfig
from hippo_nav.openfield.lesions import LesionStudy, bump_width_m, run_lesion_study, write_lesion_figure


@pytest.fixture(scope="module")
def study() -> LesionStudy:
    base = OpenFieldConfig(duration_s=4.0)
    return run_lesion_study(base, seeds=[0, 1], conditions=["none", "ventral", "dorsal"], units=2, shuffles=2)


def test_the_place_field_widens_in_the_order_the_theory_predicts(study: LesionStudy):
    width = {c: study.summary(c, "place_width_m") for c in study.conditions}
    assert all(w is not None and w[2] == 2 for w in width.values())
    measured = sorted(study.conditions, key=lambda c: width[c][0])  # type: ignore[index]
    theory = study.theory_width_m()
    assert measured == sorted(study.conditions, key=theory.__getitem__) == ["none", "ventral", "dorsal"]
    # Every seed, not only the mean: the dorsal module's loss widens the field by a third or more.
    none, dorsal = study.values["none"]["place_width_m"], study.values["dorsal"]["place_width_m"]
    assert all(d > 1.3 * n for d, n in zip(dorsal, none))  # type: ignore[operator]


def test_a_lesioned_module_has_no_score_and_no_width(study: LesionStudy):
    assert study.values["dorsal"]["grid_dorsal_grid_score_90"] == [None, None]
    assert study.values["dorsal"]["grid_dorsal_width_m"] == [None, None]
    assert all(v is not None for v in study.values["dorsal"]["grid_ventral_width_m"])
    mean, half, n = study.summary("none", "place_error_m")  # type: ignore[misc]
    assert n == 2 and np.isfinite(half) and mean < 0.05


def test_the_study_writes_its_numbers_and_one_figure(study: LesionStudy, tmp_path):
    paths = write_lesion_figure(study, tmp_path / "lesions")
    assert [p.suffix for p in paths] == [".png", ".pdf"] and all(p.stat().st_size > 1000 for p in paths)
    data = json.loads(json.dumps(study.to_dict()))
    assert set(data["theory_place_width_m"]) == {"none", "ventral", "dorsal"}


def test_bad_conditions_and_a_silent_population_are_refused(study: LesionStudy):
    with pytest.raises(HippoNavError, match="unknown lesion conditions"):
        run_lesion_study(OpenFieldConfig(duration_s=1.0), seeds=[0], conditions=["medial"])
    from hippo_nav.openfield import record_session

    rec = record_session(OpenFieldConfig(duration_s=1.0, lesion="ventral"))
    with pytest.raises(HippoNavError, match="no activity"):
        bump_width_m(rec, "grid_ventral")


def test_record_runs_a_lesion_study(tmp_path):
    out = tmp_path / "study"
    args = ["record", "--out", str(out), "--duration", "2", "--lesion-study", "1", "--units", "1"]
    assert main([*args, "--shuffles", "1", "--no-progress"]) == 0
    data = json.loads((out / "lesions.json").read_text())
    assert data["conditions"] == ["none", "ventral", "intermediate", "dorsal"] and data["seeds"] == [0]
    assert (out / "lesions.png").is_file() and (out / "lesions.pdf").is_file()
    assert main([*args, "--shuffles", "1", "--no-progress"]) == 2  # the study is kept, not overwritten
