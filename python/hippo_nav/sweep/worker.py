"""One run of a sweep, on whichever process Ray gives it: `execute_run(spec, sweep_dir, session, cpus)`.

The run is `hippo_nav.pipeline.run(...)`, the function behind `hippo-nav run`, called in the worker process
(not a subprocess of the command line): the same code path, no second interpreter start per run, and the
result's metrics at hand for the manifest. Isolation from a run that crashes the process (a native fault,
the kernel's OOM killer) comes from Ray: the worker process dies, Ray starts another and retries the run
(`max_retries`), and the other runs go on in their own workers.

Where it writes: into `SWEEP/runs/<id>/` directly when this process sees the sweep folder (same machine, or
a file system the cluster shares; checked by reading the session token the driver wrote there), else into a
scratch folder whose files go back to the driver with the result, and the driver writes them.

Every file it writes goes through `hippo_nav.io.atomic` (the manifest, the results) or is opened without
following a link (`open_lock`: the run's log, the results mark, the demo cache's lock), so a link planted in a
sweep folder is never written through; a run folder that is itself a link is refused.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import logging
import os
import shutil
import tempfile
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.io import DatasetError
from hippo_nav.io.atomic import open_lock
from hippo_nav.pipeline.results import RESULTS_MARK
from hippo_nav.sweep.manifest import (
    MANIFEST,
    MANIFEST_VERSION,
    RUN_LOG,
    RUNS_DIR,
    PeakMemory,
    dataset_checksum,
    machine,
    package_provenance,
    read_manifest,
    utc_now,
    write_json_atomic,
)
from hippo_nav.sweep.space import Odometry, RunSpec, config_hash

SESSION_TOKEN = ".sweep_session"
"""Written by the driver into the sweep folder; a worker that reads the same session there writes directly."""

_SIGNAL_EXIT = {"SIGINT": 130, "SIGHUP": 129, "SIGTERM": 143}


class StopFlag:
    """The sweep's stop request, as a Ray actor the driver sets on a stop signal and every run polls
    (`StopWhenAsked`); it holds the signal's name, which each run records.

    Ray's own `ray.cancel` raises KeyboardInterrupt in a running task too, but a task that catches it and
    returns (as a run does, to write the frames it processed) can trip a fatal check in the driver of Ray 2.60
    (`task_manager.cc`, "An unexpected system state has occurred"), so a sweep never cancels a running run."""

    def __init__(self) -> None:
        self.stop: str | None = None

    def set(self, signame: str = "SIGINT") -> None:
        self.stop = self.stop or signame

    def is_set(self) -> str | None:
        """The name of the signal that stopped the sweep, or None while it runs."""
        return self.stop


class StopWhenAsked:
    """An observer of a run (`hippo_nav.pipeline.Observer`) that ends it like Ctrl-C — after the current
    frame, everything processed written — once the sweep's `StopFlag` is set; it asks at most every
    `POLL_S` seconds."""

    POLL_S = 0.5

    def __init__(self, flag: Any) -> None:
        self.flag = flag
        self._asked = time.monotonic()
        self.signal: str | None = None  # the signal that stopped the sweep, once asked to stop

    def on_frame(self, event: Any) -> None:
        if time.monotonic() - self._asked < self.POLL_S:
            return
        import ray

        self._asked = time.monotonic()
        asked = ray.get(self.flag.is_set.remote())
        if asked:
            self.signal = asked if isinstance(asked, str) else "SIGINT"
            raise KeyboardInterrupt

    def on_finish(self, result: Any) -> None:
        return None


def execute_run(spec: RunSpec, sweep_dir: str, session: str, cpus: int, stop: Any = None) -> dict[str, Any]:
    """Run `spec`, write its results folder and `manifest.json`; return the manifest (and, when this
    process cannot see the sweep folder, the folder's files as `files`: name → bytes). `stop`: the sweep's
    `StopFlag` actor (None: run to the end)."""
    # The Rust cores' thread pool is made on first use: limit it to the CPUs the run was given, so runs
    # side by side do not oversubscribe the cores (OpenCV likewise).
    os.environ.setdefault("RAYON_NUM_THREADS", str(cpus))
    _limit_opencv_threads(cpus)
    memory = PeakMemory()
    clock = time.perf_counter()
    shared = _sees(Path(sweep_dir), session)
    dest = Path(sweep_dir) / RUNS_DIR / spec.run_id if shared else Path(tempfile.mkdtemp(prefix="hippo_nav_"))
    for folder in (dest.parent, dest):
        if folder.is_symlink():  # the driver refuses these too; a link made since is refused here
            raise HippoNavError(f"{folder} is a symbolic link; a sweep writes only into folders of its own")
    dest.mkdir(parents=True, exist_ok=True)
    previous = read_manifest(dest)
    retried = previous is not None and previous.get("sweep_session") == session
    retried = retried and previous is not None and previous.get("status") == "running"
    attempt = previous.get("attempt") if retried and previous is not None else None
    manifest: dict[str, Any] = {
        "manifest_version": MANIFEST_VERSION,
        "run_id": spec.run_id,
        "sweep_session": session,
        # A number read back from a file: anything but a sane count starts again at 1.
        "attempt": attempt + 1 if type(attempt) is int and 0 < attempt < 1000 else 1,
        "status": "running",
        "exit_status": None,
        "error": None,
        "axes": spec.axes(),
        "overrides": spec.overrides,
        "lesion": spec.lesion,
        "seed": spec.seed,
        "sequence": spec.sequence,
        "odometry": spec.odometry.as_dict(),
        "dataset": {**spec.dataset.as_dict(), "sequence": spec.sequence, "checksum": None},
        "config": None,
        "config_sha256": None,
        "package": package_provenance(),
        **machine(),
        "cpus": cpus,
        "started_utc": utc_now(),
        "ended_utc": None,
        "wall_s": None,
        "peak_rss_mb": None,
    }
    # A results folder made by a sweep is marked as one, so the run may replace an interrupted attempt's files.
    _plain(dest / RESULTS_MARK)
    open_lock(dest / RESULTS_MARK).close()
    write_json_atomic(dest / MANIFEST, manifest)
    stopper = None if stop is None else StopWhenAsked(stop)
    with _run_log(dest / RUN_LOG):
        _run(spec, dest, manifest, [] if stopper is None else [stopper], stopper)
    if manifest["status"] == "done":
        manifest["files"] = result_file_sizes(dest)
    manifest["ended_utc"] = utc_now()
    manifest["wall_s"] = time.perf_counter() - clock
    manifest["peak_rss_mb"] = memory.peak_mb()
    write_json_atomic(dest / MANIFEST, manifest)
    outcome: dict[str, Any] = {"run_id": spec.run_id, "manifest": manifest, "files": None}
    if not shared:
        outcome["files"] = {
            str(p.relative_to(dest)): p.read_bytes() for p in sorted(dest.rglob("*")) if p.is_file()
        }
        shutil.rmtree(dest, ignore_errors=True)
    return outcome


def result_file_sizes(folder: Path) -> dict[str, int]:
    """Each result file of a finished run (its path in the folder) and its size in bytes: what the resume
    checks, so that a file lost or cut short since has the run redone. The sweep's own files (the manifest,
    the log, the mark) and hidden ones are not results."""
    own = {MANIFEST, RUN_LOG, RESULTS_MARK}
    return {
        path.relative_to(folder).as_posix(): path.stat().st_size
        for path in sorted(folder.rglob("*"))
        if path.is_file()
        and not path.is_symlink()
        and path.name not in own
        and not any(part.startswith(".") for part in path.relative_to(folder).parts)
    }


def _run(
    spec: RunSpec,
    dest: Path,
    manifest: dict[str, Any],
    observers: list[Any],
    stopper: StopWhenAsked | None = None,
) -> None:
    """The run itself; its outcome goes into `manifest` (status, exit status, error, config, checksum). An
    interrupted run records the signal that stopped the sweep (`stopper`), else the one the run caught."""
    from hippo_nav.pipeline import run
    from hippo_nav.system.config import resolved_config_dict

    log = logging.getLogger("hippo_nav.sweep")
    try:
        config = spec.pipeline_config()
        manifest["config"] = resolved_config_dict(config)
        manifest["config_sha256"] = config_hash(config)
        dataset = spec.dataset
        if dataset.path is None:
            _demo_rendered()
        result = run(
                dest, dataset=dataset.path, sequence=spec.sequence, start=dataset.start, stop=dataset.stop,
            stride=dataset.stride, config=config, progress=False, odometry=odometry_of(spec.odometry),
            overwrite=True, dataset_kind=dataset.kind, dataset_options=dict(dataset.options), observers=observers,
        )  # fmt: skip
        manifest["dataset"]["checksum"] = dataset_checksum(result)
        beside = result.out_dir
        if beside is not None and Path(beside).resolve() != dest.resolve():
            # Stopped before its last frame while the folder held a whole earlier run (done under another
            # config, which the plan redoes): `run` kept that run and wrote this part beside it. A sweep
            # reruns an interrupted run from its start, so the part would only sit in `runs/` as a run of its
            # own; the manifest says the run is interrupted, and the next resume runs it.
            shutil.rmtree(beside, ignore_errors=True)
            log.warning(
                "the attempt's part-written results (%s) are removed: the run is redone on resume", beside
            )
        if result.interrupted:
            by = _stopped_by(stopper, result.metrics.get("interrupted_by"))
            manifest.update(
                status="interrupted", exit_status=_SIGNAL_EXIT.get(by, 130), error=f"interrupted ({by})"
            )
        else:
            manifest.update(status="done", exit_status=0)
    except KeyboardInterrupt:  # stopped before the first frame or while writing: the results are not whole
        by = _stopped_by(stopper, None)
        manifest.update(
            status="interrupted",
            exit_status=_SIGNAL_EXIT.get(by, 130),
            error=f"interrupted ({by}) before its results were written",
        )
    except (HippoNavError, DatasetError, OSError) as err:
        # Bad input, as `hippo-nav run` exits 2 on it; a dataset that breaks mid-run keeps the frames before.
        partial = getattr(err, "result", None)
        if partial is not None:
            manifest["dataset"]["checksum"] = dataset_checksum(partial)
        manifest.update(status="failed", exit_status=2, error=_one_line(err))
        log.error("run failed: %s", manifest["error"])
    except Exception as err:  # noqa: BLE001 - one run's bug must not cost the sweep; kept with its traceback
        manifest.update(status="failed", exit_status=1, error=f"{type(err).__name__}: {_one_line(err)}")
        log.error("run failed:\n%s", traceback.format_exc())


def _plain(path: Path) -> None:
    """Remove a link planted at `path` (the link itself, never what it points to): the file is made anew."""
    if path.is_symlink():
        path.unlink()


def _stopped_by(stopper: StopWhenAsked | None, caught: Any) -> str:
    """The signal a run was stopped by: the sweep's (its driver's signal, passed on by the `StopFlag`) or the
    one this process caught; SIGINT when neither is known."""
    if stopper is not None and stopper.signal:
        return stopper.signal
    return caught if isinstance(caught, str) and caught in _SIGNAL_EXIT else "SIGINT"


def odometry_of(choice: Odometry) -> Any:
    """The `odometry` argument of `pipeline.run` for one value of the odometry axis."""
    if choice.kind == "vo":
        return None
    if choice.kind == "drift":
        return drifting_replay
    from hippo_nav.vo.replay import replay_odometry

    assert choice.file is not None
    return replay_odometry(choice.file, file_format=choice.file_format, align=choice.align or "exact")


def drifting_replay(dataset: Any) -> Any:
    """The dataset's ground truth made to drift like a real odometry (`drifting_odometry`'s defaults: every
    step between processed frames 1 % too long and turned 0.02° left), replayed as odometry."""
    from hippo_nav.synthetic import drifting_odometry
    from hippo_nav.vo.replay import PoseFile, ReplayOdometry

    truth = dataset.ground_truth()
    if truth is None:
        raise HippoNavError(f"odometry drift: {dataset.name} has no ground truth to drift")
    indices = np.asarray(dataset.frame_indices, dtype=np.int64)
    # A KITTI pose file is one line per frame number: the drifted poses at the processed frames' lines.
    lines = np.tile(np.eye(4), (int(indices.max()) + 1, 1, 1))
    lines[indices] = drifting_odometry(truth)
    pose_file = PoseFile(Path(f"drift of {dataset.name}"), "kitti", lines, None)
    return ReplayOdometry(pose_file, dataset, align="start")


def _sees(sweep_dir: Path, session: str) -> bool:
    try:
        return (sweep_dir / SESSION_TOKEN).read_text(encoding="utf-8").strip() == session
    except OSError:
        return False


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def _limit_opencv_threads(cpus: int) -> None:
    import cv2

    cv2.setNumThreads(cpus)


@contextlib.contextmanager
def _run_log(path: Path) -> Iterator[None]:
    """The run's log lines (hippo_nav's warnings: VO failures, clamped motion, errors) into `run.log`, opened
    without following a link at its name (`open_lock`), emptied, and readable while the run goes on."""
    _plain(path)
    stream = open_lock(path)
    stream.truncate(0)
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger("hippo_nav")
    level = root.level
    root.addHandler(handler)
    if root.getEffectiveLevel() > logging.INFO:
        root.setLevel(logging.INFO)
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(level)
        handler.close()
        stream.close()


@functools.cache
def _demo_rendered() -> None:
    """The demo loop is rendered once into a cache every worker of a machine shares: the first run renders
    it while the others wait on the lock, instead of all rendering into the same folder at once (once per
    process; later runs find the cache)."""
    from hippo_nav.synthetic import default_cache_dir, demo_sequence

    cache = default_cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    with open_lock(cache / "demo_kitti.lock") as lock:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX)
        try:
            demo_sequence()
        finally:
            fcntl.flock(lock.fileno(), fcntl.LOCK_UN)
