"""The per-frame SLAM system: odometry → spatial memory ← view cells → experience map, one frame at a time.

`SlamSystem(calibration, config).step(frame, camera_prev_from_camera_cur, vo_status)` processes one
stereo frame whose odometry step is known and returns what it decided (`SystemStep`: the typed
`FrameRecord`, the networks' readout). It has no threads, signals, progress bars or files: the runner
(`runner.Pipeline`) loads frames, measures the odometry ahead, records, shows progress, feeds observers
and writes results. Per frame, in this order (docs/pipeline.md):

1. Odometry: the SE(3) step is chained into `vo_world_from_camera`. The map's odometry step is the SE(2)
   motion between the planar parts of consecutive chained poses (`hippo_nav.geometry`), so composing the
   map's steps reproduces the odometry's planar trajectory exactly; `dt` comes from the frame timestamps.
2. Local view cells (`ViewRecall`): the frame's view is matched against the cells seen near where the
   odometry puts the agent; a familiar cell injects its stored network state with a decaying strength.
3. Loop closure (the map's geometric mode): the closure proposer (`hippo_nav.closure`) measures a closure
   to a vertex the map knows, which the map accepts or rejects in step 5. It needs only the view and the
   map, so it runs before the networks: with `injection.placement = "measured"` the measured pose also
   places the state a familiar view recalls.
4. Spatial memory (HD ring, three grid modules, place torus) integrates the motion with the injection
   (`MotionLimiter`: clamped to `config.limits`); a new view cell then stores the network's state.
5. Experience map: `on_frame(view cell, place code, heading code, planar step, dt, closure)` creates
   vertices (pure odometry links) and loop links and corrects the map online. Each frame keeps its offset
   from its vertex, so after the final correction every frame gets a corrected pose (vertex ∘ offset).

Which descriptor fills the view cells and which proposers close loops is the config's `parts` section
(`parts.py`). Everything a run learns that could outlive it — the experience map, the view cells with the
network states they recall, the closure's keyframes — is `SlamSystem.memory`; each part that keeps state is
`Persistent` (`hippo_nav.plugs`: what it depends on, export, restore).

A system can start inside what an earlier run learnt (`memory=read_memory(path)`, docs/memory.md): with
`resume=True` it continues exactly where that run stopped (the next frames give the same records as if it had
never stopped); otherwise it starts a new session in the loaded map, lost until a familiar view is confirmed by
the closure measurement (the `relocalisation` proposer, `hippo_nav.closure.relocalisation`): the map then joins the session's own part to
the loaded one, and the networks are set from the recognised view's stored state (`relocalisation` says when
and where). `save_memory()` gives what a later run needs.

Nothing depends on wall-clock time (stages are only timed), and OpenCV's RNG is seeded from `config.seed`,
so a run is deterministic for a given config and input.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.closure import NO_ATTEMPT, ClosureAttempt, ClosureChain
from hippo_nav.closure.relocalisation import RelocalisationProposer
from hippo_nav.datasets.base import StereoCalibration, StereoFrame
from hippo_nav.engine import SpatialMemory, SpatialReadout
from hippo_nav.geometry import planar_from_pose, se2_between, se2_compose
from hippo_nav.map import ClosureMode, ExperienceMap, MapFrameOutcome, new_experience_map
from hippo_nav.memory import SavedMemory, SavedMemoryError, check_compatible, check_parts_agree
from hippo_nav.plugs import Persistent
from hippo_nav.system import parts
from hippo_nav.system.config import PipelineConfig
from hippo_nav.system.policies import Motion, MotionLimiter, ViewRecall, final_correction
from hippo_nav.system.records import FrameRecord, StageTimer
from hippo_nav.view_cells import NO_VIEW_CELL, ViewDescriptor, ViewObservation
from hippo_nav.workers import INLINE, Worker

log = logging.getLogger("hippo_nav.pipeline")

__all__ = ["Memory", "SlamSystem", "SystemStep"]


@dataclass(frozen=True)
class SystemStep:
    """What the system decided for one frame."""

    record: FrameRecord
    readout: SpatialReadout  # the networks after this frame's step


@dataclass(frozen=True)
class _Motion:
    """A frame's motion as the back end takes it: the map's planar odometry step (forward m, left m, yaw
    rad), the time since the previous frame, and what is odd about the frame's place in the data."""

    planar_step: tuple[float, float, float]
    dt_s: float
    data_flags: str


@dataclass(frozen=True)
class Memory:
    """What a run has learnt of its world: the parts that would be kept for a later run."""

    experience_map: ExperienceMap
    view_recall: ViewRecall  # the view cells and the network states they recall
    closure: ClosureChain | None  # what closures onto known vertices need (keyframes); None in RatSLAM mode


class SlamSystem:
    """The per-frame system (module doc).

    `view_cells` and `closure` replace the parts the config's `parts` section names; `stride` is the
    dataset's frame stride (a larger jump in frame numbers is flagged as skipped frames). The parts are
    exposed for notebooks and observers: `engine`, `map`, `view_recall`, `closure`, `limits`.
    """

    def __init__(
        self,
        calibration: StereoCalibration,
        config: PipelineConfig | None = None,
        *,
        view_cells: ViewDescriptor | None = None,
        closure: ClosureChain | None = None,
        stride: int = 1,
        memory: SavedMemory | None = None,
        resume: bool = False,
    ) -> None:
        import cv2

        self.config = config if config is not None else PipelineConfig()
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
        descriptor = view_cells if view_cells is not None else parts.make_view_cells(self.config, calibration)
        self.view_recall = ViewRecall(
            descriptor,
            self.config.view_search,
            self.config.injection,
            torus_period_m=self.config.engine.torus_period_m,
        )
        self.map = new_experience_map(self.config.map)
        self.closure = closure if closure is not None else parts.make_closure(self.config, calibration)
        self.stride = max(int(stride), 1)
        self.limits = MotionLimiter(self.config.limits, self.stride)
        self.frames = 0  # frames processed
        self.map_revision = 0  # changes whenever the map may have changed (a frame, a correction)
        self._vo_pose = np.eye(4)
        self._last_timestamp_s: float | None = None
        self._last_frame_index: int | None = None
        self._last_online_pose = np.zeros(3)
        self._last_code: tuple[float, float] = (0.0, 0.0)
        self.calibration = calibration
        # Relocalisation in a loaded map: when (frame, vertex joined onto, odometer since the start) or None.
        self.relocalisation: dict[str, Any] | None = None
        self._session_first_cell = 0  # the first view cell this session made
        self._session_start_m = 0.0
        self.loaded: dict[str, Any] | None = None  # what was loaded (`memory`), for metrics.json
        if memory is not None:
            self._load(memory, resume)

    @property
    def view_cells(self) -> ViewDescriptor:
        return self.view_recall.descriptor

    @property
    def memory(self) -> Memory:
        return Memory(self.map, self.view_recall, self.closure)

    # ----------------------------------------------------------------------------------------------
    def step(
        self,
        frame: StereoFrame,
        camera_prev_from_camera_cur: np.ndarray,
        vo_status: str = "ok",
        *,
        view_description: object = None,
        disparity_offset_px: float | None = None,
        worker: Worker = INLINE,
        timer: StageTimer | None = None,
    ) -> SystemStep:
        """Process one frame whose odometry step is `camera_prev_from_camera_cur` (4 × 4 SE(3), identity on
        the first frame; `vo_status` as the odometry reported it), in the stages of the module doc.
        `view_description`: the view descriptor's `describe(frame)` when the front end made it ahead (None:
        made here). `disparity_offset_px`: the odometry's stereo correction after this frame, which the
        closure's keyframes apply too (None: the configured `vo.disparity_offset_px`). Slow work whose result
        is needed only later goes to `worker`; `timer` is told where each stage ends."""
        timer = timer if timer is not None else StageTimer()
        step = np.asarray(camera_prev_from_camera_cur, dtype=np.float64)
        motion = self._odometry(frame, step)
        obs = self._views(frame, motion, view_description)
        timer.lap("views")
        attempt = self._propose_closure(frame, motion, obs, disparity_offset_px)
        timer.lap("closure")
        readout, strength, limited = self._networks(motion, obs, attempt, vo_status)
        timer.lap("engine")
        outcome, note = self._experience_map(frame, motion, obs, attempt, readout, worker)
        timer.lap("map")
        record = self._record(frame, motion, vo_status, obs, strength, readout, limited, outcome, note)
        self.frames += 1
        self.map_revision += 1
        self._last_frame_index = int(frame.index)
        self._last_online_pose = record.online_pose
        return SystemStep(record, readout)

    # -- the stages of a frame ------------------------------------------------------------------------
    def _odometry(self, frame: StereoFrame, step: np.ndarray) -> _Motion:
        """1. The SE(3) step chained into the 3-D pose; the map's planar step; dt; what is odd in the data."""
        previous_planar = planar_from_pose(self._vo_pose)
        self._vo_pose = self._vo_pose @ step
        planar = se2_between(previous_planar, planar_from_pose(self._vo_pose))
        dt_s = 0.0 if self._last_timestamp_s is None else float(frame.timestamp_s - self._last_timestamp_s)
        self._last_timestamp_s = float(frame.timestamp_s)
        planar_step_map = (float(planar[0]), float(planar[1]), float(planar[2]))
        return _Motion(planar_step_map, dt_s, self._data_flags(frame, dt_s))

    def _views(self, frame: StereoFrame, motion: _Motion, description: object) -> ViewObservation:
        """2. Local view cells: which view, and what (if anything) it recalls."""
        if description is None:
            description = self.view_cells.describe(frame)
        return self.view_recall.observe(description, motion.planar_step, self.map, self.frames)

    def _propose_closure(
        self, frame: StereoFrame, motion: _Motion, obs: ViewObservation, disparity_offset_px: float | None
    ) -> ClosureAttempt:
        """3. A loop closure proposed (and measured) for the map to accept or reject. It needs the view and
        the map only, so it runs before the networks: the measured pose can also place the recalled state."""
        if self.closure is None:
            return NO_ATTEMPT
        cell = obs.cell_id
        familiar = obs.status == "familiar" and cell is not None
        anchor = self.view_recall.anchor_of(int(cell)) if familiar and cell is not None else None
        return self.closure.propose(frame, motion.planar_step, anchor, self.map, disparity_offset_px)

    def _networks(
        self, motion: _Motion, obs: ViewObservation, attempt: ClosureAttempt, vo_status: str
    ) -> tuple[SpatialReadout, float, Motion]:
        """4. The spatial memory integrates the motion, with what a familiar view recalls; a new view cell
        then stores the state it reached. (readout, injection strength, what the engine was given)"""
        measured = None
        if attempt.closure is not None:
            measured = (attempt.closure.target_vertex, attempt.closure.agent_from_target)
        view, strength = self.view_recall.injection(obs, measured, self.map)
        readout, limited = self.limits.drive(self.engine, motion.planar_step, motion.dt_s, vo_status, view)
        self.view_recall.remember(obs, self.engine)
        return readout, strength, limited

    def _experience_map(
        self,
        frame: StereoFrame,
        motion: _Motion,
        obs: ViewObservation,
        attempt: ClosureAttempt,
        readout: SpatialReadout,
        worker: Worker,
    ) -> tuple[MapFrameOutcome, str]:
        """5. The experience map takes the frame (a vertex, a loop link); the closure's note for frames.csv."""
        closure = attempt.closure
        outcome = self.map.on_frame(
            self.view_recall.active_cell,
            self._place_code(readout),
            float(readout.heading_rad),
            motion.planar_step,
            max(motion.dt_s, 0.0),
            None if closure is None else closure.map_input(),
        )
        note = attempt.note
        if closure is not None:
            accepted = "accepted" if closure.via == "view_cell" else f"accepted_{closure.via}"
            note = accepted if outcome.loop_closure is not None else str(outcome.rejected_closure)
            if outcome.relocalized:
                note = "relocalised"
        elif outcome.rejected_closure is not None:
            note = str(outcome.rejected_closure)
        if self.closure is not None:
            self.closure.after_map(frame, outcome, self.map, worker)
        self.view_recall.anchor(obs, outcome.vertex, outcome.vertex_from_agent)
        if outcome.relocalized and self.relocalisation is None and obs.cell_id is not None:
            self._joined(frame, outcome, int(obs.cell_id))
        return outcome, note

    def _record(
        self,
        frame: StereoFrame,
        motion: _Motion,
        vo_status: str,
        obs: ViewObservation,
        strength: float,
        readout: SpatialReadout,
        limited: Motion,
        outcome: MapFrameOutcome,
        note: str,
    ) -> FrameRecord:
        """6. What was decided, as the frame's record."""
        online_pose, vertex_from_agent = self._online_pose(outcome, motion.planar_step)
        return FrameRecord(
            frame_index=int(frame.index),
            timestamp_s=float(frame.timestamp_s),
            vo_world_from_camera=self._vo_pose.copy(),
            vo_status=vo_status,
            motion_flag=limited.flag,
            yaw_rate_rad_s=limited.yaw_rate_rad_s,
            speed_m_s=limited.speed_m_s,
            view_cell=NO_VIEW_CELL if obs.cell_id is None else int(obs.cell_id),
            view_status=str(obs.status),
            view_difference=float(obs.difference),
            injection_strength=strength,
            heading_rad=float(readout.heading_rad),
            place_code_rad=self._last_code,
            place_position_m=(float(readout.place_position_m[0]), float(readout.place_position_m[1])),
            vertex=-1 if outcome.vertex is None else int(outcome.vertex),
            vertex_created=bool(outcome.created),
            loop_closure=outcome.loop_closure,
            closure_note=note,
            data_flags=motion.data_flags,
            online_pose=online_pose,
            vertex_from_agent=vertex_from_agent,
        )

    def finish(self) -> None:
        """Wait for work still pending (keyframes being extracted on the worker)."""
        if self.closure is not None:
            self.closure.finish()

    def correct(self) -> dict[str, Any]:
        """The configured final correction (`config.correction`, `policies.final_correction`); its report."""
        report = final_correction(self.map, self.config.correction)
        if report["method"] != "none":
            self.map_revision += 1
        return report

    # ----------------------------------------------------------------------------------------------
    def depends_on(self) -> dict[str, object]:
        """The settings what this system stores depends on (a memory made with others is refused): each
        persistent part's own (`Persistent.depends_on`), the networks', the map's and the camera's."""
        cfg = json.loads(self.config.model_dump_json(by_alias=True))
        width, height = self.calibration.image_size_px
        descriptor = self.view_cells
        return {
            "parts": {"view_cells": cfg["parts"]["view_cells"]},
            "view_cells": descriptor.depends_on() if isinstance(descriptor, Persistent) else {},
            "closure": {} if self.closure is None else self.closure.depends_on(),
            "engine": cfg["engine"],
            "lesions": cfg["lesions"],
            "map": cfg["map"],
            "camera": {
                "image_size_px": [int(width), int(height)],
                "fx_px": float(self.calibration.fx),
                "baseline_m": float(self.calibration.baseline_m),
            },
        }

    def save_memory(self) -> SavedMemory:
        """What a later run needs to start inside this one's map (docs/memory.md); call after `finish`.
        Raises `HippoNavError` when a part cannot be saved (a custom descriptor or proposer without export)."""
        descriptor = self.view_cells
        if not isinstance(descriptor, Persistent):
            raise HippoNavError(
                f"the view cells {type(descriptor).__name__} cannot be saved (they are not Persistent: "
                "depends_on, export_state, restore_state)"
            )
        keyframes = {} if self.closure is None else self.closure.export_state()
        views = {f"cells.{k}": v for k, v in descriptor.export_state().items()}
        views.update({f"recall.{k}": v for k, v in self.view_recall.export_state().items()})
        state = {
            **_engine_arrays(self.engine),
            "vo_pose": self._vo_pose,
            "last_timestamp_s": np.array(
                np.nan if self._last_timestamp_s is None else self._last_timestamp_s
            ),
            "last_frame_index": np.array(-1 if self._last_frame_index is None else self._last_frame_index),
            "last_online_pose": np.asarray(self._last_online_pose, np.float64),
            "last_code": np.asarray(self._last_code, np.float64),
            "frames": np.array(self.frames),
            "initial_heading_rad": np.array(self.initial_heading_rad),
            # A session saved before it joined its loaded map: where it began, for when it joins.
            "session_first_cell": np.array(self._session_first_cell),
            "session_start_m": np.array(self._session_start_m),
        }
        info = {
            "depends_on": self.depends_on(),
            "config": json.loads(self.config.model_dump_json(by_alias=True)),
            "counts": {
                "vertices": len(self.map),
                "view_cells": len(self.view_cells),
                "keyframes": 0 if self.closure is None else int(self.closure.stored),
                "frames": self.frames,
            },
        }
        return SavedMemory(bytes(self.map.to_bytes()), views, keyframes, state, info)

    def _load(self, memory: SavedMemory, resume: bool) -> None:
        """Take a saved memory (class doc): checked for compatibility, every part restored (any failure one
        `SavedMemoryError`), then its parts checked to agree with each other (`check_parts_agree`)."""
        check_compatible(memory, self.depends_on())
        with _errors_said_of(memory):
            self._restore(memory, resume)
        check_parts_agree(memory, vertices=len(self.map), view_cells=len(self.view_cells))

    def _restore(self, memory: SavedMemory, resume: bool) -> None:
        if self.config.map.closure != ClosureMode.GEOMETRIC and not resume:
            raise HippoNavError(
                'starting inside a saved map needs the geometric closure (map.closure = "Geometric"): '
                "relocalisation is confirmed by the closure measurement"
            )
        if len(self.view_cells) != 0:
            raise HippoNavError("a memory is loaded into fresh view cells only")
        descriptor = self.view_cells
        if not isinstance(descriptor, Persistent):
            raise HippoNavError(
                f"the view cells {type(descriptor).__name__} cannot be restored (not Persistent)"
            )
        descriptor.restore_state(
            {k[len("cells.") :]: v for k, v in memory.views.items() if k.startswith("cells.")}
        )
        self.view_recall.restore_state(
            {k[len("recall.") :]: v for k, v in memory.views.items() if k.startswith("recall.")},
            resume=resume,
        )
        if self.closure is not None and len(memory.keyframes):
            self.closure.restore_state(memory.keyframes)
        self.map = ExperienceMap.from_bytes(memory.map_bytes)
        self.loaded = {
            "folder": str(memory.folder) if memory.folder is not None else None,
            "vertices": len(self.map),
            "view_cells": len(self.view_cells),
            "resumed": bool(resume),
        }
        if resume:
            st = memory.state
            _restore_engine(self.engine, st)
            self._vo_pose = np.array(st["vo_pose"], np.float64)
            timestamp = float(st["last_timestamp_s"])
            self._last_timestamp_s = None if np.isnan(timestamp) else timestamp
            index = int(st["last_frame_index"])
            self._last_frame_index = None if index < 0 else index
            self._last_online_pose = np.array(st["last_online_pose"], np.float64)
            code = np.asarray(st["last_code"], np.float64)
            self._last_code = (float(code[0]), float(code[1]))
            self.frames = int(st["frames"])
            self.initial_heading_rad = float(st["initial_heading_rad"])
            self._session_first_cell = int(st["session_first_cell"])
            self._session_start_m = float(st["session_start_m"])
            return
        self.map.start_session()
        self._session_first_cell = len(self.view_cells)
        self._session_start_m = float(self.map.odometer_m)

    def _joined(self, frame: StereoFrame, outcome: MapFrameOutcome, cell: int) -> None:
        """The session joined its loaded map on this frame: set the networks from the recognised view's
        stored state, placed where the map now puts the agent; views made before the join stop recalling
        (their states are in the session's old frame)."""
        placed = None
        if outcome.world_from_agent is not None:
            placed = self.view_recall.placed_state(cell, self.map, outcome.world_from_agent)
        if placed is not None:
            self.engine.reset(placed[0], placed[1])
        self.view_recall.forget_states(range(self._session_first_cell, len(self.view_cells)))
        self.relocalisation = {
            "frame": int(frame.index),
            "frames_lost": int(self.frames),
            "travelled_m": float(self.map.odometer_m - self._session_start_m),
            "vertex": None if outcome.loop_closure is None else int(outcome.loop_closure[1]),
            "view_cell": int(cell),
            "networks_set": placed is not None,
            "retrace": self._retraced(),
        }
        log.info("frame %s: relocalised in the loaded map (%s)", frame.index, self.relocalisation)

    def _retraced(self) -> dict[str, object] | None:
        """What the retrace of the lost stretch did at the join (`closure.retrace`), or None (no retrace)."""
        proposer = None if self.closure is None else self.closure.proposer("relocalisation")
        report = proposer.retraced if isinstance(proposer, RelocalisationProposer) else None
        return None if report is None else report.as_dict()

    def _data_flags(self, frame: StereoFrame, dt_s: float) -> str:
        """What is odd about this frame's place in the data: sequence frames skipped before it (holes in
        the images), or a time gap. Both are logged once here and flagged in frames.csv."""
        flags = []
        if self._last_frame_index is not None:
            skipped = int(frame.index) - self._last_frame_index - self.stride
            if skipped > 0:
                flags.append(f"skipped_frames:{skipped}")
                log.warning("frame %s: %d sequence frame(s) before it are missing", frame.index, skipped)
        if dt_s > self.limits.max_gap_s:
            flags.append(f"time_gap:{dt_s:.3g}s")
            log.warning(
                "frame %s: %.3g s since the previous frame (a gap); its motion is not extrapolated",
                frame.index,
                dt_s,
            )
        return ";".join(flags)

    def _place_code(self, readout: SpatialReadout) -> tuple[float, float]:
        """The place bump's centre on the torus; the fused grid estimate (or the last code) without one."""
        bump = readout.place if readout.place is not None else readout.fused
        if bump is not None:
            self._last_code = (float(bump.mean_rad[0]), float(bump.mean_rad[1]))
        return self._last_code

    def _online_pose(
        self, outcome: MapFrameOutcome, planar_step_map: tuple[float, float, float]
    ) -> tuple[np.ndarray, np.ndarray]:
        """The map's agent pose and its offset from the current vertex; while lost (relocalising), the pose
        dead-reckoned from the last online pose and no offset (NaN)."""
        if outcome.world_from_agent is None:
            return se2_compose(self._last_online_pose, np.array(planar_step_map)), np.full(3, np.nan)
        return np.array(outcome.world_from_agent), np.array(outcome.vertex_from_agent)


def _engine_arrays(engine: SpatialMemory) -> dict[str, np.ndarray]:
    """The networks' state as named arrays of a memory folder's `state.npz`."""
    state = engine.state()
    return {
        "engine.hd": state["hd"],
        "engine.place": state["place"],
        "engine.aux": np.array(state["aux"]),
        **{f"engine.grid{i}": g for i, g in enumerate(state["grid"])},
    }


@contextlib.contextmanager
def _errors_said_of(memory: SavedMemory) -> Iterator[None]:
    """A part's own error while restoring (e.g. the networks' sizes), or an array that is missing or of
    another shape or type: one `SavedMemoryError` naming the memory's folder."""
    try:
        yield
    except HippoNavError as err:
        if isinstance(err, SavedMemoryError) and str(memory.folder) in str(err):
            raise
        raise SavedMemoryError(f"the saved memory in {memory.folder}: {err}") from None
    except (KeyError, ValueError, TypeError, IndexError, OverflowError) as err:
        raise SavedMemoryError(
            f"the saved memory in {memory.folder}: its arrays cannot be restored ({type(err).__name__}: "
            f"{err}); it was not written by this hippo_nav or was changed after the run: start a new map"
        ) from None


def _restore_engine(engine: SpatialMemory, saved: dict[str, np.ndarray]) -> None:
    """The networks set to the state of `_engine_arrays`."""
    engine.set_state(
        {
            "hd": saved["engine.hd"],
            "grid": [saved[f"engine.grid{i}"] for i in range(len(engine.config.grid))],
            "place": saved["engine.place"],
            "aux": str(saved["engine.aux"]),
        }
    )
