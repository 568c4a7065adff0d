"""The driver of a sweep: which runs are left to do (resume), Ray (local or a cluster), progress, Ctrl-C.

`run_sweep(space, out, options)`:
1. expands the space and validates every run's config (a bad value stops the sweep before anything runs);
2. locks the sweep folder (a second sweep into it is refused while this one runs) and writes `sweep.json`;
3. resume: a run whose `manifest.json` says `done`, with `metrics.json` beside it and the same resolved
   config (hash), is skipped; one that says `failed` is skipped unless `retry_failed`; every other run
   (never started, `running` when its worker or the driver died, `interrupted`, or done with another
   config because the base config or the package's defaults changed) runs (again);
4. starts Ray (`ray.init(num_cpus=workers × cpus_per_run)` on this machine) or connects to a cluster
   (`address`), and keeps as many runs in flight as the cluster has CPUs for (`cpus_per_run` each, declared
   to Ray, which places a run only where that many CPUs are free);
5. a run's own error is caught in its worker and written into its manifest (`failed`, with the error); a
   worker that dies mid-run (killed, out of memory) is restarted by Ray up to `retries` times, then the run
   is listed as failed with Ray's error; neither stops the other runs;
6. Ctrl-C (or SIGTERM): the runs in flight are asked to stop (`worker.StopFlag`, polled by each run) — each
   stops after its current frame and writes what it processed, marked `interrupted`, which the next
   invocation reruns — and the finished runs stay. A second Ctrl-C stops at once.
"""

from __future__ import annotations

import contextlib
import fcntl
import shutil
import signal
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hippo_nav._core import HippoNavError
from hippo_nav.sweep.manifest import (
    MANIFEST,
    RUNS_DIR,
    read_manifest,
    utc_now,
    write_json_atomic,
)
from hippo_nav.sweep.space import RunSpec, SweepSpace, config_hash
from hippo_nav.sweep.worker import SESSION_TOKEN, StopFlag, execute_run

SWEEP_FILE = "sweep.json"
LOCK_FILE = ".sweep.lock"
STOP_WAIT_S = 60.0
"""How long a Ctrl-C waits for the runs in flight to write what they processed."""
RAY_MISSING = "hippo-nav sweep needs Ray: pip install 'hippo-nav[sweep]' (or pip install 'ray[default]')"


@dataclass(frozen=True)
class SweepOptions:
    """How a sweep runs. `address`: None starts Ray on this machine with `workers × cpus_per_run` CPUs
    (`workers` None: as many runs as the machine's cores allow); "auto" or "HOST:PORT" joins a running
    cluster. `retries`: restarts of a run whose worker died."""

    address: str | None = None
    cpus_per_run: int = 1
    workers: int | None = None
    retries: int = 2
    retry_failed: bool = False
    progress: bool = True


@dataclass
class SweepSummary:
    out: Path
    total: int
    skipped_done: int = 0
    skipped_failed: int = 0
    done: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)  # (run id, error)
    left: int = 0  # runs not finished when the sweep was interrupted
    interrupted: bool = False
    wall_s: float = 0.0


@dataclass(frozen=True)
class Plan:
    """What resume found: the runs to do now and those already finished."""

    todo: list[RunSpec]
    done: list[RunSpec]
    failed: list[RunSpec]
    changed: list[RunSpec]  # done earlier with another resolved config: run again


def plan(runs: list[RunSpec], out: Path, retry_failed: bool = False) -> Plan:
    """The resume rule (module doc, step 3) applied to every run's folder under `out/runs/`."""
    todo, done, failed, changed = [], [], [], []
    for spec in runs:
        folder = out / RUNS_DIR / spec.run_id
        manifest = read_manifest(folder)
        status = None if manifest is None else manifest.get("status")
        if status == "done" and (folder / "metrics.json").is_file():
            if manifest is not None and manifest.get("config_sha256") == config_hash(spec.pipeline_config()):
                done.append(spec)
                continue
            changed.append(spec)
        elif status == "failed" and not retry_failed:
            failed.append(spec)
            continue
        todo.append(spec)
    return Plan(todo, done, failed, changed)


def run_sweep(
    space: SweepSpace,
    out: str | Path,
    options: SweepOptions | None = None,
    echo: Callable[[str], None] = print,
) -> SweepSummary:
    """Run every run of `space` not finished yet into `out` (module doc)."""
    options = options or SweepOptions()
    if options.cpus_per_run < 1:
        raise HippoNavError(f"--cpus-per-run {options.cpus_per_run}: give 1 or more")
    if options.workers is not None and options.workers < 1:
        raise HippoNavError(f"--workers {options.workers}: give 1 or more")
    if options.retries < 0:
        raise HippoNavError(f"--retries {options.retries}: give 0 or more")
    clock = time.perf_counter()
    runs = space.runs()
    out = Path(out)
    if plan(runs, out, options.retry_failed).todo:
        import_ray()  # a missing Ray is said before anything is written
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise HippoNavError(f"sweep folder {out} cannot be created ({err.strerror})") from None
    with _locked(out):
        session = uuid.uuid4().hex
        (out / SESSION_TOKEN).write_text(session + "\n", encoding="utf-8")
        write_json_atomic(
            out / SWEEP_FILE,
            {"session": session, "started_utc": utc_now(), "space": space.as_dict(),
             "runs": [{"run_id": s.run_id, "axes": s.axes()} for s in runs]},
        )  # fmt: skip
        # Planned again under the lock: another sweep into this folder may have just ended.
        found = plan(runs, out, options.retry_failed)
        summary = SweepSummary(out, len(runs), len(found.done), len(found.failed))
        echo(_plan_line(found, len(runs)))
        if found.todo:
            _dispatch(found.todo, out, session, options, summary, echo)
    summary.wall_s = time.perf_counter() - clock
    return summary


def dry_run(space: SweepSpace, out: str | Path, retry_failed: bool = False) -> list[str]:
    """One line per run: what a sweep into `out` would do with it (run, or keep), its id and axes."""
    runs = space.runs()
    found = plan(runs, Path(out), retry_failed)
    kept = {s.run_id: "done" for s in found.done} | {s.run_id: "failed" for s in found.failed}
    lines = [_plan_line(found, len(runs))]
    for spec in runs:
        axes = ", ".join(f"{k}={v}" for k, v in spec.axes().items() if v is not None)
        lines.append(f"{kept.get(spec.run_id, 'to run'):>7}  {spec.run_id}  ({axes})")
    return lines


def describe(summary: SweepSummary) -> str:
    """The closing line of a sweep."""
    parts = [f"{summary.done} runs done"]
    if summary.skipped_done:
        parts.append(f"{summary.skipped_done} kept from before")
    if summary.failed or summary.skipped_failed:
        parts.append(f"{len(summary.failed) + summary.skipped_failed} failed")
    if summary.interrupted:
        parts.append(f"{summary.left} left (interrupted; rerun the same command to go on)")
    return f"{', '.join(parts)} in {summary.wall_s:.0f} s; results in {summary.out}; table: hippo-nav report {summary.out}"


def _plan_line(found: Plan, total: int) -> str:
    parts = [f"{total} runs: {len(found.todo)} to run"]
    if found.done:
        parts.append(f"{len(found.done)} done earlier (kept)")
    if found.failed:
        parts.append(f"{len(found.failed)} failed earlier (kept; --retry-failed runs them again)")
    if found.changed:
        parts.append(f"{len(found.changed)} done with another resolved config (run again)")
    return ", ".join(parts)


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    with open(out / LOCK_FILE, "a", encoding="utf-8") as lock:
        try:
            fcntl.flock(lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise HippoNavError(
                f"another sweep is running into {out}; wait for it to finish or give another --out"
            ) from None
        yield


def import_ray() -> Any:
    """Ray, imported only here: the rest of hippo_nav never needs it."""
    try:
        import ray
    except ModuleNotFoundError:
        raise HippoNavError(RAY_MISSING) from None
    return ray


def _connect(ray: Any, options: SweepOptions) -> bool:
    """Start or join Ray; True when this call started it (and must shut it down)."""
    import logging
    import os

    if ray.is_initialized():
        return False
    quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
    if options.address is not None:
        try:
            ray.init(address=options.address, **quiet)
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise HippoNavError(
                f"--address {options.address}: cannot join the Ray cluster ({' '.join(str(err).split())[:300]}); "
                "is `ray start --head` running there (docs/sweep.md)?"
            ) from None
        return True
    workers = options.workers or max(1, (os.cpu_count() or 1) // options.cpus_per_run)
    # A sweep on this machine sends nothing anywhere unless asked to (Ray reports usage by default).
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    # "local": a new instance of our own, even when another Ray runs on this machine (ray.init() alone would
    # join it, and run the sweep on someone else's CPUs).
    ray.init(address="local", num_cpus=workers * options.cpus_per_run, include_dashboard=False, **quiet)
    return True


def _slots(ray: Any, cpus_per_run: int) -> int:
    """Runs the cluster has CPUs for now (nodes may join or leave while a sweep runs)."""
    return max(1, int(ray.cluster_resources().get("CPU", 0) // cpus_per_run))


def _check_fits(ray: Any, cpus_per_run: int) -> None:
    largest = max((n["Resources"].get("CPU", 0) for n in ray.nodes() if n.get("Alive")), default=0)
    if largest < cpus_per_run:
        raise HippoNavError(
            f"--cpus-per-run {cpus_per_run}: no machine of the Ray cluster has that many CPUs (the largest has "
            f"{largest:g}); give at most {int(largest)}"
        )


def _dispatch(
    todo: list[RunSpec],
    out: Path,
    session: str,
    options: SweepOptions,
    summary: SweepSummary,
    echo: Callable[[str], None],
) -> None:
    ray = import_ray()
    started_here = _connect(ray, options)
    try:
        _check_fits(ray, options.cpus_per_run)
        remote = ray.remote(execute_run).options(
            num_cpus=options.cpus_per_run, max_retries=options.retries, retry_exceptions=False
        )
        stop = ray.remote(num_cpus=0)(StopFlag).remote()
        pending = deque(todo)
        in_flight: dict[Any, RunSpec] = {}
        bar = _progress_bar(len(todo), options.progress)
        try:
            with _sigterm_as_interrupt():
                while pending or in_flight:
                    slots = _slots(ray, options.cpus_per_run)
                    while pending and len(in_flight) < slots:
                        spec = pending.popleft()
                        in_flight[remote.remote(spec, str(out), session, options.cpus_per_run, stop)] = spec
                    ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                    for ref in ready:
                        _finished(ray, ref, in_flight.pop(ref), out, session, summary)
                        bar.update()
                    bar.set_postfix(running=len(in_flight), failed=len(summary.failed), refresh=bool(ready))
        except KeyboardInterrupt:
            summary.interrupted = True
            bar.write(
                f"interrupted: stopping {len(in_flight)} runs in flight after their current frame; the finished "
                "runs are kept and a rerun of the same command goes on from here (Ctrl-C again: stop at once)"
            )
            stop.set.remote()  # each run stops after its current frame and writes what it processed
            deadline = time.monotonic() + STOP_WAIT_S
            while in_flight and time.monotonic() < deadline:
                ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                for ref in ready:
                    _finished(ray, ref, in_flight.pop(ref), out, session, summary)
            summary.left = len(todo) - summary.done - len(summary.failed)
        except ray.exceptions.RaySystemError as err:
            # The cluster itself failed (its head stopped, the connection dropped): what finished is kept.
            raise HippoNavError(
                f"the Ray cluster stopped answering ({' '.join(str(err).split())[:300]}); the finished runs are "
                "kept: rerun the same command to go on"
            ) from None
        finally:
            bar.close()
    finally:
        if started_here:
            ray.shutdown()
    for run_id, error in summary.failed:
        echo(f"failed: {run_id}: {error}")


def _finished(ray: Any, ref: Any, spec: RunSpec, out: Path, session: str, summary: SweepSummary) -> None:
    """Take a finished task's outcome: write what the worker could not (shipped files, a died worker's
    manifest) and count it."""
    folder = out / RUNS_DIR / spec.run_id
    try:
        outcome = ray.get(ref)
    except ray.exceptions.TaskCancelledError:  # by hand (`ray` tools): a sweep itself never cancels
        _mark(folder, spec, session, "interrupted", 130, "cancelled")
        return
    except ray.exceptions.RayError as err:
        # The worker died (after Ray's retries) or the task could not run at all: the run is failed, the
        # message says why; the other runs go on.
        error = " ".join(str(err).split())[:500]
        _mark(folder, spec, session, "failed", None, f"{type(err).__name__}: {error}")
        summary.failed.append((spec.run_id, f"{type(err).__name__}: {error}"))
        return
    manifest = outcome["manifest"]
    if outcome["files"] is not None:
        _write_shipped(folder, outcome["files"])
    status = manifest["status"]
    if status == "done":
        summary.done += 1
    elif status == "failed":
        summary.failed.append((spec.run_id, str(manifest.get("error"))))


def _mark(
    folder: Path, spec: RunSpec, session: str, status: str, exit_status: int | None, error: str
) -> None:
    """Write the outcome of a run its worker could not report into its manifest (kept where it had one)."""
    manifest = read_manifest(folder) or {"run_id": spec.run_id, "axes": spec.axes(), "attempt": 1}
    if (
        manifest.get("status") in ("done", "interrupted", "failed")
        and manifest.get("sweep_session") == session
    ):
        return  # the worker wrote its own outcome before the task ended
    manifest.update(
        sweep_session=session, status=status, exit_status=exit_status, error=error, ended_utc=utc_now()
    )
    write_json_atomic(folder / MANIFEST, manifest)


def _write_shipped(folder: Path, files: dict[str, bytes]) -> None:
    """A run from a machine that cannot see the sweep folder: its files replace the folder's, at once."""
    incoming = folder.with_name(f".{folder.name}.incoming")
    shutil.rmtree(incoming, ignore_errors=True)
    for name, data in files.items():
        path = incoming / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    shutil.rmtree(folder, ignore_errors=True)
    incoming.rename(folder)


def _progress_bar(total: int, enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc="sweep", unit="run", dynamic_ncols=True, disable=not enabled)


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (a scheduler's stop) ends a sweep as Ctrl-C does: the finished runs and the frames so far kept."""

    def stop(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous is signal.SIG_IGN:
        yield
        return
    signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
