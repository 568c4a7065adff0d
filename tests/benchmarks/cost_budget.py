"""What a frame costs, stage by stage (docs/results.md, "Cost"): the CPU budget of the pipeline.

Two measurements of the same sequence, interleaved round by round:
- **the budget by stage**: the pipeline with its stages one after another on the calling thread
  (`overlap_front_end` off, the libraries' own threads as they are), each stage timed by a wrapper around the
  functions that do it. A stage is charged only for the time outside the stages it calls (the innermost
  stage wins: the KLT inside the self-calibration is KLT), and the clock is the process's CPU time, so an
  engine's helper threads and a library's count where they run. `other` is what no stage claims (the loop,
  the frame records, numpy glue).
- **the pipeline as it runs**: the defaults, stages overlapped on their threads, unwrapped: its wall time a
  frame and the CPU of every thread a frame (`metrics.json` `timing.cpu_ms_per_frame`).

    python tests/benchmarks/cost_budget.py --kitti KITTI_ROOT [--sequence 06] [--rounds 3] [--config FILE]

`--config` adds sections to the defaults (e.g. bird's-eye closures on:
`{"parts": {"closure": ["relocalisation", "view_cell", "proximity", "home", "birdseye"]}}`). The median over the rounds
is printed as a Markdown table. Not a test (no assertions; pytest does not collect it).
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

# stage: (module, class or None, function) whose calls are the stage's work. Order = the table's rows.
STAGES: dict[str, list[tuple[str, str | None, str]]] = {
    "loading (image decoding)": [("hippo_nav.datasets.base", "StereoLoader", "__getitem__")],
    "VO: corner detection": [("hippo_nav.vo.matching", "ImageMatcher", "detect")],
    "VO: KLT (temporal and stereo)": [
        ("hippo_nav.vo.matching", "ImageMatcher", "track"),
        ("hippo_nav.vo.matching", "ImageMatcher", "track_back"),
        ("hippo_nav.vo.odometry", "StereoOdometry", "_match_right"),
    ],
    "VO: stereo check": [("hippo_nav.vo.matching", "ImageMatcher", "stereo_check")],
    "VO: match refinement": [("hippo_nav.vo.matching", "ImageMatcher", "refined")],
    "VO: PnP RANSAC": [("hippo_nav.vo.odometry", "StereoOdometry", "_track_and_pnp")],
    "VO: window": [("hippo_nav.vo.odometry", "StereoOdometry", "_keyframe")],
    "VO: self-calibration": [
        ("hippo_nav.vo.stereo_pair", "StereoPairWatch", "fit_tracks"),
        ("hippo_nav.vo.stereo_pair", "StereoPairWatch", "calibrate"),
    ],
    "VO: rest (pyramids, stereo refinement, checks)": [
        ("hippo_nav.vo.odometry", "StereoOdometry", "process")
    ],
    "views: description (words or template)": [
        ("hippo_nav.view_cells.words", "WordViewCells", "describe"),
        ("hippo_nav.view_cells.template", "TemplateViewCells", "describe"),
    ],
    "views: matching and recall": [("hippo_nav.system.slam", "SlamSystem", "_views")],
    "closure: proposers and measurement": [("hippo_nav.system.slam", "SlamSystem", "_propose_closure")],
    "networks (engine step, injection)": [("hippo_nav.system.slam", "SlamSystem", "_networks")],
    "keyframes (new vertices)": [("hippo_nav.closure.keyframes", "KeyframeExtractor", "__call__")],
    "map (vertices, links, correction)": [("hippo_nav.system.slam", "SlamSystem", "_experience_map")],
}


class StageClock:
    """Exclusive CPU time per stage: entering a stage pauses the one it was called from."""

    def __init__(self) -> None:
        self.cpu_s: dict[str, float] = defaultdict(float)
        self._stack: list[str] = []
        self._since = time.process_time()

    def _switch(self) -> None:
        now = time.process_time()
        if self._stack:
            self.cpu_s[self._stack[-1]] += now - self._since
        self._since = now

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        self._switch()
        self._stack.append(name)
        try:
            yield
        finally:
            self._switch()
            self._stack.pop()

    def wrap(self, name: str, function: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(function)
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.stage(name):
                return function(*args, **kwargs)

        return timed


@contextmanager
def instrumented(clock: StageClock) -> Iterator[None]:
    """Every stage's functions wrapped by `clock` for the duration; put back after."""
    import importlib

    originals = []
    for name, targets in STAGES.items():
        for module_name, class_name, function_name in targets:
            owner: Any = importlib.import_module(module_name)
            if class_name is not None:
                owner = getattr(owner, class_name)
            function = owner.__dict__[function_name] if class_name else getattr(owner, function_name)
            originals.append((owner, function_name, function))
            setattr(owner, function_name, clock.wrap(name, function))
    try:
        yield
    finally:
        for owner, function_name, function in reversed(originals):
            setattr(owner, function_name, function)


def budget_round(dataset: Any, sections: dict) -> dict[str, float]:
    """CPU ms a frame by stage, the stages one after another on this thread."""
    from hippo_nav.pipeline import Pipeline, config_from_dict

    config = config_from_dict({**sections, "overlap_front_end": False, "output": {"figures": False}})
    pipeline = Pipeline(dataset, config)
    clock = StageClock()
    with instrumented(clock), clock.stage("other"):
        started = time.process_time()
        result = pipeline.run(None)
        total_s = time.process_time() - started
    frames = result.metrics["frames"]
    row = {name: 1e3 * clock.cpu_s.get(name, 0.0) / frames for name in [*STAGES, "other"]}
    row["total"] = 1e3 * total_s / frames
    return row


def running_round(dataset: Any, sections: dict) -> dict[str, float]:
    """The defaults as they run: wall and every thread's CPU, ms a frame."""
    from hippo_nav.pipeline import Pipeline, config_from_dict

    config = config_from_dict({**sections, "output": {"figures": False}})
    timing = Pipeline(dataset, config).run(None).metrics["timing"]
    return {
        "wall ms a frame (pipeline as it runs)": 1e3 / timing["frames_per_s"],
        "CPU ms a frame, every thread (as it runs)": timing["cpu_ms_per_frame"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kitti", type=Path, required=True, help="KITTI odometry root (sequences/NN/…)")
    parser.add_argument("--sequence", default="06")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--config", type=Path, help="JSON sections added to the defaults")
    args = parser.parse_args()
    from hippo_nav.datasets import KittiOdometry

    sections = json.loads(args.config.read_text()) if args.config else {}
    dataset = KittiOdometry(args.kitti, args.sequence)
    rounds: dict[str, list[float]] = defaultdict(list)
    for _ in range(args.rounds):
        for row in (budget_round(dataset, sections), running_round(dataset, sections)):
            for name, ms in row.items():
                rounds[name].append(ms)
    print(
        f"KITTI {args.sequence}, {len(dataset)} frames, {args.rounds} rounds, config {sections or 'defaults'}"
    )
    print("| stage | CPU ms a frame (median) | rounds |")
    print("|---|---|---|")
    for name, values in rounds.items():
        spread = ", ".join(f"{v:.1f}" for v in values)
        print(f"| {name} | {statistics.median(values):.1f} | {spread} |")


if __name__ == "__main__":
    main()
