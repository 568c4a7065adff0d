"""Closures at home (`"home"`): the session's first vertices are measured wherever the map's loop gate admits
them, once the agent has been away, at most once per `every_m`; a drive back home closes its loop through an
odometry drifted beyond the proximity proposer's reach."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from hippo_nav.closure.base import ClosureContext
from hippo_nav.closure.home import HomeConfig, HomeProposer
from hippo_nav.io import write_kitti_poses
from hippo_nav.map import new_experience_map
from hippo_nav.pipeline import Pipeline, config_from_dict
from hippo_nav.vo.replay import ReplayOdometry

_AHEAD = (5.0, 0.0, 0.0)  # a home vertex 5 m ahead, passed the agent's way


class _Map:
    """The map as the proposer sees it: an odometer, the gated vertices, a session that may not have joined."""

    def __init__(self) -> None:
        self.odometer_m = 0.0
        self.gated: dict[int, tuple[float, float, float]] = {}  # vertex → agent_from_vertex, when admitted
        self.unjoined_from: int | None = None

    def __len__(self) -> int:
        return 0  # as the proposer first sees it: empty (a map with vertices is a real one, below)

    def loop_candidates(self, vertices, step):
        return [(v, self.gated[v], 5.0, 100.0) for v in vertices if v in self.gated]

    def params_json(self) -> str:
        return json.dumps({"min_loop_separation_m": 50.0})


class _Store:
    """Every vertex keeps a keyframe; a measurement of a vertex is recorded and succeeds with `inliers[vertex]`."""

    def __init__(self) -> None:
        self.measured: set[int] = set()
        self.tries: list[int] = []
        self.inliers = {2: 40}  # 20 elsewhere
        self.confirmations: list[int] = []

    def keyframed(self, vertices):
        return list(vertices)

    def current(self):
        return object(), "ok"

    def measure(self, vertex, current, min_inliers):
        self.tries.append(vertex)
        inliers = self.inliers.get(vertex, 20)
        return SimpleNamespace(
            agent_from_target=(5.0, 0.0, 0.0), information=np.eye(3), inliers=inliers
        ), "ok"

    def confirmed(self, experience_map, vertex, measurement, current, via):
        self.confirmations.append(vertex)
        return True, "ok"


class _Drive:
    """Frames of 1 m each: the proposer asked, then told what the map did (a vertex every `vertex_every`)."""

    def __init__(self, proposer: HomeProposer) -> None:
        self.proposer, self.map, self.store = proposer, _Map(), _Store()
        self.vertices = 0

    def frame(self, new_vertex: bool = True, accept: bool = False):
        context = ClosureContext(None, (1.0, 0.0, 0.0), None, self.map, self.store)  # type: ignore[arg-type]
        attempt = self.proposer.propose(context)
        closure = None
        if attempt.closure is not None and accept:
            closure = (self.vertices, attempt.closure.target_vertex)
        outcome = SimpleNamespace(
            created=new_vertex, vertex=self.vertices if new_vertex else None, loop_closure=closure
        )
        self.proposer.after_map(outcome)  # type: ignore[arg-type]
        self.vertices += int(new_vertex)
        self.map.odometer_m += 1.0
        return attempt


def test_home_is_the_first_vertices_and_is_measured_only_after_being_away():
    proposer = HomeProposer(HomeConfig(length_m=3.0, every_m=2.0))
    drive = _Drive(proposer)
    for _ in range(5):
        drive.frame()
    assert proposer._homes == [0, 1, 2, 3]  # made within 3 m of the first
    # Leaving home: still gated (within 10 m + 10 %) and too recent — nothing is measured, nothing arms.
    drive.map.gated = {0: _AHEAD, 1: _AHEAD}
    for _ in range(60):
        drive.frame(new_vertex=False)
    assert drive.store.tries == [] and not proposer._away
    # Out of every home vertex's gate, 50 m after home: away.
    drive.map.gated = {}
    drive.frame(new_vertex=False)
    assert proposer._away and drive.store.tries == []
    # Back within the gate: every 2 m each gated home vertex passed the agent's way is measured (not one passed
    # the other way: 150° off), and the best measured (most inliers), once confirmed, is proposed.
    drive.map.gated = {0: _AHEAD, 2: _AHEAD, 3: (5.0, 0.0, np.radians(150.0))}
    attempts = [drive.frame(new_vertex=False) for _ in range(6)]
    assert drive.store.tries == [0, 2] * 3 and drive.store.confirmations == [2] * 3
    closure = attempts[0].closure
    assert closure is not None and closure.via == "home" and closure.target_vertex == 2
    assert [a.closure is not None for a in attempts] == [True, False] * 3
    # An accepted closure onto home disarms until the agent has been away again.
    drive.frame(new_vertex=False, accept=True)
    assert not proposer._away
    tries = len(drive.store.tries)
    for _ in range(10):
        drive.frame(new_vertex=False)
    assert len(drive.store.tries) == tries


def test_a_session_inside_a_memory_gets_a_home_of_its_own_and_the_homes_outlive_the_run():
    first = HomeProposer(HomeConfig(length_m=0.0))
    drive = _Drive(first)
    for _ in range(4):
        drive.frame()
    assert first._homes == [0]
    second = HomeProposer(HomeConfig(length_m=0.0))
    second.restore_state(first.export_state())
    assert second._homes == [0] and not second._pending
    drive.proposer = second
    drive.map.unjoined_from = 4  # the new session has not yet joined the memory: it proposes nothing
    assert drive.frame(new_vertex=True).closure is None and drive.store.tries == []
    assert second._homes == [0, 4]  # where the session began is its home
    drive.map.unjoined_from = None
    drive.frame()
    assert second._homes == [0, 4]
    # A damaged state starts fresh instead of failing.
    fresh = HomeProposer()
    fresh.restore_state({"vertices": np.array([1, 2])})
    assert fresh._homes == [] and fresh._pending


class _Resumed:
    """A loaded map as a resumed run sees it: its odometer where the saved run stopped."""

    def __init__(self, experience_map, odometer_m: float) -> None:
        self.experience_map, self.odometer_m = experience_map, odometer_m

    def __len__(self) -> int:
        return len(self.experience_map)

    def __getattr__(self, name):
        return getattr(self.experience_map, name)


def test_a_map_made_without_home_gives_every_session_its_home_from_the_map():
    # A memory saved before `home` existed (or by a chain without it) holds no home: the homes are read from the
    # map at the first frame — each session's first vertex (no odometry link leads to it) and those within
    # `length_m` of travel after it. Without that a resumed run took its first new vertex, wherever it was, for home.
    experience_map = new_experience_map()
    sessions = [(0.0, 8), (200.0, 6)]  # (odometer at a session's first vertex, vertices), a vertex a 2 m
    for start_m, count in sessions:
        first = len(experience_map)
        for i in range(count):
            vertex = experience_map.add_vertex(0, (0.0, 0.0), 0.0, (2.0 * i, start_m, 0.0), start_m + 2.0 * i)
            if i > 0:
                experience_map.add_link(vertex - 1, vertex, (2.0, 0.0, 0.0), 0.2)
        if first > 0:  # the second session joined the first by a closure: a loop link, not odometry
            experience_map.add_link(first, 2, (0.0, 0.0, 0.0), 0.0, is_loop=True)
    proposer = HomeProposer(HomeConfig(length_m=5.0))
    resumed = _Resumed(experience_map, odometer_m=212.0)
    context = ClosureContext(None, (1.0, 0.0, 0.0), None, resumed, _Store())  # type: ignore[arg-type]
    proposer.propose(context)
    assert proposer._homes == [0, 1, 2, 8, 9, 10]
    assert not proposer._pending and proposer._home_odometer_m == 200.0
    # The run goes on (resumed): its next vertex is not home.
    proposer.after_map(SimpleNamespace(created=True, vertex=14, loop_closure=None))  # type: ignore[arg-type]
    assert proposer._homes == [0, 1, 2, 8, 9, 10]
    # A saved state wins over the map, and an empty map reads nothing.
    restored = HomeProposer()
    restored.restore_state(proposer.export_state())
    restored.propose(context)
    assert restored._homes == [0, 1, 2, 8, 9, 10]
    fresh = HomeProposer()
    fresh.propose(ClosureContext(None, (1.0, 0.0, 0.0), None, new_experience_map(), _Store()))  # type: ignore[arg-type]
    assert fresh._homes == [] and fresh._pending


@pytest.mark.slow
@pytest.mark.parametrize("with_home", [True, False])
def test_a_drive_back_home_closes_through_drift_the_proximity_ring_does_not_reach(demo, tmp_path, with_home):
    # The demo drives a 190 m loop and goes on past its start. Its odometry slides 18 m sideways over frames 80-120
    # (0.45 m a frame, as a VO that misreads its lateral motion), then follows the truth: back home (frame 131) and on
    # over the first lap's road it puts each place 18 m away, beyond the proximity ring (8 m + 1 % of the path) and inside the map's gate (10 m
    # + 10 %). The view cells are left out of the chain: another look would not be recognised.
    truth = demo.ground_truth()
    drifted = truth.copy()
    drifted[:, 0, 3] += 18.0 * np.clip((np.arange(len(truth)) - 80) / 40.0, 0.0, 1.0)
    home_from_return = np.linalg.norm(drifted[131, [0, 2], 3] - drifted[0, [0, 2], 3])
    assert 12.0 < home_from_return < 25.0, home_from_return
    replay = ReplayOdometry(write_kitti_poses(tmp_path / "odometry.txt", drifted), demo)
    proposers = ["relocalisation", "proximity"] + (["home"] if with_home else [])
    config = config_from_dict(
        {"output": {"figures": False, "save_map": False}, "parts": {"closure": proposers}}
    )
    metrics = Pipeline(demo, config, odometry=replay).run(None).metrics
    quality, errors = metrics["closure_quality"], metrics["errors"]
    if not with_home:
        assert quality["closures"] == 0, quality
        return
    assert quality["closures"] >= 1 and quality["false_closures"] == 0, quality
    assert metrics["closure_attempts"].get("accepted_home", 0) >= 1, metrics["closure_attempts"]
    assert errors["corrected"]["ate_2d_m"] < 0.5 * errors["vo"]["ate_2d_m"], errors
