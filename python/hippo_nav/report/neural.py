"""The networks of one `hippo-nav run`, measured and drawn as a lab would (`hippo-nav figures --run DIR`): from
the results folder's recording (`recording.npz`, `module_phase.npz`; `hippo_nav.pipeline.recording`), without
running again.

Written into the figures folder (PNG at 300 dpi and PDF; 180 mm wide, 7 pt type, perceptually uniform colour
maps, every axis labelled with its unit):

- `rate_maps_track`: rate maps of three example units per population (grid k = 1, 2, 4 and the CA3 place
  torus) on the true positions over the whole drive;
- `rate_maps_folded`: the same units with the positions folded onto the population's spacing P/k (the place
  torus: P), where a grid unit's lattice of fields becomes one field;
- `decoded_phase`: each grid module's decoded phase against the true position modulo P/k, per torus axis
  (2-D histograms), and the circular error's distribution, with its RMS; the place code likewise modulo P;
- `neural_measures.json`: the circular errors, the rate maps' bins and kernels, the example units.

Positions are the recording's: the networks' torus frame (`pipeline/recording.py`), metres from the start.

Rate maps (the usual recipe): occupancy (s) and activity × time summed in square bins, each smoothed with the
same Gaussian kernel, then divided, `r = G∗(Σ a·dt) / G∗(Σ dt)`; bins never visited are left blank. Folded
maps smooth on the torus (wrap-around). Each panel is scaled to its unit's peak (given above it, in the
network's own units). Example units: the three whose track maps vary most (coefficient of variation over
the visited bins), the same units in both figures.

Circular error of a module: `e = wrap(x̂ − x)` into `[−P/2k, P/2k)` per axis, with `x̂ = (θ̂ − θ̂₀)·P/2π` the
decoded displacement (θ̂ the followed bump on the torus, θ̂₀ before the first frame) and `x` the true position;
reported as the RMS of |e| over frames (both axes) in metres and as a fraction of P/k. It is blind to whole
periods, as the grid code is.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps, rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from hippo_nav._core import HippoNavError
from hippo_nav.io.atomic import atomic_path, write_text
from hippo_nav.pipeline.recording import MODULE_PHASE_FILE, RECORDING_FILE, ModulePhases
from hippo_nav.recording import GRID_POPULATIONS, Recording, RecordingError

__all__ = [
    "FIGURES",
    "MEASURES_FILE",
    "RateMaps",
    "circular_error",
    "decoded_phase_errors",
    "load_run_recording",
    "rate_maps",
    "write_neural_figures",
]

FIGURES = ("rate_maps_track", "rate_maps_folded", "decoded_phase")
MEASURES_FILE = "neural_measures.json"
POPULATIONS = (*GRID_POPULATIONS, "place")
EXAMPLE_UNITS = 3
MIN_PEAK_SHARE = 0.25
TRACK_BINS_ACROSS = 150  # bins over the drive's larger extent (at least `MIN_TRACK_BIN_M`)
MIN_TRACK_BIN_M = 2.0
TRACK_SIGMA_BINS = 1.5
FOLDED_BINS = 32  # bins per spacing P/k
FOLDED_SIGMA_BINS = 1.0
PAGE_WIDTH_IN = 7.08  # 180 mm, a journal's double column
DPI = 300
RATE_CMAP = "viridis"
COUNT_CMAP = "magma_r"
STYLE = {
    "font.size": 7, "axes.titlesize": 7, "axes.labelsize": 7, "xtick.labelsize": 6, "ytick.labelsize": 6,
    "legend.fontsize": 6, "axes.linewidth": 0.6, "xtick.major.width": 0.6, "ytick.major.width": 0.6,
    "lines.linewidth": 0.8, "pdf.fonttype": 42, "ps.fonttype": 42, "savefig.dpi": DPI,
}  # fmt: skip
"""Journal type: 7 pt text, 6 pt ticks, fonts embedded as TrueType (editable in the PDF)."""

_NAMES = {
    "grid_ventral": "ventral",
    "grid_intermediate": "intermediate",
    "grid_dorsal": "dorsal",
    "place": "CA3 place",
}


# ------------------------------------------------------------------------------------------------
# Reading


def load_run_recording(folder: str | Path) -> tuple[Recording, ModulePhases]:
    """The recording of a `hippo-nav run` results folder; a folder without one (an older version's, or a
    run with `output.recording` off) is a `HippoNavError` saying to run it again."""
    folder = Path(folder)
    if not folder.is_dir():
        raise HippoNavError(f"--run {folder}: no such results folder")
    missing = [name for name in (RECORDING_FILE, MODULE_PHASE_FILE) if not (folder / name).is_file()]
    if missing:
        raise HippoNavError(
            f"--run {folder}: no {' or '.join(missing)} (a results folder of an older hippo-nav, or a run "
            f"with output.recording off); run it again to record the networks: hippo-nav run … --out {folder} "
            "--overwrite"
        )
    try:
        return Recording.load(folder / RECORDING_FILE), ModulePhases.load(folder / MODULE_PHASE_FILE)
    except RecordingError as err:
        raise HippoNavError(f"--run {folder}: {err}; run it again to write a whole recording") from None


# ------------------------------------------------------------------------------------------------
# Measures


@dataclass(frozen=True)
class RateMaps:
    """Rate maps of several units over one grid of bins: `rates` (units, rows = y, columns = x), NaN where
    never visited; `extent_m` (x0, x1, y0, y1) of the grid; the bin side and the kernel's σ (m)."""

    rates: np.ndarray
    extent_m: tuple[float, float, float, float]
    bin_size_m: float
    sigma_m: float
    period_m: float | None = None


def _smooth(image: np.ndarray, sigma_bins: float, periodic: bool) -> np.ndarray:
    """Gaussian smoothing of the last two axes (separable; zero outside the grid, or wrapped around)."""
    radius = int(np.ceil(3.0 * sigma_bins))
    if radius == 0:
        return image
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma_bins) ** 2)
    taps /= taps.sum()
    for axis in (image.ndim - 2, image.ndim - 1):
        size = image.shape[axis]
        pad = [(0, 0)] * image.ndim
        pad[axis] = (radius, radius)
        padded = np.pad(image, pad, mode="wrap" if periodic else "constant")
        image = sum(
            (w * np.take(padded, np.arange(i, i + size), axis=axis) for i, w in enumerate(taps)),
            start=np.zeros_like(image),
        )
    return image


def rate_maps(
    positions_m: np.ndarray,
    activity: np.ndarray,
    dt_s: float,
    bin_size_m: float,
    sigma_m: float,
    period_m: float | None = None,
) -> RateMaps:
    """Occupancy-normalised, smoothed rate maps (module doc) of every column of `activity` (n, units) over
    `positions_m` (n, 2). With `period_m`, the positions are folded modulo it onto a square of that side,
    in a whole number of bins (the side closest to `bin_size_m`), smoothed on the torus."""
    positions_m = np.asarray(positions_m, np.float64)
    activity = np.asarray(activity, np.float64).reshape(len(positions_m), -1)
    keep = np.isfinite(positions_m).all(axis=1) & np.isfinite(activity).all(axis=1)
    positions_m, activity = positions_m[keep], activity[keep]
    if period_m is not None:
        bins = max(round(period_m / bin_size_m), 2)
        bin_size_m = period_m / bins
        positions_m = np.remainder(positions_m, period_m)
        origin, shape = np.zeros(2), (bins, bins)
    else:
        low = positions_m.min(axis=0) - 2 * bin_size_m if len(positions_m) else np.zeros(2)
        high = positions_m.max(axis=0) + 2 * bin_size_m if len(positions_m) else np.ones(2)
        origin = np.floor(low / bin_size_m) * bin_size_m
        columns, rows = np.ceil((high - origin) / bin_size_m).astype(int)
        shape = (int(rows), int(columns))
    cells = np.floor((positions_m - origin) / bin_size_m).astype(np.int64)
    cells = np.minimum(cells, [shape[1] - 1, shape[0] - 1])  # a position at exactly P folds onto the edge
    flat = cells[:, 1] * shape[1] + cells[:, 0]
    size = shape[0] * shape[1]
    occupancy_s = np.bincount(flat, minlength=size).astype(np.float64) * dt_s
    sums = np.stack([np.bincount(flat, weights=a * dt_s, minlength=size) for a in activity.T])
    sigma_bins, periodic = sigma_m / bin_size_m, period_m is not None
    smooth_occupancy = _smooth(occupancy_s.reshape(shape), sigma_bins, periodic)
    smooth_sums = _smooth(sums.reshape(-1, *shape), sigma_bins, periodic)
    with np.errstate(invalid="ignore", divide="ignore"):
        rates = np.where(occupancy_s.reshape(shape) > 0, smooth_sums / smooth_occupancy, np.nan)
    x0, y0 = float(origin[0]), float(origin[1])
    extent = (x0, x0 + shape[1] * bin_size_m, y0, y0 + shape[0] * bin_size_m)
    return RateMaps(rates, extent, float(bin_size_m), float(sigma_m), period_m)


def most_variable_units(rates: np.ndarray, count: int = EXAMPLE_UNITS) -> list[int]:
    """The `count` units (first axis of `rates`) whose maps vary most over the visited bins (coefficient of
    variation), among those that fire: a peak at least `MIN_PEAK_SHARE` of the population's highest (a unit
    whose field the drive never crossed has a peak of rounding noise, and its variation means nothing).
    Ties go to the lowest index."""
    flat = rates.reshape(len(rates), -1)
    if flat.size == 0 or not np.isfinite(flat).any():
        return list(range(min(count, len(rates))))
    with np.errstate(invalid="ignore", divide="ignore"):
        variation = np.nan_to_num(np.nanstd(flat, axis=1) / np.nanmean(flat, axis=1), nan=-1.0)
    peaks = np.nan_to_num(np.nanmax(flat, axis=1), nan=0.0)
    variation[peaks < MIN_PEAK_SHARE * peaks.max()] = -1.0
    return [int(u) for u in np.argsort(-variation, kind="stable")[:count]]


def circular_error(decoded_m: np.ndarray, true_m: np.ndarray, spacing_m: float) -> dict[str, float]:
    """RMS of the decoded position's error wrapped into [−s/2, s/2) per axis (s = `spacing_m`): over both
    axes (`rms_error_m`, and as a fraction of s) and per axis. Frames with a NaN are left out."""
    error = (
        np.remainder(np.asarray(decoded_m) - np.asarray(true_m) + spacing_m / 2, spacing_m) - spacing_m / 2
    )
    error = error[np.isfinite(error).all(axis=1)]
    rms = float(np.sqrt(np.mean(np.sum(error**2, axis=1)))) if len(error) else float("nan")
    per_axis = np.sqrt(np.mean(error**2, axis=0)) if len(error) else np.full(2, np.nan)
    return {
        "spacing_m": float(spacing_m),
        "rms_error_m": rms,
        "rms_error_fraction_of_spacing": rms / spacing_m,
        "rms_error_x_m": float(per_axis[0]),
        "rms_error_y_m": float(per_axis[1]),
        "frames": len(error),
    }


def decoded_displacements_m(recording: Recording, phases: ModulePhases) -> dict[str, np.ndarray]:
    """Each live grid module's decoded displacement (T, 2) m, defined modulo P (module doc), and the place
    code's unwrapped position, by population name."""
    period_m = recording.torus_period_m
    decoded: dict[str, np.ndarray] = {}
    for m, name in enumerate(GRID_POPULATIONS):
        if m >= phases.tracked_rad.shape[1] or recording.lesioned[m]:
            continue
        tracked = phases.tracked_rad[:, m]
        start = phases.start_tracked_rad[m]
        if not np.isfinite(start).all():  # no phase before the first frame: the first frame's
            start = tracked[0]
        decoded[name] = (tracked - start) * period_m / (2 * np.pi)
    decoded["place"] = np.asarray(recording.decoded_position_m)
    return decoded


def decoded_phase_errors(recording: Recording, phases: ModulePhases) -> dict[str, dict[str, Any]]:
    """`circular_error` of every live grid module modulo its spacing P/k, and of the place code modulo P."""
    errors: dict[str, dict[str, Any]] = {}
    for name, decoded in decoded_displacements_m(recording, phases).items():
        k = 1 if name == "place" else recording.module_k[GRID_POPULATIONS.index(name)]
        errors[name] = {"k": k, **circular_error(decoded, recording.position_m, recording.spacing_m(name))}
    return errors


# ------------------------------------------------------------------------------------------------
# Figures


def _new_figure(width_in: float, height_in: float) -> Figure:
    figure = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(figure)  # our own canvas: no pyplot, no global backend
    return figure


def _save(figure: Figure, out: Path, stem: str) -> list[Path]:
    paths = []
    for suffix in (".png", ".pdf"):
        with atomic_path(out / f"{stem}{suffix}") as tmp:
            figure.savefig(tmp, dpi=DPI)
        paths.append(out / f"{stem}{suffix}")
    return paths


def _row_title(recording: Recording, name: str) -> str:
    if name == "place":
        return f"CA3 place (P = {recording.torus_period_m:g} m)"
    k = recording.module_k[GRID_POPULATIONS.index(name)]
    return f"{_NAMES[name]}, k = {k} (P/k = {recording.spacing_m(name):g} m)"


def _lesioned(recording: Recording, name: str) -> bool:
    return name in GRID_POPULATIONS and recording.lesioned[GRID_POPULATIONS.index(name)]


def _blank(ax: Axes, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_xticks([])
    ax.set_yticks([])


def _track_bin_m(recording: Recording) -> float:
    finite = recording.position_m[np.isfinite(recording.position_m).all(axis=1)]
    span_m = float(np.ptp(finite, axis=0).max()) if len(finite) else 0.0
    return max(MIN_TRACK_BIN_M, span_m / TRACK_BINS_ACROSS)


def _all_rate_maps(recording: Recording, folded: bool) -> dict[str, RateMaps]:
    dt_s = recording.sample_dt_s or 1.0
    bin_m = _track_bin_m(recording)
    maps = {}
    for name in POPULATIONS:
        if name not in recording.populations or _lesioned(recording, name):
            continue
        if folded:
            spacing_m = recording.spacing_m(name)
            bin_m = spacing_m / FOLDED_BINS
            maps[name] = rate_maps(
                recording.position_m, recording.populations[name], dt_s, bin_m, FOLDED_SIGMA_BINS * bin_m,
                period_m=spacing_m,
            )  # fmt: skip
        else:
            maps[name] = rate_maps(
                recording.position_m, recording.populations[name], dt_s, bin_m, TRACK_SIGMA_BINS * bin_m
            )
    return maps


def rate_maps_figure(
    recording: Recording, maps: dict[str, RateMaps], units: dict[str, list[int]], folded: bool
) -> Figure:
    """One row per population, one column per example unit (`units`), each panel scaled to its peak."""
    x0, x1, y0, y1 = next(iter(maps.values())).extent_m if maps else (0.0, 1.0, 0.0, 1.0)
    aspect = 1.0 if folded else float(np.clip((y1 - y0) / max(x1 - x0, 1e-9), 0.35, 1.2))
    panel_in = (PAGE_WIDTH_IN - 0.9) / EXAMPLE_UNITS
    figure = _new_figure(PAGE_WIDTH_IN, len(POPULATIONS) * panel_in * aspect + 0.9)
    axes = figure.subplots(len(POPULATIONS), EXAMPLE_UNITS, squeeze=False)
    cmap = colormaps[RATE_CMAP].with_extremes(bad="white")
    for row, name in enumerate(POPULATIONS):
        for column in range(EXAMPLE_UNITS):
            ax = axes[row, column]
            if name not in maps or column >= len(units.get(name, [])):
                _blank(ax, "lesioned" if _lesioned(recording, name) else "")
                continue
            unit = units[name][column]
            _draw_rate_map(ax, maps[name], unit, cmap, recording.unit_phase_rad[name][unit])
            if column == 0:
                ax.set_ylabel(f"{_row_title(recording, name)}\n{_axis_label('y', maps[name])}")
            if row == len(POPULATIONS) - 1:
                ax.set_xlabel(_axis_label("x", maps[name]))
    figure.colorbar(
        ScalarMappable(Normalize(0.0, 1.0), cmap), ax=axes, shrink=0.5, label="rate / unit's peak"
    )
    some = next(iter(maps.values()), None)
    if folded:
        how = (
            f"true positions folded onto each population's spacing (P/k; place: P),\n{FOLDED_BINS} bins per "
            f"spacing, Gaussian kernel σ = {FOLDED_SIGMA_BINS:g} bin, smoothed across the fold"
        )
    else:
        bin_m, sigma_m = (some.bin_size_m, some.sigma_m) if some else (0.0, 0.0)
        how = f"true positions over the drive, {bin_m:.3g} m bins, Gaussian kernel σ = {sigma_m:.3g} m"
    figure.suptitle(
        f"Occupancy-normalised rate maps: {how}.\nWhite: never visited. Networks' (torus) frame, metres "
        f"from the start; positions from the {recording.metadata.get('position_source', 'recording')}.",
        fontsize=7,
    )
    return figure


def _axis_label(axis: str, maps: RateMaps) -> str:
    if maps.period_m is None:
        return f"{axis} (m)"
    return f"{axis} mod {maps.period_m:.3g} m (m)"


def _draw_rate_map(ax: Axes, maps: RateMaps, unit: int, cmap: Any, phase_rad: np.ndarray) -> None:
    rate = maps.rates[unit]
    peak = float(np.nanmax(rate)) if np.isfinite(rate).any() else 0.0
    ax.imshow(
        rate / (peak or 1.0), origin="lower", extent=maps.extent_m, cmap=cmap, vmin=0.0, vmax=1.0,
        interpolation="nearest",
    )  # fmt: skip
    phase = np.atleast_1d(phase_rad)
    where = ", ".join(f"{p:.2f}" for p in phase)
    ax.set_title(f"unit {unit} (phase {where} rad), peak {peak:.3g}", fontsize=6)
    ax.set_aspect("equal")
    if maps.period_m is not None:
        ticks = np.linspace(0.0, maps.period_m, 3)
        ax.set_xticks(ticks)
        ax.set_yticks(ticks)


def decoded_phase_figure(
    recording: Recording, phases: ModulePhases, errors: dict[str, dict[str, Any]]
) -> Figure:
    """Per population (rows): decoded against true position modulo its spacing, x and y (2-D histograms),
    and the circular error's histogram with its RMS."""
    decoded = decoded_displacements_m(recording, phases)
    figure = _new_figure(PAGE_WIDTH_IN, len(POPULATIONS) * 2.0 + 0.5)
    axes = figure.subplots(len(POPULATIONS), 3, squeeze=False)
    cmap = colormaps[COUNT_CMAP].with_extremes(under="white")
    for row, name in enumerate(POPULATIONS):
        if name not in decoded:
            for ax in axes[row]:
                _blank(ax, "lesioned")
            continue
        spacing_m = recording.spacing_m(name)
        for axis, ax in enumerate(axes[row, :2]):
            true = np.remainder(recording.position_m[:, axis], spacing_m)
            guess = np.remainder(decoded[name][:, axis], spacing_m)
            ok = np.isfinite(true) & np.isfinite(guess)
            image = ax.hist2d(
                true[ok], guess[ok], bins=40, range=[[0, spacing_m], [0, spacing_m]], cmap=cmap, vmin=0.5
            )[3]
            ax.plot([0, spacing_m], [0, spacing_m], color="0.4", lw=0.5, ls="--")
            ax.set_aspect("equal")
            label = "xy"[axis]
            ax.set_xlabel(f"true {label} mod {spacing_m:g} m (m)")
            ax.set_ylabel(f"decoded {label} mod {spacing_m:g} m (m)")
            if axis == 0:
                ax.set_title(_row_title(recording, name), loc="left")
            figure.colorbar(image, ax=ax, shrink=0.8, label="frames")
        _draw_error_histogram(axes[row, 2], decoded[name], recording.position_m, spacing_m, errors[name])
    figure.suptitle(
        "Decoded phase against the true position modulo each population's spacing (networks' frame); "
        "error wrapped into ±spacing/2",
        fontsize=7,
    )
    return figure


def _draw_error_histogram(
    ax: Axes, decoded_m: np.ndarray, true_m: np.ndarray, spacing_m: float, error: dict[str, Any]
) -> None:
    wrapped = np.remainder(decoded_m - true_m + spacing_m / 2, spacing_m) - spacing_m / 2
    wrapped = wrapped[np.isfinite(wrapped).all(axis=1)]
    # The axis spans the errors seen (whole spacing at most), so that a small error is not one thin bar.
    half_m = min(spacing_m / 2, max(6.0 * error["rms_error_m"], 1.0))
    edges = np.linspace(-half_m, half_m, 41)
    for axis, colour in ((0, "#3b528b"), (1, "#5ec962")):  # viridis' blue and green
        ax.hist(wrapped[:, axis], bins=edges, histtype="step", color=colour, label="xy"[axis])
    ax.set_xlim(-half_m, half_m)
    ax.set_xlabel("circular error (m)")
    ax.set_ylabel("frames")
    ax.legend(loc="upper right", frameon=False)
    beyond = int(np.sum(np.abs(wrapped) > half_m))
    note = f"wraps at ±{spacing_m / 2:g} m" + (f"\n{beyond} beyond the axis" if beyond else "")
    ax.text(0.03, 0.95, note, transform=ax.transAxes, va="top", ha="left", fontsize=6)
    share = 100 * error["rms_error_fraction_of_spacing"]
    ax.set_title(f"RMS {error['rms_error_m']:.2f} m = {share:.2f} % of {spacing_m:g} m")


# ------------------------------------------------------------------------------------------------
# The whole set


def write_neural_figures(folder: str | Path, out: str | Path | None = None) -> list[Path]:
    """Measure the recording of the results folder `folder` and write the figures (PNG and PDF) and
    `neural_measures.json` into `out` (default `folder/figures`); returns the paths written."""
    recording, phases = load_run_recording(folder)
    out = Path(out) if out is not None else Path(folder) / "figures"
    out.mkdir(parents=True, exist_ok=True)
    errors = decoded_phase_errors(recording, phases)
    track, folded = _all_rate_maps(recording, folded=False), _all_rate_maps(recording, folded=True)
    units = {name: most_variable_units(maps.rates) for name, maps in track.items()}
    written: list[Path] = []
    with rc_context(STYLE):
        written += _save(rate_maps_figure(recording, track, units, folded=False), out, FIGURES[0])
        written += _save(rate_maps_figure(recording, folded, units, folded=True), out, FIGURES[1])
        written += _save(decoded_phase_figure(recording, phases, errors), out, FIGURES[2])
    measures = _measures(folder, recording, track, folded, units, errors)
    written.append(write_text(out / MEASURES_FILE, json.dumps(measures, indent=2) + "\n"))
    return written


def _measures(
    folder: str | Path,
    recording: Recording,
    track: dict[str, RateMaps],
    folded: dict[str, RateMaps],
    units: dict[str, list[int]],
    errors: dict[str, dict[str, Any]],
) -> dict[str, Any]:
    some = next(iter(track.values()), None)
    return {
        "run": str(folder),
        "frames": len(recording.time_s),
        "position_source": recording.metadata.get("position_source"),
        "frame": recording.metadata.get("frame"),
        "torus_period_m": recording.torus_period_m,
        "decoded_phase": errors,
        "rate_maps": {
            "track": {
                "bin_size_m": some.bin_size_m if some else None,
                "kernel_sigma_m": some.sigma_m if some else None,
            },
            "folded": {
                name: {"period_m": m.period_m, "bin_size_m": m.bin_size_m, "kernel_sigma_m": m.sigma_m}
                for name, m in folded.items()
            },
            "example_units": units,
        },
        "figures": [f"{stem}.{suffix}" for stem in FIGURES for suffix in ("png", "pdf")],
    }
