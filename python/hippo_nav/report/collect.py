"""The runs a report reads, as rows: what each run varies (`axes`) and its numbers (`values`).

A run is a folder holding `metrics.json`: a sweep's `runs/<id>/` (with `manifest.json`: its axes, status,
wall time and peak memory) or a plain `hippo-nav run` folder, whose axes are read from what it wrote: the
sequence, the seed and the lesions from `metrics.json`, and every config value that differs from the
defaults (`config.json` against `PipelineConfig()`) as an override. A sweep run without `metrics.json`
(failed before its first frame, or never finished) is a row too, with its status and error.

`METRICS` is the one list of the numbers a row carries: the name of the column and where it comes from.
Three are measured from the run's files rather than read: `place_sigma_rad` (the CA3 place bump's width,
mean of its two axes, averaged over the snapshot frames of `bump_table.csv`), `theory_sigma_rad` (the
1-D theory's fused width, `(Σ_m 1/σ_m²)^(−1/2)`, from the same frames' grid-module widths, lesioned modules
absent) and `pi_error_2d_m` (path integration: the place code's trajectory against the odometry it
integrates, ATE on the ground plane after SE(3) alignment, so the odometry's own error drops out).

Every file a row is read from (`manifest.json`, `metrics.json`, `config.json`, `bump_table.csv`, the
trajectories) is checked field by field as it is read: a file that is truncated, not JSON, too large, not a
regular file, or holds a field of the wrong type or an impossible value (a negative count, NaN, a precision
above 1) makes the run *unreadable*. A report over many runs goes on without it: the run is left out of every
table and statistic (a half-read run would bias them silently), one warning names the file, the field and what
is wrong, and `table.md` lists it under "Skipped runs". A missing optional file (no `bump_table.csv`, no
trajectories) is not an error: its numbers are empty. A sweep's `sweep.json` only orders its runs: when it is
unreadable the runs are in name order, with one warning.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav._defaults import dotted
from hippo_nav.io.errors import MAX_DATA_FILE_BYTES, MAX_SETTINGS_FILE_BYTES, read_text
from hippo_nav.sweep.manifest import MANIFEST, RUNS_DIR, STATUSES

log = logging.getLogger(__name__)

LESION_MODULES = ("ventral", "intermediate", "dorsal")
MAX_NESTING = 32
"""The deepest nesting of a JSON file read (hippo-nav's own are 4 deep): deeper is not one of its files, and
is refused before anything walks it (no recursion limit to hit)."""
MAX_INTEGER = 2**53
"""The largest integer a field may hold: beyond it a number is not exact as a float (and far beyond any count
or setting hippo-nav writes)."""


class RunFileError(HippoNavError):
    """A file of a run is malformed; the message names the file, the field and what is wrong."""


def _bad(path: Path, field: str | None, problem: str) -> RunFileError:
    return RunFileError(f"{path}: {field}: {problem}" if field else f"{path}: {problem}")


@dataclass(frozen=True)
class SkippedRun:
    """A run left out of a report: its folder and why (the file, the field, what is wrong)."""

    folder: Path
    reason: str


def _at(*path: str) -> Callable[[dict[str, Any]], Any]:
    """A getter of the field at `path`; None when a level is absent or null. A level that is there but not
    an object raises `TypeError` naming the dotted field (the caller adds the file)."""

    def get(metrics: dict[str, Any]) -> Any:
        value: Any = metrics
        for depth, key in enumerate(path):
            if value is None:
                return None
            if not isinstance(value, dict):
                raise TypeError(".".join(path[:depth]), f"expected an object, got {_what(value)}")
            value = value.get(key)
        return value

    return get


METRIC_FIELDS: dict[str, tuple[str, ...]] = {
    "frames": ("frames",),
    "ate_2d_vo_m": ("errors", "vo", "ate_2d_m"),
    "ate_2d_online_m": ("errors", "online", "ate_2d_m"),
    "ate_2d_corrected_m": ("errors", "corrected", "ate_2d_m"),
    "ate_2d_neural_m": ("errors", "neural", "ate_2d_m"),
    "ate_3d_vo_m": ("errors", "vo", "ate_3d_m"),
    "ate_3d_corrected_m": ("errors", "corrected", "ate_3d_m"),
    "t_rel_corrected_percent": ("errors", "corrected", "t_rel_percent"),
    "loop_closures": ("loop_closures",),
    "true_closures": ("closure_quality", "true_closures"),
    "precision": ("closure_quality", "precision"),
    "recall": ("closure_quality", "recall"),
    "view_cells": ("view_cells",),
    "vertices": ("vertices",),
    "frames_per_s": ("timing", "frames_per_s"),
}
"""Where each number of `metrics.json` is: (column: path of keys)."""
METRICS: list[tuple[str, Callable[[dict[str, Any]], Any]]] = [
    (name, _at(*path)) for name, path in METRIC_FIELDS.items()
]
"""Numbers read from `metrics.json`: (column, getter)."""
COUNTS = ("frames", "loop_closures", "true_closures", "view_cells", "vertices")
"""Columns that are whole numbers."""
FRACTIONS = ("precision", "recall")
"""Columns between 0 and 1."""
MEASURED = ("place_sigma_rad", "theory_sigma_rad", "pi_error_2d_m")
"""Numbers measured from a run's files (module doc)."""
TIMINGS = ("wall_s", "peak_rss_mb")
"""From the manifest (a plain run: `metrics.json`'s timing)."""


@dataclass
class RunRow:
    """One run: its folder, id, sweep, status, what it varies and its numbers."""

    folder: Path
    run_id: str
    sweep: str
    status: str
    error: str | None
    axes: dict[str, Any]
    values: dict[str, float | None] = field(default_factory=dict)
    # What the run was set up with besides its axes (a sweep's base config, its frame range), when known:
    # runs that differ only there are not one configuration (`reveal_setups`).
    setup: dict[str, Any] | None = None


def find_run_folders(dirs: Sequence[str | Path]) -> list[tuple[Path, str]]:
    """(run folder, sweep or parent name) of every run under `dirs`: sweep folders, plain run folders and
    folders holding either, in a stable order; a folder is read once even when named twice."""
    found: dict[Path, str] = {}
    seen: set[Path] = set()
    for given in dirs:
        root = Path(given)
        if not root.is_dir():
            what = "a file, not a folder" if root.exists() else "no such folder"
            raise HippoNavError(f"{given}: {what} (give sweep folders or hippo-nav run folders)")
        candidates = {p.parent for p in root.rglob("metrics.json")} | {p.parent for p in root.rglob(MANIFEST)}
        # A hidden folder is not a run of its own: `.hippo_nav_previous/` holds an earlier run that an
        # `--overwrite` set aside (and puts back or removes).
        candidates = {f for f in candidates if not any(p.startswith(".") for p in f.relative_to(root).parts)}
        # A sweep's runs in the order of its space (the lesion conditions as given); other folders by name.
        ranks = {f.parent: _run_order(f.parent.parent) for f in candidates if f.parent.name == RUNS_DIR}
        for folder in sorted(
            candidates,
            key=lambda f: (
                str(f.parent),
                ranks.get(f.parent, {}).get(f.name, len(ranks.get(f.parent, {}))),
                f.name,
            ),
        ):
            if folder.resolve() in seen:
                continue
            seen.add(folder.resolve())
            sweep = folder.parent.parent.name if folder.parent.name == RUNS_DIR else folder.parent.name
            found[folder] = sweep or root.name
    if not found:
        raise HippoNavError(
            f"{', '.join(map(str, dirs))}: no runs found (no metrics.json or manifest.json below)"
        )
    return list(found.items())


def _run_order(sweep: Path) -> dict[str, int]:
    """A sweep's run ids in the order of its space (`sweep.json`); {} (name order, one warning) when the
    file is unreadable: it orders the runs, it holds none of their numbers."""
    path = sweep / "sweep.json"
    try:
        data = read_json_object(path) or {}
        runs = data.get("runs")
        if runs is None:
            return {}
        if not isinstance(runs, list):
            raise _bad(path, "runs", f"expected a list of runs, got {_what(runs)}")
        order: dict[str, int] = {}
        for i, run in enumerate(runs):
            run_id = run.get("run_id") if isinstance(run, dict) else None
            if not isinstance(run_id, str):
                raise _bad(path, f"runs[{i}].run_id", f"expected a run id (text), got {_what(run_id)}")
            order.setdefault(run_id, i)
        return order
    except RunFileError as err:
        log.warning("warning: %s; the runs of %s are listed in name order", err, sweep)
        return {}


def collect(dirs: Sequence[str | Path]) -> tuple[list[RunRow], list[SkippedRun]]:
    """Every readable run under `dirs` as a row, and the runs left out because a file of theirs is
    malformed (module doc), each logged as one warning."""
    rows: list[RunRow] = []
    skipped: list[SkippedRun] = []
    for folder, sweep in find_run_folders(dirs):
        try:
            rows.append(_row(folder, sweep))
        except RunFileError as err:
            log.warning("warning: run left out of the report: %s", err)
            skipped.append(SkippedRun(folder, str(err)))
    reveal_setups(rows)
    return rows, skipped


def collect_runs(dirs: Sequence[str | Path]) -> list[RunRow]:
    """Every readable run under `dirs` as a row (module doc; the unreadable ones are logged and left out)."""
    return collect(dirs)[0]


def _row(folder: Path, sweep: str) -> RunRow:
    manifest_path = folder / MANIFEST
    metrics_path = folder / "metrics.json"
    manifest = read_json_object(manifest_path)
    metrics = read_json_object(metrics_path)
    if manifest is not None:
        axes = _axes(manifest.get("axes"), manifest_path, "axes")
        status = manifest.get("status")
        if status not in STATUSES:
            raise _bad(manifest_path, "status", f"expected one of {', '.join(STATUSES)}, got {_what(status)}")
        error = _optional(manifest, "error", str, manifest_path, "text")
        run_id = _optional(manifest, "run_id", str, manifest_path, "text")
        if run_id is None or not run_id.strip():
            run_id = folder.name
    else:
        if metrics is None:  # a folder with neither: found by a name that is not a plain file
            raise _bad(metrics_path, None, "missing")
        axes = _plain_axes(folder, metrics)
        interrupted = _optional(metrics, "interrupted", bool, metrics_path, "true or false")
        status = "interrupted" if interrupted else "done"
        error = _optional(metrics, "stopped_by_error", str, metrics_path, "text")
        run_id = folder.name
    row = RunRow(folder, run_id, sweep, str(status), error, axes)
    if manifest is not None:
        row.setup = _sweep_setup(manifest, manifest_path)
    timing: dict[str, Any] = {}
    if metrics is not None:
        for name, get in METRICS:
            row.values[name] = _metric(metrics, name, get, metrics_path)
        timing = _object(metrics.get("timing"), metrics_path, "timing")
    else:
        row.values.update({name: None for name, _ in METRICS})
    row.values.update(bump_widths(folder / "bump_table.csv"))
    row.values["pi_error_2d_m"] = path_integration_error_m(folder)
    for name in TIMINGS:
        if manifest is not None and manifest.get(name) is not None:
            row.values[name] = _checked(manifest.get(name), manifest_path, name, "non-negative")
        else:
            row.values[name] = _checked(timing.get(name), metrics_path, f"timing.{name}", "non-negative")
    return row


def _own_axis(key: str) -> bool:
    """A config key that is an axis of its own: the seed (vo.seed follows it) and the lesions."""
    return key in ("seed", "vo.seed") or key.startswith("lesions.")


_DATASET_FLAGS = {
    "path": "dataset",
    "kind": "dataset_kind",
    "start": "start",
    "stop": "stop",
    "stride": "stride",
}


def _sweep_setup(manifest: dict[str, Any], path: Path) -> dict[str, Any] | None:
    """A sweep run's dataset flags and resolved config, flat (None before its config was resolved)."""
    config, dataset = manifest.get("config"), manifest.get("dataset")
    if not isinstance(config, dict) or not isinstance(dataset, dict):
        return None
    setup = {key: value for key, value in dotted(config).items() if not _own_axis(key)}
    for name, flag in _DATASET_FLAGS.items():
        setup[flag] = dataset.get(name)
    for key, value in setup.items():
        _check_axis_value(value, path, key)
    return setup


def reveal_setups(rows: Sequence[RunRow]) -> None:
    """Runs whose axes are equal but that were set up differently (two sweeps with other base configs or
    frame ranges in one folder, or several sweeps reported together) are not one configuration: each setting
    in which the sweep runs differ becomes an axis of theirs, so the tables group and label them apart."""
    known = [row for row in rows if row.setup is not None]
    axes = sorted({key for row in known for key in row.axes if key != "seed"})
    together: dict[tuple[str, ...], list[RunRow]] = {}
    for row in known:  # as the tables would group them
        together.setdefault(tuple(repr(row.axes.get(key)) for key in axes), []).append(row)
    keys = sorted({key for row in known for key in row.setup or {}})
    differing = [
        key
        for key in keys
        if any(len({repr((row.setup or {}).get(key)) for row in group}) > 1 for group in together.values())
    ]
    for key in differing:
        for row in known:
            row.axes.setdefault(key, (row.setup or {}).get(key))


def read_json_object(path: Path) -> dict[str, Any] | None:
    """The JSON object in `path`, None when there is no such file; `RunFileError` naming the file when it
    is not a readable regular file of at most `MAX_SETTINGS_FILE_BYTES`, not JSON, not an object or nested
    deeper than `MAX_NESTING`."""
    if not path.exists() and not path.is_symlink():
        return None
    if not path.is_file():
        # A folder, a dangling link, a pipe (which would block the read forever) or a device.
        raise _bad(
            path, None, "not a regular file (a folder, a broken link or a device); expected a JSON file"
        )
    try:
        text = read_text(path, "JSON file", MAX_SETTINGS_FILE_BYTES)
    except OSError as err:
        raise _bad(path, None, f"cannot read it ({err.strerror or err})") from None
    except HippoNavError as err:  # too large, not UTF-8: the message already names the file
        raise RunFileError(str(err)) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise _bad(
            path,
            None,
            f"not valid JSON ({err.msg} at line {err.lineno}, column {err.colno}); is it truncated?",
        ) from None
    except (RecursionError, ValueError) as err:  # nesting beyond the parser's limit; an absurd number
        raise _bad(path, None, f"not a JSON file hippo-nav wrote ({type(err).__name__}: {err})") from None
    if not isinstance(data, dict):
        raise _bad(path, None, f"expected a JSON object {{…}}, got {_what(data)}")
    _check_nesting(data, path)
    return data


def _check_nesting(data: Any, path: Path) -> None:
    """Refuse a document nested deeper than `MAX_NESTING` (iteratively: no recursion limit to hit here, and
    none for the recursive readers after it)."""
    stack: list[tuple[Any, int]] = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        if depth > MAX_NESTING:
            raise _bad(path, None, f"nested more than {MAX_NESTING} levels deep; not a file hippo-nav wrote")
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else ()
        stack += [(child, depth + 1) for child in children if isinstance(child, (dict, list))]


def _what(value: Any) -> str:
    """A value as a message shows it: its JSON type and, when short, the value."""
    kind = {dict: "an object", list: "a list", str: "text", bool: "a boolean", type(None): "null"}.get(
        type(value), "a number" if isinstance(value, (int, float)) else type(value).__name__
    )
    shown = repr(value) if not isinstance(value, (dict, list)) else ""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_INTEGER:
        shown = f"with {len(str(abs(value)))} digits"
    return f"{kind} {shown[:40]}{'…' if len(shown) > 40 else ''}".rstrip()


def _object(value: Any, path: Path, field: str) -> dict[str, Any]:
    """An optional object field: {} when absent or null."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _bad(path, field, f"expected an object, got {_what(value)}")
    return value


def _optional(data: dict[str, Any], field: str, kind: type, path: Path, described: str) -> Any:
    """An optional field of one JSON type (`kind`; a boolean is not a number): None when absent or null."""
    value = data.get(field)
    if value is None:
        return None
    if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
        raise _bad(path, field, f"expected {described} or null, got {_what(value)}")
    return value


def _checked(value: Any, path: Path, field: str, kind: str) -> float | None:
    """A number of a run: None when absent or null; a `RunFileError` naming the field when it is not a
    number, not finite (hippo-nav writes null for a missing number, never NaN), negative, not whole for a
    count (`kind` "count") or above 1 for a fraction (`kind` "fraction")."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _bad(path, field, f"expected a number or null, got {_what(value)}")
    if isinstance(value, int) and abs(value) > MAX_INTEGER:
        raise _bad(path, field, f"out of range ({_what(value)})")
    if not math.isfinite(value):
        raise _bad(path, field, f"{value} is not a number hippo-nav writes (a missing number is null)")
    if value < 0:
        raise _bad(path, field, f"{value} is negative; it cannot be")
    if kind == "count" and float(value) != int(value):
        raise _bad(path, field, f"{value} is not a whole number; it is a count")
    if kind == "fraction" and value > 1:
        raise _bad(path, field, f"{value} is above 1; it is a fraction")
    return float(value)


def _metric(
    metrics: dict[str, Any], name: str, get: Callable[[dict[str, Any]], Any], path: Path
) -> float | None:
    try:
        value = get(metrics)
    except TypeError as err:
        field, problem = err.args
        raise _bad(path, field, problem) from None
    kind = "count" if name in COUNTS else "fraction" if name in FRACTIONS else "non-negative"
    return _checked(value, path, ".".join(METRIC_FIELDS.get(name, (name,))), kind)


def _axes(value: Any, path: Path, field: str) -> dict[str, Any]:
    axes = _object(value, path, field)
    for key, axis in axes.items():
        _check_axis_value(axis, path, f"{field}.{key}")
    return dict(axes)


def _check_axis_value(value: Any, path: Path, field: str) -> None:
    """An axis is compared, sorted and drawn: its numbers must be finite and of a size a float holds exactly
    (`_check_nesting` bounds the depth of the recursion)."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return
    if isinstance(value, (int, float)):
        if (isinstance(value, int) and abs(value) > MAX_INTEGER) or not math.isfinite(value):
            raise _bad(path, field, f"out of range ({_what(value)}); expected a finite number")
        return
    items = (
        value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else None
    )
    if items is None:
        raise _bad(path, field, f"expected a JSON value, got {_what(value)}")
    for key, item in items:
        _check_axis_value(item, path, f"{field}.{key}" if isinstance(value, dict) else f"{field}[{key}]")


def lesion_condition(lesioned: Sequence[bool]) -> str:
    """`[False, False, True]` (the engine's order: ventral, intermediate, dorsal) → `dorsal`; none → `none`."""
    names = [name for name, off in zip(LESION_MODULES, lesioned, strict=False) if off]
    return "+".join(names) or "none"


def _plain_axes(folder: Path, metrics: dict[str, Any]) -> dict[str, Any]:
    """A plain run's axes from its files: sequence, lesion, the config values that differ from the
    defaults, seed."""
    from hippo_nav.system.config import PipelineConfig, resolved_config_dict

    metrics_path = folder / "metrics.json"
    lesioned = metrics.get("lesioned")
    if lesioned is not None and not (
        isinstance(lesioned, list) and all(isinstance(v, bool) for v in lesioned)
    ):
        raise _bad(
            metrics_path, "lesioned", f"expected a list of true/false per module, got {_what(lesioned)}"
        )
    seed = _optional(metrics, "seed", int, metrics_path, "a whole number")
    if seed is not None and not 0 <= seed <= MAX_INTEGER:
        raise _bad(metrics_path, "seed", f"out of range ({_what(seed)}); a seed is 0 or more")
    axes: dict[str, Any] = {
        "sequence": _optional(metrics, "sequence", str, metrics_path, "text"),
        "lesion": lesion_condition(lesioned or []),
    }
    config_path = folder / "config.json"
    config = read_json_object(config_path)
    if config is not None:
        defaults = dotted(resolved_config_dict(PipelineConfig()))
        for key, value in dotted(config).items():
            if key in defaults and value != defaults[key] and not _own_axis(key):
                _check_axis_value(value, config_path, key)
                axes[key] = value
    axes["seed"] = seed
    return axes


BUMP_COLUMNS = ("frame", "what", "k", "sigma_x_rad", "sigma_y_rad")
"""The columns of `bump_table.csv` the widths are measured from."""
MIN_WIDTH_RAD = 1e-9
"""The narrowest bump width read (module doc of `bump_widths`)."""


def bump_widths(path: Path) -> dict[str, float | None]:
    """`place_sigma_rad` and `theory_sigma_rad` of a run's `bump_table.csv` (module doc); both None without
    the file, a `RunFileError` naming the line and column when it is malformed."""
    from hippo_nav.theory import fused_sigma

    empty: dict[str, float | None] = {"place_sigma_rad": None, "theory_sigma_rad": None}
    if not path.exists() and not path.is_symlink():
        return empty
    if not path.is_file():
        raise _bad(
            path, None, "not a regular file (a folder, a broken link or a device); expected a CSV file"
        )
    try:
        text = read_text(path, "bump table", MAX_DATA_FILE_BYTES)
    except OSError as err:
        raise _bad(path, None, f"cannot read it ({err.strerror or err})") from None
    except HippoNavError as err:
        raise RunFileError(str(err)) from None
    place: dict[int, list[float]] = {}
    grid: dict[int, dict[str, list[float]]] = {}
    try:
        reader = csv.DictReader(io.StringIO(text, newline=""))
        missing = [c for c in BUMP_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise _bad(
                path, "line 1", f"no column {', '.join(missing)}; expected a header {','.join(BUMP_COLUMNS)}"
            )
        for row in reader:
            line = reader.line_num
            if any(row.get(c) is None for c in BUMP_COLUMNS):
                raise _bad(path, f"line {line}", "fewer cells than the header's columns; is it truncated?")
            frame = _csv_number(row["frame"], path, line, "frame")
            # A width is positive (1/σ² fuses them) and far above 1e-9 rad (a grid of 64 cells).
            width = 0.5 * (
                _csv_number(row["sigma_x_rad"], path, line, "sigma_x_rad", MIN_WIDTH_RAD)
                + _csv_number(row["sigma_y_rad"], path, line, "sigma_y_rad", MIN_WIDTH_RAD)
            )
            if row["what"] == "place":
                place.setdefault(int(frame), []).append(width)
            elif row["what"] == "grid":
                grid.setdefault(int(frame), {}).setdefault(row["k"], []).append(width)
    except csv.Error as err:
        raise _bad(path, None, f"not a CSV table ({err})") from None
    theory = [
        fused_sigma([float(np.mean(widths)) for widths in modules.values()]) for modules in grid.values()
    ]
    place_all = [w for widths in place.values() for w in widths]
    return {
        "place_sigma_rad": float(np.mean(place_all)) if place_all else None,
        "theory_sigma_rad": float(np.mean(theory)) if theory else None,
    }


def _csv_number(cell: str, path: Path, line: int, column: str, least: float = 0.0) -> float:
    try:
        value = float(cell)
    except ValueError:
        raise _bad(path, f"line {line}, column {column}", f"{cell[:40]!r} is not a number") from None
    if not (math.isfinite(value) and least <= value <= MAX_INTEGER):
        raise _bad(path, f"line {line}, column {column}", f"{cell[:40]!r}: expected a number from {least:g}")
    return value


def path_integration_error_m(folder: Path) -> float | None:
    """ATE 2-D of the place code's trajectory against the odometry's (module doc); None without them (or
    too few poses to align), a `RunFileError` when one of them is malformed."""
    from hippo_nav.io import DatasetError, read_kitti_poses
    from hippo_nav.metrics import ate_rmse

    files = [folder / "trajectory_vo.kitti.txt", folder / "trajectory_neural.kitti.txt"]
    if not all(f.exists() for f in files):
        return None
    try:
        odometry, neural = (read_kitti_poses(f) for f in files)
    except DatasetError as err:
        raise RunFileError(str(err)) from None
    except OSError as err:
        raise _bad(Path(err.filename or files[0]), None, f"cannot read it ({err.strerror or err})") from None
    if len(odometry) != len(neural):  # one run writes both, a pose a frame: one of them was cut short
        raise _bad(
            files[1],
            None,
            f"{len(neural)} poses against {len(odometry)} in {files[0].name}: one of them is cut short",
        )
    try:
        value = ate_rmse(odometry, neural, planar=True, align="se3")
    except (HippoNavError, ValueError, np.linalg.LinAlgError):
        return None  # e.g. a run of one frame: nothing to align
    return float(value) if math.isfinite(value) else None
