"""Retracing a lost stretch (`closure.relocalisation.retrace`): when a session joins its loaded map, the part
it drove while lost is tied to the loaded map wherever it passed known ground, not only at the joining frame.

A session that starts inside a loaded map drives lost until relocalisation is confirmed (`relocalisation.py`);
the map then moves the session's part rigidly so that the joining closure holds (docs/map.md "Sessions"). That
part is a chain hanging from one link: its odometry's drift, measured back from the join, is never corrected,
and where the lost stretch passed day 1's places before they were recognised (the first frames of a drive
that goes on from where day 1 stopped; known streets driven before two measurements agreed), it lies metres
beside them (on the 00 render from frame 2500: day 2's first vertex 2.1 m and 0.04 rad from day 1's last).

At the join each vertex of the lost stretch (nearest the join first, one per `spacing_m` of its travel) is
measured against the loaded vertices the moved chain puts within reach: `radius_m` at the join, growing by
`radius_per_m` of the travel back along the chain (the drift that moved it), at most `max_radius_m`, facing
within `max_heading_rad`. Both are stored keyframes (`KeyframeStore`): the session vertex's keyframe plays the
current frame. A measurement counts at the closure's own bar (`closure.min_inliers`), or at `min_inliers`
when a path neighbour of the loaded vertex confirms it (`KeyframeStore.confirmed`), as proximity closures are
checked. The measured links are then tried in the pose graph together with the joining closure: one whose χ²
after the solve exceeds the map's `max_loop_chi2` is dropped (and the rest solved again), as the map refuses an
inconsistent closure. The links that hold become loop links, and the map is corrected once.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field

import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection
from hippo_nav.closure.store import KeyframeStore
from hippo_nav.geometry import se2_between, wrap_angle
from hippo_nav.map import ExperienceMap, PoseGraph

log = logging.getLogger("hippo_nav.pipeline")

__all__ = ["RetraceConfig", "RetraceReport", "retrace_lost_stretch"]


class RetraceConfig(ConfigSection):
    """`closure.relocalisation.retrace`: how the lost stretch is tied to the loaded map at the join."""

    model_config = ConfigDict(frozen=True)

    max_links: int = Field(
        40, ge=0, le=10_000, description="most links the lost stretch gets at the join (0: no retrace)"
    )
    spacing_m: float = Field(
        4.0, gt=0.0, description="the lost stretch's travel between two of its vertices that get a link"
    )
    radius_m: float = Field(
        5.0,
        gt=0.0,
        description="a loaded vertex is measured when the moved chain puts it this close at the join "
        "(`closure.max_distance_m` plus a vertex spacing)",
    )
    radius_per_m: float = Field(
        0.03,
        ge=0.0,
        description="… plus this share of the travel back along the chain from the join (the odometry's "
        "drift, about 1 %, times a margin)",
    )
    max_radius_m: float = Field(30.0, gt=0.0, description="the reach never exceeds this")
    max_heading_rad: float = Field(
        0.5, gt=0.0, le=np.pi, description="the two keyframes' cameras face within this of each other"
    )
    tries_per_vertex: int = Field(
        2, ge=1, le=20, description="loaded vertices measured per lost vertex, nearest first"
    )
    min_inliers: int = Field(
        15,
        ge=6,
        le=20000,
        description="PnP inliers a confirmed link needs; below `closure.min_inliers` a path neighbour of the "
        "loaded vertex must confirm it",
    )


@dataclass
class RetraceReport:
    """What the retrace did: lost vertices looked at, measured pairs, links kept and dropped by χ²."""

    lost_vertices: int = 0
    measured: int = 0
    links: int = 0
    dropped_inconsistent: int = 0
    pairs: list[tuple[int, int]] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        return {
            "lost_vertices": self.lost_vertices,
            "measured": self.measured,
            "links": self.links,
            "dropped_inconsistent": self.dropped_inconsistent,
        }


@dataclass(frozen=True)
class _Link:
    lost: int
    loaded: int
    lost_from_loaded: np.ndarray  # (3,) planar
    information: np.ndarray  # (3, 3)


def _chain_travel_m(poses: np.ndarray, first: int, joined: int) -> np.ndarray:
    """Travel along the chain first..joined back from `joined` (0 there), per vertex first..joined."""
    steps = np.hypot(*np.diff(poses[first : joined + 1, :2], axis=0).T)
    back = np.concatenate([np.cumsum(steps[::-1])[::-1], [0.0]])
    return back


def _measure_pairs(
    experience_map: ExperienceMap,
    store: KeyframeStore,
    first: int,
    joined: int,
    config: RetraceConfig,
    report: RetraceReport,
) -> list[_Link]:
    """The links measured between the lost stretch's vertices and the loaded map (module doc)."""
    poses = np.asarray(experience_map.poses(), np.float64)
    loaded = poses[:first]
    travel = _chain_travel_m(poses, first, joined)
    bar = store.config.min_inliers
    links: list[_Link] = []
    last_linked_m = -np.inf
    for lost in range(joined - 1, first - 1, -1):
        if len(links) >= config.max_links:
            break
        back_m = float(travel[lost - first])
        if back_m - last_linked_m < config.spacing_m:
            continue
        report.lost_vertices += 1
        reach = min(config.max_radius_m, config.radius_m + config.radius_per_m * back_m)
        distance = np.hypot(*(loaded[:, :2] - poses[lost, :2]).T)
        facing = np.abs(wrap_angle(loaded[:, 2] - poses[lost, 2])) <= config.max_heading_rad
        near = np.array(store.keyframed(np.flatnonzero((distance <= reach) & facing).tolist()), np.int64)
        if len(near) == 0:
            continue
        current = store.keyframe(lost)
        if current is None:
            continue
        for target in near[np.argsort(distance[near])][: config.tries_per_vertex].tolist():
            if store.keyframe(target) is None:
                continue
            measurement, _ = store.measure(target, current, config.min_inliers)
            if measurement is None:
                continue
            report.measured += 1
            measured = np.asarray(measurement.agent_from_target, np.float64)
            predicted = se2_between(poses[lost], poses[target])
            off = se2_between(predicted, measured)
            if np.hypot(off[0], off[1]) > reach or abs(off[2]) > config.max_heading_rad:
                continue
            if measurement.inliers < bar:
                ok, _ = store.confirmed(experience_map, target, measurement, current, "retrace")
                if not ok:
                    continue
            links.append(_Link(lost, target, measured, np.asarray(measurement.information, np.float64)))
            last_linked_m = back_m
            break
    return links


def _edge_chi2(a: np.ndarray, b: np.ndarray, link: _Link) -> float:
    """χ² of one link at poses a (lost vertex) and b (loaded vertex), as the map computes it."""
    graph = PoseGraph.from_arrays(
        np.stack([a, b]),
        np.array([[0, 1]], np.int64),
        link.lost_from_loaded[None, :],
        link.information[None, :, :],
        np.array([True]),
    )
    return float(graph.chi2())


def _consistent(experience_map: ExperienceMap, links: list[_Link], max_chi2: float) -> list[_Link]:
    """The links that hold after solving the map's graph with them (dropping the worst until all do)."""
    graph = experience_map.pose_graph()
    poses, edges = np.asarray(graph.poses()), np.asarray(graph.edges())
    measurements, information = np.asarray(graph.measurements()), np.asarray(graph.information())
    is_loop = np.asarray(graph.is_loop())
    kept = list(links)
    while kept:
        trial = PoseGraph.from_arrays(
            poses,
            np.concatenate([edges, np.array([[k.lost, k.loaded] for k in kept], np.int64)]),
            np.concatenate([measurements, np.stack([k.lost_from_loaded for k in kept])]),
            np.concatenate([information, np.stack([k.information for k in kept])]),
            np.concatenate([is_loop, np.ones(len(kept), bool)]),
        )
        trial.optimize(initialization="current")
        solved = np.asarray(trial.poses())
        chi2 = [_edge_chi2(solved[k.lost], solved[k.loaded], k) for k in kept]
        worst = int(np.argmax(chi2))
        if not np.isfinite(chi2[worst]) or chi2[worst] > max_chi2:
            kept.pop(worst)
            continue
        return kept
    return []


def retrace_lost_stretch(
    experience_map: ExperienceMap, store: KeyframeStore, first: int, joined: int, config: RetraceConfig
) -> RetraceReport:
    """Tie the lost stretch (vertices `first` … `joined` − 1; `joined`: the vertex the joining closure made)
    to the loaded map (vertices before `first`) where it passed known ground, and correct the map (module doc)."""
    report = RetraceReport()
    if config.max_links == 0 or not 0 < first < joined <= len(experience_map) - 1:
        return report
    links = _measure_pairs(experience_map, store, first, joined, config, report)
    if not links:
        return report
    max_chi2 = float(json.loads(experience_map.params_json())["max_loop_chi2"])
    kept = _consistent(experience_map, links, max_chi2)
    report.dropped_inconsistent = len(links) - len(kept)
    for link in kept:
        experience_map.add_link(
            link.lost, link.loaded, tuple(link.lost_from_loaded), 0.0, True, link.information
        )
        report.pairs.append((link.lost, link.loaded))
    report.links = len(kept)
    if kept:
        experience_map.correct(method="least_squares", initialization="current")
    log.info("retrace of the lost stretch at the join: %s", report.as_dict())
    return report
