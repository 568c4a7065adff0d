"""Metrics of a run (`evaluate`, from its `RunResult` and `RunFacts`) and its results folder (`write_results`).

Results folder (every file is written even when the run was interrupted, for the frames processed;
trajectories first, then metrics, then figures, so a failing figure never costs the rest):

| file | what |
|---|---|
| `config.json` | the fully resolved config of the run (feed it back with `--config` to repeat the run) |
| `trajectory_vo.{kitti,tum}.txt` | the odometry alone (built-in VO or replayed), SE(3) |
| `trajectory_online.{kitti,tum}.txt` | the map's agent pose at each frame as the run went |
| `trajectory_corrected.{kitti,tum}.txt` | the final corrected map at every frame: vertex pose ∘ the frame's offset |
| `trajectory_neural.{kitti,tum}.txt` | the networks' own estimate: unwrapped place-bump position and HD heading |
| `ground_truth.{kitti,tum}.txt` | the dataset's ground truth for the frames used, rebased to the first of them |
| `trajectory_sessions.tum.txt` | a session inside a loaded map: every frame of every session the memory holds, earlier sessions first, re-placed on this run's corrected map (planar, height 0; `pipeline.sessions`) |
| `frames.csv` | per frame: odometry status, motion given to the engine, view cell, injection, vertex, closures |
| `bump_table.csv` | the paper's bump table (μ, σ of every bump of every module, fused and place) at chosen frames |
| `map.bin`, `map.g2o` | the corrected experience map (versioned save file; g2o pose graph) |
| `memory/` | what a later run needs to start inside this map (`--map`; `hippo_nav.memory`, docs/memory.md) |
| `metrics.json` | sizes, loop closures (precision, recall), timing per stage and, with ground truth, errors |
| `recording.npz` | the networks' sampled units, true and decoded position and heading per frame (`Recording`) |
| `module_phase.npz` | each grid module's decoded bump per frame (`recording.py`; both for `figures --run`) |
| `figures/` | not written by the run: `hippo-nav figures --run` draws there; `--overwrite` sets it aside too |
| `cognitive_map.png`, `neural_state_NNNNNN.png`, `rate_maps.png` | figures (see `plots.py`) |

Every trajectory is in the KITTI camera frame of the first processed frame (x right, y down, z forward).
The map's and the networks' planar estimates carry the odometry's height, pitch and roll. Metrics use
`hippo_nav.metrics`: ATE after rigid (SE(3)) Umeyama alignment of the positions, in 3-D and projected on
the ground plane (2-D); relative errors with the KITTI devkit protocol over the devkit's lengths
(100–800 m) that fit the trajectory, else over 1/4, 1/2 and 3/4 of its length (the lengths used are
written with the numbers).

Loop closures against ground truth: a closure (the frame that closed it and the frame that made its target
vertex) is *true* when the two camera positions are within `CLOSURE_TRUE_M` (5 m). A frame is a *revisit*
when the ground truth passed within 5 m of it earlier, at least the map's `min_loop_separation_m` of path
before; recall is the share of revisit frames that lie within `CLOSURE_COVER_M` of travel of a true
closure (a closure every few metres along a revisited street counts the whole street as recognised).
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import json
import logging
import math
import os
import resource
import shutil
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.io import write_kitti_poses, write_tum
from hippo_nav.io.atomic import RESULTS_MARK, WriteError, open_atomic, open_lock, write_text
from hippo_nav.io.errors import os_error_words
from hippo_nav.map import ExperienceMap
from hippo_nav.memory import MEMORY_FOLDER, SavedMemory, write_memory
from hippo_nav.metrics import KITTI_SEGMENT_LENGTHS_M, ate_rmse, relative_errors_kitti, trajectory_distances_m
from hippo_nav.pipeline.records import RunRecord, RunResult
from hippo_nav.pipeline.truth import LoadedTruth
from hippo_nav.system.config import PipelineConfig, resolved_config_dict
from hippo_nav.system.records import STAGES

log = logging.getLogger("hippo_nav.pipeline")

RESULT_FILES = (
    "config.json", "frames.csv", "bump_table.csv", "map.bin", "map.g2o", "metrics.json",
    "cognitive_map.png", "rate_maps.png", "mapping.mp4", "recording.npz", "module_phase.npz",
    "memory/memory.json", "memory/map.bin", "memory/views.npz", "memory/keyframes.npz", "memory/state.npz",
    "figures/neural_measures.json",  # `hippo-nav figures --run`'s: an earlier run's, never the new one's
)  # fmt: skip
RESULT_PATTERNS = (
    "trajectory_*.kitti.txt",
    "trajectory_*.tum.txt",
    "ground_truth.*.txt",
    "neural_state_*.png",
)
"""What a run writes into its results folder (and what `--overwrite` clears, nothing else)."""
PREVIOUS_RESULTS = ".hippo_nav_previous"
"""With `--overwrite`, the earlier run's files are moved here before the first frame (`PreviousResults`), not
deleted: the map a run reads (`--map X --out X`) and the earlier results survive until the new ones are
written whole, and come back when the new run writes nothing."""

CLOSURE_TRUE_M = 5.0
CLOSURE_COVER_M = 10.0
TIMING_WINDOW_FRAMES = 100


def prepare_results_folder(
    out: str | Path, overwrite: bool = False
) -> tuple[Path, IO[str], PreviousResults | None]:
    """Check (and create) the results folder before the first frame, so a run never finishes its frames
    only to find it cannot write them; returns it, its lock (keep the file open for the whole run) and,
    with `overwrite`, the earlier run's files set aside (`PreviousResults`: discard them once the new
    results are written, restore them when nothing was).

    A folder holding files is refused unless `overwrite`, which sets aside the files an earlier run wrote
    there (`RESULT_FILES`, `RESULT_PATTERNS`) and nothing else, and only in a folder a run prepared
    (`RESULTS_MARK`). The mark is also the run's lock (`flock`, exclusive): a second run into the same
    folder is refused while the first one is writing, before it touches anything."""
    if str(out).strip() == "":
        raise HippoNavError("the results folder is an empty path; give --out a folder, e.g. --out runs/x")
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise HippoNavError(f"results folder {path} is a file; give --out a folder path")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise HippoNavError(
            f"results folder {path} cannot be created: a part of that path is a file; choose another --out"
        ) from None
    except PermissionError:
        raise HippoNavError(f"results folder {path} cannot be created here (permission denied)") from None
    except OSError as err:  # a file system that takes no folders there (/proc, a full or read-only disk)
        raise HippoNavError(
            f"results folder {path} cannot be created ({os_error_words(err)}); choose another --out"
        ) from None
    try:
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-check-"):
            pass
    except OSError as err:
        raise HippoNavError(
            f"results folder {path} is not writable ({err.strerror}); choose another --out"
        ) from None
    present = sorted(p.name for p in path.iterdir() if p.name != RESULTS_MARK)
    mark = path / RESULTS_MARK
    if present and not mark.is_file() and overwrite:
        shown = ", ".join(present[:4]) + (", …" if len(present) > 4 else "")
        raise HippoNavError(
            f"--overwrite clears only a hippo_nav results folder, and {path} holds files no run made ({shown}; "
            f"no {RESULTS_MARK} mark); choose another --out (an older results folder: delete it yourself)"
        )
    if present and not overwrite:
        shown = ", ".join(present[:4]) + (", …" if len(present) > 4 else "")
        raise HippoNavError(
            f"results folder {path} is not empty ({shown}); choose another --out, or pass --overwrite "
            "to replace an earlier run's results there"
        )
    if mark.is_symlink():
        raise HippoNavError(f"{mark} is a symbolic link; a results folder's mark must be a plain file")
    try:
        lock = open_lock(mark)  # held open (and locked) for the whole run
    except WriteError as err:
        raise HippoNavError(str(err)) from None
    try:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise HippoNavError(
            f"another run is writing into {path} (it holds {RESULTS_MARK}); wait for it or choose another --out"
        ) from None
    previous = None
    try:
        if overwrite:
            previous = PreviousResults.set_aside(path)
        lock.seek(0)
        lock.truncate()
        lock.write(json.dumps({"hippo_nav_results": 1, "pid": os.getpid()}) + "\n")
        lock.flush()
    except BaseException:
        if previous is not None:
            previous.restore()
        lock.close()
        raise
    return path, lock, previous


def _result_entries(folder: Path) -> list[Path]:
    """The files (and the memory folder) an earlier run wrote into `folder`: `RESULT_FILES`' top-level names
    and `RESULT_PATTERNS`' matches, links included (as links)."""
    names = {name.split("/")[0] for name in RESULT_FILES}
    entries = [folder / name for name in sorted(names)]
    entries += [p for pattern in RESULT_PATTERNS for p in sorted(folder.glob(pattern))]
    return [p for p in dict.fromkeys(entries) if p.is_symlink() or p.exists()]


def _remove(path: Path) -> None:
    """Remove a file, a link (never what it points to) or a folder a run wrote."""
    if path.is_symlink() or not path.is_dir():
        path.unlink(missing_ok=True)
    else:
        shutil.rmtree(path)


class PreviousResults:
    """An earlier run's files in a results folder, set aside by `--overwrite` (`PREVIOUS_RESULTS`).

    `set_aside` moves them (renames: nothing is copied or deleted, a link moves as a link) before the first
    frame; `discard` removes them once the new results are written whole; `restore` puts them back when the
    new run wrote nothing here (stopped before its first frame, its results went beside the folder because it
    stopped before its last frame, or every file went to a rescue folder). A run
    killed outright leaves them set aside: the next `--overwrite` keeps that complete earlier run and drops
    the killed run's part-written files instead."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.aside = folder / PREVIOUS_RESULTS

    @classmethod
    def set_aside(cls, folder: Path) -> PreviousResults:
        previous = cls(folder)
        aside = previous.aside
        moved: list[Path] = []
        try:
            if aside.is_symlink() or (aside.exists() and not aside.is_dir()):
                raise HippoNavError(
                    f"{aside} is not a folder a run made (a link or a file); remove it, then run again"
                )
            if (
                aside.is_dir()
                and not (aside / "metrics.json").exists()
                and (folder / "metrics.json").exists()
            ):
                # Not a killed run's doing (the set-aside run would be whole, its metrics.json with it): an
                # earlier run's files split between the two (a set-aside that stopped part-way, before this
                # version undid it). Removing either half would lose a run.
                raise HippoNavError(
                    f"the earlier results in {folder} are split: some are in {aside}, metrics.json and others "
                    f"are still in {folder}; move the files in {aside} back into {folder} (or remove what you "
                    "do not need), then run again; nothing was removed"
                )
            if aside.is_dir():
                # A run was killed while writing here: the complete run before it is in `aside`; what it
                # left in the folder itself is part-written.
                log.warning(
                    "%s holds an earlier run set aside by a run that never finished; keeping it and "
                    "removing the unfinished run's files",
                    aside,
                )
                for entry in _result_entries(folder):
                    _remove(entry)
                return previous
            entries = _result_entries(folder)
            if entries:
                aside.mkdir()
                for entry in entries:
                    os.rename(entry, aside / entry.name)
                    moved.append(entry)
        except OSError as err:
            # A rename failed part-way (a read-only memory folder cannot be moved: its `..` changes): the files
            # already moved go back, so the folder is whole again and a retry does not take the half set aside
            # for a killed run's whole results.
            left = previous._put_back(moved)
            where = (
                "nothing was removed"
                if not left
                else f"{', '.join(p.name for p in left)} could not be moved back from {aside}: move them into "
                f"{folder} by hand before running again"
            )
            raise HippoNavError(
                f"cannot set the earlier results in {folder} aside for --overwrite: {os_error_words(err)}; {where}"
            ) from None
        return previous

    def _put_back(self, moved: list[Path]) -> list[Path]:
        """Undo a part-way `set_aside`: each moved entry back to its place; the set-aside folder removed when
        empty. Returns the entries that could not be moved back."""
        left = []
        for entry in reversed(moved):
            try:
                os.rename(self.aside / entry.name, entry)
            except OSError:
                left.append(entry)
        with contextlib.suppress(OSError):
            self.aside.rmdir()
        return left

    def holds_whole_run(self) -> bool:
        """The files set aside are a whole run's: some are, and their metrics.json does not say the run
        stopped before its last frame (a sweep's retry replaces its interrupted attempt in place). A
        metrics.json that cannot be read counts as whole: what cannot be judged is kept."""
        if not self.aside.is_dir() or self.aside.is_symlink() or not any(self.aside.iterdir()):
            return False
        try:
            metrics = json.loads((self.aside / "metrics.json").read_text())
        except (OSError, ValueError):
            return True
        return not (isinstance(metrics, dict) and metrics.get("interrupted") is True)

    def discard(self) -> None:
        """The new results are written whole: the earlier ones go."""
        if self.aside.is_dir() and not self.aside.is_symlink():
            shutil.rmtree(self.aside, ignore_errors=True)

    def restore(self) -> None:
        """The new run wrote nothing usable here: the earlier run's files back in place (replacing any
        part-written file of the new one)."""
        if not self.aside.is_dir() or self.aside.is_symlink():
            return
        try:
            for entry in sorted(self.aside.iterdir()):
                target = self.folder / entry.name
                if target.is_symlink() or target.exists():
                    _remove(target)
                os.rename(entry, target)
            self.aside.rmdir()
        except OSError as err:
            log.error(
                "the earlier results could not all be put back from %s: %s", self.aside, os_error_words(err)
            )


def _segment_lengths(gt: np.ndarray) -> tuple[float, ...]:
    total = float(trajectory_distances_m(gt)[-1])
    fitting = tuple(float(length) for length in KITTI_SEGMENT_LENGTHS_M if length < total)
    if fitting:
        return fitting
    # Too short for the devkit's lengths (e.g. the 51-frame KITTI excerpts): quarters of the path.
    return tuple(round(total * f, 1) for f in (0.25, 0.5, 0.75) if total * f > 1.0)


def json_safe(value: Any) -> Any:
    """JSON-safe: NaN/inf → None (strict parsers refuse them), numpy scalars → Python."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def trajectory_errors(gt: np.ndarray, estimates: dict[str, np.ndarray]) -> dict[str, Any]:
    """ATE (3-D and 2-D, SE(3)-aligned) and KITTI relative errors of each estimate against `gt`."""
    if len(gt) < 2:
        raise HippoNavError("a single frame has no trajectory to compare")
    if float(trajectory_distances_m(gt)[-1]) < 1e-6:
        raise HippoNavError("the ground truth never moves, so no alignment is defined")
    lengths = _segment_lengths(gt)
    step = max(1, min(10, len(gt) // 20))
    out: dict[str, Any] = {
        "alignment": "SE(3) Umeyama on positions (no scale); 2-D: projected on the ground plane first",
        "segment_lengths_m": list(lengths),
        "segment_step_frames": step,
    }
    for name, est in estimates.items():
        try:
            entry: dict[str, Any] = {
                "ate_3d_m": ate_rmse(gt, est, planar=False, align="se3"),
                "ate_2d_m": ate_rmse(gt, est, planar=True, align="se3"),
            }
            if lengths:
                rel = relative_errors_kitti(gt, est, lengths=lengths, step=step)
                entry.update(
                    t_rel_percent=rel["t_rel_percent"],
                    r_rel_deg_per_100m=rel["r_rel_deg_per_100m"],
                    segments=rel["segments"],
                )
        except HippoNavError as err:
            # One estimate that cannot be scored (e.g. the networks' estimate with every module lesioned
            # never moves) must not cost the others their numbers.
            entry = {"unavailable": str(err)}
            log.warning("errors of the %s trajectory unavailable: %s", name, err)
        out[name] = entry
    return out


def closure_quality(
    gt: np.ndarray, record: RunRecord, min_separation_m: float, loaded: LoadedTruth | None = None
) -> dict[str, Any]:
    """Precision and recall of the run's loop closures against ground truth (module doc). `loaded`: the truth
    of the map the run started inside (`pipeline.truth`): closures onto its vertices are scored too, and a
    frame near where an earlier session went is a revisit."""
    positions = gt[:, :3, 3]
    path_m = trajectory_distances_m(gt)
    closures = [(p, c) for p, c in enumerate(record.column("loop_closure")) if c is not None]
    true_frames: list[int] = []
    errors_m: list[float] = []
    onto_loaded = [0, 0]  # closures onto a loaded vertex scored, and true
    for position, (_, target) in closures:
        made = record.vertex_position.get(int(target))
        if made is not None:
            there = positions[made]
        elif loaded is not None and 0 <= int(target) < len(loaded.vertex_position_m):
            there = loaded.vertex_position_m[int(target)]
            if not np.isfinite(there).all():
                continue
        else:
            continue
        distance = float(np.linalg.norm(positions[position] - there))
        errors_m.append(distance)
        if made is None:
            onto_loaded[0] += 1
            onto_loaded[1] += distance < CLOSURE_TRUE_M
        if distance < CLOSURE_TRUE_M:
            true_frames.append(position)
    revisit = _revisits(positions, path_m, min_separation_m, loaded)
    covered = np.zeros(len(gt), dtype=bool)
    for position in true_frames:
        covered |= np.abs(path_m - path_m[position]) <= CLOSURE_COVER_M
    n_revisit = int(revisit.sum())
    scored_loaded = (
        {}
        if loaded is None
        else {"onto_loaded_map": {"closures": onto_loaded[0], "true_closures": onto_loaded[1]}}
    )
    return {
        **scored_loaded,
        "closures": len(closures),
        "true_closures": len(true_frames),
        "false_closures": len(errors_m) - len(true_frames),
        "precision": len(true_frames) / len(errors_m) if errors_m else None,
        "revisit_frames": n_revisit,
        "recall": float((revisit & covered).sum() / n_revisit) if n_revisit else None,
        "max_closure_distance_m": max(errors_m) if errors_m else None,
        "true_distance_m": CLOSURE_TRUE_M,
        "cover_m": CLOSURE_COVER_M,
    }


def _revisits(
    positions: np.ndarray, path_m: np.ndarray, min_separation_m: float, loaded: LoadedTruth | None
) -> np.ndarray:
    """Frames within `CLOSURE_TRUE_M` of where the run went at least `min_separation_m` of path earlier, or
    of where an earlier session of the loaded map went (another day: no separation needed)."""
    revisit = np.zeros(len(positions), dtype=bool)
    earlier_days = np.zeros((0, 3)) if loaded is None else loaded.path_position_m
    chunk = 512
    for lo in range(0, len(positions), chunk):
        d = np.linalg.norm(positions[lo : lo + chunk, None, :] - positions[None, :, :], axis=-1)
        earlier = path_m[None, :] <= path_m[lo : lo + chunk, None] - min_separation_m
        revisit[lo : lo + chunk] = ((d < CLOSURE_TRUE_M) & earlier).any(axis=1)
        for start in range(0, len(earlier_days), chunk):
            there = earlier_days[None, start : start + chunk, :]
            near = np.linalg.norm(positions[lo : lo + chunk, None, :] - there, axis=-1) < CLOSURE_TRUE_M
            revisit[lo : lo + chunk] |= near.any(axis=1)
    return revisit


def _peak_rss_mb() -> float:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # Linux reports kilobytes, macOS bytes.
    return peak / 1024.0 if sys.platform != "darwin" else peak / 2**20


def timing(record: RunRecord) -> dict[str, Any]:
    """Per-frame time of every stage over the run, its first and last `TIMING_WINDOW_FRAMES` frames."""
    n = len(record)
    per_stage = {s: float(np.sum(record.stage_s[s])) for s in STAGES}
    frame_total = sum(per_stage.values())
    window = min(TIMING_WINDOW_FRAMES, n)

    def ms(which: slice) -> dict[str, float | None]:
        # A frame stopped part-way (a signal in the middle of its stages) has no time for the stages after.
        window_s = {s: record.stage_s[s][which] for s in STAGES}
        return {s: 1e3 * float(np.mean(t)) if len(t) else None for s, t in window_s.items()} if n else {}

    return {
        "frames": n,
        "wall_s": record.wall_s,
        "per_frame_ms": {s: 1e3 * v / max(n, 1) for s, v in per_stage.items()},
        "first_frames_ms": ms(slice(0, window)),
        "last_frames_ms": ms(slice(n - window, n)),
        "window_frames": window,
        "share_of_frame": {s: v / frame_total if frame_total > 0 else None for s, v in per_stage.items()},
        # Throughput: frames over the loop's wall time (the front end runs frames ahead, so this beats
        # the stages' sum); `frames_per_s_sequential` is what the stages would give one after another.
        "frames_per_s": n / record.wall_s
        if record.wall_s > 0
        else (n / frame_total if frame_total else None),
        "frames_per_s_sequential": n / frame_total if frame_total > 0 else None,
        # Every thread's CPU a frame (the stages' times above are wall times on their own threads), and the
        # cores it kept busy on average: the budget a shared machine pays, which more overlap cannot lower.
        "cpu_ms_per_frame": 1e3 * record.cpu_s / n if n else None,
        "cores_busy": record.cpu_s / record.wall_s if record.wall_s > 0 else None,
        "frames_per_s_without_image_loading": n / (frame_total - per_stage["load"])
        if frame_total > per_stage["load"]
        else None,
        "peak_rss_mb": _peak_rss_mb(),
    }


@dataclass(frozen=True)
class RunFacts:
    """What the metrics need to know of a run besides its result: gathered by the runner from the dataset,
    the config and the system's parts."""

    frames_requested: int
    note: str  # the dataset's note
    seed: int
    lesioned: list[bool]
    closure_mode: str
    min_loop_separation_m: float
    view_cells: int
    keyframes: int  # places the closure proposer keeps, and their bytes
    keyframe_bytes: int
    data_warnings: list[str]  # the dataset's and the odometry's
    stereo_bias_px: float | None  # the odometry's running disparity residual, if it measures one
    disparity_offset_px: float | None  # the stereo correction the odometry applied at the end, if any
    missing_frames: int
    frames_without_timestamp: int
    stereo_fault: str | None = None  # the odometry's verdict on the stereo pair ("swapped", "unrectified", …)
    loaded_truth: LoadedTruth | None = None  # the loaded map's truth (`pipeline.truth`), when comparable
    loaded_truth_note: str | None = None  # why a loaded map's closures go unscored
    # Keyframes extracted this run, by whom (`KeyframeStore.extractions`); None without a closure chain.
    keyframe_extractions: dict[str, int] | None = None


def evaluate(
    result: RunResult, facts: RunFacts, correction: dict[str, Any], stopped_by: str | None
) -> dict[str, Any]:
    """The run's metrics (sizes, closures, timing, and with ground truth the trajectory errors)."""
    record = result.record
    n = len(record)
    export = result.map_export
    closures = record.column("loop_closure")
    attempts = Counter(note for note in record.column("closure_note") if note)
    vo_statuses = Counter(record.column("vo_status"))
    low_texture = int(sum(s in ("low_texture", "failed") for s in record.column("vo_status")))
    if n >= 10 and low_texture > 0.5 * n:
        # A swapped or unrectified pair also leaves the odometry without points, but the images are fine.
        what = (
            f"no stereo depth for the odometry (the stereo pair looks {facts.stereo_fault}: see the warning above)"
            if facts.stereo_fault
            else "too little usable texture for the odometry (dark, blurred or covered images? or a stereo "
            "calibration that gives the pair no depth: check both cameras' intrinsics and the baseline)"
        )
        log.warning(
            "%d of %d frames (%.0f %%) had %s: the trajectory leans on the motion prior there",
            low_texture, n, 100.0 * low_texture / n, what,
        )  # fmt: skip
    rejected = vo_statuses.get("rejected", 0)
    if n >= 10 and rejected > 0.5 * n:
        # Steps faster or turning faster than the VO's limits: wrong timestamps or a wrong calibration more
        # often than a car that fast; the odometry then holds the motion prior, and the map is not the drive.
        log.warning(
            "%d of %d frames (%.0f %%) had an odometry step the VO rejected as too fast for the time between "
            "the frames (vo.max_speed_m_s, vo.max_yaw_rate_rad_s): check the timestamps' unit and the calibration",
            rejected, n, 100.0 * rejected / n,
        )  # fmt: skip
    metrics: dict[str, Any] = {
        "sequence": result.name,
        "note": facts.note,
        "frames": n,
        "frames_requested": facts.frames_requested,
        "interrupted": result.interrupted,
        "stopped_by_error": stopped_by,
        "seed": facts.seed,
        "lesioned": list(facts.lesioned),
        "closure_mode": facts.closure_mode,
        "distance_vo_m": float(trajectory_distances_m(result.vo_world_from_camera)[-1]),
        "view_cells": facts.view_cells,
        "familiar_view_frames": int(sum(s == "familiar" for s in record.column("view_status"))),
        "injected_frames": int(sum(s > 0 for s in record.column("injection_strength"))),
        "vertices": len(export["poses"]),
        "links": len(export["links"]),
        "keyframes": facts.keyframes,
        "keyframe_bytes": facts.keyframe_bytes,
        "keyframe_extractions": facts.keyframe_extractions,
        "loop_closures": int(sum(c is not None for c in closures)),
        "loop_closure_frames": [
            record.frames[p].frame_index for p, c in enumerate(closures) if c is not None
        ],
        "closure_attempts": dict(sorted(attempts.items())),
        "vo_status_counts": dict(sorted(vo_statuses.items())),
        "motion_flags": int(sum(f != "ok" for f in record.column("motion_flag"))),
        "data": {
            "warnings": list(facts.data_warnings),
            "stereo_bias_px": facts.stereo_bias_px,
            "disparity_offset_px": facts.disparity_offset_px,
            "missing_frames": facts.missing_frames,
            "frames_without_timestamp": facts.frames_without_timestamp,
            "frames_after_skipped_frames": sum("skipped_frames" in f for f in record.column("data_flags")),
            "time_gaps": sum("time_gap" in f for f in record.column("data_flags")),
            "low_texture_frames": low_texture,
            "stereo_fault": facts.stereo_fault,
        },
        "correction": correction,
        "timing": timing(record),
    }
    gt = result.ground_truth
    unavailable: dict[str, str] = {}
    if gt is not None:
        metrics["distance_gt_m"] = float(trajectory_distances_m(gt)[-1])
        metrics["errors"] = _guarded("errors", unavailable, lambda: trajectory_errors(gt, result.estimates))
        metrics["closure_quality"] = _guarded(
            "closure_quality",
            unavailable,
            lambda: closure_quality(gt, record, facts.min_loop_separation_m, facts.loaded_truth),
        )
        if facts.loaded_truth_note is not None and metrics["closure_quality"] is not None:
            metrics["closure_quality"]["onto_loaded_map"] = {"unscored": facts.loaded_truth_note}
    if unavailable:
        metrics["unavailable"] = unavailable
    return metrics


def _guarded(what: str, unavailable: dict[str, str], compute: Any) -> Any:
    """`compute()`, or None with the reason recorded in `unavailable[what]`: a metric that cannot be
    computed (one frame, a trajectory that never moved) must not cost the run's other results."""
    try:
        return compute()
    except Exception as err:  # noqa: BLE001 - recorded in metrics.json and logged, never swallowed silently
        unavailable[what] = f"{type(err).__name__}: {err}"
        log.warning("metric %s unavailable: %s", what, unavailable[what])
        return None


def bump_rows(record: RunRecord) -> list[dict[str, Any]]:
    """The paper's bump table at the snapshot frames: one row per bump (μ, σ per axis, rad)."""
    rows: list[dict[str, Any]] = []
    for _position, snapshot in sorted(record.snapshots.items()):
        readout = snapshot.get("readout")
        if readout is None:
            continue
        frame = int(snapshot["frame_index"])
        for module in readout.modules:
            for index, bump in enumerate(module.bumps):
                rows.append(_bump_row(frame, "grid", module.k, index, bump))
        if readout.fused is not None:
            rows.append(_bump_row(frame, "fused", "", 0, readout.fused))
        if readout.place is not None:
            rows.append(_bump_row(frame, "place", "", 0, readout.place))
    return rows


def _bump_row(frame: int, what: str, k: int | str, index: int, bump: Any) -> dict[str, Any]:
    return {
        "frame": frame, "what": what, "k": k, "bump": index,
        "mu_x_rad": bump.mean_rad[0], "mu_y_rad": bump.mean_rad[1],
        "sigma_x_rad": bump.std_rad[0], "sigma_y_rad": bump.std_rad[1],
    }  # fmt: skip


def format_bump_table(rows: list[dict[str, Any]]) -> str:
    """The bump table as aligned text, one block per frame."""
    lines = []
    for frame in sorted({r["frame"] for r in rows}):
        lines.append(f"frame {frame}:  what   k  bump   μx (rad)  μy (rad)   σx (rad)  σy (rad)")
        for r in (r for r in rows if r["frame"] == frame):
            lines.append(
                f"            {r['what']:<6} {r['k']!s:>2} {r['bump']:>5} {r['mu_x_rad']:>9.3f} "
                f"{r['mu_y_rad']:>9.3f} {r['sigma_x_rad']:>10.3f} {r['sigma_y_rad']:>9.3f}"
            )
    return "\n".join(lines)


def _write_frames_csv(path: Path, record: RunRecord) -> None:
    with open_atomic(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "frame", "timestamp_s", "vo_status", "motion_flag", "yaw_rate_rad_s", "speed_m_s",
                "view_cell", "view_status", "view_difference", "injection_strength", "heading_rad",
                "place_code_x_rad", "place_code_y_rad", "vertex", "vertex_created", "loop_closure",
                "closure_note", "data_flags",
            ]
        )  # fmt: skip
        for r in record.frames:
            loop = r.loop_closure
            w.writerow(
                [
                    r.frame_index, f"{r.timestamp_s:.6f}", r.vo_status, r.motion_flag,
                    f"{r.yaw_rate_rad_s:.6g}", f"{r.speed_m_s:.6g}", r.view_cell, r.view_status,
                    f"{r.view_difference:.4f}", f"{r.injection_strength:.4g}", f"{r.heading_rad:.6f}",
                    f"{r.place_code_rad[0]:.6f}", f"{r.place_code_rad[1]:.6f}", r.vertex,
                    int(r.vertex_created), "" if loop is None else f"{loop[0]}->{loop[1]}", r.closure_note,
                    r.data_flags,
                ]
            )  # fmt: skip


def _write_bump_table(path: Path, rows: list[dict[str, Any]]) -> None:
    with open_atomic(path, "w", newline="") as f:
        names = ["frame", "what", "k", "bump", "mu_x_rad", "mu_y_rad", "sigma_x_rad", "sigma_y_rad"]
        w = csv.DictWriter(f, fieldnames=names)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6f}" if isinstance(v, float) else v) for k, v in r.items()})


class ResultsNotWrittenError(WriteError):
    """The results folder could not be written (read-only, full, removed); `rescued_to` is the folder the
    whole results were written to instead, or None when that failed too (the results are then only in
    the exception's `result`)."""

    def __init__(self, failure: WriteError, rescued_to: Path | None, rescue_error: str | None = None) -> None:
        self.rescued_to = rescued_to
        super().__init__(failure.path, failure.reason)
        if rescued_to is not None:
            where = f"the whole results are written to {rescued_to} instead"
        else:
            where = f"and they could not be written elsewhere either ({rescue_error}); nothing was saved"
        self.args = (f"cannot write {failure.path}: {failure.reason}; {where}",)


def stopped_run_folder(out: Path) -> Path:
    """A fresh folder beside `out` for the results of an `--overwrite` run that stopped before its last frame
    (an unreadable frame, a signal) while `out` holds an earlier run: a part of a run never replaces a whole
    one. `OUT.stopped-XXXX` next to `out`, or in a rescue folder when its parent takes no new folder."""
    for parent in [out.parent, *rescue_folder_candidates()]:
        try:
            return Path(tempfile.mkdtemp(prefix=f"{out.name}.stopped-", dir=parent))
        except OSError:
            continue
    raise WriteError(out.parent, "no folder could be made for the stopped run's results")


def rescue_folder_candidates() -> list[Path]:
    """Where results go when their folder cannot take them: the system's temporary folder, then the
    home folder (a full temporary file system is common on small machines)."""
    return [Path(tempfile.gettempdir()), Path.home()]


def write_results(
    result: RunResult,
    out: Path,
    config: PipelineConfig,
    frontend: dict[str, Any] | None = None,
    experience_map: ExperienceMap | None = None,
    shield: Callable[[], AbstractContextManager[Any]] = contextlib.nullcontext,
    memory: SavedMemory | None = None,
    interruptible: Callable[[], AbstractContextManager[Any]] = contextlib.nullcontext,
) -> None:
    """Write the results folder of a run (module doc); `result.out_dir` is set. `frontend`: the resolved
    front-end parameters for config.json; `experience_map`: the map to save (map.bin, map.g2o); `memory`:
    what a later run needs to start inside this one's map (`memory/`, docs/memory.md); `shield`:
    a context in which signals wait (the runner's), entered for everything but the figures, which an
    interrupt only cuts short (the figures drawn by then are listed in metrics.json); `interruptible`: the
    runner's context in which a signal may cut a step short, entered for the figures.

    Every file is written atomically (`hippo_nav.io.atomic`): none is ever left truncated. When the folder
    stops taking files (read-only, full, removed), the whole results are written to a fresh folder
    elsewhere (`rescue_folder_candidates`) and `ResultsNotWrittenError` names the file that failed and
    that folder, so no finished run is lost."""
    try:
        _write_results(result, out, config, frontend, experience_map, shield, memory, interruptible)
    except WriteError as failure:
        log.error("%s", failure)
        rescue_error = "no folder to write to"
        for parent in rescue_folder_candidates():
            rescue = None
            try:
                rescue = Path(tempfile.mkdtemp(prefix="hippo_nav_results_", dir=parent))
                _write_results(
                    result, rescue, config, frontend, experience_map, shield, memory, interruptible
                )
            except WriteError as err:
                rescue_error = str(err)
                if rescue is not None:
                    shutil.rmtree(rescue, ignore_errors=True)
                continue
            except OSError as err:
                rescue_error = os_error_words(err)
                if rescue is not None:
                    shutil.rmtree(rescue, ignore_errors=True)
                continue
            raise ResultsNotWrittenError(failure, rescue) from None
        raise ResultsNotWrittenError(failure, None, rescue_error) from None


def _write_results(
    result: RunResult,
    out: Path,
    config: PipelineConfig,
    frontend: dict[str, Any] | None,
    experience_map: ExperienceMap | None,
    shield: Callable[[], AbstractContextManager[Any]],
    memory: SavedMemory | None,
    interruptible: Callable[[], AbstractContextManager[Any]],
) -> None:
    with shield():
        _write_data(result, out, config, frontend, experience_map, memory)
    metrics = result.metrics
    if config.output.figures:
        from hippo_nav.pipeline.plots import write_run_figures

        clock = time.perf_counter()
        written: list[Path] = []
        try:
            with interruptible():
                write_run_figures(
                    result, out, config.output.rate_map_bin_m, config.engine.torus_period_m, written=written
                )
        except KeyboardInterrupt:
            log.warning("figures interrupted after %d; the other results are written", len(written))
            metrics.setdefault("unavailable", {})["figures"] = "interrupted"
        except WriteError:
            raise  # the folder stopped taking files: `write_results` writes everything elsewhere
        except Exception as err:  # noqa: BLE001 - a figure must never cost the written results
            log.warning("figures failed (%s: %s); the other results are written", type(err).__name__, err)
            metrics.setdefault("unavailable", {})["figures"] = f"{type(err).__name__}: {err}"
        metrics["figures"] = [p.name for p in written]
        metrics["timing"]["figures_s"] = time.perf_counter() - clock
    with shield():
        write_text(out / "metrics.json", json.dumps(json_safe(metrics), indent=2) + "\n")


def _write_data(
    result: RunResult,
    out: Path,
    config: PipelineConfig,
    frontend: dict[str, Any] | None,
    experience_map: ExperienceMap | None,
    memory: SavedMemory | None,
) -> None:
    """Everything but the figures, trajectories first (module doc)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise WriteError(out, "it is not a folder any more") from None
    except OSError as err:
        raise WriteError(out, os_error_words(err)) from None
    clock = time.perf_counter()
    resolved = resolved_config_dict(config)
    resolved.update(frontend or {})
    write_text(out / "config.json", json.dumps(resolved, indent=2) + "\n")
    times = np.asarray(result.record.column("timestamp_s"))
    for name, poses in result.estimates.items():
        write_kitti_poses(out / f"trajectory_{name}.kitti.txt", poses)
        write_tum(out / f"trajectory_{name}.tum.txt", times, poses)
    if result.ground_truth is not None:
        write_kitti_poses(out / "ground_truth.kitti.txt", result.ground_truth)
        write_tum(out / "ground_truth.tum.txt", times, result.ground_truth)
    if result.sessions is not None:
        placed = np.isfinite(result.sessions.planar).all(axis=1)
        write_tum(
            out / "trajectory_sessions.tum.txt",
            result.sessions.timestamp_s[placed],
            result.sessions.world_from_camera()[placed],
        )
    _write_frames_csv(out / "frames.csv", result.record)
    _write_bump_table(out / "bump_table.csv", bump_rows(result.record))
    result.out_dir = out
    metrics = result.metrics
    metrics["timing"]["write_s"] = time.perf_counter() - clock
    # Written before the map and the figures too, so that whatever happens then the metrics are there.
    write_text(out / "metrics.json", json.dumps(json_safe(metrics), indent=2) + "\n")
    if config.output.save_map and experience_map is not None:
        for name, save in (("map.bin", experience_map.save), ("map.g2o", experience_map.write_g2o)):
            try:
                save(out / name)
            except HippoNavError as err:  # the core's file error, as the one every other file gives
                raise WriteError(out / name, str(err).rsplit(": ", 1)[-1]) from None
    if config.output.save_map and memory is not None:
        write_memory(memory, out / MEMORY_FOLDER)
    if config.output.recording:
        from hippo_nav.pipeline.recording import write_recording

        write_recording(result, out, config.engine_config(), config.seed)
