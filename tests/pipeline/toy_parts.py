"""A view descriptor and a closure proposer of a user's own, each in this one module and plugged in by one
registry line (`test_plug_points.py`): what docs/architecture.md promises a newcomer."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from hippo_nav._defaults import ConfigSection
from hippo_nav.closure import NO_ATTEMPT, ClosureAttempt, ClosureContext, ProposedClosure
from hippo_nav.view_cells import Observation
from pydantic import Field


class ThumbnailConfig(ConfigSection):
    width_px: int = Field(24, ge=4, le=256)
    threshold: float = Field(0.45, gt=0.0)


class ThumbnailCells:
    """Views as 8 × width normalised thumbnails, matched by mean absolute difference; Persistent."""

    describe_on_worker = True

    def __init__(self, config: ThumbnailConfig, calibration: Any) -> None:
        self.config, self.thumbnails = config, []

    def describe(self, frame):
        small = cv2.resize(frame.left, (self.config.width_px, 8), interpolation=cv2.INTER_AREA)
        small = small.astype(np.float32)
        return (small - small.mean()) / (small.std() + 5.0)

    def observe(self, description, candidates=None, recent=None):
        recent_ids = set() if recent is None else {int(c) for c in np.asarray(recent).reshape(-1)}
        pool = range(len(self.thumbnails)) if candidates is None else sorted(set(map(int, candidates)))
        scored = [(float(np.abs(self.thumbnails[i] - description).mean()), i) for i in pool]
        old = [s for s in scored if s[1] not in recent_ids]
        best = min(old or scored, default=None)
        if best is not None and best[0] < self.config.threshold:
            return Observation("familiar", best[1], best[0])
        self.thumbnails.append(description)
        return Observation("new", len(self.thumbnails) - 1, 1.0 if best is None else best[0])

    def __len__(self) -> int:
        return len(self.thumbnails)

    def image_rows(self, height_px):
        return None

    def depends_on(self) -> dict[str, object]:
        return {"width_px": self.config.width_px}

    def export_state(self) -> dict[str, np.ndarray]:
        return {"thumbnails": np.array(self.thumbnails, np.float32).reshape(-1, 8, self.config.width_px)}

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        self.thumbnails = list(saved["thumbnails"])


class NearestVertexConfig(ConfigSection):
    radius_m: float = Field(6.0, gt=0.0)
    min_inliers: int = Field(20, ge=6)


class NearestVertexProposer:
    """Measures the gated vertex nearest to where the odometry puts the agent; Persistent (it counts what it
    proposed, so a resumed run goes on counting)."""

    def __init__(self, config: NearestVertexConfig) -> None:
        self.config, self.proposed = config, 0

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        if context.lost or not context.spaced:
            return NO_ATTEMPT
        experience_map, step = context.experience_map, context.planar_step
        near = experience_map.vertices_near(self.config.radius_m, step)
        gated = experience_map.loop_candidates(near, step) if near else []
        if not gated:
            return NO_ATTEMPT
        current, why = context.keyframes.current()
        if current is None:
            return ClosureAttempt(None, why)
        vertex = int(gated[0][0])
        measurement, why = context.keyframes.measure(vertex, current, self.config.min_inliers)
        if measurement is None:
            return ClosureAttempt(None, f"nearest_{why}")
        self.proposed += 1
        closure = ProposedClosure(vertex, measurement.agent_from_target, measurement.information, "nearest")
        return ClosureAttempt(closure, "measured")

    def after_map(self, outcome) -> None:
        pass

    def depends_on(self) -> dict[str, object]:
        return {}

    def export_state(self) -> dict[str, np.ndarray]:
        return {"proposed": np.array(self.proposed)}

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        self.proposed = int(saved["proposed"])
