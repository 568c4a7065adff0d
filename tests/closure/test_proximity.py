"""The proximity ring reaches each vertex as far as the odometry that relates it to the agent can have drifted:
`radius_m + radius_per_m · path`, the path through the map's links, at most `max_radius_m`."""

from __future__ import annotations

from types import SimpleNamespace

from hippo_nav.closure.proximity import ProximityConfig, ProximityProposer


class _Map:
    """Gated vertices as `(vertex, predicted_agent_from_vertex, distance_m, path_m)`, nearest first."""

    def __init__(self, candidates):
        self.candidates = candidates
        self.radii: list[float] = []

    def vertices_near(self, radius_m, step):
        self.radii.append(radius_m)
        return [c[0] for c in self.candidates if c[2] <= radius_m]

    def loop_candidates(self, vertices, step):
        return [c for c in self.candidates if c[0] in vertices]


def _measured_over(frames: int, candidates) -> tuple[set[int], list[float]]:
    proposer = ProximityProposer(ProximityConfig(radius_m=8.0, radius_per_m=0.01, max_radius_m=50.0))
    experience_map = _Map(candidates)
    every_vertex_keyframed = SimpleNamespace(keyframed=list)
    context = SimpleNamespace(
        experience_map=experience_map, planar_step=(0.0, 0.0, 0.0), keyframes=every_vertex_keyframed
    )
    chosen = {v for _ in range(frames) for v in proposer._candidates(context)}
    return chosen, experience_map.radii


def test_the_ring_reaches_each_vertex_as_far_as_the_path_to_it_allows():
    ahead = (0.0, 0.0, 0.0)
    candidates = [
        (1, ahead, 5.0, 60.0),  # within the radius: always measured first
        (2, ahead, 20.0, 100.0),  # 100 m of map between: it can be 9 m off, not 20
        (3, ahead, 20.0, 2000.0),  # 2 km of map between (a closure elsewhere since): 28 m
        (4, ahead, 45.0, 20_000.0),  # 20 km: capped at 50 m
        (5, ahead, 60.0, 20_000.0),  # beyond the cap
        (6, (0.0, 0.0, 3.0), 20.0, 2000.0),  # passed the other way: a forward camera sees nothing of it
    ]
    chosen, radii = _measured_over(6, candidates)
    assert chosen == {1, 3, 4}
    assert radii and all(r == 50.0 for r in radii)  # asked once a frame, out to the cap
