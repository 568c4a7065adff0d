"""The whole system, one stereo frame at a time: VO → spatial memory ← view cells → experience map.

`Pipeline(dataset, config).run(out_dir)` is the package's main job (the `hippo-nav run` command). Per
frame, in this order:

1. Stereo VO: the SE(3) step `camera_prev_from_camera_cur`. Its planar part (SPEC §9: camera x right,
   y down, z forward) is the map's odometry step `(forward, left, yaw) = (dz, −dx, yaw about −y)`; the
   engine is given `yaw_rate = yaw / dt` and `speed = ±|(dz, dx)| / dt` (negative when reversing), with
   `dt` from the frame timestamps. A VO failure (an exception or a non-finite step) is flagged and the
   previous step is reused (constant-velocity prior); motion beyond `config.limits` is clamped and flagged.
2. Local view cells: a template of the left image is matched; a new cell stores the network's
   `view_patterns()` after this frame's step (so the cell remembers the state where the view was first
   seen); a familiar cell injects its stored patterns (`InjectionConfig`, strength decaying while the
   same cell stays active).
3. Spatial memory (HD ring, three grid modules, place torus) integrates the motion, with the injection.
4. Experience map: `on_frame(view cell, place code (θx, θy), heading code ψ, planar step, dt)`, which
   creates vertices, links, loop closures and runs the online relaxation. The online estimate is the
   map's agent pose; each frame also keeps its offset from its vertex, so after the final correction
   every frame gets a corrected pose (vertex pose ∘ offset).

Nothing depends on wall-clock time (timings are only measured), and OpenCV's RNG is seeded from
`config.seed`, so a run is deterministic for a given config and input. Ctrl-C (KeyboardInterrupt) stops
after the current frame; everything for the frames processed so far is still corrected and written.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine import SpatialMemory, SpatialReadout, ViewPatterns
from hippo_nav.io import DatasetError
from hippo_nav.map import new_experience_map
from hippo_nav.pipeline.config import PipelineConfig
from hippo_nav.pipeline.frontend import make_odometry, make_view_cells
from hippo_nav.vo import planar_step, planar_velocities

log = logging.getLogger("hippo_nav.pipeline")

STAGES = ("load", "vo", "views", "engine", "map", "record")
"""Per-frame stages whose wall time is measured (seconds per frame in `RunRecord.stage_s`)."""

NO_VIEW_ID = 2**63 - 1
"""View-cell id given to the map before any informative view has been seen."""


def se2_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊕ b for (…, 3) arrays of (x, y, yaw)."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, a[..., 2] + b[..., 2]], axis=-1)


def se2_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a⁻¹ ⊕ b for (…, 3) arrays of (x, y, yaw)."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    yaw = np.remainder(b[..., 2] - a[..., 2] + np.pi, 2 * np.pi) - np.pi
    return np.stack([c * dx + s * dy, -s * dx + c * dy, yaw], axis=-1)


@dataclass
class RunRecord:
    """Everything recorded per processed frame (lists grow frame by frame; `arrays()` stacks them)."""

    frame_index: list[int] = field(default_factory=list)
    timestamp_s: list[float] = field(default_factory=list)
    vo_world_from_camera: list[np.ndarray] = field(default_factory=list)
    vo_status: list[str] = field(default_factory=list)
    motion_flag: list[str] = field(default_factory=list)
    yaw_rate_rad_s: list[float] = field(default_factory=list)
    speed_m_s: list[float] = field(default_factory=list)
    view_cell: list[int] = field(default_factory=list)
    view_status: list[str] = field(default_factory=list)
    view_difference: list[float] = field(default_factory=list)
    injection_strength: list[float] = field(default_factory=list)
    heading_rad: list[float] = field(default_factory=list)
    place_code_rad: list[tuple[float, float]] = field(default_factory=list)
    place_position_m: list[tuple[float, float]] = field(default_factory=list)
    vertex: list[int] = field(default_factory=list)
    vertex_created: list[bool] = field(default_factory=list)
    loop_closure: list[tuple[int, int] | None] = field(default_factory=list)
    online_pose: list[np.ndarray] = field(default_factory=list)
    vertex_from_agent: list[np.ndarray] = field(default_factory=list)
    stage_s: dict[str, list[float]] = field(default_factory=lambda: {s: [] for s in STAGES})
    # Sub-sampled unit activities for the firing-rate maps: name -> list of (units,) float32 arrays.
    unit_activity: dict[str, list[np.ndarray]] = field(default_factory=dict)
    # Full network snapshots at chosen frames: frame position -> dict of arrays.
    snapshots: dict[int, dict[str, Any]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frame_index)


@dataclass
class RunResult:
    """What `Pipeline.run` produced; `out_dir` holds the written files (None when not writing)."""

    name: str
    record: RunRecord
    metrics: dict[str, Any]
    vo_world_from_camera: np.ndarray  # (n, 4, 4)
    online_world_from_camera: np.ndarray  # (n, 4, 4), planar
    corrected_world_from_camera: np.ndarray  # (n, 4, 4), planar
    neural_world_from_camera: np.ndarray  # (n, 4, 4), planar: place-bump position and HD heading
    ground_truth: np.ndarray | None  # (n, 4, 4), rebased to the first processed frame
    map_export: dict[str, np.ndarray]
    interrupted: bool
    out_dir: Path | None = None


class Pipeline:
    """`Pipeline(dataset, config).run(out_dir)`: run the whole system on a stereo dataset.

    `dataset` follows `hippo_nav.datasets.StereoDataset`. `progress` shows a tqdm bar with the frame rate
    and the map size. `odometry` and `view_cells` replace the configured front end (see `frontend.py` for
    what they must offer). The parts are exposed for notebooks: `engine`, `views`, `odometry`, `map`.
    """

    def __init__(
        self,
        dataset: Any,
        config: PipelineConfig | None = None,
        progress: bool = False,
        *,
        odometry: Any = None,
        view_cells: Any = None,
    ) -> None:
        import cv2

        self.dataset = dataset
        self.config = config if config is not None else PipelineConfig()
        self.progress = progress
        cv2.setRNGSeed(int(self.config.seed))
        self.engine = SpatialMemory(self.config.engine_config())
        # Front-end parts can be given (e.g. another VO in a notebook); by default they come from the config.
        self.odometry = (
            odometry if odometry is not None else make_odometry(dataset.calibration, self.config.vo)
        )
        self.views = (
            view_cells if view_cells is not None else make_view_cells(self.config.views, dataset.calibration)
        )
        self.map = new_experience_map(self.config.map)
        self.record = RunRecord()
        self._stored_views: dict[int, ViewPatterns] = {}
        self._active_view: int | None = None
        self._active_run = 0
        self._last_active: dict[int, int] = {}
        self._activation_gap: int | None = None
        self._last_step = np.eye(4)
        self._last_timestamp_s: float | None = None
        self._last_code: tuple[float, float] = (0.0, 0.0)
        n = len(dataset)
        wanted = self.config.output.state_frames
        self._state_frames = set(wanted if wanted is not None else [0, n // 2])
        self._unit_stride = max(self.config.engine.place.n_theta // 8, 1)

    # ----------------------------------------------------------------------------------------------
    def run(self, out_dir: str | Path | None = None) -> RunResult:
        """Process every frame, correct the map, and (when `out_dir` is given) write the results folder.

        Ctrl-C stops after the current frame; the frames processed so far are corrected and written, and
        the result says `interrupted=True`.
        """
        from hippo_nav.pipeline.results import finish_run

        frames = range(len(self.dataset))
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=len(self.dataset), desc=self.dataset_name, unit="frame", dynamic_ncols=True)
        interrupted = False
        stopped_by: DatasetError | None = None
        try:
            for i in frames:
                self._process(i)
                if bar is not None:
                    bar.update()
                    bar.set_postfix(
                        vertices=len(self.map),
                        views=len(self.views),
                        loops=sum(c is not None for c in self.record.loop_closure),
                        refresh=False,
                    )
        except KeyboardInterrupt:
            interrupted = True
            log.warning("interrupted after %d frames; writing what was processed", len(self.record))
        except DatasetError as err:
            # A missing or corrupt frame mid-sequence: keep (and write) everything before it, then report.
            if len(self.record) == 0:
                raise
            interrupted, stopped_by = True, err
        finally:
            if bar is not None:
                bar.close()
        if len(self.record) == 0:
            raise HippoNavError("no frame was processed; nothing to write")
        self._snapshot(len(self.record) - 1, final=True)
        result = finish_run(
            self, out_dir, interrupted, stopped_by=None if stopped_by is None else str(stopped_by)
        )
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
    def _process(self, i: int) -> None:
        rec = self.record
        clock = time.perf_counter()
        frame = self.dataset[i]
        clock = self._lap("load", clock)

        # 1. Visual odometry → planar step and the engine's velocities.
        step, vo_status = self._vo_step(frame)
        dt_s = 0.0 if self._last_timestamp_s is None else float(frame.timestamp_s - self._last_timestamp_s)
        self._last_timestamp_s = float(frame.timestamp_s)
        forward_m, left_m, yaw_rad = planar_step(step)
        clock = self._lap("vo", clock)

        # 2. Local view cells: which view, and what (if anything) it injects.
        obs = self._observe_view(frame.left)
        view, strength = self._injection(obs)
        clock = self._lap("views", clock)

        # 3. Spatial memory integrates the motion (not on the first frame: there is no motion yet).
        yaw_rate, speed, flag = 0.0, 0.0, "ok" if vo_status == "ok" else f"vo:{vo_status}"
        if dt_s > 0:
            yaw_rate, speed = planar_velocities(step, dt_s)
            readout, yaw_rate, speed, engine_flag = self._engine_step(yaw_rate, speed, dt_s, view)
            flag = engine_flag or flag
        else:
            readout = self.engine.readout()
        if obs is not None and obs.is_new:
            self._stored_views[int(obs.cell_id)] = self._patterns_to_store()
        clock = self._lap("engine", clock)

        # 4. Experience map.
        code = self._place_code(readout)
        view_id = NO_VIEW_ID if self._active_view is None else self._active_view
        outcome = self.map.on_frame(
            view_id, code, float(readout.heading_rad), (forward_m, left_m, yaw_rad), max(dt_s, 0.0)
        )
        vertex = outcome["vertex"]
        agent = outcome["world_from_agent"]
        if agent is None:  # lost (relocalising): dead-reckon from the last online pose
            previous = rec.online_pose[-1] if rec.online_pose else np.zeros(3)
            agent_pose = se2_compose(previous, np.array([forward_m, left_m, yaw_rad]))
            offset = np.full(3, np.nan)
        else:
            agent_pose = np.array(agent, dtype=np.float64)
            offset = se2_between(np.asarray(self.map.poses())[vertex], agent_pose)
        clock = self._lap("map", clock)

        previous_vo = rec.vo_world_from_camera[-1] if rec.vo_world_from_camera else np.eye(4)
        rec.frame_index.append(int(frame.index))
        rec.timestamp_s.append(float(frame.timestamp_s))
        rec.vo_world_from_camera.append(previous_vo @ step)
        rec.vo_status.append(vo_status)
        rec.motion_flag.append(flag)
        rec.yaw_rate_rad_s.append(yaw_rate)
        rec.speed_m_s.append(speed)
        rec.view_cell.append(-1 if obs is None or obs.cell_id is None else int(obs.cell_id))
        rec.view_status.append("none" if obs is None else str(obs.status))
        rec.view_difference.append(float("nan") if obs is None else float(obs.difference))
        rec.injection_strength.append(strength)
        rec.heading_rad.append(float(readout.heading_rad))
        rec.place_code_rad.append(code)
        rec.place_position_m.append(tuple(readout.place_position_m))
        rec.vertex.append(-1 if vertex is None else int(vertex))
        rec.vertex_created.append(bool(outcome["created"]))
        rec.loop_closure.append(outcome["loop_closure"])
        rec.online_pose.append(agent_pose)
        rec.vertex_from_agent.append(offset)
        self._record_units()
        self._snapshot(len(rec) - 1)
        self._lap("record", clock)

    def _lap(self, stage: str, since: float) -> float:
        now = time.perf_counter()
        self.record.stage_s[stage].append(now - since)
        return now

    # ----------------------------------------------------------------------------------------------
    def _vo_step(self, frame: Any) -> tuple[np.ndarray, str]:
        """The VO's SE(3) step, or the previous step (constant-velocity prior) when the VO fails."""
        try:
            result = self.odometry.process(frame)
            step = np.asarray(result.camera_prev_from_camera_cur, dtype=np.float64)
            status = str(getattr(result, "status", "ok"))
        except (HippoNavError, ArithmeticError) as err:
            log.warning("frame %s: VO failed (%s); using the previous step", frame.index, err)
            return self._last_step.copy(), "failed"
        if step.shape != (4, 4) or not np.isfinite(step).all():
            log.warning("frame %s: VO returned an invalid step; using the previous step", frame.index)
            return self._last_step.copy(), "failed"
        self._last_step = step
        return step, status

    def _observe_view(self, left: np.ndarray) -> Any:
        obs = self.views.observe(self.views.template_from_image(left))
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
        """The stored patterns of a familiar view, scaled by the decaying strength (SPEC §7)."""
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
        hd = stored.hd_profile
        if cfg.shift_heading:
            # The stored profile peaks at the heading the view was stored with; now the camera faces
            # `relative_heading_rad` further (counter-clockwise), so rotate it by that many θ bins.
            shift = int(np.rint(float(obs.relative_heading_rad) / (2 * np.pi / len(hd))))
            hd = np.roll(hd, shift)
        return ViewPatterns(hd_profile=hd, grid_layer2=list(stored.grid_layer2), strength=strength), strength

    def _patterns_to_store(self) -> ViewPatterns:
        # float32 keeps a stored view at ~50 kB (HD profile + three 64×64 layer-II patterns).
        p = self.engine.view_patterns()
        return ViewPatterns(
            hd_profile=np.asarray(p.hd_profile, dtype=np.float32),
            grid_layer2=[None if g is None else np.asarray(g, dtype=np.float32) for g in p.grid_layer2],
        )

    def _engine_step(
        self, yaw_rate: float, speed: float, dt_s: float, view: ViewPatterns | None
    ) -> tuple[SpatialReadout, float, float, str]:
        """Step the engine; clamp absurd motion, and if the engine still refuses, skip the motion."""
        limits = self.config.limits
        flag = ""
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

    def _place_code(self, readout: SpatialReadout) -> tuple[float, float]:
        """The place bump's centre on the torus; the fused grid estimate (or the last code) without one."""
        bump = readout.place if readout.place is not None else readout.fused
        if bump is not None:
            self._last_code = (float(bump.mean_rad[0]), float(bump.mean_rad[1]))
        return self._last_code

    # ----------------------------------------------------------------------------------------------
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

    def _snapshot(self, position: int, final: bool = False) -> None:
        if not (final or position in self._state_frames) or position in self.record.snapshots:
            return
        sm = self.engine
        self.record.snapshots[position] = {
            "frame_index": self.record.frame_index[position],
            "hd": sm.hd_activity(),
            "grid": [None if sm.config.lesioned[m] else sm.grid_activity(m) for m in range(3)],
            "layer2": [None if sm.config.lesioned[m] else sm.grid_layer2(m) for m in range(3)],
            "place": sm.place_activity(),
            "k": [g.k for g in sm.config.grid],
            "nu_max": [g.nu_max for g in sm.config.grid],
            "hd_nu_max": sm.config.hd.nu_max,
        }


def open_input(
    kitti: str | Path | None = None,
    sequence: str = "00",
    start: int | None = None,
    stop: int | None = None,
    stride: int = 1,
    progress: bool = False,
) -> Any:
    """The dataset of a run: a KITTI sequence, or (no `kitti`) the built-in synthetic demo loop."""
    from hippo_nav.datasets import KittiOdometry, open_dataset

    if kitti is None:
        from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence

        dataset = KittiOdometry(demo_sequence(progress=progress), DEMO_SEQUENCE, start, stop, stride)
        dataset.name = "synthetic demo loop"
        return dataset
    return open_dataset(kitti, sequence, start=start, stop=stop, stride=stride)


def run(
    out_dir: str | Path | None = "runs/demo",
    kitti: str | Path | None = None,
    sequence: str = "00",
    start: int | None = None,
    stop: int | None = None,
    stride: int = 1,
    config: PipelineConfig | None = None,
    progress: bool = True,
    odometry: Any = None,
) -> RunResult:
    """The `hippo-nav run` command as a function: open the input, run the pipeline, write `out_dir`.

    `odometry` replaces the built-in stereo VO (e.g. another system's trajectory replayed from a file,
    see `hippo_nav.vo.replay`); it may also be a callable taking the opened dataset and returning one."""
    dataset = open_input(kitti, sequence, start, stop, stride, progress=progress)
    note = getattr(dataset, "note", "")
    if note:
        log.info("%s", note)
    if callable(odometry) and not hasattr(odometry, "process"):
        odometry = odometry(dataset)
    return Pipeline(dataset, config, progress=progress, odometry=odometry).run(out_dir)
