"""The whole system, one stereo frame at a time: odometry → spatial memory ← view cells → experience map.

`Pipeline(dataset, config).run(out_dir)` is the package's main job (the `hippo-nav run` command). Per
frame, in this order (docs/pipeline.md):

1. Odometry: the SE(3) step `camera_prev_from_camera_cur` of the stereo VO (or of another system's
   trajectory, `hippo_nav.vo.replay`), chained into `vo_world_from_camera`. The map's odometry step is
   the SE(2) motion between the planar parts of consecutive chained poses (`hippo_nav.geometry`), so
   composing the map's steps reproduces the odometry's planar trajectory exactly. The engine is given
   `yaw_rate = Δyaw / dt` and `speed = ±|Δxy| / dt` (negative when reversing), `dt` from the frame
   timestamps. An odometry failure (an exception or a non-finite step) is flagged and the previous step
   is reused (constant-velocity prior); motion beyond `config.limits` is clamped and flagged.
2. Local view cells: a template of the left image is matched; a familiar cell injects its stored
   patterns (`InjectionConfig`, strength decaying while the same cell stays active); a new cell stores
   the network's patterns after this frame's step (where the view was first seen).
3. Spatial memory (HD ring, three grid modules, place torus) integrates the motion, with the injection.
4. Loop closure (the map's geometric mode): when the view is familiar, the map lists the vertices a
   closure may join (far enough back along the path, inside the loop gate around the odometry's
   prediction: evidence the injection has not touched); the current stereo frame measures the pose of
   each candidate's keyframe (`hippo_nav.closure`); the first verified one goes to the map.
5. Experience map: `on_frame(view cell, place code, heading code, planar step, dt, closure)` creates
   vertices (pure odometry links) and loop links, and corrects the map online. A new vertex keeps the
   frame's stereo keyframe. Each frame keeps its offset from its vertex, so after the final correction
   every frame gets a corrected pose (vertex pose ∘ offset).

The end of a run (`_finish`): the final correction, the trajectories (planar estimates lifted to 3-D
with the odometry's height, pitch and roll), and `results.evaluate` / `results.write_results`.

Nothing depends on wall-clock time (timings are only measured), and OpenCV's RNG is seeded from
`config.seed`, so a run is deterministic for a given config and input. Ctrl-C (KeyboardInterrupt) stops
after the current frame; everything for the frames processed so far is still corrected and written.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.closure import Keyframe, KeyframeExtractor, LoopMeasurer
from hippo_nav.datasets.base import StereoDataset, StereoFrame
from hippo_nav.engine import N_MODULES, CompactView, SpatialMemory, SpatialReadout, ViewPatterns
from hippo_nav.geometry import lift_planar, planar_from_pose, se2_between, se2_compose
from hippo_nav.io import DatasetError
from hippo_nav.map import ClosureMode, new_experience_map
from hippo_nav.pipeline.config import PipelineConfig
from hippo_nav.pipeline.frontend import (
    Odometry,
    ViewCellFrontEnd,
    make_odometry,
    make_view_cells,
    tracked_pixels,
)
from hippo_nav.pipeline.records import STAGES, FrameRecord, RunRecord, RunResult
from hippo_nav.vo import planar_step

if TYPE_CHECKING:
    from typing_extensions import Self

log = logging.getLogger("hippo_nav.pipeline")
T = TypeVar("T")

NO_VIEW_ID = 2**63 - 1
"""View-cell id given to the map before any informative view has been seen."""

__all__ = [
    "NO_VIEW_ID",
    "STAGES",
    "Observer",
    "Pipeline",
    "RunRecord",
    "RunResult",
    "open_input",
    "planar_step",
    "run",
]


class Observer(Protocol):
    """Watches a run: `on_frame` after every processed frame (the pipeline's parts, the frame, what was
    recorded for it and the networks' readout), `on_finish` with the result. Live viewers and video
    writers are observers; an observer must not change the pipeline."""

    def on_frame(
        self, pipeline: Pipeline, frame: StereoFrame, record: FrameRecord, readout: SpatialReadout
    ) -> None: ...

    def on_finish(self, result: RunResult) -> None: ...


class Pipeline:
    """`Pipeline(dataset, config).run(out_dir)`: run the whole system on a stereo dataset.

    `dataset` follows `hippo_nav.datasets.StereoDataset`. `progress` shows a tqdm bar with the frame rate
    and the map size. `odometry` and `view_cells` replace the configured front end (see `frontend.py` for
    what they must offer); `observers` watch the run frame by frame (`Observer`). The parts are exposed
    for notebooks and observers: `engine`, `views`, `odometry`, `map`, `keyframes`, `record`.
    """

    def __init__(
        self,
        dataset: StereoDataset,
        config: PipelineConfig | None = None,
        progress: bool = False,
        *,
        odometry: Odometry | None = None,
        view_cells: ViewCellFrontEnd | None = None,
        observers: Sequence[Observer] = (),
    ) -> None:
        import cv2

        self.dataset = dataset
        self.config = config if config is not None else PipelineConfig()
        self.progress = progress
        cv2.setRNGSeed(int(self.config.seed))
        self.engine = SpatialMemory(self.config.engine_config())
        # The seed places the networks' bumps at the start (an animal's grid phases and heading code are
        # arbitrary where it starts); everything in the map frame is relative to them. OpenCV's RANSAC
        # uses a fixed internal seed, so the odometry itself is deterministic whatever the seed.
        rng = np.random.default_rng(self.config.seed)
        self.initial_heading_rad = float(rng.uniform(-np.pi, np.pi))
        initial_phase_rad = rng.uniform(0.0, 2 * np.pi, size=2)
        self.engine.reset(
            self.initial_heading_rad, (float(initial_phase_rad[0]), float(initial_phase_rad[1]))
        )
        # Front-end parts can be given (e.g. another VO in a notebook); by default they come from the config.
        self.odometry: Odometry = (
            odometry if odometry is not None else make_odometry(dataset.calibration, self.config.vo)
        )
        self.views: ViewCellFrontEnd = (
            view_cells if view_cells is not None else make_view_cells(self.config.views, dataset.calibration)
        )
        self.map = new_experience_map(self.config.map)
        self.geometric_closure = self.config.map.closure == ClosureMode.GEOMETRIC
        self.keyframes: dict[int, Keyframe] = {}
        # Keyframes being extracted on the front end's worker (vertex → future); see `_keep_keyframe`.
        self._pending_keyframes: dict[int, Future[Keyframe]] = {}
        self._front_end: _FrontEnd | None = None
        if self.geometric_closure:
            self._extract = KeyframeExtractor(dataset.calibration, self.config.closure)
            self._measurer = LoopMeasurer(dataset.calibration, self.config.closure)
        self.record = RunRecord()
        self.observers = list(observers)
        self._stored_views: dict[int, CompactView] = {}
        self._cell_vertex: dict[int, int] = {}  # view cell -> the vertex the agent was at when it was made
        self._vertex_cells: dict[int, list[int]] = {}  # the inverse
        self._active_view: int | None = None
        self._active_run = 0
        self._last_active: dict[int, int] = {}
        self._activation_gap: int | None = None
        self._last_step = np.eye(4)
        self._vo_pose = np.eye(4)
        self.frame_features_px: np.ndarray | None = None  # the odometry's tracked features, this frame
        self._last_timestamp_s: float | None = None
        self._last_code: tuple[float, float] = (0.0, 0.0)
        self._closure_odometer_m = -np.inf
        n = len(dataset)
        wanted = self.config.output.state_frames
        outside = [p for p in (wanted or []) if not 0 <= p < n]
        if outside:
            raise HippoNavError(
                f"output.state_frames: {outside} lie outside this run of {n} frames (positions 0 to {n - 1})"
            )
        self._state_frames = set(wanted if wanted is not None else [0, n // 2])
        self._unit_stride = max(self.config.engine.place.n_theta // 8, 1)

    # ----------------------------------------------------------------------------------------------
    def run(self, out_dir: str | Path | None = None, overwrite: bool = False) -> RunResult:
        """Process every frame, correct the map, and (when `out_dir` is given) write the results folder.

        The results folder is checked (and created) before the first frame; one that holds files is
        refused unless `overwrite` (which clears only what a run writes). Ctrl-C, SIGTERM and SIGHUP stop
        after the current frame; the frames processed so far are corrected and written, and the result says
        `interrupted=True` (`metrics["interrupted_by"]` names the signal). Interrupted before the first
        frame, `KeyboardInterrupt` propagates (nothing to write).
        """
        if out_dir is not None:
            from hippo_nav.pipeline.results import prepare_results_folder

            out_dir = prepare_results_folder(out_dir, overwrite)
        for warning in getattr(self.dataset, "warnings", []):
            log.warning("%s", warning)
        interrupted = False
        stopped_by: DatasetError | None = None
        started = time.perf_counter()
        with _stop_on_signals() as caught, _progress(self) as bar, _FrontEnd(self) as front:
            self._front_end = front
            try:
                loops = 0
                for i in range(len(self.dataset)):
                    self._process(front.get(i))
                    if bar is not None:
                        loops += self.record.frames[-1].loop_closure is not None
                        bar.update()
                        bar.set_postfix(
                            vertices=len(self.map), views=len(self.views), loops=loops, refresh=False
                        )
            except KeyboardInterrupt:
                if len(self.record) == 0:
                    raise
                interrupted = True
                log.warning(
                    "interrupted (%s) after %d frames; writing what was processed",
                    caught.get("signal", "SIGINT"),
                    len(self.record),
                )
            except DatasetError as err:
                # A missing or corrupt frame mid-sequence: keep (and write) everything before it, then report.
                if len(self.record) == 0:
                    raise
                interrupted, stopped_by = True, err
        self._front_end = None
        for vertex in list(self._pending_keyframes):
            self._keyframe(vertex)
        self.record.wall_s = time.perf_counter() - started
        self._snapshot(len(self.record) - 1, final=True)
        interrupted_by = caught.get("signal", "SIGINT") if interrupted and stopped_by is None else None
        result = self._finish(
            out_dir, interrupted, None if stopped_by is None else str(stopped_by), interrupted_by
        )
        for observer in self.observers:
            observer.on_finish(result)
        if stopped_by is not None:
            where = f"written to {out_dir}" if out_dir is not None else "returned in the exception's `result`"
            error = DatasetError(
                f"{stopped_by} — stopped there; the results of the {len(self.record)} frames before it are {where}"
            )
            error.result = result  # type: ignore[attr-defined]
            raise error
        return result

    @property
    def dataset_name(self) -> str:
        return str(getattr(self.dataset, "name", "sequence"))

    # ----------------------------------------------------------------------------------------------
    def _load(self, i: int) -> tuple[StereoFrame, float]:
        """Frame `i` and the seconds its loading took."""
        clock = time.perf_counter()
        frame = self.dataset[i]
        return frame, time.perf_counter() - clock

    def _front(self, i: int, loaded: Future[tuple[StereoFrame, float]] | None = None) -> _FrontResult:
        """Load frame `i` (or take it from `loaded`, loaded ahead) and measure its odometry step (the part
        that runs ahead of the back end, see `_FrontEnd`)."""
        frame, load_s = self._load(i) if loaded is None else loaded.result()
        clock = time.perf_counter()
        step, vo_status = self._odometry_step(frame)
        vo_s = time.perf_counter() - clock
        # Read now: with the front end a frame ahead, the odometry moves on before the back end is done.
        features_px = tracked_pixels(self.odometry)
        return _FrontResult(frame, step, vo_status, load_s, vo_s, features_px)

    def _process(self, front: _FrontResult) -> None:
        frame, step, vo_status = front.frame, front.step, front.vo_status
        self.frame_features_px = front.features_px
        self.record.stage_s["load"].append(front.load_s)
        self.record.stage_s["vo"].append(front.vo_s)
        clock = time.perf_counter()

        # 1. Odometry → the 3-D pose, the planar step of the map, dt.
        previous_planar = planar_from_pose(self._vo_pose)
        self._vo_pose = self._vo_pose @ step
        planar = se2_between(previous_planar, planar_from_pose(self._vo_pose))
        dt_s = 0.0 if self._last_timestamp_s is None else float(frame.timestamp_s - self._last_timestamp_s)
        self._last_timestamp_s = float(frame.timestamp_s)
        data_flags = self._data_flags(frame, dt_s)

        # 2. Local view cells: which view, and what (if anything) it injects.
        obs = self._observe_view(frame.left, planar)
        view, strength = self._injection(obs)
        clock = self._lap("views", clock)

        # 3. Spatial memory integrates the motion (not on the first frame: there is no motion yet).
        readout, yaw_rate, speed, flag = self._integrate(planar, dt_s, view, vo_status)
        if obs is not None and obs.is_new:
            # What the cell recalls: the bumps' phases and widths (88 bytes), not the patterns (~50 kB).
            self._stored_views[int(obs.cell_id)] = CompactView.from_engine(self.engine)
        clock = self._lap("engine", clock)

        # 4. Loop closure measured against the keyframes of candidate vertices.
        current: Keyframe | None = None
        closure, note = None, ""
        if self.geometric_closure and obs is not None and obs.status == "familiar":
            closure, note, current = self._measure_closure(frame, int(obs.cell_id), planar)
        clock = self._lap("closure", clock)

        # 5. Experience map.
        code = self._place_code(readout)
        view_id = NO_VIEW_ID if self._active_view is None else self._active_view
        outcome = self.map.on_frame(
            view_id, code, float(readout.heading_rad), tuple(planar), max(dt_s, 0.0), closure
        )
        if closure is not None:
            note = "accepted" if outcome.loop_closure is not None else str(outcome.rejected_closure)
            if outcome.loop_closure is not None:
                self._closure_odometer_m = self.map.odometer_m
        elif outcome.rejected_closure is not None:
            note = str(outcome.rejected_closure)
        if outcome.created and outcome.vertex is not None:
            self.record.vertex_position[int(outcome.vertex)] = len(self.record)
            if self.geometric_closure:
                self._keep_keyframe(int(outcome.vertex), current, frame)
        if obs is not None and obs.is_new and outcome.vertex is not None:
            self._cell_vertex[int(obs.cell_id)] = int(outcome.vertex)
            self._vertex_cells.setdefault(int(outcome.vertex), []).append(int(obs.cell_id))
        clock = self._lap("map", clock)

        self._record(
            frame,
            step,
            vo_status,
            flag,
            yaw_rate,
            speed,
            obs,
            strength,
            readout,
            code,
            outcome,
            note,
            data_flags,
        )
        for observer in self.observers:
            observer.on_frame(self, frame, self.record.frames[-1], readout)
        self._lap("record", clock)

    def _data_flags(self, frame: Any, dt_s: float) -> str:
        """What is odd about this frame's place in the data: sequence frames skipped before it (holes in
        the images), or a time gap. Both are logged once here and flagged in frames.csv."""
        flags = []
        if self.record.frames:
            stride = int(getattr(self.dataset, "stride", 1) or 1)
            skipped = int(frame.index) - self.record.frames[-1].frame_index - stride
            if skipped > 0:
                flags.append(f"skipped_frames:{skipped}")
                log.warning("frame %s: %d sequence frame(s) before it are missing", frame.index, skipped)
        if dt_s > self.config.limits.max_gap_s:
            flags.append(f"time_gap:{dt_s:.3g}s")
            log.warning(
                "frame %s: %.3g s since the previous frame (a gap); its motion is not extrapolated",
                frame.index,
                dt_s,
            )
        return ";".join(flags)

    def _lap(self, stage: str, since: float) -> float:
        now = time.perf_counter()
        self.record.stage_s[stage].append(now - since)
        return now

    # ----------------------------------------------------------------------------------------------
    def _odometry_step(self, frame: Any) -> tuple[np.ndarray, str]:
        """The odometry's SE(3) step, or the previous step (constant-velocity prior) when it fails."""
        try:
            result = self.odometry.process(frame)
            step = np.asarray(result.camera_prev_from_camera_cur, dtype=np.float64)
            status = str(getattr(result, "status", "ok"))
        except (HippoNavError, ArithmeticError) as err:
            log.warning("frame %s: odometry failed (%s); using the previous step", frame.index, err)
            return self._last_step.copy(), "failed"
        if step.shape != (4, 4) or not np.isfinite(step).all():
            log.warning("frame %s: odometry returned an invalid step; using the previous step", frame.index)
            return self._last_step.copy(), "failed"
        self._last_step = step
        return step, status

    def _view_candidates(self, planar: np.ndarray) -> list[int] | None:
        """The cells to compare this frame with (None: all; see `ViewSearchConfig`)."""
        cfg = self.config.view_search
        if not cfg.near_only or len(self.map) == 0:
            return None
        radius_m = min(self.map.loop_gate()[0] + cfg.radius_margin_m, cfg.max_radius_m)
        cells = [
            c for v in self.map.vertices_near(radius_m, tuple(planar)) for c in self._vertex_cells.get(v, ())
        ]
        n = len(self.views)
        cells.extend(range(max(n - cfg.recent_cells, 0), n))
        return cells

    def _observe_view(self, left: np.ndarray, planar: np.ndarray) -> Any:
        template = self.views.template_from_image(left)
        obs = self.views.observe(template, self._view_candidates(planar))
        if obs.cell_id is not None:
            cell = int(obs.cell_id)
            position = len(self.record)
            if cell == self._active_view:
                self._active_run += 1
            else:
                self._active_run = 0
                last = self._last_active.get(cell)
                self._activation_gap = position - last if last is not None else None
            self._last_active[cell] = position
            self._active_view = cell
        return obs

    def _injection(self, obs: Any) -> tuple[ViewPatterns | None, float]:
        """The stored patterns of a familiar view, scaled by the decaying strength (docs/model.md)."""
        cfg = self.config.injection
        if not cfg.enabled or obs is None or obs.is_new or obs.cell_id is None:
            return None, 0.0
        stored = self._stored_views.get(int(obs.cell_id))
        # Only a revisit injects: a cell seen again within `revisit_gap_frames` belongs to the passage the
        # agent is still on, and its (older) stored state would drag path integration backwards.
        gap = self._activation_gap
        if stored is None or gap is None or gap <= cfg.revisit_gap_frames:
            return None, 0.0
        strength = cfg.initial_strength * cfg.decay_per_frame**self._active_run
        if strength < cfg.min_strength or strength == 0.0:
            return None, 0.0
        # The stored heading is where the camera faced when the view was stored; now it faces
        # `relative_heading_rad` further (counter-clockwise), so the recalled heading turns with it.
        offset = float(obs.relative_heading_rad) if cfg.shift_heading else 0.0
        return stored.patterns(strength=strength, heading_offset_rad=offset), strength

    def _integrate(
        self, planar: np.ndarray, dt_s: float, view: ViewPatterns | None, vo_status: str
    ) -> tuple[SpatialReadout, float, float, str]:
        """Step the engine with the planar step's velocities; clamp absurd motion, and if the engine still
        refuses, skip the motion."""
        flag = "ok" if vo_status in ("ok", "first") else f"vo:{vo_status}"
        if dt_s <= 0:
            return self.engine.readout(), 0.0, 0.0, flag
        if dt_s > self.config.limits.max_gap_s:
            # Integrate the measured step over the longest plausible frame time, not over the whole gap
            # (the networks cannot represent slow motion over minutes, and need not).
            dt_s = self.config.limits.max_gap_s
            flag = "gap"
        forward_m, left_m, yaw_rad = (float(v) for v in planar)
        yaw_rate = yaw_rad / dt_s
        speed = float(np.copysign(np.hypot(forward_m, left_m), forward_m)) / dt_s
        limits = self.config.limits
        if abs(speed) > limits.max_speed_m_s or abs(yaw_rate) > limits.max_yaw_rate_rad_s:
            speed = float(np.clip(speed, -limits.max_speed_m_s, limits.max_speed_m_s))
            yaw_rate = float(np.clip(yaw_rate, -limits.max_yaw_rate_rad_s, limits.max_yaw_rate_rad_s))
            flag = "clamped"
        try:
            return self.engine.step(yaw_rate, speed, dt_s, view), yaw_rate, speed, flag
        except HippoNavError as err:
            log.warning(
                "engine refused yaw rate %.3g rad/s, speed %.3g m/s (%s); frame held", yaw_rate, speed, err
            )
        # dt outside the engine's range (a long gap) or velocities it cannot represent: hold still.
        try:
            return self.engine.step(0.0, 0.0, min(max(dt_s, 1e-3), 10.0), view), 0.0, 0.0, "engine_skipped"
        except HippoNavError:
            return self.engine.readout(), 0.0, 0.0, "engine_skipped"

    def _keep_keyframe(self, vertex: int, made: Keyframe | None, frame: StereoFrame) -> None:
        """Store the stereo keyframe of a new vertex. Unless this frame already made one (a closure attempt),
        it is extracted on the front end's worker, beside the next frame's odometry: a vertex's keyframe is
        first needed when the agent comes back, at least `min_loop_separation_m` later."""
        front = self._front_end
        if made is not None:
            self.keyframes[vertex] = made
        elif front is not None and front.overlapping:
            self._pending_keyframes[vertex] = front.submit(self._extract, frame.left, frame.right)
        else:
            done: Future[Keyframe] = Future()
            try:
                done.set_result(self._extract(frame.left, frame.right))
            except Exception as err:  # noqa: BLE001 - handled in `_keyframe`, like the worker's failures
                done.set_exception(err)
            self._pending_keyframes[vertex] = done
            self._keyframe(vertex)

    def _keyframe(self, vertex: int) -> Keyframe | None:
        """The keyframe of `vertex` (waiting for it if it is still being extracted), or None."""
        pending = self._pending_keyframes.pop(vertex, None)
        if pending is not None:
            try:
                self.keyframes[vertex] = pending.result()
            except Exception as err:  # noqa: BLE001 - a keyframe costs closures to one vertex, never the run
                log.warning("vertex %d: no stereo keyframe (%s); no loop can close onto it", vertex, err)
        return self.keyframes.get(vertex)

    def _measure_closure(
        self, frame: Any, cell: int, planar: np.ndarray
    ) -> tuple[tuple[int, tuple[float, float, float], np.ndarray] | None, str, Keyframe | None]:
        """A verified loop closure for the map (or None), why not, and the frame's keyframe if made.

        Candidates: the vertex where the familiar view was first seen and its odometry neighbours; the map
        keeps those far enough back along the path and inside its loop gate (the odometry's prediction)."""
        cfg = self.config.closure
        if self.map.odometer_m - self._closure_odometer_m < cfg.closure_spacing_m:
            return None, "", None
        anchor = self._cell_vertex.get(cell)
        if anchor is None:
            return None, "", None
        nearby = [v for v in (anchor - 1, anchor, anchor + 1) if 0 <= v < len(self.map)]
        candidates = self.map.loop_candidates(nearby, tuple(planar))
        if not candidates:
            return None, "no_candidate", None
        try:
            current = self._extract(frame.left, frame.right)
        except Exception as err:  # noqa: BLE001 - a frame without a keyframe closes no loop; the run goes on
            log.warning("frame %s: no stereo keyframe (%s); no loop closure attempted", frame.index, err)
            return None, "no_current_keyframe", None
        why = "no_keyframe"
        for vertex, _predicted, _distance in candidates[: cfg.candidates_per_frame]:
            keyframe = self._keyframe(vertex)
            if keyframe is None:
                continue
            measurement, why = self._measurer.measure(keyframe, current)
            if measurement is not None:
                return (vertex, measurement.agent_from_target, measurement.information), "measured", current
        return None, why, current

    def _place_code(self, readout: SpatialReadout) -> tuple[float, float]:
        """The place bump's centre on the torus; the fused grid estimate (or the last code) without one."""
        bump = readout.place if readout.place is not None else readout.fused
        if bump is not None:
            self._last_code = (float(bump.mean_rad[0]), float(bump.mean_rad[1]))
        return self._last_code

    # ----------------------------------------------------------------------------------------------
    def _record(
        self,
        frame,
        step,
        vo_status,
        flag,
        yaw_rate,
        speed,
        obs,
        strength,
        readout,
        code,
        outcome,
        note,
        data_flags,
    ) -> None:
        agent = outcome.world_from_agent
        offset = outcome.vertex_from_agent
        if agent is None:  # lost (relocalising): dead-reckon from the last online pose
            previous = self.record.frames[-1].online_pose if self.record.frames else np.zeros(3)
            agent_pose = se2_compose(previous, np.array(planar_step(step)))
            offset_pose = np.full(3, np.nan)
        else:
            agent_pose, offset_pose = np.array(agent), np.array(offset)
        self.record.append(
            FrameRecord(
                frame_index=int(frame.index),
                timestamp_s=float(frame.timestamp_s),
                vo_world_from_camera=self._vo_pose.copy(),
                vo_status=vo_status,
                motion_flag=flag,
                yaw_rate_rad_s=yaw_rate,
                speed_m_s=speed,
                view_cell=-1 if obs is None or obs.cell_id is None else int(obs.cell_id),
                view_status="none" if obs is None else str(obs.status),
                view_difference=float("nan") if obs is None else float(obs.difference),
                injection_strength=strength,
                heading_rad=float(readout.heading_rad),
                place_code_rad=code,
                place_position_m=(float(readout.place_position_m[0]), float(readout.place_position_m[1])),
                vertex=-1 if outcome.vertex is None else int(outcome.vertex),
                vertex_created=bool(outcome.created),
                loop_closure=outcome.loop_closure,
                closure_note=note,
                data_flags=data_flags,
                online_pose=agent_pose,
                vertex_from_agent=offset_pose,
            )
        )
        self._record_units()
        self._snapshot(len(self.record) - 1, readout=readout)

    def _record_units(self) -> None:
        """A regular sub-grid of units of every layer-II pattern and of the place torus, for rate maps."""
        s = self._unit_stride
        acts = self.record.unit_activity
        for m, grid in enumerate(self.engine.config.grid):
            if self.engine.config.lesioned[m]:
                continue
            name = f"grid k={grid.k}"
            acts.setdefault(name, []).append(
                np.asarray(self.engine.grid_layer2(m)[::s, ::s], dtype=np.float32).ravel()
            )
        acts.setdefault("place", []).append(
            np.asarray(self.engine.place_activity()[::s, ::s], dtype=np.float32).ravel()
        )

    def _snapshot(self, position: int, final: bool = False, readout: SpatialReadout | None = None) -> None:
        if not (final or position in self._state_frames) or position in self.record.snapshots:
            return
        sm = self.engine
        self.record.snapshots[position] = {
            "frame_index": self.record.frames[position].frame_index,
            "hd": sm.hd_activity(),
            "grid": [None if sm.config.lesioned[m] else sm.grid_activity(m) for m in range(N_MODULES)],
            "layer2": [None if sm.config.lesioned[m] else sm.grid_layer2(m) for m in range(N_MODULES)],
            "place": sm.place_activity(),
            "k": [g.k for g in sm.config.grid],
            "nu_max": [g.nu_max for g in sm.config.grid],
            "hd_nu_max": sm.config.hd.nu_max,
            "readout": readout if readout is not None else sm.readout(),
        }

    # ----------------------------------------------------------------------------------------------
    def _correct(self) -> dict[str, Any]:
        """The configured final correction; its report (method "none" when disabled or loop-free)."""
        cfg = self.config.correction
        export = self.map.export()
        if cfg.method == "none" or not np.asarray(export["link_is_loop"]).any():
            return {"method": "none", "reason": "disabled" if cfg.method == "none" else "no loop closure"}
        if cfg.method == "relaxation":
            report = self.map.correct("relaxation", passes=cfg.relaxation_passes, gain=cfg.relaxation_gain)
        else:
            report = self.map.correct(
                "least_squares",
                initialization="current",
                robust_loss=cfg.robust_loss,
                robust_scale_chi2=cfg.robust_scale_chi2,
                max_iterations=cfg.max_iterations,
            )
        return {"method": cfg.method, **report.as_dict()}

    def _finish(
        self,
        out_dir: str | Path | None,
        interrupted: bool,
        stopped_by: str | None,
        interrupted_by: str | None = None,
    ) -> RunResult:
        """Correct the map, assemble the trajectories, evaluate, and write the results folder."""
        from hippo_nav.pipeline.frontend import resolved_frontend_params
        from hippo_nav.pipeline.results import evaluate, write_results

        clock = time.perf_counter()
        correction = self._correct()
        correction_s = time.perf_counter() - clock
        record = self.record
        export = {k: np.asarray(v) for k, v in self.map.export().items()}
        vo = np.stack(record.column("vo_world_from_camera"))
        online = np.stack(record.column("online_pose"))
        corrected = corrected_track(record, export["poses"])
        # The networks' own estimate in the map frame: their displacement and heading code relative to
        # the heading code they started with.
        h0 = self.initial_heading_rad
        displacement = np.asarray(record.column("place_position_m"))
        c, s = np.cos(h0), np.sin(h0)
        neural = np.column_stack(
            [
                c * displacement[:, 0] + s * displacement[:, 1],
                -s * displacement[:, 0] + c * displacement[:, 1],
                np.asarray(record.column("heading_rad")) - h0,
            ]
        )
        gt = self.dataset.ground_truth()
        if gt is not None:
            gt = np.asarray(gt)[: len(record)]
            gt = np.linalg.inv(gt[0]) @ gt
        result = RunResult(
            name=self.dataset_name,
            record=record,
            metrics={},
            vo_world_from_camera=vo,
            online_world_from_camera=lift_planar(online, vo),
            corrected_world_from_camera=lift_planar(corrected, vo),
            neural_world_from_camera=lift_planar(neural, vo),
            ground_truth=gt,
            map_export=export,
            interrupted=interrupted,
        )
        result.metrics = evaluate(self, result, correction, stopped_by)
        result.metrics["timing"]["correction_s"] = correction_s
        if interrupted_by is not None:
            result.metrics["interrupted_by"] = interrupted_by
        if out_dir is not None:
            frontend = resolved_frontend_params(self.odometry, self.views)
            write_results(result, Path(out_dir), self.config, frontend, self.map)
        return result


@dataclass(frozen=True)
class _FrontResult:
    """A loaded frame and its odometry step, with the time each took."""

    frame: StereoFrame
    step: np.ndarray
    vo_status: str
    load_s: float
    vo_s: float
    features_px: np.ndarray | None  # the odometry's tracked features in this frame (None: it has none)


class _FrontEnd:
    """Loads frames two ahead of the back end and measures their odometry one frame ahead, each on its
    own worker thread.

    The odometry only looks at images, never at the networks or the map, so frame k+1's VO (OpenCV
    releases the interpreter) can run while the networks and the map (Rust, also without the interpreter)
    process frame k, and frame k+2's images are decoded meanwhile (PNG decoding releases it too). One
    loader and one VO worker keep the frames in order, so the results do not depend on the threads, and
    only the loader reads the dataset (a bag reader need not be thread-safe). `config.overlap_front_end =
    false` runs everything on the calling thread. An error of a later frame (a corrupt image) surfaces
    when the back end asks for that frame, after the frames before it are done, as without the overlap."""

    def __init__(self, pipeline: Pipeline) -> None:
        self._pipeline = pipeline
        self._overlap = pipeline.config.overlap_front_end
        self._pool: ThreadPoolExecutor | None = None
        self._loader: ThreadPoolExecutor | None = None
        self._next: tuple[int, Future[_FrontResult]] | None = None
        self._loads: dict[int, Future[tuple[StereoFrame, float]]] = {}

    def __enter__(self) -> Self:
        if self._overlap:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hippo-nav-front")
            self._loader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hippo-nav-load")
        return self

    @property
    def overlapping(self) -> bool:
        return self._pool is not None

    def submit(self, work: Callable[..., T], *args: Any) -> Future[T]:
        """Run `work(*args)` on the worker, after the frames already asked for (overlapping only)."""
        assert self._pool is not None
        return self._pool.submit(work, *args)

    def _loaded(self, i: int) -> Future[tuple[StereoFrame, float]]:
        """Frame `i` being loaded (asked for now if it was not yet), and frame i+1 asked for."""
        assert self._loader is not None
        for j in (i, i + 1):
            if j < len(self._pipeline.dataset) and j not in self._loads:
                self._loads[j] = self._loader.submit(self._pipeline._load, j)
        return self._loads.pop(i)

    def _start(self, i: int) -> Future[_FrontResult]:
        assert self._pool is not None
        return self._pool.submit(self._pipeline._front, i, self._loaded(i))

    def get(self, i: int) -> _FrontResult:
        """Frame `i`'s front-end result; starts frame i+1's."""
        if self._pool is None:
            return self._pipeline._front(i)
        if self._next is not None and self._next[0] == i:
            result = self._next[1].result()
        else:
            result = self._start(i).result()
        self._next = (i + 1, self._start(i + 1)) if i + 1 < len(self._pipeline.dataset) else None
        return result

    def __exit__(self, *exc: object) -> None:
        # Finish what is queued (the next frame's odometry, keyframes being extracted: a few ms each) so
        # that nothing touches the VO after the run and every vertex gets its keyframe; a frame loaded
        # ahead and never used is dropped.
        for pool in (self._loader, self._pool):
            if pool is not None:
                pool.shutdown(wait=True)


@contextlib.contextmanager
def _stop_on_signals():
    """SIGTERM and SIGHUP (what schedulers and `docker stop` send) stop the run like Ctrl-C: the frames
    processed so far are still written. Yields a dict that names the signal caught. Only the main thread
    can install handlers; elsewhere the default behaviour stays."""
    caught: dict[str, str] = {}

    def stop(signum, _frame):
        caught["signal"] = signal.Signals(signum).name
        raise KeyboardInterrupt

    wanted = [s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s is not None]
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for s in wanted:
            previous[s] = signal.signal(s, stop)
    try:
        yield caught
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextlib.contextmanager
def _progress(pipeline: Pipeline):
    """A tqdm bar (or None), with log lines routed through it so that warnings never glue onto the bar."""
    if not pipeline.progress:
        yield None
        return
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    bar = tqdm(total=len(pipeline.dataset), desc=pipeline.dataset_name, unit="frame", dynamic_ncols=True)
    try:
        with logging_redirect_tqdm():
            yield bar
    finally:
        bar.close()


def corrected_track(record: RunRecord, vertex_poses: np.ndarray) -> np.ndarray:
    """(n, 3) planar pose of every frame after correction: its vertex's corrected pose ∘ its offset.
    Frames without a vertex (never, unless relocalising) keep their online pose."""
    vertex = np.asarray(record.column("vertex"))
    offset = np.stack(record.column("vertex_from_agent"))
    online = np.stack(record.column("online_pose"))
    track = online.copy()
    ok = (vertex >= 0) & np.isfinite(offset).all(axis=1)
    if ok.any():
        track[ok] = se2_compose(vertex_poses[vertex[ok]], offset[ok])
    return track


def open_input(
    kitti: str | Path | None = None,
    sequence: str | None = "00",
    start: int | None = None,
    stop: int | None = None,
    stride: int = 1,
    progress: bool = False,
    kind: str | None = None,
    options: dict[str, Any] | None = None,
) -> Any:
    """The dataset of a run: any `open_dataset` path (KITTI root, EuRoC, ROS bag, stereo folder; `kind` and
    loader `options` as there), or (no `kitti`) the built-in synthetic demo loop."""
    from hippo_nav.datasets import KittiOdometry, open_dataset

    if kitti is None:
        from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence

        dataset = KittiOdometry(demo_sequence(progress=progress), DEMO_SEQUENCE, start, stop, stride)
        dataset.name = "synthetic demo loop"
        return dataset
    return open_dataset(kitti, sequence, kind=kind, start=start, stop=stop, stride=stride, **(options or {}))


def run(
    out_dir: str | Path | None = "runs/demo",
    kitti: str | Path | None = None,
    sequence: str | None = "00",
    start: int | None = None,
    stop: int | None = None,
    stride: int = 1,
    config: PipelineConfig | None = None,
    progress: bool = True,
    odometry: Any = None,
    overwrite: bool = False,
    observers: Sequence[Observer] = (),
    dataset_kind: str | None = None,
    dataset_options: dict[str, Any] | None = None,
) -> RunResult:
    """The `hippo-nav run` command as a function: open the input, run the pipeline, write `out_dir`.

    `odometry` replaces the built-in stereo VO (e.g. another system's trajectory replayed from a file,
    see `hippo_nav.vo.replay`); it may also be a callable taking the opened dataset and returning one.
    `kitti` may be any dataset path `open_dataset` reads; `dataset_kind`/`dataset_options` go to it."""
    dataset = open_input(kitti, sequence, start, stop, stride, progress, dataset_kind, dataset_options)
    note = getattr(dataset, "note", "")
    if note:
        log.info("%s", note)
    if callable(odometry) and not hasattr(odometry, "process"):
        odometry = odometry(dataset)
    pipeline = Pipeline(dataset, config, progress=progress, odometry=odometry, observers=observers)
    return pipeline.run(out_dir, overwrite=overwrite)
