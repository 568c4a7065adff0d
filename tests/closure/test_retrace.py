"""The retrace's consistency check (`closure/retrace.py`): a measured link between the lost stretch and the
loaded map is kept only when the graph solved with it leaves its χ² within the map's `max_loop_chi2`, as the
map refuses an inconsistent closure. (The retrace as a whole: tests/memory/test_sessions.py.)"""

from __future__ import annotations

import json

import numpy as np
from hippo_nav.closure.retrace import RetraceConfig, _consistent, _Link, retrace_lost_stretch
from hippo_nav.map import ExperienceMap

TIGHT = np.diag([100.0, 100.0, 1000.0])  # σ 0.1 m, 0.03 rad


def _two_parallel_chains() -> ExperienceMap:
    """A loaded chain 0…5 along y = 0 and a lost chain 6…11 along y = 0.5, each linked by odometry only,
    and the lost chain's last vertex tied to the loaded chain's by a loop (the join)."""
    m = ExperienceMap()
    for i in range(6):
        m.add_vertex(0, (0.0, 0.0), 0.0, (float(i), 0.0, 0.0))
    for i in range(6):
        m.add_vertex(0, (0.0, 0.0), 0.0, (float(i), 0.5, 0.0))
    for a in (0, 6):
        for i in range(a, a + 5):
            m.add_link(i, i + 1, (1.0, 0.0, 0.0), 0.1)
    m.add_link(11, 5, (0.0, -0.5, 0.0), 0.0, True, TIGHT)
    return m


def test_a_link_that_agrees_with_the_graph_is_kept_and_one_that_does_not_is_dropped():
    m = _two_parallel_chains()
    max_chi2 = float(json.loads(m.params_json())["max_loop_chi2"])
    good = _Link(6, 0, np.array([0.0, -0.5, 0.0]), TIGHT)  # where the two chains say vertex 0 is
    bad = _Link(7, 1, np.array([4.0, 3.0, 0.0]), TIGHT)  # 5 m from it
    kept = _consistent(m, [good, bad], max_chi2)
    assert kept == [good]
    assert _consistent(m, [bad], max_chi2) == []


def test_no_retrace_when_it_is_switched_off_or_there_is_no_lost_stretch():
    m = _two_parallel_chains()
    off = retrace_lost_stretch(m, None, 6, 11, RetraceConfig(max_links=0))  # type: ignore[arg-type]
    assert off.links == 0 and off.lost_vertices == 0
    none = retrace_lost_stretch(m, None, 6, 6, RetraceConfig())  # type: ignore[arg-type]
    assert none.links == 0 and none.lost_vertices == 0
