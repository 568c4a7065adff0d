"""Issue 3's 2-D experiment: lesion grid modules in the full network and compare the place bump with the
1-D Bayesian theory fed with the network's own module bump widths."""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.engine import N_MODULES, SpatialMemory
from hippo_nav.theory import predicted_lesion_order


@pytest.fixture(scope="module")
def measured() -> dict:
    sm = SpatialMemory()
    module_widths = np.array([m.bumps[0].width_rad for m in sm.readout().modules])
    widths = {}
    for active in [(0, 1, 2), (1, 2), (0, 2), (0, 1)]:
        off = [i not in active for i in range(N_MODULES)]
        sm.set_lesions(*off)
        frames = [sm.step(0.0, 0.0, 0.1) for _ in range(8)]
        widths[active] = (
            float(np.mean([r.place.width_rad for r in frames[4:]])),
            float(np.mean([r.fused.width_rad for r in frames[4:]])),
        )
    return {"module_widths": module_widths, "widths": widths}


def test_module_widths_are_ordered_ventral_to_dorsal(measured: dict):
    w = measured["module_widths"]
    assert w[0] > w[1] > w[2]  # k = 1 (ventral) broadest, k = 4 (dorsal) sharpest


def test_network_fusion_matches_the_1d_theory_for_every_lesion(measured: dict):
    theory = predicted_lesion_order(measured["module_widths"])
    for active, (_, fused) in measured["widths"].items():
        assert fused == pytest.approx(theory[active], rel=0.05), active


def test_place_field_widens_in_the_theorys_order(measured: dict):
    place = {k: v[0] for k, v in measured["widths"].items()}
    red, green, yellow = place[(0, 1, 2)], place[(1, 2)], place[(0, 1)]
    assert yellow > green > red
    # Same ranking of all four conditions as the theory.
    theory = predicted_lesion_order(measured["module_widths"])
    assert sorted(place, key=place.get) == sorted(place, key=lambda k: theory[k])
