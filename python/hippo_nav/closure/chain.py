"""The closure chain: the configured proposers (`parts.closure`, in order) over one keyframe store.

Per frame the chain asks each proposer in turn (`base.ClosureProposer.propose`); the first closure proposed is
the frame's, and the later proposers are not asked. A frame without a closure is noted with the last note a
proposer gave (the most specific reason: the last proposer that tried). A proposer can be added, removed or
reordered in the config without touching another. Closures are at least `closure.spacing_m` of travel apart
(`ClosureContext.spaced`: the proposers that close loops respect it; relocalisation, which joins a session to
its loaded map, does not).

Saved state (`Persistent`): the store's keyframes, the odometer at the last accepted closure, and each
proposer's own state under its name (`proximity.ring_turn`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hippo_nav.closure.base import ClosureAttempt, ClosureContext, ClosureProposer
from hippo_nav.closure.store import KeyframeStore
from hippo_nav.datasets.base import StereoFrame
from hippo_nav.map import ExperienceMap, MapFrameOutcome
from hippo_nav.plugs import Persistent
from hippo_nav.workers import Worker

__all__ = ["ClosureChain"]

# Keys of memories saved before the proposers had names of their own (`restore_state`).
_UNNAMED_STATE = {"ring_turn": "proximity.ring_turn", "hypotheses": "relocalisation.hypotheses"}
_STORE_KEYS = ("vertex", "count", "pixels_px", "descriptors", "points_m")
_STORE_OPTIONAL = ("last_keyframe_odometer_m",)  # absent from memories saved before it existed


class ClosureChain:
    """Named proposers, asked in order, over one keyframe store (module doc)."""

    def __init__(self, store: KeyframeStore, proposers: Sequence[tuple[str, ClosureProposer]]) -> None:
        names = [name for name, _ in proposers]
        if len(set(names)) != len(names):
            raise ValueError(f"closure proposers named twice: {names}")
        self.store = store
        self.proposers = list(proposers)
        self._closure_odometer_m = -np.inf  # where the last accepted closure was
        self._proposed = False  # whether this frame proposed a closure

    @property
    def names(self) -> list[str]:
        return [name for name, _ in self.proposers]

    def proposer(self, name: str) -> ClosureProposer | None:
        """The proposer configured under `name`, or None when the chain has none of that name."""
        return next((proposer for own, proposer in self.proposers if own == name), None)

    def propose(
        self,
        frame: StereoFrame,
        planar_step: tuple[float, float, float],
        anchor_vertex: int | None,
        experience_map: ExperienceMap,
        disparity_offset_px: float | None = None,
    ) -> ClosureAttempt:
        """The frame's closure: the first proposer's that proposes one (module doc). `anchor_vertex`: where
        the frame's familiar view was first seen; `disparity_offset_px`: the odometry's stereo correction now
        (None: the configured one), which this frame's keyframe applies too."""
        self.store.begin_frame(frame, disparity_offset_px)
        odometer = experience_map.odometer_m
        context = ClosureContext(
            frame,
            planar_step,
            anchor_vertex,
            experience_map,
            self.store,
            spaced=odometer - self._closure_odometer_m >= self.store.config.spacing_m,
        )
        self._proposed = False
        note = ""
        for _, proposer in self.proposers:
            attempt = proposer.propose(context)
            if attempt.closure is not None:
                self._proposed = True
                return attempt
            note = attempt.note or note
        return ClosureAttempt(None, note)

    def after_map(
        self, frame: StereoFrame, outcome: MapFrameOutcome, experience_map: ExperienceMap, worker: Worker
    ) -> None:
        """The map has taken the frame: an accepted closure restarts the spacing; a new vertex keeps this
        frame's keyframe (the store); each proposer is told."""
        if self._proposed and outcome.loop_closure is not None:
            self._closure_odometer_m = experience_map.odometer_m
        self.store.after_map(frame, outcome, worker, experience_map.odometer_m)
        for _, proposer in self.proposers:
            proposer.after_map(outcome)

    def finish(self) -> None:
        """Wait for keyframes still being extracted."""
        self.store.finish()

    @property
    def stored(self) -> int:
        """How many vertices keep a keyframe."""
        return len(self.store)

    @property
    def stored_bytes(self) -> int:
        return self.store.stored_bytes

    @property
    def extractions(self) -> dict[str, int]:
        """The keyframes extracted this run, by whom (`KeyframeStore.extractions`)."""
        return self.store.extractions

    # -- Persistent -----------------------------------------------------------------------------------
    def depends_on(self) -> dict[str, object]:
        """What the saved keyframes depend on (the proposers keep no settings a memory depends on)."""
        return self.store.depends_on()

    def export_state(self) -> dict[str, np.ndarray]:
        state = self.store.export_state()
        state["closure_odometer_m"] = np.array(self._closure_odometer_m)
        for name, proposer in self.proposers:
            if isinstance(proposer, Persistent):
                state.update({f"{name}.{k}": v for k, v in proposer.export_state().items()})
        return state

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        """The state of `export_state`; a proposer whose state the memory lacks starts fresh."""
        saved = {_UNNAMED_STATE.get(k, k): v for k, v in saved.items()}
        self.store.restore_state({k: saved[k] for k in _STORE_KEYS + _STORE_OPTIONAL if k in saved})
        self._closure_odometer_m = float(saved["closure_odometer_m"])
        for name, proposer in self.proposers:
            own = {k[len(name) + 1 :]: v for k, v in saved.items() if k.startswith(f"{name}.")}
            if own and isinstance(proposer, Persistent):
                proposer.restore_state(own)
