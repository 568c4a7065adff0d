"""The lab's measures of a recording: rate maps, 60° and 90° grid scores with their shuffle thresholds, lattice
spacing and orientation, spatial information and firing fields, head-direction tuning (`measure_recording`).

The measures are opexebo's (the Kavli Institute's Python port of the Moser lab's MATLAB toolbox, BNT):
`spatial_occupancy`'s conventions, `smooth`, `autocorrelation`, `rate_map_stats`, `place_field`,
`tuning_curve_stats`. What opexebo lacks or cannot do here is written on top of its outputs:

**Rate maps** (`rate_maps`). opexebo's `rate_map` histograms spike positions; a network unit has a continuous
activity a(t) instead, and its map is the activity-weighted occupancy (what a Poisson neuron firing at a(t)
would give on average). Square bins of `bin_size_m` (default 2.5 cm, opexebo's and BNT's; arenas over 2 m get
size/80, so a map stays 80 bins across and a measure's cost is bounded) over the arena's box [0, size]²
(RatInABox's frame, which `hippo_nav.openfield` uses) when the positions lie in it, else their bounding box.
For bin b, with dt the sample interval:
    A(b) = Σ_t a(t)·dt·[x(t) ∈ b],   O(b) = Σ_t dt·[x(t) ∈ b],   map(b) = (G_σ∗A)(b) / (G_σ∗O)(b),
NaN where O(b) = 0 (unvisited). G_σ is opexebo's Gaussian (`smooth`, σ = `sigma_bins`, default 2 bins, its
default; edges mirrored). The two maps are smoothed before dividing (a kernel-weighted mean of the activity
around the bin): smoothing a divided map would pull bins next to unvisited ones towards zero. Row i of a
map is y, column j is x (draw with origin="lower").

**Grid scores** (`grid_scores`), on opexebo's autocorrelogram (Pearson correlation over the overlap, its
central 80 % kept, NaN bins taken as 0). The expanding-annulus score of Sargolini et al. 2006 and Langston et
al. 2010, as BNT and opexebo compute it: for each outer radius r from the central field's radius c to half
the autocorrelogram, ρ_α(r) is the Pearson correlation, over the annulus c < d < r, of the autocorrelogram
with itself rotated by α (bilinear, as opexebo), and
    g60(r) = min(ρ60, ρ120) − max(ρ30, ρ90, ρ150)          (hexagonal lattice: the literature's score)
    g90(r) = ρ90 − (ρ45 + ρ135)/2                           (square lattice: Banino et al. 2018, Nature 557,
                                                             the "90° gridness" of DeepMind's grid-cells code)
each unit's score being the largest mean of g over 3 consecutive radii (opexebo's rule). The model's modules
are square lattices, so g90 is the score that should pass and g60 should stay low. Why not
`opexebo.analysis.grid_score`: opexebo 0.7.2's raises TypeError with the NumPy this project uses (2.4:
`int()` of a one-element array in `_findCentreRadius`, deprecated since NumPy 1.25) and has no 90° score; this port computes every annulus's
correlations from cumulative sums over the bins sorted by radius. The one deliberate change: opexebo finds
the central field with its adaptive place-field search (about 60 ms a map, more than everything else a
shuffle costs); here it is the region connected to the centre where the normalised autocorrelogram is ≥
0.2, the threshold that search ends at when nothing stops it earlier (c = ⌊√(area/π)⌋ as opexebo).
tests/recording/test_measures.py checks the score against opexebo's own (with the NumPy fix applied).

**Shuffle test** (as Langston et al. 2010 and the Moser lab's papers): each measured unit's activity is
circularly shifted against the trajectory by a random lag of at least `min_shift_s` (20 s; a quarter of the
session when that is shorter), `shuffles` times; the shifted maps are scored exactly as the real ones and
pooled over the measured units of the population; a unit passes when its score exceeds the pool's 95th
percentile. Lags, and which units are measured (`units_per_population`, default 16, or "all"), are drawn
from a generator seeded by (`seed`, the population's name): the same seed gives the same numbers.

**Lattice** (`square_lattice`): the autocorrelogram's local maxima (≥ 0.1) outside the central field,
nearest first; the 4 nearest at most 1.25× the nearest's distance and ≥ 30° apart in direction (a square
lattice's 4 neighbours; its diagonals lie √2 further), refined to sub-bin precision by a parabola through
each peak's neighbours. Spacing = their mean distance (m); orientation = arg(Σ e^{4iθ})/4 in (−45°, 45°]
(θ counter-clockwise from +x): a square lattice's axes modulo 90°. Opexebo's `grid_score_stats` takes six
neighbours and orientations modulo 60°, a hexagonal lattice's. The module's spacing ratio to design is the
mean spacing over P/k (design 1 : ½ : ¼ between modules for k = 1, 2, 4).

**Spatial information and fields.** `rate_map_stats` (Skaggs et al. 1993): I = Σ_b p_b (λ_b/λ̄) log2(λ_b/λ̄)
bits per spike (p_b the occupancy probability; BNT's variant counts bins above the mean only), which does
not depend on the activity's units; the rate form λ̄·I is bits/s only if the activity is a rate in Hz.
Fields are `place_field`'s (BNT's adaptive threshold), at least 9 bins (opexebo's default) with a peak of at
least 20 % of the map's peak (opexebo's defaults in Hz mean nothing for network activity), seeded with peaks
found here: opexebo's peak search rejects every peak of a map without exact zeros (its distance transform of
such a map is −1 everywhere), and activity maps have none.

**Head direction** (`hd_tuning`): heading bins of `hd_bin_deg` (6°) over [0, 2π); the tuning curve is
(G∗A)/(G∗O) as for maps, circularly smoothed with σ = `hd_sigma_bins` (1 bin). `tuning_curve_stats` gives the
mean vector length (Rayleigh's R of the curve, Zar eq. 26.13) and the mean direction, the unit's preferred
direction; its error is the preferred minus the designed direction (`unit_phase_rad["hd"]`) wrapped to
(−180°, 180°]. The same shuffle protocol gives a mean vector length threshold.

Import cost: numpy only at import; opexebo, scipy and scikit-image are imported inside the functions (the
`neuro` extra).
"""

from __future__ import annotations

import functools
import json
import math
import zlib
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.recording.session import GRID_POPULATIONS, Recording

__all__ = [
    "HD_POPULATION",
    "SPATIAL_POPULATIONS",
    "GridScores",
    "HeadDirectionPopulation",
    "HeadDirectionUnit",
    "MeasureError",
    "MeasureSettings",
    "RateMaps",
    "RecordingMeasures",
    "SpatialBinning",
    "SpatialPopulation",
    "SpatialUnit",
    "SquareLattice",
    "TuningCurves",
    "autocorrelogram",
    "central_field_radius_bins",
    "default_bin_size_m",
    "firing_fields",
    "grid_scores",
    "hd_tuning",
    "measure_recording",
    "rate_maps",
    "spatial_binning",
    "spatial_information",
    "square_lattice",
]

HD_POPULATION = "hd"
SPATIAL_POPULATIONS = (*GRID_POPULATIONS, "place")
"""The populations with spatial maps (the grid modules and the place torus), measured in this order."""

_CENTRAL_FIELD_THRESHOLD = 0.2
_PEAK_THRESHOLD = 0.1
_SHUFFLE_PERCENTILE = 95.0


class MeasureError(HippoNavError):
    """A recording cannot be measured as asked (bad shapes, NaN positions, an unknown population, …)."""


def _opexebo() -> Any:
    try:
        import opexebo
    except ImportError:
        raise MeasureError("the lab's measures need opexebo: pip install 'hippo-nav[neuro]'") from None
    return opexebo


# --------------------------------------------------------------------------------------------- settings


def default_bin_size_m(arena_size_m: float) -> float:
    """2.5 cm (opexebo's and BNT's default) up to a 2 m arena; larger arenas keep 80 bins across."""
    return max(0.025, arena_size_m / 80.0)


@dataclass(frozen=True)
class MeasureSettings:
    """What `measure_recording` was asked (written into measures.json)."""

    bin_size_m: float
    sigma_bins: float = 2.0
    units_per_population: int | Literal["all"] = 16
    shuffles: int = 25
    """Shuffles per measured unit; the threshold pools them over the population's measured units."""
    min_shift_s: float = 20.0
    seed: int = 0
    hd_bin_deg: float = 6.0
    hd_sigma_bins: float = 1.0
    field_threshold: float = 0.2
    """A field's peak must reach this fraction of its map's peak."""
    min_field_bins: int = 9


# --------------------------------------------------------------------------------------------- rate maps


@dataclass(frozen=True)
class SpatialBinning:
    """Square bins of `bin_size_m` from `origin_m` (x, y); maps are `shape` = (ny, nx), row = y."""

    origin_m: tuple[float, float]
    bin_size_m: float
    shape: tuple[int, int]

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1), for `imshow(..., extent=..., origin="lower")`."""
        ny, nx = self.shape
        x0, y0 = self.origin_m
        return (x0, x0 + nx * self.bin_size_m, y0, y0 + ny * self.bin_size_m)

    def flat_index(self, position_m: np.ndarray) -> np.ndarray:
        """Each position's bin as a flat index (row-major), −1 more than half a bin outside the bins."""
        ny, nx = self.shape
        cell = (np.asarray(position_m, dtype=np.float64) - np.asarray(self.origin_m)) / self.bin_size_m
        # A position on a wall, or a tracking jitter just beyond it, belongs to the bin beside the wall.
        inside = np.all((cell >= -0.5) & (cell < np.array([nx, ny]) + 0.5), axis=1)
        column = np.clip(np.floor(cell[:, 0]), 0, nx - 1).astype(np.int64)
        row = np.clip(np.floor(cell[:, 1]), 0, ny - 1).astype(np.int64)
        return np.where(inside, row * nx + column, -1)


def spatial_binning(rec: Recording, bin_size_m: float | None = None) -> SpatialBinning:
    """The bins of `rec`'s rate maps (module doc): the arena's box when the positions lie in it."""
    _check_trajectory(rec)
    position = rec.position_m
    arena = rec.metadata.get("arena") or {}
    size = arena.get("size_m")
    lo, hi = position.min(axis=0), position.max(axis=0)
    if bin_size_m is None:
        bin_size_m = default_bin_size_m(float(size) if size else float(np.max(hi - lo)))
    if not (math.isfinite(bin_size_m) and bin_size_m > 0):
        raise MeasureError(f"bin_size_m = {bin_size_m}: give a positive bin size in metres")
    tolerance = 0.5 * bin_size_m
    if size and np.all(lo >= -tolerance) and np.all(hi <= float(size) + tolerance):
        origin, span = np.zeros(2), np.full(2, float(size))
    else:
        origin, span = lo, np.maximum(hi - lo, bin_size_m)
    nx, ny = (math.ceil(s / bin_size_m - 1e-9) for s in span)
    return SpatialBinning((float(origin[0]), float(origin[1])), float(bin_size_m), (ny, nx))


class _MapMaker:
    """One session's bins and smoothed occupancy, reused for every unit's (and every shuffle's) map."""

    def __init__(self, rec: Recording, binning: SpatialBinning, sigma_bins: float) -> None:
        if not (math.isfinite(sigma_bins) and sigma_bins >= 0):
            raise MeasureError(f"sigma_bins = {sigma_bins}: give a smoothing width ≥ 0 in bins")
        self.binning = binning
        self.sigma_bins = sigma_bins
        self.dt_s = rec.sample_dt_s
        index = binning.flat_index(rec.position_m)
        self.inside = index >= 0
        self.index = index[self.inside]
        self.size = binning.shape[0] * binning.shape[1]
        counts = np.bincount(self.index, minlength=self.size).reshape(binning.shape)
        self.occupancy_s = counts * self.dt_s
        self.visited = counts > 0
        self.smoothed_occupancy = self._smooth(self.occupancy_s)

    def _smooth(self, image: np.ndarray) -> np.ndarray:
        if self.sigma_bins == 0:
            return image
        return np.asarray(_opexebo().general.smooth(image, self.sigma_bins))

    def rate_map(self, activity: np.ndarray) -> np.ndarray:
        """The map of one unit's activity series (T,): NaN in unvisited bins."""
        weighted = np.bincount(self.index, weights=activity[self.inside] * self.dt_s, minlength=self.size)
        smoothed = self._smooth(weighted.reshape(self.binning.shape))
        out = np.full(self.binning.shape, np.nan)
        out[self.visited] = smoothed[self.visited] / self.smoothed_occupancy[self.visited]
        return out


@dataclass(frozen=True)
class RateMaps:
    """Smoothed, occupancy-normalised maps of some units of a population (module doc)."""

    population: str
    units: np.ndarray
    maps: np.ndarray
    """(n_units, ny, nx), activity in the population's units, NaN where the animal never was."""
    occupancy_s: np.ndarray
    """(ny, nx), seconds spent in each bin (unsmoothed)."""
    binning: SpatialBinning
    sigma_bins: float


def rate_maps(
    rec: Recording,
    population: str,
    units: Sequence[int] | np.ndarray | None = None,
    *,
    bin_size_m: float | None = None,
    sigma_bins: float = 2.0,
) -> RateMaps:
    """Rate maps of `units` (default all) of `population` (module doc for the definition)."""
    activity = _population(rec, population)
    chosen = _unit_indices(units, activity.shape[1], population)
    maker = _MapMaker(rec, spatial_binning(rec, bin_size_m), sigma_bins)
    maps = (
        np.stack([maker.rate_map(activity[:, u].astype(np.float64)) for u in chosen])
        if len(chosen)
        else (np.empty((0, *maker.binning.shape)))
    )
    return RateMaps(population, chosen, maps, maker.occupancy_s, maker.binning, sigma_bins)


# --------------------------------------------------------------------------------------------- scores


@dataclass(frozen=True)
class GridScores:
    """A map's rotational-symmetry scores (module doc); NaN when the autocorrelogram has no structure."""

    score_60: float
    score_90: float
    central_radius_bins: int


_ROTATIONS_DEG = (30, 45, 60, 90, 120, 135, 150)
_NO_SCORES = GridScores(math.nan, math.nan, 0)


def autocorrelogram(rate_map: np.ndarray) -> np.ndarray:
    """opexebo's spatial autocorrelogram of a map (odd-sized, zero lag at the centre, one bin a pixel)."""
    rate_map = _two_d(rate_map, "autocorrelogram", "a rate map")
    finite = rate_map[np.isfinite(rate_map)]
    if finite.size < 4 or np.ptp(finite) <= 1e-12 * max(1.0, float(np.abs(finite).max())):
        # A flat or empty map (a silent or lesioned unit) has no autocorrelation; opexebo would divide 0 by 0.
        return np.full(tuple(_autocorrelogram_size(n) for n in rate_map.shape), np.nan)
    return np.asarray(_opexebo().analysis.autocorrelation(rate_map), dtype=np.float64)


def _two_d(image: np.ndarray, function: str, what: str) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 2 or min(image.shape) < 2:
        raise MeasureError(f"{function} takes {what} as one 2-D array; it was given shape {image.shape}")
    return image


def _autocorrelogram_size(n: int) -> int:
    size = round(n + n * 0.8)
    return size - 1 if size % 2 == 0 else size


def _centre(shape: tuple[int, ...]) -> tuple[int, int]:
    """The zero-lag pixel, as opexebo places it (ceil(n/2) in MATLAB's 1-based indices)."""
    return math.ceil(shape[0] / 2) - 1, math.ceil(shape[1] / 2) - 1


def central_field_radius_bins(acorr: np.ndarray) -> int:
    """⌊√(area/π)⌋ of the region connected to the centre where acorr/max ≥ 0.2 (module doc); 0 if none."""
    from scipy import ndimage

    a = np.asarray(acorr, dtype=np.float64)
    if not np.isfinite(a).all() or a.max() <= 0:
        return 0
    # 4-connected, as opexebo's place_field labels a field.
    labels, _ = ndimage.label(a / a.max() >= _CENTRAL_FIELD_THRESHOLD)
    label = labels[_centre(a.shape)]
    if label == 0:
        return 0
    return math.floor(math.sqrt(float(np.count_nonzero(labels == label)) / math.pi))


def grid_scores(acorr: np.ndarray, *, central_radius_bins: int | None = None) -> GridScores:
    """60° and 90° scores of an autocorrelogram (module doc); `central_radius_bins` overrides the
    central field's radius (opexebo's own, to compare with it)."""
    from skimage import transform

    a = _two_d(acorr, "grid_scores", "an autocorrelogram")
    if not np.isfinite(a).all() or a.max() <= 0:
        return _NO_SCORES
    a = a / a.max()
    c = central_field_radius_bins(a) if central_radius_bins is None else int(central_radius_bins)
    outer = math.floor(min(a.shape) / 2)
    if c == 0 or outer < c:
        return GridScores(math.nan, math.nan, c)
    radii = np.linspace(max(3, c + 1), outer, outer - c).astype(int)
    if radii.size == 0:
        return GridScores(math.nan, math.nan, c)
    ring, order, counts = _annuli(a.shape, c, tuple(radii.tolist()))
    x = a.reshape(-1)[ring][order]
    rho = {}
    for angle in _ROTATIONS_DEG:
        rotated = transform.rotate(a, angle, preserve_range=True, clip=False).reshape(-1)
        rho[angle] = _prefix_pearson(x, rotated[ring][order], counts)
    g60 = np.minimum(rho[60], rho[120]) - np.maximum(np.maximum(rho[30], rho[90]), rho[150])
    g90 = rho[90] - 0.5 * (rho[45] + rho[135])
    return GridScores(_sliding_max(g60), _sliding_max(g90), c)


@functools.lru_cache(maxsize=32)
def _annuli(
    shape: tuple[int, ...], c: int, radii: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The flat indices of the bins with c < d < max(radii), their order by d, and how many lie within each
    radius (d < r): every annulus of opexebo's sweep is a prefix of that order. Cached: a session's maps share
    one shape, and their central fields a few radii."""
    rows, cols = np.indices(shape)
    # opexebo's distances: MATLAB's 1-based indices from ceil(n/2).
    d = np.hypot(cols + 1 - math.ceil(shape[1] / 2), rows + 1 - math.ceil(shape[0] / 2)).reshape(-1)
    ring = np.flatnonzero((d > c) & (d < max(radii)))
    order = np.argsort(d[ring], kind="stable")
    counts = np.searchsorted(d[ring][order], np.asarray(radii), side="left")
    for array in (ring, order, counts):
        array.flags.writeable = False
    return ring, order, counts


def _prefix_pearson(x: np.ndarray, y: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Pearson's r of x[:n] and y[:n] for every n in `counts` (NaN where either is constant)."""
    x = x - x.mean()
    y = y - y.mean()
    sums = np.cumsum(np.stack([x, y, x * y, x * x, y * y]), axis=1)
    sx, sy, sxy, sxx, syy = np.concatenate([np.zeros((5, 1)), sums], axis=1)[:, counts]
    n = counts.astype(np.float64)
    cov = n * sxy - sx * sy
    vx = n * sxx - sx * sx
    vy = n * syy - sy * sy
    ok = (counts >= 2) & (vx > 1e-12 * n * n) & (vy > 1e-12 * n * n)
    r = np.full(counts.shape, np.nan)
    r[ok] = cov[ok] / np.sqrt(vx[ok] * vy[ok])
    return r


def _sliding_max(g: np.ndarray) -> float:
    """opexebo's rule: the largest mean over 3 consecutive radii (the plain mean when there are ≤ 4)."""
    steps = max(g.size - 3, 1)
    if steps == 1:
        return float(np.mean(g))
    windows = np.lib.stride_tricks.sliding_window_view(g, 3)[:steps]
    finite = np.isfinite(windows)
    counts = finite.sum(axis=1)
    if not counts.any():
        return math.nan
    means = np.where(finite, windows, 0.0).sum(axis=1) / np.maximum(counts, 1)
    return float(np.max(means[counts > 0]))


# --------------------------------------------------------------------------------------------- lattice


@dataclass(frozen=True)
class SquareLattice:
    """A square lattice read from an autocorrelogram's 4 nearest peaks (module doc)."""

    spacing_m: float
    orientation_deg: float
    """Of the lattice's axes, counter-clockwise from +x, in (−45°, 45°]."""
    peaks_m: np.ndarray
    """(m, 2) offsets (x, y) of the peaks used, metres (m < 4: not a square lattice, NaN spacing)."""


def square_lattice(
    acorr: np.ndarray, bin_size_m: float, central_radius_bins: int | None = None
) -> SquareLattice:
    """Spacing and orientation of the square lattice in `acorr` (module doc)."""
    from scipy import ndimage

    a = _two_d(acorr, "square_lattice", "an autocorrelogram")
    if not np.isfinite(a).all() or a.max() <= 0:
        return SquareLattice(math.nan, math.nan, np.empty((0, 2)))
    a = a / a.max()
    c = central_field_radius_bins(a) if central_radius_bins is None else central_radius_bins
    peaks = (a == ndimage.maximum_filter(a, size=3, mode="nearest")) & (a >= _PEAK_THRESHOLD)
    rows, cols = np.nonzero(peaks)
    cy, cx = _centre(a.shape)
    dy, dx = rows - cy, cols - cx
    distance = np.hypot(dx, dy)
    chosen: list[int] = []
    for i in np.argsort(distance, kind="stable"):
        if distance[i] <= max(c, 1):
            continue
        if chosen and distance[i] > 1.25 * distance[chosen[0]]:
            break
        angle = math.atan2(dy[i], dx[i])
        if all(abs(_wrap(angle - math.atan2(dy[j], dx[j]))) >= math.radians(30) for j in chosen):
            chosen.append(int(i))
        if len(chosen) == 4:
            break
    offsets = np.array([_refine(a, rows[i], cols[i]) for i in chosen]).reshape(-1, 2) - [cx, cy]
    if len(chosen) < 4:
        return SquareLattice(math.nan, math.nan, offsets * bin_size_m)
    theta = np.arctan2(offsets[:, 1], offsets[:, 0])
    orientation = math.degrees(float(np.angle(np.exp(4j * theta).sum())) / 4)
    spacing = float(np.hypot(offsets[:, 0], offsets[:, 1]).mean()) * bin_size_m
    return SquareLattice(spacing, orientation, offsets * bin_size_m)


def _refine(a: np.ndarray, row: int, col: int) -> tuple[float, float]:
    """(x, y) of a peak to sub-bin precision: the vertex of a parabola through it and its two neighbours
    along each axis (none at the border)."""

    def vertex(lo: float, mid: float, hi: float) -> float:
        curvature = lo - 2 * mid + hi
        return 0.5 * (lo - hi) / curvature if curvature < 0 else 0.0

    x, y = float(col), float(row)
    if 0 < col < a.shape[1] - 1:
        x += vertex(a[row, col - 1], a[row, col], a[row, col + 1])
    if 0 < row < a.shape[0] - 1:
        y += vertex(a[row - 1, col], a[row, col], a[row + 1, col])
    return x, y


def _wrap(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


# --------------------------------------------------------------------------------------------- info, fields


def spatial_information(rate_map: np.ndarray, occupancy_s: np.ndarray) -> tuple[float, float]:
    """Skaggs information of a map (module doc): (bits per spike, bits per second for a rate in Hz)."""
    rate_map = np.asarray(rate_map, dtype=np.float64)
    visited = np.isfinite(rate_map) & (occupancy_s > 0)
    if not visited.any() or np.nanmax(rate_map) <= 0:
        return math.nan, math.nan
    stats = _opexebo().analysis.rate_map_stats(
        np.ma.masked_array(np.where(visited, rate_map, 0.0), mask=~visited),
        np.ma.masked_array(occupancy_s, mask=~visited),
    )
    return float(stats["spatial_information_content"]), float(stats["spatial_information_rate"])


def firing_fields(
    rate_map: np.ndarray, bin_size_m: float, *, threshold: float = 0.2, min_bins: int = 9
) -> tuple[int, float]:
    """(number of fields, their mean area in m²) by opexebo's `place_field` (module doc); NaN area if none."""
    from scipy import ndimage

    rate_map = np.asarray(rate_map, dtype=np.float64)
    if not np.isfinite(rate_map).any() or np.nanmax(rate_map) <= 0:
        return 0, math.nan
    peak = float(np.nanmax(rate_map))
    filled = np.where(np.isfinite(rate_map), rate_map, -np.inf)
    local = (filled == ndimage.maximum_filter(filled, size=3, mode="nearest")) & (filled >= threshold * peak)
    # A plateau is one peak: one seed per connected group of equal maxima (two would split one field).
    labels, n = ndimage.label(local, structure=np.ones((3, 3)))
    if n == 0:
        return 0, math.nan
    seeds = np.array(ndimage.maximum_position(filled, labels, range(1, n + 1)), dtype=int).reshape(-1, 2)
    fields, _ = _opexebo().analysis.place_field(
        rate_map, min_bins=min_bins, min_peak=threshold * peak, min_mean=0.0, peak_coords=seeds
    )
    # opexebo grows a field by lowering its threshold, and where the bins around a peak are silent or never
    # visited (a short session: a path of a few bins, NaN beside it) it floods the whole arena: one field of
    # 4 m² in a 2 m box. A field holds only visited bins with activity, connected to its peak.
    firing = np.isfinite(rate_map) & (rate_map > 0)
    areas = []
    for f in fields:
        mask, _ = ndimage.label(np.asarray(f["map"], bool) & firing)
        own = mask == mask[tuple(np.asarray(f["peak_coords"], int))]
        if mask[tuple(np.asarray(f["peak_coords"], int))] and int(own.sum()) >= min_bins:
            areas.append(int(own.sum()))
    if not areas:
        return 0, math.nan
    return len(areas), float(np.mean(areas)) * bin_size_m**2


# --------------------------------------------------------------------------------------------- head direction


@dataclass(frozen=True)
class TuningCurves:
    """Smoothed, occupancy-normalised head-direction tuning of some units (module doc)."""

    units: np.ndarray
    bin_centres_rad: np.ndarray
    curves: np.ndarray
    """(n_units, n_bins), activity in the population's units, NaN at headings never taken."""
    occupancy_s: np.ndarray


def hd_tuning(
    rec: Recording,
    units: Sequence[int] | np.ndarray | None = None,
    *,
    bin_deg: float = 6.0,
    sigma_bins: float = 1.0,
    population: str = HD_POPULATION,
) -> TuningCurves:
    """Tuning curves over heading of `units` (default all) of the HD population (module doc)."""
    activity = _population(rec, population)
    chosen = _unit_indices(units, activity.shape[1], population)
    index, n_bins = _heading_bins(rec, bin_deg)
    occupancy = np.bincount(index, minlength=n_bins) * rec.sample_dt_s
    curves = np.stack(
        [_tuning(activity[:, u], index, occupancy, rec.sample_dt_s, sigma_bins) for u in chosen]
    )
    centres = (np.arange(n_bins) + 0.5) * 2 * np.pi / n_bins
    return TuningCurves(chosen, centres, curves.reshape(len(chosen), n_bins), occupancy)


def _heading_bins(rec: Recording, bin_deg: float) -> tuple[np.ndarray, int]:
    if not (0 < bin_deg <= 90):
        raise MeasureError(f"hd_bin_deg = {bin_deg}: give a heading bin in (0, 90] degrees")
    n_bins = math.ceil(360.0 / bin_deg - 1e-9)
    heading = np.mod(np.asarray(rec.heading_rad, dtype=np.float64), 2 * np.pi)
    return np.minimum((heading / (2 * np.pi) * n_bins).astype(np.int64), n_bins - 1), n_bins


def _tuning(
    activity: np.ndarray, index: np.ndarray, occupancy_s: np.ndarray, dt_s: float, sigma: float
) -> np.ndarray:
    weighted = np.bincount(
        index, weights=np.asarray(activity, dtype=np.float64) * dt_s, minlength=occupancy_s.size
    )
    if sigma > 0:
        smooth = _opexebo().general.smooth
        weighted, occupancy = (
            smooth(weighted, sigma, circular=True),
            smooth(occupancy_s, sigma, circular=True),
        )
    else:
        occupancy = occupancy_s
    out = np.full(occupancy_s.size, np.nan)
    seen = occupancy_s > 0
    out[seen] = weighted[seen] / occupancy[seen]
    return out


def _tuning_stats(curve: np.ndarray) -> tuple[float, float, float]:
    """(mean direction rad in [0, 2π), mean vector length, peak direction rad) by opexebo; NaN if flat."""
    if not np.isfinite(curve).any() or np.nanmax(curve) <= 0:
        return math.nan, math.nan, math.nan
    stats = _opexebo().analysis.tuning_curve_stats(np.ma.masked_invalid(curve))
    return (
        float(stats["hd_mean_direction_rad"]) % (2 * math.pi),
        float(stats["hd_mvl"]),
        float(stats["hd_peak_direction_rad"]),
    )


# --------------------------------------------------------------------------------------------- results


@dataclass(frozen=True)
class SpatialUnit:
    """One measured unit of a spatial population."""

    unit: int
    grid_score_60: float
    grid_score_90: float
    passes_60: bool
    passes_90: bool
    spacing_m: float
    spacing_over_design: float
    orientation_deg: float
    information_bits_per_spike: float
    information_bits_per_s: float
    """Bits/s if the activity is a rate in Hz; else bits per unit of activity per second."""
    field_count: int
    field_area_mean_m2: float
    peak_activity: float
    """The smoothed map's peak, in the population's activity units."""


@dataclass(frozen=True)
class SpatialPopulation:
    """A spatial population's summary over its measured units, the units, and the shuffled scores."""

    population: str
    design_spacing_m: float
    units_measured: int
    threshold_60: float
    threshold_90: float
    fraction_passing_60: float
    fraction_passing_90: float
    spacing_mean_m: float
    spacing_std_m: float
    spacing_over_design: float
    orientation_mean_deg: float
    orientation_std_deg: float
    information_mean_bits_per_spike: float
    field_count_mean: float
    field_area_mean_m2: float
    units: tuple[SpatialUnit, ...]
    shuffled_60: tuple[float, ...] = field(repr=False)
    shuffled_90: tuple[float, ...] = field(repr=False)


@dataclass(frozen=True)
class HeadDirectionUnit:
    """One measured HD unit: its preferred direction against its design, and how sharply it is tuned."""

    unit: int
    preferred_direction_deg: float
    design_direction_deg: float
    direction_error_deg: float
    mean_vector_length: float
    peak_direction_deg: float
    passes: bool


@dataclass(frozen=True)
class HeadDirectionPopulation:
    """The HD population's summary over its measured units, the units, and the shuffled vector lengths."""

    population: str
    units_measured: int
    threshold_mean_vector_length: float
    fraction_passing: float
    mean_vector_length_mean: float
    direction_error_mean_abs_deg: float
    direction_error_max_abs_deg: float
    units: tuple[HeadDirectionUnit, ...]
    shuffled_mean_vector_length: tuple[float, ...] = field(repr=False)


@dataclass(frozen=True)
class RecordingMeasures:
    """Everything `measure_recording` measured; `to_dict`/`to_json` for measures.json (NaN as null)."""

    settings: MeasureSettings
    spatial: dict[str, SpatialPopulation]
    head_direction: HeadDirectionPopulation | None
    module_spacing_ratios: dict[str, float]
    """Each grid module's mean spacing over the coarsest measured module's (design 1 : ½ : ¼)."""
    design_spacing_ratios: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return _jsonable(asdict(self))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, allow_nan=False)

    def write_json(self, path: str | Path) -> Path:
        """Write `to_json()` to `path` atomically."""
        from hippo_nav.io.atomic import write_text

        return write_text(path, self.to_json() + "\n")


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


# --------------------------------------------------------------------------------------------- checks


def _check_trajectory(rec: Recording) -> None:
    time_s = np.asarray(rec.time_s)
    if time_s.ndim != 1 or time_s.size < 2:
        raise MeasureError(f"time_s has shape {time_s.shape}: a recording needs ≥ 2 samples in a 1-D array")
    n = time_s.size
    dt = np.diff(time_s)
    if not np.isfinite(time_s).all() or dt.min() <= 0 or np.ptp(dt) > 1e-6 * dt.mean() + 1e-9:
        raise MeasureError(
            "time_s must be finite and uniformly increasing (time_s[i] = i·dt); resample it first"
        )
    position = np.asarray(rec.position_m)
    if position.shape != (n, 2):
        raise MeasureError(f"position_m has shape {position.shape}; expected ({n}, 2) (x, y per sample)")
    if not np.isfinite(position).all():
        raise MeasureError(
            f"position_m has {int((~np.isfinite(position)).any(axis=1).sum())} samples with NaN or infinite "
            "values: drop or interpolate them before measuring"
        )
    heading = np.asarray(rec.heading_rad)
    if heading.shape != (n,) or not np.isfinite(heading).all():
        raise MeasureError(f"heading_rad must be {n} finite angles (rad); it has shape {heading.shape}")


def _population(rec: Recording, name: str) -> np.ndarray:
    if name not in rec.populations:
        raise MeasureError(
            f"no population {name!r} in this recording; it has {', '.join(sorted(rec.populations)) or 'none'}"
        )
    _check_trajectory(rec)
    activity = np.asarray(rec.populations[name])
    if activity.ndim != 2 or activity.shape[0] != rec.time_s.size:
        raise MeasureError(
            f"population {name!r} has shape {activity.shape}; expected ({rec.time_s.size}, n_units): one row a sample"
        )
    if not np.isfinite(activity).all():
        raise MeasureError(
            f"population {name!r} has NaN or infinite activity; a recording's activity is finite"
        )
    return activity


def _unit_indices(units: Sequence[int] | np.ndarray | None, n_units: int, population: str) -> np.ndarray:
    if units is None:
        return np.arange(n_units)
    chosen = np.asarray(units, dtype=np.int64).reshape(-1)
    if chosen.size and (chosen.min() < 0 or chosen.max() >= n_units):
        raise MeasureError(
            f"population {population!r} has units 0..{n_units - 1}; asked for {chosen.tolist()}"
        )
    return chosen


# --------------------------------------------------------------------------------------------- the session


def measure_recording(
    rec: Recording,
    *,
    populations: Sequence[str] | None = None,
    units_per_population: int | Literal["all"] = 16,
    shuffles: int = 25,
    seed: int = 0,
    bin_size_m: float | None = None,
    sigma_bins: float = 2.0,
    min_shift_s: float = 20.0,
) -> RecordingMeasures:
    """Measure `populations` (default every one the recording has) as the lab does (module doc):
    `units_per_population` units each (seeded; "all" for every unit), `shuffles` shuffles per unit.
    Deterministic per `seed`."""
    names = _populations_to_measure(rec, populations)
    _check_trajectory(rec)
    if bin_size_m is None:
        bin_size_m = spatial_binning(rec).bin_size_m
    settings = _settings(bin_size_m, sigma_bins, units_per_population, shuffles, min_shift_s, seed)
    lags = _lag_range(rec, min_shift_s)
    spatial: dict[str, SpatialPopulation] = {}
    if any(name in SPATIAL_POPULATIONS for name in names):
        maker = _MapMaker(rec, spatial_binning(rec, settings.bin_size_m), sigma_bins)
        for name in names:
            if name in SPATIAL_POPULATIONS:
                spatial[name] = _measure_spatial(rec, name, maker, settings, lags)
    head_direction = _measure_hd(rec, settings, lags) if HD_POPULATION in names else None
    measured, design = _spacing_ratios(rec, spatial)
    return RecordingMeasures(settings, spatial, head_direction, measured, design)


def _settings(
    bin_size_m: float,
    sigma_bins: float,
    units_per_population: int | Literal["all"],
    shuffles: int,
    min_shift_s: float,
    seed: int,
) -> MeasureSettings:
    if units_per_population != "all" and not (
        isinstance(units_per_population, int) and units_per_population >= 1
    ):
        raise MeasureError(f"units_per_population = {units_per_population!r}: give a count ≥ 1 or 'all'")
    if not (isinstance(shuffles, int) and shuffles >= 0):
        raise MeasureError(f"shuffles = {shuffles!r}: give a count ≥ 0 of shuffles per unit")
    if not (isinstance(seed, int) and seed >= 0):
        raise MeasureError(f"seed = {seed!r}: give an integer ≥ 0")
    if not (math.isfinite(min_shift_s) and min_shift_s > 0):
        raise MeasureError(f"min_shift_s = {min_shift_s}: give a positive shortest shuffle lag in seconds")
    return MeasureSettings(
        bin_size_m=float(bin_size_m),
        sigma_bins=float(sigma_bins),
        units_per_population=units_per_population,
        shuffles=shuffles,
        min_shift_s=float(min_shift_s),
        seed=seed,
    )


def _populations_to_measure(rec: Recording, populations: Sequence[str] | None) -> list[str]:
    """The populations to measure, in `SPATIAL_POPULATIONS` order after "hd", each checked before any work."""
    known = (HD_POPULATION, *SPATIAL_POPULATIONS)
    if isinstance(populations, str):
        raise MeasureError(f"populations = {populations!r}: give a list of names, e.g. [{populations!r}]")
    for name in populations or ():
        if name not in known:
            raise MeasureError(f"no measures for population {name!r}; the populations are {', '.join(known)}")
    names = [n for n in known if (n in rec.populations if populations is None else n in populations)]
    for name in names:
        _population(rec, name)
    return names


def _lag_range(rec: Recording, min_shift_s: float) -> tuple[int, int]:
    """Shuffle lags in samples: [m, T − m] with m = min(min_shift_s, a quarter of the session)."""
    n = rec.time_s.size
    shortest = max(1, math.ceil(min(min_shift_s, 0.25 * n * rec.sample_dt_s) / rec.sample_dt_s - 1e-9))
    return shortest, max(shortest, n - shortest)


def _rng(seed: int, population: str) -> np.random.Generator:
    """A generator per (seed, population): one population's draws never depend on which others are measured."""
    return np.random.default_rng([seed, zlib.crc32(population.encode())])


def _choose_units(rng: np.random.Generator, n_units: int, wanted: int | Literal["all"]) -> np.ndarray:
    if wanted == "all" or wanted >= n_units:
        return np.arange(n_units)
    return np.sort(rng.choice(n_units, size=wanted, replace=False))


def _threshold(scores: np.ndarray) -> float:
    finite = scores[np.isfinite(scores)]
    return float(np.percentile(finite, _SHUFFLE_PERCENTILE)) if finite.size else math.nan


def _mean_std(values: Sequence[float]) -> tuple[float, float]:
    finite = np.asarray([v for v in values if math.isfinite(v)], dtype=np.float64)
    if finite.size == 0:
        return math.nan, math.nan
    return float(finite.mean()), float(finite.std())


def _square_mean_std_deg(orientations_deg: Sequence[float]) -> tuple[float, float]:
    """Circular mean and standard deviation of square-lattice orientations (period 90°), degrees."""
    finite = np.radians([v for v in orientations_deg if math.isfinite(v)])
    if finite.size == 0:
        return math.nan, math.nan
    resultant = np.exp(4j * finite).mean()
    spread = math.sqrt(max(0.0, -2.0 * math.log(max(abs(resultant), 1e-300)))) / 4
    return math.degrees(float(np.angle(resultant)) / 4), math.degrees(spread)


def _measure_map(maker: _MapMaker, series: np.ndarray, settings: MeasureSettings) -> dict[str, Any]:
    """Everything measured on one unit's map (its scores, lattice, information and fields)."""
    rate_map = maker.rate_map(series)
    acorr = autocorrelogram(rate_map)
    scores = grid_scores(acorr)
    lattice = square_lattice(acorr, settings.bin_size_m, scores.central_radius_bins or None)
    bits_per_spike, bits_per_s = spatial_information(rate_map, maker.occupancy_s)
    count, area = firing_fields(
        rate_map, settings.bin_size_m, threshold=settings.field_threshold, min_bins=settings.min_field_bins
    )
    return {
        "grid_score_60": scores.score_60,
        "grid_score_90": scores.score_90,
        "spacing_m": lattice.spacing_m,
        "orientation_deg": lattice.orientation_deg,
        "information_bits_per_spike": bits_per_spike,
        "information_bits_per_s": bits_per_s,
        "field_count": count,
        "field_area_mean_m2": area,
        "peak_activity": float(np.nanmax(rate_map)) if np.isfinite(rate_map).any() else math.nan,
    }


def _shuffled_scores(
    maker: _MapMaker, activity: np.ndarray, units: np.ndarray, shuffles: int, lags: np.ndarray
) -> np.ndarray:
    """(n_units · shuffles, 2) 60° and 90° scores of the maps of circularly shifted activity."""
    out = np.full((len(units), shuffles, 2), np.nan)
    for row, unit in enumerate(units):
        series = activity[:, unit].astype(np.float64)
        for column, lag in enumerate(lags[row]):
            scores = grid_scores(autocorrelogram(maker.rate_map(np.roll(series, int(lag)))))
            out[row, column] = scores.score_60, scores.score_90
    return out.reshape(-1, 2)


def passes_shuffle_test(score: float, threshold: float) -> bool:
    """A unit's grid score passes above its shuffles' threshold, and above zero: a negative score is no
    lattice, however low a few shuffles put the threshold (two shuffles gave −0.16 a pass over −0.1597)."""
    return bool(score > threshold and score > 0.0)


def _measure_spatial(
    rec: Recording, name: str, maker: _MapMaker, settings: MeasureSettings, lag_range: tuple[int, int]
) -> SpatialPopulation:
    activity = _population(rec, name)
    rng = _rng(settings.seed, name)
    units = _choose_units(rng, activity.shape[1], settings.units_per_population)
    lags = rng.integers(lag_range[0], lag_range[1] + 1, size=(len(units), settings.shuffles))
    design = rec.spacing_m(name)
    observed = [_measure_map(maker, activity[:, u].astype(np.float64), settings) for u in units]
    shuffled = _shuffled_scores(maker, activity, units, settings.shuffles, lags)
    t60, t90 = _threshold(shuffled[:, 0]), _threshold(shuffled[:, 1])
    rows = tuple(
        SpatialUnit(
            unit=int(u),
            passes_60=passes_shuffle_test(m["grid_score_60"], t60),
            passes_90=passes_shuffle_test(m["grid_score_90"], t90),
            spacing_over_design=m["spacing_m"] / design,
            **m,
        )
        for u, m in zip(units, observed)
    )
    spacing_mean, spacing_std = _mean_std([r.spacing_m for r in rows])
    orientation_mean, orientation_std = _square_mean_std_deg([r.orientation_deg for r in rows])
    n = max(len(rows), 1)
    return SpatialPopulation(
        population=name,
        design_spacing_m=design,
        units_measured=len(rows),
        threshold_60=t60,
        threshold_90=t90,
        fraction_passing_60=sum(r.passes_60 for r in rows) / n,
        fraction_passing_90=sum(r.passes_90 for r in rows) / n,
        spacing_mean_m=spacing_mean,
        spacing_std_m=spacing_std,
        spacing_over_design=spacing_mean / design,
        orientation_mean_deg=orientation_mean,
        orientation_std_deg=orientation_std,
        information_mean_bits_per_spike=_mean_std([r.information_bits_per_spike for r in rows])[0],
        field_count_mean=_mean_std([float(r.field_count) for r in rows])[0],
        field_area_mean_m2=_mean_std([r.field_area_mean_m2 for r in rows])[0],
        units=rows,
        shuffled_60=tuple(float(v) for v in shuffled[:, 0]),
        shuffled_90=tuple(float(v) for v in shuffled[:, 1]),
    )


def _hd_design_rad(rec: Recording, n_units: int) -> np.ndarray:
    phase = rec.unit_phase_rad.get(HD_POPULATION)
    if phase is None:
        return np.full(n_units, np.nan)
    phase = np.asarray(phase, dtype=np.float64)
    if phase.shape != (n_units,):
        raise MeasureError(
            f"unit_phase_rad['hd'] has shape {phase.shape}; expected ({n_units},), one heading a unit"
        )
    return phase


def _measure_hd(
    rec: Recording, settings: MeasureSettings, lag_range: tuple[int, int]
) -> HeadDirectionPopulation:
    activity = _population(rec, HD_POPULATION)
    rng = _rng(settings.seed, HD_POPULATION)
    units = _choose_units(rng, activity.shape[1], settings.units_per_population)
    lags = rng.integers(lag_range[0], lag_range[1] + 1, size=(len(units), settings.shuffles))
    design = _hd_design_rad(rec, activity.shape[1])
    index, n_bins = _heading_bins(rec, settings.hd_bin_deg)
    occupancy = np.bincount(index, minlength=n_bins) * rec.sample_dt_s
    dt, sigma = rec.sample_dt_s, settings.hd_sigma_bins
    observed, shuffled = [], []
    for row, u in enumerate(units):
        series = activity[:, u].astype(np.float64)
        observed.append(_tuning_stats(_tuning(series, index, occupancy, dt, sigma)))
        for lag in lags[row]:
            shuffled.append(_tuning_stats(_tuning(np.roll(series, int(lag)), index, occupancy, dt, sigma))[1])
    threshold = _threshold(np.asarray(shuffled, dtype=np.float64))
    rows = tuple(
        HeadDirectionUnit(
            unit=int(u),
            preferred_direction_deg=math.degrees(mean),
            design_direction_deg=math.degrees(float(design[u])),
            direction_error_deg=math.degrees(_wrap(mean - float(design[u]))),
            mean_vector_length=mvl,
            peak_direction_deg=math.degrees(peak),
            passes=bool(mvl > threshold),
        )
        for u, (mean, mvl, peak) in zip(units, observed)
    )
    errors = [abs(r.direction_error_deg) for r in rows if math.isfinite(r.direction_error_deg)]
    return HeadDirectionPopulation(
        population=HD_POPULATION,
        units_measured=len(rows),
        threshold_mean_vector_length=threshold,
        fraction_passing=sum(r.passes for r in rows) / max(len(rows), 1),
        mean_vector_length_mean=_mean_std([r.mean_vector_length for r in rows])[0],
        direction_error_mean_abs_deg=float(np.mean(errors)) if errors else math.nan,
        direction_error_max_abs_deg=float(np.max(errors)) if errors else math.nan,
        units=rows,
        shuffled_mean_vector_length=tuple(float(v) for v in shuffled),
    )


def _spacing_ratios(
    rec: Recording, spatial: dict[str, SpatialPopulation]
) -> tuple[dict[str, float], dict[str, float]]:
    """Each measured grid module's spacing over the coarsest measured one's, measured and designed."""
    modules = [name for name in GRID_POPULATIONS if name in spatial]
    if not modules:
        return {}, {}
    reference = spatial[modules[0]]
    measured = {name: spatial[name].spacing_mean_m / reference.spacing_mean_m for name in modules}
    design = {name: rec.spacing_m(name) / rec.spacing_m(modules[0]) for name in modules}
    return measured, design
