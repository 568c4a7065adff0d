"""What every view descriptor offers the system, and what it answers: the plug point of local view cells.

A *view descriptor* turns a camera frame into a description (`describe`) and matches it against the views
it has stored (`observe`): the answer is a `ViewObservation` — which cell (`cell_id`), whether it was `new`
(stored now), `familiar` (matched a stored cell) or `uninformative` (nothing to recognise, e.g. a blank
image; no cell), how far the best stored view was (`difference`: 0 identical, larger is less alike; a
descriptor that scores similarity reports `1 − score`), and how much the camera has turned since the
matched view was stored (`relative_heading_rad`, counter-clockwise positive; 0 when it cannot tell).

`describe` must depend on the frame alone (the images; the calibration is given when the descriptor is
made), so it may run ahead of the back end on the front end's loader thread: a descriptor says so with
`describe_on_worker = True` (e.g. ORB features, a few milliseconds a frame). `observe` runs on the back end,
in frame order, and may store the view; `candidates` restricts the match to those cell ids (the cells seen
near where the map puts the agent; None: every cell); `recent` names the candidates made on the passage
the agent is on (`view_search.passage_m`), which a descriptor may treat differently from older ones (a
revisit is a match to an older cell).

Cell ids are 0, 1, 2, … in the order cells are made. A frame with no cell (before the first informative
view, or an uninformative one) has `cell_id` None; where an integer column needs a value (`FrameRecord`,
`frames.csv`) it is `NO_VIEW_CELL`.

The built-in descriptors are the word view cells (`words.py`, the default) and the paper's patch-normalised
whole-image template (`template.py`); measured side by side in docs/views.md; adding one: docs/architecture.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Protocol, runtime_checkable

from hippo_nav.datasets.base import StereoFrame

__all__ = ["NO_VIEW_CELL", "Observation", "ViewDescriptor", "ViewObservation", "ViewStatus"]

ViewStatus = Literal["new", "familiar", "uninformative"]

NO_VIEW_CELL = -1
"""The view cell of a frame that has none, in integer columns (`FrameRecord.view_cell`, `frames.csv`)."""


@runtime_checkable
class ViewObservation(Protocol):
    """What one frame's view was (module doc). The template descriptor's is the native
    `hippo_nav._core.ViewObservation`; a descriptor written in Python can return an `Observation`."""

    @property
    def status(self) -> str: ...

    @property
    def cell_id(self) -> int | None: ...

    @property
    def is_new(self) -> bool: ...

    @property
    def difference(self) -> float: ...

    @property
    def relative_heading_rad(self) -> float: ...


@dataclass(frozen=True)
class Observation:
    """A `ViewObservation` as plain data."""

    status: ViewStatus
    cell_id: int | None
    difference: float
    relative_heading_rad: float = 0.0

    @property
    def is_new(self) -> bool:
        return self.status == "new"


class ViewDescriptor(Protocol):
    """Local view cells as the system drives them (module doc). `describe_on_worker`: whether `describe` may
    run on the front end's loader thread, ahead of the back end."""

    describe_on_worker: ClassVar[bool]

    def describe(self, frame: StereoFrame) -> Any: ...

    def observe(
        self,
        description: Any,
        candidates: Sequence[int] | None = None,
        recent: Sequence[int] | None = None,
    ) -> ViewObservation: ...

    def __len__(self) -> int: ...

    def image_rows(self, height_px: int) -> tuple[int, int] | None:
        """The image rows (top, bottom) the descriptor looks at, for viewers to outline; None: all of them."""
        ...
