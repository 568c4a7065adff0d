"""The sequence proposer's search speed (`make bench`; skipped by the default test run).

One round = one sampled view's search (`SequenceProposer._search`): its last 15 views against every stretch of
15 ending at a view of the search region, over a store of 2 000 views (about 4 km at 2 m). The region holds
runs of consecutive views, as a street passed before does: 4 runs of 25 views (a 50 m radius across four
passes) and 8 runs of 75 (the 150 m cap). The baseline (`stretch_by_stretch`) is the search as it was until
2026-12-05: every stretch's 15 views centred, normalised and compared anew, although neighbouring stretches share
14 of them; the proposer now does each view once. Both give the same distances to 1e-12 and the same
ranking (checked before timing); compare within a group (`sequence_search_<views>`) for the speed-up.
"""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.closure.sequence import SequenceConfig, SequenceProposer

STORE = 2_000
REGIONS = {100: (4, 25), 600: (8, 75)}  # views in the region: (runs, views a run)


def _stretch_by_stretch(proposer: SequenceProposer, gated: np.ndarray) -> np.ndarray:
    """The former search's distances, in the order of the stretches' end views (the baseline)."""
    cfg = proposer.config
    views = proposer._views
    now = len(views) - 1
    ends = np.flatnonzero(np.isin(proposer._view_vertex, gated))
    ends = ends[(ends >= cfg.length - 1) & (ends < now)]
    mean = proposer._sum / len(views)
    steps = np.arange(cfg.length)
    query = proposer._unit(views[now - steps] - mean)
    stored = proposer._unit(views[ends[:, None] - steps[None]] - mean)
    return 1.0 - np.einsum("eld,ld->e", stored, query) / cfg.length


@pytest.fixture(scope="module")
def proposer() -> SequenceProposer:
    rng = np.random.default_rng(0)
    proposer = SequenceProposer(SequenceConfig(shortlist=6))
    views = rng.random((STORE, proposer._descriptors.shape[1]), dtype=np.float32)
    proposer.restore_state(
        {
            "views": views.astype(np.float16),
            "view_vertex": np.arange(STORE, dtype=np.int64),
            "view_odometer_m": 2.0 * np.arange(STORE, dtype=np.float64),
            "next_sample_m": np.array(2.0 * STORE),
        }
    )
    return proposer


def _region(views: int) -> np.ndarray:
    runs, length = REGIONS[views]
    starts = np.linspace(100, STORE - 200, runs).astype(int)
    return np.concatenate([np.arange(s, s + length) for s in starts]).astype(np.int64)


@pytest.mark.parametrize("views", sorted(REGIONS))
@pytest.mark.parametrize("search", ["shared_views", "stretch_by_stretch"])
def test_sequence_search(benchmark, proposer: SequenceProposer, views: int, search: str) -> None:
    gated = _region(views)
    prior = np.zeros(len(gated))
    baseline = _stretch_by_stretch(proposer, gated)
    ranked = proposer._search(gated, prior)
    # The same answer: the best vertices of the baseline's distances, in order (the vertex of a view is its index).
    expected = np.flatnonzero(np.isin(proposer._view_vertex, gated))
    expected = expected[(expected >= proposer.config.length - 1) & (expected < len(proposer) - 1)]
    assert ranked == expected[np.argsort(baseline, kind="stable")][: proposer.config.shortlist].tolist()
    benchmark.group = f"sequence_search_{views}"
    if search == "shared_views":
        benchmark(proposer._search, gated, prior)
    else:
        benchmark(_stretch_by_stretch, proposer, gated)
