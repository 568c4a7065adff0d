"""The closure chain: proposers asked in order over one store; configs and memories written before the
proposers had names and sections of their own still read, as they meant."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hippo_nav.closure import ClosureChain, KeyframeStore
from hippo_nav.closure.proximity import ProximityProposer
from hippo_nav.closure.relocalisation import RelocalisationProposer
from hippo_nav.closure.view_cell import ViewCellProposer
from hippo_nav.datasets import KittiOdometry
from hippo_nav.memory import SavedMemory, check_compatible
from hippo_nav.pipeline import config_from_dict
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence


def test_a_config_of_flat_closure_keys_reads_as_the_sections_it_meant(caplog):
    old = {
        "parts": {"closure": "view_cell_pnp"},
        "closure": {
            "birdseye": True,
            "proximity": False,
            "birdseye_search_m": 60.0,
            "proximity_min_inliers": 12,
            "proximity_agreement_m": 2.0,
            "relocalisation_confirmations": 3,
            "view_cell_confirmed_min_inliers": 20,
            "closure_spacing_m": 5.0,
            "min_inliers": 25,
        },
    }
    new = {
        "parts": {"closure": ["relocalisation", "view_cell", "birdseye"]},
        "closure": {
            "birdseye": {"search_m": 60.0},
            "proximity": {"min_inliers": 12},
            "confirm": {"agreement_m": 2.0},
            "relocalisation": {"confirmations": 3},
            "view_cell": {"confirmed_min_inliers": 20},
            "spacing_m": 5.0,
            "min_inliers": 25,
        },
    }
    with caplog.at_level(logging.WARNING, logger="hippo_nav.pipeline"):
        read = config_from_dict(old)
    assert read == config_from_dict(new)
    assert "closure.proximity_min_inliers → closure.proximity.min_inliers" in caplog.text
    assert "closure.birdseye = true" in caplog.text
    # The old single proposer's name is the chain it stood for (home closures came later).
    old_chain = ["relocalisation", "view_cell", "proximity"]
    assert config_from_dict({"parts": {"closure": "view_cell_pnp"}}).parts.closure == old_chain


def _chain(calibration) -> ClosureChain:
    store = KeyframeStore(calibration)
    proposers = [
        ("relocalisation", RelocalisationProposer()),
        ("view_cell", ViewCellProposer()),
        ("proximity", ProximityProposer()),
    ]
    return ClosureChain(store, proposers)


def test_a_memory_saved_before_the_proposers_had_names_restores_their_state():
    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE, stop=2)
    chain = _chain(dataset.calibration)
    chain.store.keyframes[0] = chain.store.extract(dataset[0].left, dataset[0].right)
    state = chain.export_state()
    assert {"closure_odometer_m", "proximity.ring_turn", "relocalisation.hypotheses"} <= set(state)
    # The keys of then: the ring's turn and the relocalisation hypotheses at the top level.
    old = {k: v for k, v in state.items() if "." not in k}
    old["ring_turn"] = np.array(7)
    old["hypotheses"] = np.array([[12.0, 1.0, 2.0, 0.1]])
    again = _chain(dataset.calibration)
    again.restore_state(old)
    proposers = dict(again.proposers)
    assert proposers["proximity"].export_state()["ring_turn"] == 7
    np.testing.assert_array_equal(proposers["relocalisation"].export_state()["hypotheses"], old["hypotheses"])
    np.testing.assert_array_equal(again.store.keyframes[0].points_m, chain.store.keyframes[0].points_m)


def test_a_memory_that_recorded_its_one_proposer_is_not_refused_for_it():
    now = {"parts": {"view_cells": "words"}, "closure": {"descriptor": "sift"}}
    then = {"parts": {"view_cells": "words", "closure": "view_cell_pnp"}, "closure": {"descriptor": "sift"}}
    memory = SavedMemory(b"", {}, {}, {}, {"depends_on": then})
    check_compatible(memory, now)  # no error
    changed = SavedMemory(b"", {}, {}, {}, {"depends_on": {**then, "parts": {"view_cells": "template"}}})
    with pytest.raises(Exception, match="parts.view_cells"):
        check_compatible(changed, now)


def test_a_proposer_named_twice_is_refused():
    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE, stop=1)
    with pytest.raises(ValueError, match="named twice"):
        ClosureChain(
            KeyframeStore(dataset.calibration), [("a", ViewCellProposer()), ("a", ViewCellProposer())]
        )
