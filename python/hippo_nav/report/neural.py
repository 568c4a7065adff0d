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
- `lab_measures`: the lab's measures on folded maps (below), per spatial population: the folded map of the
  measured unit with the highest 90° score, its autocorrelogram with the lattice's four peaks, and the
  measured units' 90° scores against their shuffles; a population not measured says why;
- `topology_<population>` (only with `write_neural_figures(..., topology=True)`): barcodes and persistence
  diagram (`hippo_nav.recording.topology.write_topology_figure`);
- `neural_measures.json`: the circular errors, the rate maps' bins and kernels, the example units;
  `lab_measures` (settings, and per population either `"measured": false` with a `reason`, or the lab's
  summary: shuffle thresholds, fractions passing at 90° and 60°, median scores, spacing mean and spread and
  its ratio to P/k, orientation mean and spread, spatial information, field count and area, the measured
  units; the ring: vector lengths, preferred directions against design; `module_spacing_ratios` against
  `design_spacing_ratios`); `topology` (per grid module and the ring: Betti numbers against the torus's
  (1, 2, 1) or the ring's (1, 1, 0), or why not; `"computed": false` when not asked). Null where a number
  could not be measured, never NaN.

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

**The lab's measures of a whole drive** (`drive_measures`). On a road network the maps on the track are
mostly empty, and grid scores on them mean little. So each spatial population is measured on its true
positions folded modulo `LAB_FOLD_PERIODS` = 2 of its spacings (P/k; the place torus: P), where a unit's
lattice shows 2 × 2 fields, by `hippo_nav.recording.measures.measure_recording` itself (opexebo's maps,
autocorrelogram and scores, the shuffle test, `square_lattice`, Skaggs information, `place_field`) on a
`Recording` whose arena is the folded square (`fold_recording`). Why these numbers (ideal units of P = 100 m,
fields a fifth of the spacing wide, along the ground truths of KITTI 00, 05 and 07; 16 units, 20 shuffles;
measured 2026-12-03): two periods a side rather than three give 2.25× the frames a bin, and pass more of
the ideal units where the drive is thin (k = 1: 94 % on 00 where three periods pass 75 %; k = 2 on 05: 44 %
against 19 %); the spacing is not imposed by the fold (only 2P/k is), so it is a measure (ideal units on
00: 1.018–1.033 × P/k). `LAB_BINS_PER_SPACING` = 12 (a 24 × 24 map) with opexebo's smoothing at σ = 1.5
bins: σ = 2 bins on ten bins a spacing pulled the spacing 5 % long on a fully covered fold, σ = 1.5 on
twelve leaves it 1.5–2 % long (the open field's 0.5–2 %) and keeps a field over `place_field`'s 9 bins.
`LAB_MIN_COVERAGE`: a population is measured when the drive visited at least 25 % of the folded square's
bins (the k = 1 fold of KITTI 00: 54 %, of 05: 32 %, of 07: 16 %; 07's passes none of the ideal units);
the coverage and the median frames a visited bin are written beside the scores, and a thin drive shows as a
low fraction passing (05's k = 1: 6 %). 16 units a population (of the run's 64) and 25 shuffles each,
`measure_recording`'s defaults; 2–4 s a population over 4 500 frames. Road geometry is in the occupancy
(streets at right angles make any map's autocorrelogram 90°-symmetric), which is why the shuffle thresholds
are higher than an open field's (0.6–1.1 at 90°) and why only the shuffle test says a unit passes:
time-smoothed noise passes in 0–12 % of the units (the test's 5 %, with 16 units' sampling).

The ring (`hd`) is measured on the true heading (no fold), when the drive took at least half of the 6°
heading bins with a median of 5 frames each (fewer, and a shuffled curve is as peaked as a tuned one).
opexebo's preferred direction (the curve's mean direction) is NaN when any heading bin was never taken; it is
then null, and each unit's peak direction is given.

**Topology** (`drive_topology`, asked with `topology=True`: 3–20 s a population): `population_topology` of
each grid module and of the ring, with the open field's pipeline unchanged, where the drive has at least
`TOPOLOGY_MIN_FRAMES` (600, the cloud's points) moving frames and visited at least half of the module's
torus (its positions modulo P/k in 10 × 10 bins) or of the ring (100 heading bins): a torus visited unevenly
shows extra H1 bars or misses its H2 (ideal modules along KITTI 00: (1, 2, 1) or (1, 3, 1) at full coverage;
07's k = 1, 57 % covered: (1, 3, 0)). The place torus is left out: its bump is too narrow for the
pipeline's four components even in the open field (docs/neuro.md).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import textwrap
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
from hippo_nav.recording import measures as lab
from hippo_nav.recording.topology import (
    RING_BETTI,
    TORUS_BETTI,
    TopologyError,
    TopologyParams,
    TopologyResult,
    population_topology,
    write_topology_figure,
)

__all__ = [
    "FIGURES",
    "MEASURES_FILE",
    "DriveMeasures",
    "RateMaps",
    "circular_error",
    "decoded_phase_errors",
    "drive_measures",
    "drive_topology",
    "finite_frames",
    "fold_coverage",
    "fold_recording",
    "lab_measures_figure",
    "load_run_recording",
    "rate_maps",
    "write_neural_figures",
]

FIGURES = ("rate_maps_track", "rate_maps_folded", "decoded_phase", "lab_measures")
MEASURES_FILE = "neural_measures.json"
POPULATIONS = (*GRID_POPULATIONS, "place")
EXAMPLE_UNITS = 3
MIN_PEAK_SHARE = 0.25
TRACK_BINS_ACROSS = 150  # bins over the drive's larger extent (at least `MIN_TRACK_BIN_M`)
MIN_TRACK_BIN_M = 2.0
TRACK_SIGMA_BINS = 1.5
FOLDED_BINS = 32  # bins per spacing P/k
FOLDED_SIGMA_BINS = 1.0
LAB_FOLD_PERIODS = 2  # the lab measures' folded square: this many spacings a side (module doc)
LAB_BINS_PER_SPACING = 12
LAB_SIGMA_BINS = 1.5
LAB_MIN_COVERAGE = 0.25  # of the folded square's bins visited, or the population is not measured
LAB_UNITS = 16  # measured units a population (of the run's 64), chosen by the seed
LAB_SHUFFLES = 25  # per measured unit, pooled over the population
LAB_HD_BIN_DEG = 6.0  # the measures' heading bins (`MeasureSettings.hd_bin_deg`)
LAB_MIN_HEADING_COVERAGE = 0.5  # of the heading bins taken, or the ring is not measured
LAB_MIN_FRAMES_PER_HEADING = 5  # median frames in a taken heading bin, or the ring is not measured
TOPOLOGY_POPULATIONS = (*GRID_POPULATIONS, "hd")
TOPOLOGY_BINS_PER_SPACING = 10  # the torus coverage's bins (positions modulo one spacing)
TOPOLOGY_MIN_COVERAGE = 0.5  # of the torus's (or the ring's) bins visited, or no topology is read
TOPOLOGY_MIN_FRAMES = TopologyParams().n_points  # moving frames: the cloud the pipeline reads a shape from
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
        recording, phases = (
            Recording.load(folder / RECORDING_FILE),
            ModulePhases.load(folder / MODULE_PHASE_FILE),
        )
    except RecordingError as err:
        raise HippoNavError(f"--run {folder}: {err}; run it again to write a whole recording") from None
    # Both are written by one run, a row a frame: files of different runs (one copied in) do not pair.
    if len(recording.time_s) != len(phases.frame_index):
        raise HippoNavError(
            f"--run {folder}: {RECORDING_FILE} holds {len(recording.time_s)} frames and {MODULE_PHASE_FILE} "
            f"{len(phases.frame_index)}: they come from different runs; run it again to write both"
        )
    return recording, phases


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
# The lab's measures, on maps folded onto a few periods


def finite_frames(recording: Recording) -> Recording:
    """`recording` without the frames where the position, heading or any activity is NaN, its time re-spaced
    uniformly (the lab's measures refuse NaN and need `time_s[i] = i·dt`; the shuffles' lags are counted in
    frames, so dropping a few changes nothing else)."""
    keep = np.isfinite(recording.position_m).all(axis=1) & np.isfinite(recording.heading_rad)
    for activity in recording.populations.values():
        keep &= np.isfinite(activity).all(axis=1)
    if keep.all():
        return recording
    dt_s = recording.sample_dt_s or 1.0
    return dataclasses.replace(
        recording,
        time_s=np.arange(int(keep.sum())) * dt_s,
        position_m=recording.position_m[keep],
        heading_rad=recording.heading_rad[keep],
        speed_m_s=recording.speed_m_s[keep],
        decoded_position_m=recording.decoded_position_m[keep],
        decoded_heading_rad=recording.decoded_heading_rad[keep],
        populations={name: activity[keep] for name, activity in recording.populations.items()},
    )


def fold_recording(recording: Recording, population: str, periods: int = LAB_FOLD_PERIODS) -> Recording:
    """The recording of one population with the true positions folded modulo `periods` spacings (P/k; the
    place torus: P), as an arena of that side: `hippo_nav.recording.measures` then bins the square
    [0, side]² (module doc)."""
    side_m = periods * recording.spacing_m(population)
    return dataclasses.replace(
        recording,
        position_m=np.remainder(recording.position_m, side_m),
        populations={population: recording.populations[population]},
        unit_phase_rad={population: recording.unit_phase_rad[population]},
        metadata={**recording.metadata, "arena": {"shape": "square", "size_m": side_m}},
    )


def fold_coverage(position_m: np.ndarray, side_m: float, bins: int) -> tuple[float, float]:
    """(fraction of the `bins`² square bins of the positions folded modulo `side_m` that were visited, median
    frames in a visited bin); (0, 0) without positions."""
    position_m = np.asarray(position_m, np.float64)
    position_m = position_m[np.isfinite(position_m).all(axis=1)]
    if not len(position_m):
        return 0.0, 0.0
    cells = np.minimum(np.floor(np.remainder(position_m, side_m) / side_m * bins).astype(np.int64), bins - 1)
    counts = np.bincount(cells[:, 1] * bins + cells[:, 0], minlength=bins * bins)
    return float(np.mean(counts > 0)), float(np.median(counts[counts > 0]))


def _heading_coverage(heading_rad: np.ndarray, bin_deg: float) -> tuple[float, float]:
    """(fraction of the `bin_deg` heading bins the drive took, median frames in a taken bin)."""
    n_bins = math.ceil(360.0 / bin_deg - 1e-9)
    heading = np.asarray(heading_rad, np.float64)
    heading = np.mod(heading[np.isfinite(heading)], 2 * np.pi)
    if not len(heading):
        return 0.0, 0.0
    cells = np.minimum((heading / (2 * np.pi) * n_bins).astype(np.int64), n_bins - 1)
    counts = np.bincount(cells, minlength=n_bins)
    return float(np.mean(counts > 0)), float(np.median(counts[counts > 0]))


def _not_measured(entry: dict[str, Any], reason: str) -> dict[str, Any]:
    return {"measured": False, "reason": reason, **entry}


def _percent(fraction: float) -> str:
    return f"{100 * fraction:.0f} %"


def _spatial_entry(
    recording: Recording, name: str, units: int, shuffles: int, seed: int
) -> tuple[dict[str, Any], lab.SpatialPopulation | None]:
    """One spatial population measured on its folded maps (module doc), as a JSON-able summary, and the
    measures behind it (None where it was not measured: the entry's `reason` says why)."""
    spacing_m = recording.spacing_m(name)
    side_m, bin_m = LAB_FOLD_PERIODS * spacing_m, spacing_m / LAB_BINS_PER_SPACING
    coverage, per_bin = fold_coverage(recording.position_m, side_m, LAB_FOLD_PERIODS * LAB_BINS_PER_SPACING)
    entry: dict[str, Any] = {
        "k": 1 if name == "place" else recording.module_k[GRID_POPULATIONS.index(name)],
        "design_spacing_m": spacing_m,
        "fold_m": side_m,
        "bin_size_m": bin_m,
        "coverage": coverage,
        "frames_per_visited_bin_median": per_bin,
    }
    if _lesioned(recording, name):
        return _not_measured(entry, "lesioned: its units are silent"), None
    if coverage < LAB_MIN_COVERAGE:
        reason = (
            f"the drive visited {_percent(coverage)} of the folded square's bins (positions modulo "
            f"{side_m:g} m, {bin_m:.3g} m bins), under {_percent(LAB_MIN_COVERAGE)}: too few to read a "
            "lattice from; a longer drive covers more"
        )
        return _not_measured(entry, reason), None
    try:
        measures = lab.measure_recording(
            fold_recording(recording, name), populations=[name], units_per_population=units,
            shuffles=shuffles, seed=seed, bin_size_m=bin_m, sigma_bins=LAB_SIGMA_BINS,
        )  # fmt: skip
    except (lab.MeasureError, ModuleNotFoundError) as err:  # no opexebo, or a recording it cannot measure
        return _not_measured(entry, str(err)), None
    population = measures.spatial[name]
    return {"measured": True, **entry, **_spatial_summary(measures.to_dict()["spatial"][name])}, population


def _spatial_summary(population: dict[str, Any]) -> dict[str, Any]:
    """measures.json's population summary without the shuffled scores (they are the figure's), with the
    median scores and the spacing of the units that pass at 90° (the others' peaks can be the roads')."""
    units = population.pop("units")
    for key in ("shuffled_60", "shuffled_90", "population", "design_spacing_m"):
        population.pop(key, None)

    def median(key: str, rows: list[dict[str, Any]]) -> float | None:
        values = [row[key] for row in rows if row[key] is not None]
        return float(np.median(values)) if values else None

    passing = [unit for unit in units if unit["passes_90"]]
    return {
        **population,
        "median_score_90": median("grid_score_90", units),
        "median_score_60": median("grid_score_60", units),
        "spacing_passing_90_median_m": median("spacing_m", passing),
        "units": units,
    }


def _hd_entry(
    recording: Recording, units: int, shuffles: int, seed: int
) -> tuple[dict[str, Any], lab.HeadDirectionPopulation | None]:
    """The ring's head-direction tuning (the lab's, on the true heading; no fold: heading is a circle)."""
    coverage, per_bin = _heading_coverage(recording.heading_rad, LAB_HD_BIN_DEG)
    entry: dict[str, Any] = {
        "heading_bin_deg": LAB_HD_BIN_DEG,
        "heading_coverage": coverage,
        "frames_per_heading_bin_median": per_bin,
    }
    if lab.HD_POPULATION not in recording.populations:
        return _not_measured(entry, "the recording has no hd population"), None
    if coverage < LAB_MIN_HEADING_COVERAGE or per_bin < LAB_MIN_FRAMES_PER_HEADING:
        reason = (
            f"the drive took {_percent(coverage)} of the {LAB_HD_BIN_DEG:g}° heading bins, the median one "
            f"{per_bin:g} frame{'' if per_bin == 1 else 's'}; a tuning curve needs {_percent(LAB_MIN_HEADING_COVERAGE)} of them with "
            f"{LAB_MIN_FRAMES_PER_HEADING} frames or more (with fewer, a shuffled curve is as peaked as a tuned one)"
        )
        return _not_measured(entry, reason), None
    try:
        measures = lab.measure_recording(
            recording,
            populations=[lab.HD_POPULATION],
            units_per_population=units,
            shuffles=shuffles,
            seed=seed,
        )
    except (lab.MeasureError, ModuleNotFoundError) as err:
        return _not_measured(entry, str(err)), None
    summary = measures.to_dict()["head_direction"]
    for key in ("shuffled_mean_vector_length", "population"):
        summary.pop(key, None)
    if coverage < 1.0:
        # opexebo's `tuning_curve_stats` takes the mean direction of the whole curve: one unvisited
        # (NaN) bin makes it NaN, so the preferred direction and its error are null; the peak's is not.
        entry["note"] = (
            "some heading bins were never taken: opexebo's mean direction (the preferred direction) is "
            "then undefined (null); peak_direction_deg is each unit's peak"
        )
    return {"measured": True, **entry, **summary}, measures.head_direction


@dataclass(frozen=True)
class DriveMeasures:
    """The lab's measures of a whole drive (`drive_measures`): `summary` is neural_measures.json's
    "lab_measures" (JSON-able, null for what could not be measured); `spatial` and `head_direction` the
    measures behind it, for the figure."""

    summary: dict[str, Any]
    spatial: dict[str, lab.SpatialPopulation]
    head_direction: lab.HeadDirectionPopulation | None


def drive_measures(
    recording: Recording,
    *,
    units_per_population: int = LAB_UNITS,
    shuffles: int = LAB_SHUFFLES,
    seed: int = 0,
) -> DriveMeasures:
    """The lab's measures (`hippo_nav.recording.measures`) of each spatial population on its positions folded
    modulo `LAB_FOLD_PERIODS` spacings, and of the HD ring on the heading (module doc). A population that
    cannot be measured (lesioned, too little coverage, no opexebo) says why instead; nothing raises."""
    recording = finite_frames(recording)
    populations: dict[str, Any] = {}
    spatial: dict[str, lab.SpatialPopulation] = {}
    for name in POPULATIONS:
        if name not in recording.populations:
            continue
        populations[name], measured = _spatial_entry(recording, name, units_per_population, shuffles, seed)
        if measured is not None:
            spatial[name] = measured
    populations[lab.HD_POPULATION], head_direction = _hd_entry(
        recording, units_per_population, shuffles, seed
    )
    modules = [name for name in GRID_POPULATIONS if name in spatial]
    reference = spatial[modules[0]] if modules else None
    summary = {
        "method": "the lab's measures (hippo_nav.recording.measures) on the true positions folded modulo "
        f"{LAB_FOLD_PERIODS} spacings of each population (P/k; place: P)",
        "fold_periods": LAB_FOLD_PERIODS,
        "bins_per_spacing": LAB_BINS_PER_SPACING,
        "kernel_sigma_bins": LAB_SIGMA_BINS,
        "min_coverage": LAB_MIN_COVERAGE,
        "min_heading_coverage": LAB_MIN_HEADING_COVERAGE,
        "units_per_population": units_per_population,
        "shuffles": shuffles,
        "seed": seed,
        "frames": len(recording.time_s),
        "populations": populations,
        "module_spacing_ratios": {
            name: _finite_or_none(spatial[name].spacing_mean_m / reference.spacing_mean_m)
            for name in modules
            if reference is not None
        },
        "design_spacing_ratios": {
            name: recording.spacing_m(name) / recording.spacing_m(modules[0]) for name in modules
        },
    }
    return DriveMeasures(summary, spatial, head_direction)


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _topology_coverage(recording: Recording, name: str) -> float:
    """The fraction of a module's torus (positions modulo P/k, `TOPOLOGY_BINS_PER_SPACING`² bins), or of the
    ring (the same number of heading bins), the drive visited."""
    if name == lab.HD_POPULATION:
        return _heading_coverage(recording.heading_rad, 360.0 / TOPOLOGY_BINS_PER_SPACING**2)[0]
    spacing_m = recording.spacing_m(name)
    return fold_coverage(recording.position_m, spacing_m, TOPOLOGY_BINS_PER_SPACING)[0]


def _topology_skip(recording: Recording, name: str, coverage: float) -> str | None:
    """Why a population's topology is not read (lesioned, too few moving frames, too little coverage)."""
    if _lesioned(recording, name):
        return "lesioned: its units are silent"
    min_speed = TopologyParams().min_speed_m_s or 0.0
    moving = int(np.sum(recording.speed_m_s >= min_speed))
    if moving < TOPOLOGY_MIN_FRAMES:
        return (
            f"{moving} moving frames, fewer than the {TOPOLOGY_MIN_FRAMES} points of the cloud the topology "
            "is read from (its shuffle thresholds are tuned for that size); a longer drive has them"
        )
    if coverage < TOPOLOGY_MIN_COVERAGE:
        what = "headings" if name == lab.HD_POPULATION else "phases (positions modulo P/k)"
        return (
            f"the drive visited {_percent(coverage)} of the {what} in {TOPOLOGY_BINS_PER_SPACING**2} bins, "
            f"under {_percent(TOPOLOGY_MIN_COVERAGE)}: an unevenly visited torus or ring has no shape to read"
        )
    return None


def drive_topology(recording: Recording) -> tuple[dict[str, Any], dict[str, TopologyResult]]:
    """Persistent homology (`population_topology`) of each grid module and of the HD ring, where the drive
    covered the module's torus (its positions modulo P/k) or the ring's headings well enough (module doc):
    a JSON-able entry per population (Betti numbers against the torus's or the ring's, or why not), and the
    results for their figures."""
    recording = finite_frames(recording)
    entries: dict[str, Any] = {}
    results: dict[str, TopologyResult] = {}
    for name in TOPOLOGY_POPULATIONS:
        if name not in recording.populations:
            continue
        expected = RING_BETTI if name == lab.HD_POPULATION else TORUS_BETTI
        coverage = _topology_coverage(recording, name)
        entry: dict[str, Any] = {"coverage": coverage, "expected_betti": list(expected)}
        reason = _topology_skip(recording, name, coverage)
        if reason is not None:
            entries[name] = {"computed": False, "reason": reason, **entry}
            continue
        try:
            result = population_topology(recording, name)
        except (TopologyError, ModuleNotFoundError) as err:  # too few moving frames; no ripser
            entries[name] = {"computed": False, "reason": str(err), **entry}
            continue
        results[name] = result
        summary = result.summary()
        entries[name] = {"computed": True, **entry, "matches_expected": result.betti == expected, **summary}
    return entries, results


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


def lab_measures_figure(recording: Recording, measures: DriveMeasures) -> Figure:
    """Per spatial population (rows): the folded map (`LAB_FOLD_PERIODS` spacings a side) of its measured unit
    with the highest 90° score, that map's autocorrelogram with the lattice's four peaks, and the measured
    units' 90° scores against the shuffled ones; a population not measured says why."""
    recording = finite_frames(recording)
    panel_in = (PAGE_WIDTH_IN - 0.6) / 3
    figure = _new_figure(PAGE_WIDTH_IN, len(POPULATIONS) * panel_in * 0.95 + 0.8)
    axes = figure.subplots(len(POPULATIONS), 3, squeeze=False)
    for row, name in enumerate(POPULATIONS):
        entry = measures.summary["populations"].get(name)
        if name not in measures.spatial:
            reason = entry["reason"] if entry else "not recorded"
            _blank(axes[row, 0], "\n".join(_wrap_words(f"{_NAMES[name]}: not measured ({reason})", 42)))
            for ax in axes[row, 1:]:
                _blank(ax, "")
            continue
        population = measures.spatial[name]
        best = max(
            population.units, key=lambda u: -math.inf if math.isnan(u.grid_score_90) else u.grid_score_90
        )
        maps = lab.rate_maps(
            fold_recording(recording, name), name, [best.unit], bin_size_m=entry["bin_size_m"],
            sigma_bins=LAB_SIGMA_BINS,
        )  # fmt: skip
        _draw_folded_map(axes[row, 0], maps, best, _row_title(recording, name))
        _draw_autocorrelogram(axes[row, 1], maps, best)
        _draw_score_histogram(axes[row, 2], population)
    figure.suptitle(
        f"The lab's measures on the true positions folded modulo {LAB_FOLD_PERIODS} spacings (P/k; place: P), "
        f"{LAB_BINS_PER_SPACING} bins per spacing, opexebo's smoothing σ = {LAB_SIGMA_BINS:g} bins.\nLeft: the "
        "measured unit with the highest 90° score (white: never visited); middle: its autocorrelogram (×: the "
        "lattice's 4 peaks);\nright: the 90° scores of the measured units and of their shuffles (threshold: "
        "the shuffles' 95th percentile).",
        fontsize=7,
    )
    return figure


def _wrap_words(text: str, width: int) -> list[str]:
    # A unit stays with its number: "5 %" never breaks between them (textwrap does not split at a no-break
    # space).
    return textwrap.wrap(re.sub(r"(\d) (%|m\b)", "\\1\u00a0\\2", text), width, break_on_hyphens=False)


def _draw_folded_map(ax: Axes, maps: lab.RateMaps, unit: lab.SpatialUnit, title: str) -> None:
    rate = maps.maps[0]
    peak = float(np.nanmax(rate)) if np.isfinite(rate).any() else 0.0
    cmap = colormaps[RATE_CMAP].with_extremes(bad="white")
    ax.imshow(
        rate / (peak or 1.0), origin="lower", extent=maps.binning.extent_m, cmap=cmap, vmin=0.0, vmax=1.0,
        interpolation="nearest",
    )  # fmt: skip
    side_m = maps.binning.extent_m[1]
    ax.set_title(f"{title}\nunit {unit.unit}, peak {peak:.3g}", fontsize=6, loc="left")
    ax.set_xlabel(f"x mod {side_m:g} m (m)")
    ax.set_ylabel(f"y mod {side_m:g} m (m)")
    ax.set_aspect("equal")


def _draw_autocorrelogram(ax: Axes, maps: lab.RateMaps, unit: lab.SpatialUnit) -> None:
    acorr = lab.autocorrelogram(maps.maps[0])
    bin_m = maps.binning.bin_size_m
    centre_row, centre_col = (math.ceil(n / 2) - 1 for n in acorr.shape)  # opexebo's zero lag
    extent = (
        -(centre_col + 0.5) * bin_m, (acorr.shape[1] - centre_col - 0.5) * bin_m,
        -(centre_row + 0.5) * bin_m, (acorr.shape[0] - centre_row - 0.5) * bin_m,
    )  # fmt: skip
    image = ax.imshow(acorr, origin="lower", extent=extent, cmap=RATE_CMAP, vmin=-1.0, vmax=1.0)
    peaks_m = lab.square_lattice(acorr, bin_m).peaks_m
    ax.plot(peaks_m[:, 0], peaks_m[:, 1], "x", color="white", markersize=4, mew=0.8)
    ax.set_title(
        f"90° score {unit.grid_score_90:.2f}, 60° {unit.grid_score_60:.2f}\nspacing {unit.spacing_m:.3g} m, "
        f"orientation {unit.orientation_deg:.1f}°",
        fontsize=6,
        loc="left",
    )
    ax.set_xlabel("lag x (m)")
    ax.set_ylabel("lag y (m)")
    ax.set_aspect("equal")
    ax.figure.colorbar(image, ax=ax, shrink=0.8, label="Pearson r")


def _draw_score_histogram(ax: Axes, population: lab.SpatialPopulation) -> None:
    shuffled = np.asarray(population.shuffled_90, np.float64)
    measured = np.asarray([u.grid_score_90 for u in population.units], np.float64)
    finite = np.concatenate([shuffled[np.isfinite(shuffled)], measured[np.isfinite(measured)]])
    edges = (
        np.linspace(min(-0.5, *finite), max(1.5, *finite), 31) if finite.size else np.linspace(-0.5, 1.5, 31)
    )
    ax.hist(shuffled[np.isfinite(shuffled)], bins=edges, density=True, color="0.75", label="shuffled")
    ax.hist(
        measured[np.isfinite(measured)], bins=edges, density=True, histtype="step", color="#3b528b",
        label="measured units",
    )  # fmt: skip
    if math.isfinite(population.threshold_90):
        ax.axvline(population.threshold_90, color="#b5367a", lw=0.8, ls="--", label="95th percentile")
    ax.set_xlabel("90° grid score")
    ax.set_ylabel("density")
    ax.legend(loc="upper left", frameon=False)
    ax.set_title(
        f"{_percent(population.fraction_passing_90)} of {population.units_measured} pass at 90°, "
        f"{_percent(population.fraction_passing_60)} at 60°",
        fontsize=6,
        loc="left",
    )


# ------------------------------------------------------------------------------------------------
# The whole set


def write_neural_figures(
    folder: str | Path, out: str | Path | None = None, *, topology: bool = False, seed: int = 0
) -> list[Path]:
    """Measure the recording of the results folder `folder` and write the figures (PNG and PDF) and
    `neural_measures.json` into `out` (default `folder/figures`); returns the paths written. With `topology`,
    also each grid module's and the ring's persistent homology (`topology_<population>` figures; 3–20 s
    a population, so asked for). `seed` chooses the measured units and the shuffles."""
    recording, phases = load_run_recording(folder)
    out = Path(out) if out is not None else Path(folder) / "figures"
    out.mkdir(parents=True, exist_ok=True)
    errors = decoded_phase_errors(recording, phases)
    track, folded = _all_rate_maps(recording, folded=False), _all_rate_maps(recording, folded=True)
    units = {name: most_variable_units(maps.rates) for name, maps in track.items()}
    lab_measures = drive_measures(recording, seed=seed)
    written: list[Path] = []
    with rc_context(STYLE):
        written += _save(rate_maps_figure(recording, track, units, folded=False), out, FIGURES[0])
        written += _save(rate_maps_figure(recording, folded, units, folded=True), out, FIGURES[1])
        written += _save(decoded_phase_figure(recording, phases, errors), out, FIGURES[2])
        written += _save(lab_measures_figure(recording, lab_measures), out, FIGURES[3])
    if topology:
        topology_entries, results = drive_topology(recording)
        for name, result in results.items():
            written += write_topology_figure(result, out / f"topology_{name}")
    else:
        topology_entries = {
            "computed": False,
            "reason": "not asked: write_neural_figures(..., topology=True) (3–20 s a population)",
        }
    measures = _measures(folder, recording, track, folded, units, errors)
    measures["lab_measures"] = lab_measures.summary
    measures["topology"] = topology_entries
    measures["figures"] += [p.name for p in written if p.name.startswith("topology_")]
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
