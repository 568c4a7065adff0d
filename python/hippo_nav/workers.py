"""Where a part may hand work that need not finish before the next frame: a `Worker`.

The per-frame system never starts threads. A part that has slow work whose result is needed only later
(a new vertex's stereo keyframe is first used when the agent comes back) submits it to the worker the
runner gives it: the front end's slow-work thread when the front end runs ahead (`overlap_front_end`), else
`InlineWorker`, which does the work at once. Either way the work gets the same inputs and gives the same
result, so the threads never change the numbers.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, Protocol, TypeVar

T = TypeVar("T")

__all__ = ["INLINE", "InlineWorker", "Worker"]


class Worker(Protocol):
    def submit(self, work: Callable[..., T], *args: Any) -> Future[T]:
        """Run `work(*args)` (now or later, in the order submitted); the future holds its result or error."""
        ...


class InlineWorker:
    """A `Worker` that runs the work at once on the calling thread."""

    def submit(self, work: Callable[..., T], *args: Any) -> Future[T]:
        done: Future[T] = Future()
        try:
            done.set_result(work(*args))
        except Exception as err:  # noqa: BLE001 - handed to whoever reads the future, as a thread would
            done.set_exception(err)
        return done


INLINE = InlineWorker()
"""The worker of a system run without a front end thread."""
