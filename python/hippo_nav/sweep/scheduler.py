"""The driver of a sweep: which runs are left to do (resume), Ray (local or a cluster), progress, Ctrl-C.

`run_sweep(space, out, options)`:
1. refuses a folder that is not a sweep's (a `hippo-nav run` results folder, any other non-empty folder),
   expands the space (its size bounded first) and validates every run's config (a bad value stops the
   sweep before anything runs);
2. locks the sweep folder (a second sweep into it is refused while this one runs) and writes `sweep.json`;
3. resume: a run is finished when its `manifest.json` says `done`, its `metrics.json` parses and holds what
   a finished run writes (`finished`), and its resolved config (hash) is the same; a finished run is
   skipped, one that says `failed` is skipped unless `retry_failed`; every other run (never started,
   `running` when its worker or the driver died, `interrupted`, a truncated `metrics.json`, or done with
   another config because the base config or the package's defaults changed) runs (again);
4. starts Ray (`ray.init(num_cpus=workers × cpus_per_run)` on this machine) or connects to a cluster
   (`address`: first waits at most `CONNECT_TIMEOUT_S` for its port to answer, as Ray itself would retry
   for ever), and keeps as many runs in flight as the cluster has CPUs for (`cpus_per_run` each, declared
   to Ray, which places a run only where that many CPUs are free);
5. a run's own error is caught in its worker and written into its manifest (`failed`, with the error); a
   worker that dies mid-run (killed, out of memory) is restarted by Ray up to `retries` times, then the run
   is listed as failed with Ray's error; neither stops the other runs;
6. SIGINT (Ctrl-C), SIGTERM and SIGHUP (a closed terminal) alike: the runs in flight are asked to stop
   (`worker.StopFlag`, polled by each run) — each stops after its current frame and writes what it
   processed, marked `interrupted` with the signal's name and exit status (128 + its number), which the
   next invocation reruns — and the finished runs stay. A run whose worker ends meanwhile, or that has not
   stopped within `STOP_WAIT_S`, is marked `interrupted` too, never `failed`. A second signal stops waiting.
   A signal the process was started ignoring (`nohup`, `trap '' TERM`) stays ignored.

Every file the driver writes goes through `hippo_nav.io.atomic` (a link planted at a name is replaced or
refused, never written through), and a link in place of `runs/` or a run's folder is refused.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hippo_nav._core import HippoNavError
from hippo_nav.io import read_text
from hippo_nav.io.atomic import open_lock, write_bytes, write_text
from hippo_nav.pipeline.results import RESULTS_MARK
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
"""How long a stop (a signal) waits for the runs in flight to write what they processed."""
CONNECT_TIMEOUT_S = 10.0
"""How long `--address HOST:PORT` waits for something to answer there (Ray alone would retry for ever)."""
RAY_MISSING = "hippo-nav sweep needs Ray: pip install 'hippo-nav[sweep]' (or pip install 'ray[default]')"
MAX_CPUS_PER_RUN = 4096
MAX_WORKERS = 4096
"""CPUs of a run and runs at a time at most (more than any machine has: a larger number is a typo)."""
MAX_RETRIES = 100
"""Restarts of a run whose worker died, at most (a run that dies 100 times will not finish)."""
STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")
"""The signals that stop a sweep, each the same way (module doc, step 6)."""
_TOKEN_LOGGER = "ray._private.authentication.authentication_token_setup"
"""The logger of Ray's notice that a new local instance uses token authentication (module `_connect`)."""


class SweepInterrupted(KeyboardInterrupt):
    """A stop signal arrived; `signame` names it (SIGINT, SIGTERM, SIGHUP)."""

    def __init__(self, signame: str) -> None:
        super().__init__(signame)
        self.signame = signame


_caught: list[str] = []
"""The stop signals `stop_signals`' handler caught, in order: Ray's `wait` turns the `SweepInterrupted` our
handler raises inside it into a plain KeyboardInterrupt (its `check_signals`), losing the name; a SIGTERM
was then reported, and exited, as SIGINT (130 for 143)."""
_depth: list[int] = []  # `stop_signals` blocks open (they nest)


def signal_name(err: BaseException) -> str:
    """The signal behind a KeyboardInterrupt: its own name, else the last one the handler caught (module
    `_caught`), else Ctrl-C's SIGINT."""
    return getattr(err, "signame", None) or (_caught[-1] if _caught else "SIGINT")


def exit_status(signame: str) -> int:
    """The exit status of a process stopped by `signame`: 128 + its number (SIGINT 130, SIGTERM 143, SIGHUP 129)."""
    return 128 + int(getattr(signal, signame, signal.SIGINT))


@contextlib.contextmanager
def stop_signals() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP raise `SweepInterrupted` (naming the signal) in the main thread while the
    block runs, so each stops a sweep the careful way Ctrl-C does. A signal that is ignored when the block
    starts (`nohup`, a scheduler's `trap '' TERM`) stays ignored: it means "do not stop on this". Nested
    blocks are fine (Ray's `init` installs its own SIGTERM handler, so the dispatch installs these again)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handle(signum: int, _frame: object) -> None:
        name = signal.Signals(signum).name
        _caught.append(name)
        raise SweepInterrupted(name)

    if not _depth:
        _caught.clear()  # a new sweep: the signals an earlier one in this process caught are not its own
    previous: dict[int, Any] = {}
    for name in STOP_SIGNALS:
        number = getattr(signal, name, None)
        if number is not None and signal.getsignal(number) is not signal.SIG_IGN:
            previous[number] = signal.signal(number, handle)
    _depth.append(1)
    try:
        yield
    finally:
        _depth.pop()
        for number, handler in previous.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)


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
    connect_timeout_s: float | None = None  # None: CONNECT_TIMEOUT_S


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
    signal: str | None = None  # the signal that interrupted it
    wall_s: float = 0.0

    @property
    def exit_status(self) -> int:
        """What `hippo-nav sweep` exits with: 128 + the signal's number when interrupted, 1 when runs failed."""
        if self.interrupted:
            return exit_status(self.signal or "SIGINT")
        return 1 if self.failed else 0


@dataclass(frozen=True)
class Plan:
    """What resume found: the runs to do now and those already finished."""

    todo: list[RunSpec]
    done: list[RunSpec]
    failed: list[RunSpec]
    changed: list[RunSpec]  # done earlier with another resolved config: run again


def finished(folder: Path, manifest: dict[str, Any] | None) -> bool:
    """Whether a run folder holds a finished run: its manifest says `done`, and its `metrics.json` parses and
    holds what a finished run writes (a frame count of 1 or more, `interrupted` false, no error that
    stopped it, and the frame count of the manifest's dataset checksum). A truncated or hand-edited
    `metrics.json` is a run to do again, never a finished one."""
    if manifest is None or manifest.get("status") != "done":
        return False
    try:
        metrics = json.loads(read_text(folder / "metrics.json", "metrics file"))
    except (OSError, ValueError, RecursionError):  # missing, unreadable, not JSON, not UTF-8, too big
        return False
    if not isinstance(metrics, dict):
        return False
    frames = metrics.get("frames")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        return False
    if metrics.get("interrupted") is not False or metrics.get("stopped_by_error") is not None:
        return False
    dataset = manifest.get("dataset")
    checksum = dataset.get("checksum") if isinstance(dataset, dict) else None
    if isinstance(checksum, dict) and checksum.get("frames") != frames:
        return False
    # Every result file the run wrote, at the size it had (manifests of before this check have no list).
    files = manifest.get("files")
    if files is None:
        return True
    if not isinstance(files, dict):
        return False
    for name, size in files.items():
        path = folder / str(name)
        try:
            if path.is_symlink() or not path.is_file() or path.stat().st_size != size:
                return False
        except OSError:
            return False
    return True


def plan(runs: list[RunSpec], out: Path, retry_failed: bool = False) -> Plan:
    """The resume rule (module doc, step 3) applied to every run's folder under `out/runs/`."""
    todo, done, failed, changed = [], [], [], []
    hashes: dict[str, str] = {}
    for spec in runs:
        folder = out / RUNS_DIR / spec.run_id
        manifest = read_manifest(folder)
        status = None if manifest is None else manifest.get("status")
        if finished(folder, manifest):
            # Runs of one config on other sequences or odometries share its hash: computed once.
            key = json.dumps([spec.config, spec.lesion], sort_keys=True, default=str)
            if key not in hashes:
                hashes[key] = config_hash(spec.pipeline_config())
            if manifest is not None and manifest.get("config_sha256") == hashes[key]:
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
    check_options(options)
    clock = time.perf_counter()
    out = Path(out)
    check_sweep_folder(out)
    with stop_signals():
        return _run_sweep(space, out, options, echo, clock)


def _run_sweep(
    space: SweepSpace, out: Path, options: SweepOptions, echo: Callable[[str], None], clock: float
) -> SweepSummary:
    runs = space.runs(echo)
    if plan(runs, out, options.retry_failed).todo:
        import_ray()  # a missing Ray is said before anything is written
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise HippoNavError(f"sweep folder {out} cannot be created ({_os_reason(err)})") from None
    with _locked(out):
        session = uuid.uuid4().hex
        write_text(out / SESSION_TOKEN, session + "\n")
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
            _check_no_links(out, found.todo)
            _dispatch(found.todo, out, session, options, summary, echo)
    summary.wall_s = time.perf_counter() - clock
    return summary


def check_options(options: SweepOptions) -> None:
    """The numbers of `SweepOptions` in their ranges (one line naming the option), before anything starts."""
    for name, value, lo, hi in (
        ("--cpus-per-run", options.cpus_per_run, 1, MAX_CPUS_PER_RUN),
        ("--workers", options.workers, 1, MAX_WORKERS),
        ("--retries", options.retries, 0, MAX_RETRIES),
    ):
        if value is None and name == "--workers":
            continue
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise HippoNavError(f"{name} {value!r}: give an integer from {lo} to {hi}")
    if options.address is not None and options.address != "auto":
        _host_port(options.address, options.address)


def check_sweep_folder(out: Path) -> None:
    """Refuse to turn a folder that is not a sweep's into one: a `hippo-nav run` results folder, or any other
    folder that holds files, is named and refused (a new or empty folder, or a sweep's, is fine)."""
    try:
        if not out.exists():
            return
        if not out.is_dir():
            raise HippoNavError(f"sweep folder {out} is a file; give --out a folder path")
        present = sorted(p.name for p in out.iterdir())
    except OSError as err:
        raise HippoNavError(f"sweep folder {out} cannot be read ({_os_reason(err)})") from None
    # A sweep killed before its first `sweep.json` leaves only its lock and session token.
    if not present or SWEEP_FILE in present or set(present) <= {LOCK_FILE, SESSION_TOKEN, RUNS_DIR}:
        return
    shown = ", ".join(present[:4]) + (", …" if len(present) > 4 else "")
    if RESULTS_MARK in present or "metrics.json" in present:
        raise HippoNavError(
            f"{out} is the results folder of a `hippo-nav run`, not a sweep folder; give the sweep another --out"
        )
    raise HippoNavError(
        f"{out} is not a sweep folder (it holds {shown} and no {SWEEP_FILE}); give the sweep a new or empty --out"
    )


def _check_no_links(out: Path, todo: list[RunSpec]) -> None:
    """A link in place of `runs/` or a run's folder would send the runs' files elsewhere: refused."""
    for folder in (out / RUNS_DIR, *(out / RUNS_DIR / s.run_id for s in todo)):
        if folder.is_symlink():
            raise HippoNavError(
                f"{folder} is a symbolic link; a sweep writes only into folders of its own: remove the link"
            )


def _os_reason(err: OSError) -> str:
    """What failed, in words (no `[Errno N]`)."""
    if isinstance(err, (FileExistsError, NotADirectoryError)):
        return "a part of that path is a file"
    return (err.strerror or type(err).__name__).lower()


def dry_run(
    space: SweepSpace, out: str | Path, retry_failed: bool = False, echo: Callable[[str], None] | None = None
) -> list[str]:
    """One line per run: what a sweep into `out` would do with it (run, or keep), its id and axes."""
    check_sweep_folder(Path(out))
    runs = space.runs(echo)
    found = plan(runs, Path(out), retry_failed)
    kept = {s.run_id: "done" for s in found.done} | {s.run_id: "failed" for s in found.failed}
    lines = [_plan_line(found, len(runs))]
    for spec in runs:
        axes = ", ".join(f"{k}={v}" for k, v in spec.axes().items() if v is not None)
        lines.append(f"{kept.get(spec.run_id, 'to run'):>7}  {spec.run_id}  ({axes})")
    return lines


def describe(summary: SweepSummary) -> str:
    """The closing line of a sweep (of an interrupted one: what was kept, and how to go on)."""
    if summary.interrupted:
        kept = summary.done + summary.skipped_done
        return (
            f"interrupted by {summary.signal or 'SIGINT'}: {kept} finished runs kept ({summary.done} of them now), "
            f"{summary.left} left to run (those stopped mid-run are marked interrupted); rerun the same command "
            f"to go on; results in {summary.out}"
        )
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
    with open_lock(out / LOCK_FILE) as lock:
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


def _host_port(text: str, given: str) -> tuple[str, int]:
    """HOST and PORT of a cluster address (`HOST:PORT`, `[IPv6]:PORT`, `ray://HOST:PORT`)."""
    host, colon, port = text.split("://", 1)[-1].rstrip("/").rpartition(":")
    host = host.strip("[]")
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise HippoNavError(
            f"--address {given}: give auto or HOST:PORT of a Ray head (e.g. 127.0.0.1:6379; docs/sweep.md)"
        )
    return host, int(port)


def _auto_address() -> tuple[str, str] | None:
    """The address `--address auto` joins, and where it was found: `RAY_ADDRESS`, or the file `ray start`
    leaves on this machine; None when neither has one (Ray then says at once that no cluster runs here)."""
    found = os.environ.get("RAY_ADDRESS", "").strip()
    if found:
        return found, "RAY_ADDRESS"
    current = Path(tempfile.gettempdir()) / "ray" / "ray_current_cluster"
    try:
        found = current.read_text(encoding="utf-8").strip()
    except (OSError, ValueError):
        return None
    return (found, str(current)) if found else None


def wait_for_address(address: str, timeout_s: float) -> None:
    """Wait until something accepts a connection at the cluster's address, at most `timeout_s`; else a
    one-line error naming the address given and what to check. `ray.init` alone retries a port where nothing
    listens for ever (and names the machine's own interface address instead), deaf to SIGTERM meanwhile;
    this wait is short attempts and sleeps, so a stop signal ends it at once."""
    given, text, source = address, address, ""
    if address == "auto":
        auto = _auto_address()
        if auto is None:
            return
        text, where = auto
        source = f" (the address in {where})"
    host, port = _host_port(text, given)
    deadline = time.monotonic() + timeout_s
    reason = "no answer"
    while True:
        left = deadline - time.monotonic()
        try:
            with socket.create_connection((host, port), timeout=max(0.05, min(1.0, left))):
                return
        except OSError as err:
            reason = "connection refused: nothing listens there" if isinstance(
                err, ConnectionRefusedError
            ) else (err.strerror or type(err).__name__).lower()  # fmt: skip
        if time.monotonic() >= deadline:
            raise HippoNavError(
                f"--address {given}: no Ray head answered at {host}:{port}{source} within {timeout_s:g} s "
                f"({reason}); check that `ray start --head --port={port}` runs on {host} and that this machine "
                "can reach that port (docs/sweep.md)"
            )
        time.sleep(min(0.2, max(0.0, deadline - time.monotonic())))


class _DropTokenNotice(logging.Filter):
    """Drops Ray's notice that a new local instance enables token authentication: a sweep on this machine
    starts a private instance on loopback, and the notice, printed by every sweep, says nothing to act on."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("Token authentication is")


def _connect(ray: Any, options: SweepOptions) -> bool:
    """Start or join Ray; True when this call started it (and must shut it down)."""
    if ray.is_initialized():
        return False
    quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
    if options.address is not None:
        timeout_s = CONNECT_TIMEOUT_S if options.connect_timeout_s is None else options.connect_timeout_s
        wait_for_address(options.address, timeout_s)
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
    # Silenced for a local sweep only: on a cluster the auth mode is the user's to know about (docs/sweep.md).
    notice = _DropTokenNotice()
    token_logger = logging.getLogger(_TOKEN_LOGGER)
    token_logger.addFilter(notice)
    try:
        ray.init(address="local", num_cpus=workers * options.cpus_per_run, include_dashboard=False, **quiet)
    finally:
        token_logger.removeFilter(notice)
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
        with stop_signals():  # again: `ray.init` has put its own SIGTERM handler in place of ours
            _run_all(ray, todo, out, session, options, summary)
    finally:
        if started_here:
            ray.shutdown()
    for run_id, error in summary.failed:
        echo(f"failed: {run_id}: {error}")


def _run_all(
    ray: Any, todo: list[RunSpec], out: Path, session: str, options: SweepOptions, summary: SweepSummary
) -> None:
    _check_fits(ray, options.cpus_per_run)
    remote = ray.remote(execute_run).options(
        num_cpus=options.cpus_per_run, max_retries=options.retries, retry_exceptions=False
    )
    stop = ray.remote(num_cpus=0)(StopFlag).remote()
    pending = deque(todo)
    in_flight: dict[Any, RunSpec] = {}
    bar = _progress_bar(len(todo), options.progress)
    try:
        try:
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
        except KeyboardInterrupt as err:
            summary.interrupted = True
            summary.signal = signal_name(err)
            bar.write(
                f"{summary.signal}: stopping the {len(in_flight)} runs in flight after their current frame "
                "(a second signal: stop waiting)"
            )
            try:
                stop.set.remote(summary.signal)  # each run stops after its current frame, writes what it did
                deadline = time.monotonic() + STOP_WAIT_S
                while in_flight and time.monotonic() < deadline:
                    ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                    for ref in ready:
                        _finished(ray, ref, in_flight.pop(ref), out, session, summary)
            except KeyboardInterrupt:
                pass  # a second signal: stop waiting; the runs left are marked below
            # Not failed: interrupted, so that the same command runs them again.
            for spec in in_flight.values():
                _mark(
                    out / RUNS_DIR / spec.run_id, spec, session, "interrupted", exit_status(summary.signal),
                    f"interrupted ({summary.signal}) before it wrote its results",
                )  # fmt: skip
            summary.left = len(todo) - summary.done - len(summary.failed)
        except ray.exceptions.RaySystemError as err:
            # The cluster itself failed (its head stopped, the connection dropped): what finished is kept.
            raise HippoNavError(
                f"the Ray cluster stopped answering ({' '.join(str(err).split())[:300]}); the finished runs are "
                "kept: rerun the same command to go on"
            ) from None
    finally:
        bar.close()


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
        if summary.interrupted:
            # Its worker ended while the sweep stops (the signal reached it too, or Ray is shutting down):
            # interrupted, not failed, so that the same command runs it again.
            _mark(folder, spec, session, "interrupted", exit_status(summary.signal or "SIGINT"),
                  f"interrupted ({summary.signal}): its worker stopped ({type(err).__name__})")  # fmt: skip
            return
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
    _remove(incoming)
    for name, data in files.items():
        relative = Path(name)
        if relative.is_absolute() or ".." in relative.parts:
            raise HippoNavError(
                f"run {folder.name}: its worker sent a file named {name!r}, outside its folder"
            )
        path = incoming / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes(path, data)
    _remove(folder)
    incoming.rename(folder)


def _remove(path: Path) -> None:
    """Remove a file, a folder, or a link itself (never what it points to)."""
    if path.is_symlink() or path.is_file():
        path.unlink(missing_ok=True)
    elif path.is_dir():
        shutil.rmtree(path, ignore_errors=True)


def _progress_bar(total: int, enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc="sweep", unit="run", dynamic_ncols=True, disable=not enabled)
