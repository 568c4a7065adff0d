"""The runner: `Pipeline(dataset, config).run(out_dir)` drives the per-frame system over a dataset.

It is the package's main job (the `hippo-nav run` command) and everything around the algorithm: the front
end's threads (`frontend.FrontEnd`: frames loaded and their odometry measured ahead), Ctrl-C and
termination signals, the progress bar, the run's record (`records.RunRecorder`, with per-stage timings),
the observers (`observers.FrameEvent`), and at the end the final correction, the trajectories
(`assemble.assemble_result`), the metrics (`results.evaluate`) and the results folder
(`results.write_results`). The algorithm itself is `system.SlamSystem`.

Ctrl-C (SIGINT), SIGTERM and SIGHUP stop after the current frame; everything for the frames processed
so far is still corrected and written. After the last frame a signal stops the final correction at its
last accepted step or the figures, never the writing of a results file (`_Signals`).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.closure import ClosureChain
from hippo_nav.datasets.base import DatasetExtras, StereoDataset
from hippo_nav.datasets.common import check_frame_range, check_time_unit
from hippo_nav.io import DatasetError
from hippo_nav.memory import SavedMemory, read_memory
from hippo_nav.pipeline.assemble import assemble_result, corrected_track
from hippo_nav.pipeline.frontend import (
    FrontEnd,
    FrontResult,
    Odometry,
    OdometryExtras,
    OdometryGuard,
    resolved_frontend_params,
)
from hippo_nav.pipeline.observers import FrameEvent, Observer, ObserverError, RunInfo
from hippo_nav.pipeline.records import RunRecord, RunRecorder, RunResult
from hippo_nav.pipeline.results import PreviousResults, RunFacts
from hippo_nav.pipeline.sessions import path_to_save, sessions_metrics, sessions_track
from hippo_nav.pipeline.truth import LoadedTruth, loaded_truth, truth_to_save
from hippo_nav.system import parts
from hippo_nav.system.config import PipelineConfig, config_from_dict
from hippo_nav.system.records import StageTimer
from hippo_nav.system.slam import SlamSystem
from hippo_nav.view_cells import ViewDescriptor
from hippo_nav.vo import VoParams
from hippo_nav.vo.disparity import LIMIT_PX as DISPARITY_LIMIT_PX
from hippo_nav.vo.replay import ReplayOdometry

log = logging.getLogger("hippo_nav.pipeline")

__all__ = ["Pipeline", "open_input", "run"]


class Pipeline:
    """`Pipeline(dataset, config).run(out_dir)`: run the whole system on a stereo dataset.

    `dataset` follows `hippo_nav.datasets.StereoDataset`. `progress` shows a tqdm bar with the frame rate
    and the map size. `odometry`, `view_cells` and `closure` replace the parts the config's `parts` section
    names (`frontend.Odometry`, `view_cells.ViewDescriptor`, `closure.ClosureChain`); `observers` watch
    the run frame by frame (`observers.Observer`); `memory` (`hippo_nav.memory.read_memory`) starts the run
    as a new session inside an earlier run's map. `system` is the per-frame system; `odometry` the
    odometry; `record` what has been recorded so far.
    """

    def __init__(
        self,
        dataset: StereoDataset,
        config: PipelineConfig | Mapping[str, Any] | None = None,
        progress: bool = False,
        *,
        odometry: Odometry | None = None,
        view_cells: ViewDescriptor | None = None,
        closure: ClosureChain | None = None,
        observers: Sequence[Observer] = (),
        memory: SavedMemory | None = None,
    ) -> None:
        _check_dataset_type(dataset)
        if isinstance(config, Mapping):  # the settings as a config file holds them, checked as one is
            config = config_from_dict(dict(config))
        elif config is not None and not isinstance(config, PipelineConfig):
            raise TypeError(
                f"config must be a PipelineConfig or a dict of its settings, got {type(config).__name__}"
            )
        self.dataset = dataset
        self.config = config if config is not None else PipelineConfig()
        self.progress = progress
        self.extras = DatasetExtras.of(dataset)
        _check_frames_and_times(dataset)
        self.memory = memory  # the map this run starts inside, kept for scoring (`pipeline.truth`)
        lesions = self.config.lesions
        if lesions.ventral and lesions.intermediate and lesions.dorsal:
            # A lab can inactivate the whole MEC, but then the place cells get no grid input: the neural
            # trajectory stays where it began and cannot be scored, which without this reads like a bug.
            log.warning(
                "every grid module is lesioned: the place cells get no grid input, so the neural estimate "
                "(trajectory_neural) stays at its start and is not scored; the map runs on the odometry"
            )
        self.system = SlamSystem(
            dataset.calibration,
            self.config,
            view_cells=view_cells,
            closure=closure,
            stride=self.extras.stride,
            memory=memory,
        )
        # Front-end parts can be given (e.g. another VO in a notebook); by default they come from the config.
        self.odometry: Odometry = (
            odometry
            if odometry is not None
            else parts.make_odometry(_with_saved_rig(self.config, memory), dataset.calibration)
        )
        if isinstance(self.odometry, ReplayOdometry):
            self.odometry.check_frames(np.asarray(dataset.frame_indices))  # before any frame, not at frame 20
        self.observers = list(observers)
        self._written = False  # this run's results folder is written whole (`run`, `_finish`)
        self._previous: PreviousResults | None = None  # the earlier run's files `--overwrite` set aside
        n = len(dataset)
        wanted = self.config.output.state_frames
        outside = [p for p in (wanted or []) if not 0 <= p < n]
        if outside:
            raise HippoNavError(
                f"output.state_frames: {outside} lie outside this run of {n} frames (positions 0 to {n - 1})"
            )
        state_frames = wanted if wanted is not None else [0, n // 2]
        self._recorder = RunRecorder(
            state_frames, start=self.system.engine, initial_heading_rad=self.system.initial_heading_rad
        )

    @property
    def record(self) -> RunRecord:
        return self._recorder.record

    @property
    def dataset_name(self) -> str:
        return str(self.dataset.name)

    # ----------------------------------------------------------------------------------------------
    def run(self, out_dir: str | Path | None = None, overwrite: bool = False) -> RunResult:
        """Process every frame, correct the map, and (when `out_dir` is given) write the results folder.

        The results folder is checked (and created) before the first frame; one that holds files is
        refused unless `overwrite` (which clears only what a run writes). Ctrl-C, SIGTERM and SIGHUP stop
        after the current frame; the frames processed so far are corrected and written, and the result says
        `interrupted=True` (`metrics["interrupted_by"]` names the signal). Interrupted before the first
        frame, `KeyboardInterrupt` propagates (nothing to write).
        """
        if out_dir is None:
            return self._run(None)
        from hippo_nav.pipeline.results import prepare_results_folder

        out_dir, lock, previous = prepare_results_folder(out_dir, overwrite)
        self._previous = previous
        with lock:  # held until everything is written: a second run into this folder is refused meanwhile
            try:
                return self._run(out_dir)
            finally:
                # The earlier run's files (`--overwrite`) go only once this run's are written whole in their
                # place; else (stopped before its first frame or before its last, results rescued elsewhere)
                # they come back.
                if previous is not None and self._written:
                    previous.discard()
                elif previous is not None:
                    previous.restore()

    def _run(self, out_dir: Path | None) -> RunResult:
        for warning in self.extras.warnings:
            log.warning("%s", warning)
        signals = _Signals()
        with signals.installed():
            return self._run_frames(out_dir, signals)

    def _run_frames(self, out_dir: Path | None, signals: _Signals) -> RunResult:
        interrupted = False
        stopped_by: DatasetError | None = None
        started, started_cpu = time.perf_counter(), time.process_time()
        record = self.record
        # An odometry given to a second run still holds the first one's last frame: its first step would
        # jump back to the start (a 22 m step from a replay, written as a normal trajectory).
        reset = getattr(self.odometry, "reset", None)
        if callable(reset):
            reset()
        guard = OdometryGuard(self.odometry)
        front_end = FrontEnd(
            self.dataset,
            guard,
            self.system.view_cells,
            self.config.overlap_front_end,
            image_size_px=self.dataset.calibration.image_size_px,
        )
        info = RunInfo(self.dataset_name, len(self.dataset), self.dataset.ground_truth)
        with self._progress_bar() as bar, front_end as front:
            try:
                loops = 0
                for i in range(len(self.dataset)):
                    self._process(front.get(i), front, info)
                    if bar is not None:
                        loops += record.frames[-1].loop_closure is not None
                        bar.update()
                        bar.set_postfix(
                            vertices=len(self.system.map), views=len(self.system.view_recall), loops=loops,
                            refresh=False,
                        )  # fmt: skip
                signals.frames_done()
            except KeyboardInterrupt:
                if len(record) == 0:
                    raise
                interrupted = True
                log.warning(
                    "interrupted (%s) after %d frames; writing what was processed",
                    signals.caught or "SIGINT",
                    len(record),
                )
            except DatasetError as err:
                # A missing or corrupt frame mid-sequence: keep (and write) everything before it, then report.
                if len(record) == 0:
                    raise
                interrupted, stopped_by = True, err
        with signals.shielded():
            self.system.finish()
            record.wall_s = time.perf_counter() - started
            record.cpu_s = time.process_time() - started_cpu
            self._recorder.final_snapshot(self.system.engine)
        result = self._finish(out_dir, interrupted, None if stopped_by is None else str(stopped_by), signals)
        observer_failed = self._finish_observers(result, signals)
        if stopped_by is None and observer_failed is None:
            return result
        where = "returned in the exception's `result`"
        if result.out_dir is not None:
            where = f"written to {result.out_dir}"
        error: HippoNavError
        if stopped_by is not None:
            if observer_failed is not None:  # the frame that stopped the run is the error to report
                log.warning("warning: %s", observer_failed)
            if out_dir is not None and result.out_dir != out_dir:
                where += f" (the earlier results in {out_dir} are kept)"
            error = DatasetError(
                f"{stopped_by} — stopped there; the results of the {len(record)} frames before it are {where}"
            )
        else:
            error = ObserverError(f"{observer_failed} (the run's results are {where})")
        error.result = result  # type: ignore[union-attr]
        raise error from observer_failed

    def _finish_observers(self, result: RunResult, signals: _Signals) -> Exception | None:
        """Every observer's `on_finish`, each one even when another failed (a full disk stops a video, and
        the Rerun recording beside it must still be finished); the first failure, for the caller to raise
        once the run's own outcome is settled."""
        failed: Exception | None = None
        for observer in self.observers:
            try:
                # A viewer's flush may wait on another program: a signal cuts it.
                with signals.interruptible():
                    observer.on_finish(result)
            except KeyboardInterrupt:  # the results are written; only a viewer's last frame is lost
                log.warning("the viewers' last frame interrupted; the results are written")
                result.metrics["interrupted_by"] = (
                    result.metrics.get("interrupted_by") or signals.caught or "SIGINT"
                )
                break
            except Exception as err:  # noqa: BLE001 - the results are written; the caller raises it after
                if not isinstance(err, HippoNavError):
                    err = HippoNavError(f"observer {type(observer).__name__} failed at the end: {err!r}")
                if failed is None:
                    failed = err
                else:
                    log.warning("warning: %s", err)
        return failed

    # ----------------------------------------------------------------------------------------------
    def _process(self, front: FrontResult, front_end: FrontEnd, info: RunInfo) -> None:
        """One frame through the system, then the record and the observers."""
        record = self.record
        record.stage_s["load"].append(front.load_s)
        record.stage_s["vo"].append(front.vo_s)
        timer = StageTimer(record.stage_s)
        step = self.system.step(
            front.frame,
            front.step,
            front.vo_status,
            view_description=front.view_description,
            disparity_offset_px=front.disparity_offset_px,
            worker=front_end.worker,
            timer=timer,
        )
        self._recorder.add(step.record, self.system.engine, step.readout)
        if self.observers:
            position = len(record) - 1
            previous = {s: times[position - 1] for s, times in record.stage_s.items()} if position else None
            event = FrameEvent(
                position=position,
                frame=front.frame,
                record=step.record,
                readout=step.readout,
                features_px=front.features_px,
                view_cells=len(self.system.view_recall),
                vertices=len(self.system.map),
                view_rows=self.system.view_cells.image_rows(front.frame.left.shape[0]),
                previous_stage_s=previous,
                run=info,
                _system=self.system,
                _map_revision=self.system.map_revision,
            )
            for observer in self.observers:
                observer.on_frame(event)
        timer.lap("record")

    def _facts(self) -> RunFacts:
        odometry = OdometryExtras.of(self.odometry)
        closure = self.system.closure
        truth, truth_note = loaded_truth(self.memory, self.dataset_name, self._ground_truth())
        return RunFacts(
            frames_requested=len(self.dataset),
            note=self.extras.note,
            seed=self.config.seed,
            lesioned=list(self.system.engine.config.lesioned),
            closure_mode=self.config.map.closure.value,
            min_loop_separation_m=self.config.map.min_loop_separation_m,
            view_cells=len(self.system.view_recall),
            keyframes=0 if closure is None else closure.stored,
            keyframe_bytes=0 if closure is None else closure.stored_bytes,
            keyframe_extractions=None if closure is None else dict(closure.extractions),
            data_warnings=self.extras.warnings + odometry.warnings,
            stereo_bias_px=odometry.stereo_bias_px,
            disparity_offset_px=odometry.disparity_offset_px,
            stereo_fault=odometry.stereo_fault,
            missing_frames=len(self.extras.missing_frames),
            frames_without_timestamp=self.extras.frames_without_timestamp,
            loaded_truth=truth,
            loaded_truth_note=truth_note,
        )

    def _finish(
        self,
        out_dir: str | Path | None,
        interrupted: bool,
        stopped_by: str | None,
        signals: _Signals,
    ) -> RunResult:
        """Correct the map, assemble the trajectories, evaluate, and write the results folder. A signal
        stops the correction at its last accepted step (the map is then part-corrected, and says so);
        while the files are written it waits (`_Signals`)."""
        from hippo_nav.pipeline.results import (
            ResultsNotWrittenError,
            evaluate,
            stopped_run_folder,
            write_results,
        )

        clock = time.perf_counter()
        try:
            with signals.interruptible():
                correction = self.system.correct()
        except KeyboardInterrupt:
            correction = {
                "method": self.config.correction.method,
                "interrupted_by": signals.caught or "SIGINT",
                "note": "stopped before it converged: the map is at the solver's last accepted step",
            }
            log.warning(
                "final correction interrupted (%s); writing the map as it stands",
                correction["interrupted_by"],
            )
        correction_s = time.perf_counter() - clock
        with signals.shielded():
            export = {k: np.asarray(v) for k, v in self.system.map.export().items()}
            result = assemble_result(
                self.dataset_name,
                self.record,
                export,
                self.system.initial_heading_rad,
                self.dataset.ground_truth(),
                interrupted,
            )
            facts = self._facts()
            result.metrics = evaluate(result, facts, correction, stopped_by)
            self._place_sessions(result, export, facts.loaded_truth, facts.loaded_truth_note)
            result.metrics["timing"]["correction_s"] = correction_s
            if self.system.loaded is not None:
                result.metrics["loaded_map"] = {
                    **self.system.loaded,
                    "relocalised": self.system.relocalisation is not None,
                    "relocalisation": self.system.relocalisation,
                }
            if interrupted and stopped_by is None:
                result.metrics["interrupted_by"] = signals.caught or "SIGINT"
            elif signals.caught is not None:  # every frame, but a signal during the correction
                result.metrics["interrupted_by"] = signals.caught
        if out_dir is not None:
            frontend = resolved_frontend_params(self.odometry, self.system.view_cells)
            memory = self._memory_to_save(result) if self.config.output.save_map else None
            target = Path(out_dir)
            if interrupted and self._previous is not None and self._previous.holds_whole_run():
                # Stopped before its last frame (an unreadable frame, a signal) with `--overwrite`: a part
                # of a run never replaces the whole earlier one. Its results go beside the folder, and the
                # earlier run's files come back (`run`).
                target = stopped_run_folder(target)
                log.warning(
                    "the run stopped before its last frame: its results go to %s, and the earlier results in "
                    "%s are kept (--overwrite replaces them only with a run that reaches its end)",
                    target,
                    out_dir,
                )
            try:
                write_results(
                    result,
                    target,
                    self.config,
                    frontend,
                    self.system.map,
                    shield=signals.shielded,
                    interruptible=signals.interruptible,
                    memory=memory,
                )
            except ResultsNotWrittenError as err:
                err.result = result  # type: ignore[attr-defined]
                raise
            self._written = target == Path(out_dir)
        if signals.caught is not None and not result.interrupted:
            # Every frame was processed, but a signal came during the correction or the writing.
            result.metrics["interrupted_by"] = signals.caught
        return result

    def _place_sessions(
        self,
        result: RunResult,
        export: dict[str, np.ndarray],
        truth: LoadedTruth | None,
        truth_note: str | None,
    ) -> None:
        """Every session's frames on the corrected map, and their errors (`pipeline.sessions`)."""
        corrected = corrected_track(self.record, export["poses"]) if len(self.record) else np.zeros((0, 3))
        result.sessions = sessions_track(self.memory, self.record, export["poses"], corrected)
        if result.sessions is not None:
            result.metrics["sessions"] = sessions_metrics(
                result.sessions, truth, result.ground_truth, truth_note
            )

    def _memory_to_save(self, result: RunResult) -> SavedMemory | None:
        """What `memory/` will hold, or None (said in `metrics.json`) when a part cannot be saved."""
        try:
            memory = self.system.save_memory()
        except HippoNavError as err:  # a custom part that cannot be saved: the rest is still written
            log.warning("no memory/ written: %s", err)
            result.metrics.setdefault("unavailable", {})["memory"] = str(err)
            return None
        extras = OdometryExtras.of(self.odometry)
        if extras.disparity_offset_px is not None:
            # The rig's stereo correction as this run ended (found by the VO's self-calibration) and the
            # estimates behind it: a later session with the same cameras starts from it (`_with_saved_rig`).
            memory.info["odometry"] = {"disparity_offset_px": extras.disparity_offset_px}
            if extras.disparity_offset_frames is not None:
                memory.info["odometry"]["disparity_offset_frames"] = extras.disparity_offset_frames
        truth = truth_to_save(
            self.memory, self.dataset_name, self._ground_truth(), self.record, len(self.system.map)
        )
        if truth is not None:
            memory.truth, memory.info["truth"] = truth
        resumed = bool((self.system.loaded or {}).get("resumed"))
        memory.path = path_to_save(self.memory, self.record, resumed)
        return memory

    def _ground_truth(self) -> np.ndarray | None:
        """The dataset's ground truth of the frames processed, in its own frame (not rebased)."""
        gt = self.dataset.ground_truth()
        return None if gt is None else np.asarray(gt)[: len(self.record)]

    @contextlib.contextmanager
    def _progress_bar(self) -> Iterator[Any]:
        """A tqdm bar (or None), with log lines routed through it so that warnings never glue onto the bar."""
        if not self.progress:
            yield None
            return
        from tqdm import tqdm
        from tqdm.contrib.logging import logging_redirect_tqdm

        bar = tqdm(total=len(self.dataset), desc=self.dataset_name, unit="frame", dynamic_ncols=True)
        try:
            with logging_redirect_tqdm():
                yield bar
        finally:
            bar.close()


class _Signals:
    """How the run answers Ctrl-C (SIGINT), SIGTERM and SIGHUP (what schedulers and `docker stop` send).

    The first signal during the frames raises `KeyboardInterrupt` there: the frame loop stops after the
    current frame. From then on (and once the last frame is done) the run is finishing, and a signal only
    waits — the map's correction and the results files are never lost to a second Ctrl-C — except in the
    `interruptible` steps that a signal cuts short without losing anything: the final correction (stopped at
    its last accepted step), the figures and the viewers' last frame. While files are written (`shielded`) a
    signal always waits, so every file is whole; the run then says it was interrupted. `caught` names the
    first signal. Only the main thread can install handlers; elsewhere the default behaviour stays. A signal
    the process was started ignoring stays ignored: `nohup` (SIGHUP) and a scheduler's `trap '' TERM` mean
    "do not stop on this"."""

    def __init__(self) -> None:
        self.caught: str | None = None
        self._shielded = 0
        self._interruptible = 0
        self._finishing = False
        self._told = False

    def handle(self, signum: int, _frame: object) -> None:
        name = signal.Signals(signum).name
        self.caught = self.caught or name
        if self._shielded or (self._finishing and not self._interruptible):
            if not self._told:
                self._told = True
                log.warning("%s: finishing the results files first (they are written whole)", name)
            return
        self._finishing = True
        raise KeyboardInterrupt

    def frames_done(self) -> None:
        """Every frame is processed: from now on only `interruptible` steps stop on a signal."""
        self._finishing = True

    @contextlib.contextmanager
    def interruptible(self) -> Iterator[None]:
        """A step that a signal may cut short even while the run is finishing (class doc)."""
        self._interruptible += 1
        try:
            yield
        finally:
            self._interruptible -= 1

    @contextlib.contextmanager
    def shielded(self) -> Iterator[None]:
        """Signals wait until the block is done."""
        self._shielded += 1
        try:
            yield
        finally:
            self._shielded -= 1

    @contextlib.contextmanager
    def installed(self) -> Iterator[_Signals]:
        wanted = [
            s
            for s in (signal.SIGINT, getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None))
            if s is not None
        ]
        previous = {}
        if threading.current_thread() is threading.main_thread():
            for s in wanted:
                if signal.getsignal(s) is not signal.SIG_IGN:
                    previous[s] = signal.signal(s, self.handle)
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)


def open_input(
    dataset: str | Path | None = None,
    sequence: str | None = None,
    start: int | None = None,
    stop: int | None = None,
    stride: int = 1,
    progress: bool = False,
    kind: str | None = None,
    options: dict[str, Any] | None = None,
) -> StereoDataset:
    """The dataset of a run: any path `open_dataset` reads (a KITTI root, an EuRoC sequence, a ROS bag, a
    stereo folder; `kind` and loader `options` as there; `sequence` defaults to the loader's), or (no
    `dataset`) the built-in synthetic demo loop."""
    from hippo_nav.datasets import KittiOdometry, open_dataset

    check_frame_range(start, stop, stride)
    if dataset is None:
        from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence

        demo = KittiOdometry(demo_sequence(progress=progress), DEMO_SEQUENCE, start, stop, stride)
        demo.name = "synthetic demo loop"
        return demo
    return open_dataset(
        dataset, sequence, kind=kind, start=start, stop=stop, stride=stride, **(options or {})
    )


def _with_saved_rig(config: PipelineConfig, memory: SavedMemory | None) -> PipelineConfig:
    """The config whose VO starts from the disparity offset a saved memory's run ended with (the same rig,
    calibrated by that run's self-calibration), and with the estimates behind it as its prior evidence
    (`vo.disparity_calibration_prior_frames`: the session's first streets do not overturn it), unless this
    run sets `vo.disparity_offset_px` itself."""
    odometry = {} if memory is None else (memory.info.get("odometry") or {})
    saved = odometry.get("disparity_offset_px")
    vo = config.typed_section("vo", VoParams)
    if saved is None or "disparity_offset_px" in vo.model_fields_set:
        return config
    if not (isinstance(saved, (int, float)) and np.isfinite(saved) and abs(saved) <= DISPARITY_LIMIT_PX):
        log.warning("the saved memory's disparity offset %r is not usable; starting from the config's", saved)
        return config
    update: dict[str, float | int] = {"disparity_offset_px": float(saved)}
    frames = odometry.get("disparity_offset_frames")
    # A memory written before the estimates were kept, or whose count is unusable, gives no prior evidence.
    if not (isinstance(frames, int) and not isinstance(frames, bool) and 0 <= frames <= 10**9):
        frames = None
    elif "disparity_calibration_prior_frames" not in vo.model_fields_set:
        update["disparity_calibration_prior_frames"] = frames
    log.info(
        "the stereo VO starts from the saved run's disparity offset, %+.2f px (%s estimates behind it)",
        saved,
        "no" if frames is None else frames,
    )
    vo = vo.model_copy(update=update)
    return config.model_copy(update={"vo": vo})


def run(
    out_dir: str | Path | None = "runs/demo",
    dataset: str | Path | None = None,
    sequence: str | None = None,
    start: int | None = None,
    stop: int | None = None,
    stride: int = 1,
    config: PipelineConfig | Mapping[str, Any] | None = None,
    progress: bool = True,
    odometry: Any = None,
    overwrite: bool = False,
    observers: Sequence[Observer] = (),
    dataset_kind: str | None = None,
    dataset_options: dict[str, Any] | None = None,
    memory_from: str | Path | None = None,
) -> RunResult:
    """The `hippo-nav run` command as a function: open the input, run the pipeline, write `out_dir`.

    `dataset` is any path `open_dataset` reads (None: the built-in demo loop); `dataset_kind` and
    `dataset_options` go to it. `odometry` replaces the built-in stereo VO (e.g. another system's
    trajectory replayed from a file, see `hippo_nav.vo.replay`); it may also be a callable taking the opened
    dataset and returning one. `memory_from`: an earlier run's results folder to start inside (`--map`;
    read and checked before anything else, so a bad one costs nothing)."""
    memory = read_memory(memory_from) if memory_from is not None else None
    opened = open_input(dataset, sequence, start, stop, stride, progress, dataset_kind, dataset_options)
    note = DatasetExtras.of(opened).note
    if note:
        log.info("%s", note)
    if callable(odometry) and not hasattr(odometry, "process"):
        odometry = odometry(opened)
    pipeline = Pipeline(
        opened, config, progress=progress, odometry=odometry, observers=observers, memory=memory
    )
    return pipeline.run(out_dir, overwrite=overwrite)


# What the pipeline reads of a dataset (`StereoDataset`; `__iter__` it does not need).
_DATASET_MEMBERS = (
    "name",
    "calibration",
    "frame_indices",
    "timestamps_s",
    "__len__",
    "__getitem__",
    "ground_truth",
)


def _check_dataset_type(dataset: object) -> None:
    """A path or an object that is not a dataset is a TypeError naming what it lacks, not an AttributeError
    from deep inside the run."""
    missing = [m for m in _DATASET_MEMBERS if not hasattr(dataset, m)]
    if isinstance(dataset, str | Path) or missing:
        raise TypeError(
            f"dataset must be a StereoDataset (hippo_nav.pipeline.open_input(path) opens one), got "
            f"{type(dataset).__name__}" + (f", which lacks {', '.join(missing)}" if missing else "")
        )


def _check_frames_and_times(dataset: StereoDataset) -> None:
    """Any dataset's frame numbers and timestamps must be one per frame, the timestamps in seconds (a reader
    checks its own before trimming to a ground truth; a dataset made in Python is checked here)."""
    n = len(dataset)
    for name in ("frame_indices", "timestamps_s"):
        given = len(np.asarray(getattr(dataset, name)))
        if given != n:
            raise DatasetError(
                f"{dataset.name}: {name} holds {given} values for {n} frames; give one per frame"
            )
    check_time_unit(str(dataset.name), np.asarray(dataset.frame_indices), np.asarray(dataset.timestamps_s))
