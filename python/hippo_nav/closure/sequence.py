"""Closures from a sequence of views (`"sequence"`): a revisit recognised by the last `length` views along the
odometry's path matching a stretch of an earlier pass, inside a search region that grows with the odometry
that relates the agent to each place (the path through the map), then measured (SIFT + PnP) and confirmed like a proximity closure.

Why sequences, and why edges. Under another sun, with moved cars and another lane (the `strong` renders), no
single view points at the place: the word cells recognise almost nothing and the paper's templates rank the true
place among unrelated ones (docs/views.md, "Sequences of views"). What survives is the layout of the scene's
edges (façade corners, windows, the kerb's vanishing lines): light and texture change, the geometry does not.
One view's edge layout is a weak clue; thirty metres of them, compared in order, add up. The views are
sampled by distance (every `sample_spacing_m` of odometry), so two passes at different speeds give sequences of
the same length. The neural reading is the familiar-sequence account of hippocampal recall: a sequence of
views integrated over travel as the attractor integrates motion.

The descriptor (`edge_layout`): the left image at 320 columns, its upper `rows_frac` rows (façades, not the
road), contrast-stretched, Canny edges blurred by 3 px, shrunk to 64 × 16. Two descriptors are compared by the
cosine of their differences from the mean of every stored one: the edge layout every street shares (the road's
vanishing lines) is removed. Without that, on the 06 render at `strong`, the true place was among the three best
matches for 0.17 of the revisits instead of 0.47.

The search. Samples whose vertex the map's loop gate admits and that the odometry puts within
`radius_m + radius_per_m · path` (at most `max_radius_m`), `path` the shortest path through the map's links
from the agent to the vertex (the odometry that relates the two, docs/map.md "Search by path"), are scored by
the mean distance of their last `length` descriptors to the current ones, raised by `prior_weight` × (the
sample's distance from the prediction / its search radius)²; the best `shortlist` vertices are kept. The region
is wide because a biased odometry can put a revisit 4-9 % of the path away; the prior is what keeps a wide
region from being won by look-alikes at its edge: the score is a negative log-posterior, the views' evidence
plus the odometry's (a Gaussian whose two deviations are the radius, at the views' temperature 0.1).
Each of them votes for a drift of the odometry (where the map has that vertex, less where the odometry puts the
agent), weighted by its rank; votes within 4 m add up and fade by 0.85 a sample, so a drift that sample after
sample agrees with the views outweighs the scattered look-alikes. Nothing is measured until the best-supported
drift has `min_support`: a measurement needs this frame's SIFT keyframe, most of the proposer's cost, and where
the views agree on no drift it bought nothing (docs/results.md, "Lost loops: sequences of views"). Each frame
measures, `candidates_per_frame` in all, the gated vertex nearest to where the best-supported drift puts the
agent now, then the last sample's best matches in turn, at the proximity proposer's bar (`min_inliers`),
confirmed by a path neighbour (`closure.confirm`): the views only choose what to measure; the measurement and
the map's χ² check decide. An
accepted closure (from any proposer) clears the votes: the map they were measured against has moved. Noted
`accepted_sequence`; refused, `sequence_unconfirmed` or `sequence_disagrees` (from the confirmation) or the
measurement's reason.
"""

from __future__ import annotations

import cv2
import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection
from hippo_nav.closure.base import NO_ATTEMPT, ClosureAttempt, ClosureContext, ProposedClosure
from hippo_nav.geometry import se2_compose
from hippo_nav.map import MapFrameOutcome

__all__ = ["SequenceConfig", "SequenceProposer", "edge_layout"]

_WIDTH_PX = 320  # the image is described at this width, whatever the camera's
_LAYOUT = (64, 16)  # (columns, rows) of the descriptor
_CANNY = (50, 150)
_BLUR_PX = 3.0
_STRETCH_PERCENT = (2.0, 98.0)
_VOTE_DECAY = 0.85  # a hypothesis's support fades by this a sample (about 13 samples, 26 m, to a quarter)
_MIN_SUPPORT = 0.05
_CLUSTER_M = 4.0  # votes this close are one hypothesis
_TARGET_M = 6.0  # a hypothesis measures the vertex nearest to where it puts the agent, when this close


def edge_layout(gray: np.ndarray, rows_frac: float = 0.625) -> np.ndarray:
    """The descriptor of a gray image (module doc): (1024,) float32, the blurred edge map's layout."""
    height, width = gray.shape
    height_px = max(16, round(height * _WIDTH_PX / width))
    small = cv2.resize(gray, (_WIDTH_PX, height_px), interpolation=cv2.INTER_AREA)
    top = small[: max(16, round(rows_frac * height_px))].astype(np.float32)
    # Contrast stretched (2nd-98th percentile to 0-255) so that Canny's fixed thresholds see the same edges
    # in a darker or flatter light.
    low, high = np.percentile(top, _STRETCH_PERCENT)
    stretched = np.clip((top - low) * (255.0 / max(high - low, 1.0)), 0.0, 255.0).astype(np.uint8)
    edges = cv2.Canny(stretched, *_CANNY).astype(np.float32)
    blurred = cv2.GaussianBlur(edges, (0, 0), _BLUR_PX)
    return cv2.resize(blurred, _LAYOUT, interpolation=cv2.INTER_AREA).ravel()


class SequenceConfig(ConfigSection):
    """`closure.sequence`: how views are sampled, how long a sequence is, where it is searched."""

    model_config = ConfigDict(frozen=True)

    sample_spacing_m: float = Field(
        2.0, gt=0.0, description="odometry travel between two views of a sequence (m)"
    )
    length: int = Field(
        15, ge=1, le=200, description="views compared in order (`length` × `sample_spacing_m` of road)"
    )
    rows_frac: float = Field(
        0.625, gt=0.1, le=1.0, description="upper share of the image described (the road below changes lane)"
    )
    shortlist: int = Field(
        6, ge=1, le=100, description="best-matching vertices measured until the next view is sampled"
    )
    candidates_per_frame: int = Field(2, ge=1, le=20, description="of those, measured per frame at most")
    radius_m: float = Field(10.0, gt=0.0, description="search radius around the odometry's prediction (m)")
    radius_per_m: float = Field(
        0.1,
        ge=0.0,
        description="growth of a vertex's search radius per metre of the path through the map from the agent "
        "to it (an odometry 1 % long and 0.02° a frame off puts the renders' revisits 4-9 % of the path away)",
    )
    max_radius_m: float = Field(150.0, gt=0.0, description="the search reaches at most this far (m)")
    prior_weight: float = Field(
        0.2,
        ge=0.0,
        le=10.0,
        description="a candidate's sequence distance is raised by this × (its distance from the odometry's "
        "prediction / its search radius)²: the odometry's prior against look-alikes far out in a wide region "
        "(0: every candidate in the region equal)",
    )
    min_support: float = Field(
        3.0,
        ge=0.0,
        description="nothing is measured until the best-supported drift has this much support (the votes' "
        "weights, 1 / rank a sample, fading by 0.85 a sample; one sample's six best matches give 2.45): the "
        "views must agree over several samples before a keyframe is extracted to measure them (0: measure "
        "the shortlist whatever the votes)",
    )
    min_inliers: int = Field(
        15, ge=6, le=20000, description="PnP inliers a measurement needs (as `closure.proximity.min_inliers`)"
    )
    confirm: bool = Field(
        True,
        description="a measurement is proposed only when a path neighbour confirms it (`closure.confirm`)",
    )


class SequenceProposer:
    """Closures onto places whose sequence of views matches the last ones (module doc)."""

    def __init__(self, config: SequenceConfig | None = None) -> None:
        self.config = config if config is not None else SequenceConfig()
        cfg = self.config
        # Every sampled view's descriptor, the map's vertex then and the odometer, in buffers that double when
        # full (the first `_count` rows are the views).
        self._count = 0
        self._descriptors = np.zeros((64, _LAYOUT[0] * _LAYOUT[1]), np.float32)
        self._vertex = np.zeros(64, np.int64)
        self._odometer_m = np.zeros(64, np.float64)
        self._sum = np.zeros(_LAYOUT[0] * _LAYOUT[1], np.float64)  # for the mean descriptor
        self._next_sample_m = 0.0
        # Hypotheses of the odometry's drift (map-frame offset from where it puts the agent to where it is),
        # voted for by the sampled views' best matches.
        self._drift_xy = np.zeros((0, 2), np.float64)
        self._support = np.zeros(0, np.float64)
        self._shortlist: list[int] = []  # the last sample's best matches not yet measured, best first
        self._max_gap_m = 2.5 * cfg.sample_spacing_m  # a longer gap between views breaks a sequence

    def __len__(self) -> int:
        return self._count

    @property
    def _views(self) -> np.ndarray:
        return self._descriptors[: self._count]

    @property
    def _view_vertex(self) -> np.ndarray:
        return self._vertex[: self._count]

    @property
    def _view_odometer_m(self) -> np.ndarray:
        return self._odometer_m[: self._count]

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        experience_map = context.experience_map
        vertex = experience_map.current_vertex
        agent = experience_map.world_from_agent
        if vertex is None or agent is None:
            return NO_ATTEMPT
        predicted = se2_compose(np.asarray(agent), np.asarray(context.planar_step))
        sampling = experience_map.odometer_m >= self._next_sample_m
        if context.lost or not (sampling or context.spaced):
            if sampling:
                self._sample(context, vertex, predicted[:2], None)
            return NO_ATTEMPT
        region = self._region(context)
        if sampling:
            self._sample(context, vertex, predicted[:2], region)
        if not context.spaced:
            return NO_ATTEMPT
        targets = self._targets(context, predicted[:2], region)
        if not targets:
            return NO_ATTEMPT
        store = context.keyframes
        current, why = store.current()
        if current is None:
            return ClosureAttempt(None, why)
        why = "no_keyframe"
        for target in targets:
            measurement, why = store.measure_confirmed(
                experience_map, target, current, self.config.min_inliers, self.config.confirm, "sequence"
            )
            if measurement is None:
                continue
            closure = ProposedClosure(
                target, measurement.agent_from_target, measurement.information, "sequence"
            )
            return ClosureAttempt(closure, "measured")
        return ClosureAttempt(None, why)

    def _region(self, context: ClosureContext) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the vertices the loop gate admits within their search radius plus `_TARGET_M`, their distances
        from where the odometry puts the agent, their search radii): asked of the map once a frame."""
        cfg, experience_map = self.config, context.experience_map
        near = experience_map.vertices_near(cfg.max_radius_m + _TARGET_M, context.planar_step)
        gated = experience_map.loop_candidates(near, context.planar_step) if near else []
        vertices = np.array([int(c[0]) for c in gated], np.int64)
        distances_m = np.array([float(c[2]) for c in gated])
        # A closure pins the agent to the places near it only: a place far along the graph from the last
        # closure is still where the whole drift since then put it.
        path_m = np.array([float(c[3]) for c in gated])
        reach_m = np.minimum(cfg.radius_m + cfg.radius_per_m * path_m, cfg.max_radius_m)
        inside = distances_m <= reach_m + _TARGET_M
        return vertices[inside], distances_m[inside], reach_m[inside]

    def _targets(
        self,
        context: ClosureContext,
        predicted_xy: np.ndarray,
        region: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> list[int]:
        """The gated vertex nearest to where the best-supported drift puts the agent now (within `_TARGET_M`),
        then the last sample's best matches, `candidates_per_frame` in all, none measured yet this frame."""
        cfg, experience_map, store = self.config, context.experience_map, context.keyframes
        if cfg.min_support > 0.0 and (not len(self._support) or self._support.max() < cfg.min_support):
            return []
        gated = np.array(store.keyframed(region[0].tolist()), np.int64)
        if len(gated) == 0:
            return []
        xy = experience_map.poses()[gated, :2]
        targets: list[int] = []
        if len(self._support):
            # The best-supported drift: the vertex nearest to where it puts the agent now.
            best = int(np.argmax(self._support))
            gap = np.linalg.norm(xy - (predicted_xy + self._drift_xy[best]), axis=1)
            nearest = int(np.argmin(gap))
            vertex = int(gated[nearest])
            if (
                gap[nearest] <= _TARGET_M
                and vertex not in store.measured
                and store.keyframe(vertex) is not None
            ):
                targets.append(vertex)
        # Then the last sample's best matches in turn: the votes settle on one drift, which a street that
        # repeats can bias by a few vertices; these keep the other good matches measured.
        admitted = set(gated.tolist())
        while self._shortlist and len(targets) < cfg.candidates_per_frame:
            vertex = self._shortlist.pop(0)
            fresh = vertex in admitted and vertex not in targets and vertex not in store.measured
            if fresh and store.keyframe(vertex) is not None:
                targets.append(vertex)
        return targets

    def _sample(
        self,
        context: ClosureContext,
        vertex: int,
        predicted_xy: np.ndarray,
        region: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    ) -> None:
        """Keep this frame's view and, with `length` views behind it and a `region` to search (None: lost),
        shortlist the places it matches and let them vote."""
        cfg = self.config
        odometer = context.experience_map.odometer_m
        view = edge_layout(np.asarray(context.frame.left), cfg.rows_frac)
        if self._count == len(self._vertex):
            self._grow(2 * self._count)
        self._descriptors[self._count] = view
        self._vertex[self._count] = vertex
        self._odometer_m[self._count] = odometer
        self._count += 1
        self._sum += view
        self._next_sample_m = odometer + cfg.sample_spacing_m
        if region is None:
            return
        # Each sample votes for where its best matches say the odometry has drifted; older votes fade.
        self._support *= _VOTE_DECAY
        matches = self._search_region(region)
        self._shortlist = list(matches)
        if matches:
            vertex_xy = context.experience_map.poses()[matches, :2]
            for rank, xy in enumerate(vertex_xy):
                self._vote(xy - predicted_xy, 1.0 / (rank + 1))
        keep = self._support >= _MIN_SUPPORT
        self._drift_xy, self._support = self._drift_xy[keep], self._support[keep]

    def _vote(self, drift_xy: np.ndarray, weight: float) -> None:
        """Add `weight` to the hypothesis within `_CLUSTER_M` of `drift_xy` (moved to their weighted mean), or
        start one."""
        if len(self._support):
            gap = np.linalg.norm(self._drift_xy - drift_xy, axis=1)
            index = int(np.argmin(gap))
            if gap[index] <= _CLUSTER_M:
                total = self._support[index] + weight
                self._drift_xy[index] = (
                    self._drift_xy[index] * self._support[index] + drift_xy * weight
                ) / total
                self._support[index] = total
                return
        self._drift_xy = np.vstack([self._drift_xy, drift_xy[None]])
        self._support = np.append(self._support, weight)

    def _search_region(self, region: tuple[np.ndarray, np.ndarray, np.ndarray]) -> list[int]:
        """`_search` over the vertices of `region` within their own radius, each weighed by the odometry's prior
        (its distance from the prediction over its radius, squared)."""
        vertices, distances_m, reach_m = region
        inside = distances_m <= reach_m
        return self._search(vertices[inside], (distances_m[inside] / reach_m[inside]) ** 2)

    def _search(self, gated: np.ndarray, prior: np.ndarray) -> list[int]:
        """Among the `gated` vertices (the search region), the best sequence matches of the newest view, best
        first, `shortlist` of them; `prior` (per gated vertex, (offset / reach)²) is added × `prior_weight`."""
        cfg = self.config
        now = len(self._views) - 1
        if now + 1 < cfg.length or not self._contiguous(now) or len(gated) == 0:
            return []
        ends = np.flatnonzero(np.isin(self._view_vertex, gated))
        ends = ends[(ends >= cfg.length - 1) & (ends < now)]
        # Whole stretches only: no gap longer than `_max_gap_m` among the `length` views up to each end.
        gaps = np.r_[0, np.cumsum(np.diff(self._view_odometer_m) > self._max_gap_m)]  # gaps before view i
        ends = ends[gaps[ends] == gaps[ends - cfg.length + 1]]
        if len(ends) == 0:
            return []
        mean = self._sum / len(self._views)
        steps = np.arange(cfg.length)
        query = self._unit(self._views[now - steps] - mean)  # (length, d)
        # The stretches overlap (a region holds runs of consecutive views): each view is centred, normalised
        # and compared with the query's views once, and each stretch sums its diagonal of those cosines.
        index = ends[:, None] - steps[None]  # (ends, length)
        views, at = np.unique(index, return_inverse=True)
        cosines = self._unit(self._views[views] - mean) @ query.T  # (views, length)
        distance = 1.0 - cosines[at.reshape(index.shape), steps[None]].sum(axis=1) / cfg.length
        if cfg.prior_weight > 0.0:
            order = np.argsort(gated)
            at = order[np.searchsorted(gated, self._view_vertex[ends], sorter=order)]
            distance = distance + cfg.prior_weight * prior[at]
        ranked: list[int] = []
        for j in ends[np.argsort(distance, kind="stable")]:
            vertex = int(self._view_vertex[j])
            if vertex not in ranked:
                ranked.append(vertex)
            if len(ranked) == cfg.shortlist:
                break
        return ranked

    def _contiguous(self, end: int) -> bool:
        """Whether the `length` views up to `end` were sampled along one stretch of driving."""
        start = end - self.config.length + 1
        return bool(np.all(np.diff(self._view_odometer_m[start : end + 1]) <= self._max_gap_m))

    def _grow(self, capacity: int) -> None:
        for name in ("_descriptors", "_vertex", "_odometer_m"):
            old = getattr(self, name)
            new = np.zeros((capacity, *old.shape[1:]), old.dtype)
            new[: self._count] = old[: self._count]
            setattr(self, name, new)

    @staticmethod
    def _unit(vectors: np.ndarray) -> np.ndarray:
        norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
        return vectors / np.maximum(norm, 1e-9)

    def after_map(self, outcome: MapFrameOutcome) -> None:
        if outcome.loop_closure is not None:
            # The map has moved: the drift hypotheses, measured against it, no longer hold.
            self._drift_xy = np.zeros((0, 2), np.float64)
            self._support = np.zeros(0, np.float64)
            self._shortlist = []

    # Persistent: the sampled views (a later session recognises the earlier sessions' sequences).
    def depends_on(self) -> dict[str, object]:
        return {"rows_frac": self.config.rows_frac, "sample_spacing_m": self.config.sample_spacing_m}

    def export_state(self) -> dict[str, np.ndarray]:
        return {
            "views": self._views.astype(np.float16),
            "view_vertex": self._view_vertex,
            "view_odometer_m": self._view_odometer_m,
            "next_sample_m": np.array(self._next_sample_m),
        }

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        if not {"views", "view_vertex", "view_odometer_m", "next_sample_m"} <= saved.keys():
            return  # a damaged state: start fresh
        views = np.asarray(saved["views"], np.float32)
        if views.ndim != 2 or views.shape[1] != self._views.shape[1]:
            return  # another descriptor: start fresh
        vertex = np.asarray(saved["view_vertex"], np.int64)
        odometer_m = np.asarray(saved["view_odometer_m"], np.float64)
        if not (len(views) == len(vertex) == len(odometer_m)):
            return  # a damaged state: start fresh
        self._count = 0
        self._grow(max(64, len(views)))
        self._descriptors[: len(views)] = views
        self._vertex[: len(views)] = vertex
        self._odometer_m[: len(views)] = odometer_m
        self._count = len(views)
        self._sum = views.astype(np.float64).sum(axis=0)
        self._next_sample_m = float(saved["next_sample_m"])
