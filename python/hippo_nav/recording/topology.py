"""Persistent homology of a population's activity: is the joint activity of a grid module a torus, of the
head-direction ring a circle? The preprocessing follows Gardner et al., "Toroidal topology of population
activity in grid cells", Nature 602, 123–128 (2022), Methods ("Persistent cohomology"; their code,
github.com/erikher/GridCellTorus), with the departures named below.

Pipeline (`TopologyParams` holds every number; each step is one private function):

1. Smooth each unit's activity in time with a Gaussian, σ = 50 ms (Gardner's kernel for open-field
   sessions); skipped where σ is under half a sample (the network's rates are already smooth at coarse steps).
2. Keep the time points where the animal moves (speed ≥ 2.5 cm/s, Gardner's rule) and the population is
   active: its summed activity above 10 % of its median (a silent network, e.g. a lesioned module, has no
   state to take the shape of). Of those, at most the 15 000 most active are kept (Gardner's cap).
3. z-score each unit over the kept time points (Gardner's `preprocessing.scale`); units that never change
   are dropped (they carry nothing and would divide by zero).
4. PCA to 4 components. Gardner keeps 6: the first Fourier shell of a *hexagonal* torus has three wave
   vectors, six cosine/sine modes. Our networks are *square* tori (docs/model.md), whose first shell has two
   wave vectors, four modes, and whose next shell (the four diagonal modes) is degenerate: keeping 6 takes an
   arbitrary half of it and adds spurious H1/H2 bars (measured on ideal modules: b = (1, 3, 3) with 6,
   (1, 2, 1) with 4). Four components also hold a ring (its first two harmonics).
5. Drop outliers: points whose mean distance to their 20 nearest neighbours exceeds 3× the median. Gardner
   drops sparse points by density; a fixed fraction would cut holes where the trajectory passes less often
   (it did, measured), so only outliers go.
6. Downsample by farthest-point sampling (greedy max–min, from the densest point) to 600 points, which
   cover the cloud evenly (Gardner: a density-weighted greedy cover of 1 200 points); scale the cloud to
   unit root-mean-square radius, so lifetimes are in units of the cloud's size and the data and its
   shuffles are compared on one scale.
7. `ripser.ripser(cloud, maxdim=1, coeff=47, thresh=1.5)` for H0 and H1, and `maxdim=2` on the first 250
   points of the same cover (a greedy cover's prefix is the coarser cover) for H2: Vietoris–Rips
   persistence over Z/47 (Gardner's field) with Euclidean distances. H2 costs ~30× H1 at equal size; H1
   needs the denser cover (at 300 points the torus's small sampling loops reach the shuffles' longest bars,
   at 600 they stay under 0.6× it), H2 does not (its sampling voids stay under 0.6× the shuffles' at 200).
   The filtration stops at 1.5 radii, after the ideal torus's bars end (≤ 1.3) and the shuffles' (≤ 1):
   a bar still alive there (the ring's circle, which ends at √3) is cut to it, and H2 costs 4–6× more
   without the cut. Gardner used a UMAP-style fuzzy
   metric; plain distances on the 4-component cloud gave the cleaner barcodes here.
8. The null: the same pipeline (steps 2–7) on activity whose units are each circularly shifted in time by
   an independent uniform offset (Gardner's shuffle; it keeps every unit's own statistics and destroys their
   co-activity). Threshold per dimension = the longest shuffled bar over 5 shuffles (H0: the longest finite
   one); a bar counts towards the Betti number when it is longer. Gardner took the 99th percentile over
   1 000 shuffles; with 5 the maximum (about the 83rd percentile) is the affordable stand-in, so activity
   with no structure (noise) can show a bar just over the threshold now and then, never one far over it.
   The essential H0 class (the cloud is one component at the largest scale) always counts.

A population that moves as one sheet on a torus gives b = (1, 2, 1), its two circles and its void 2.5× the
threshold or more; a ring (1, 1, 0). Runtime: a 12 000 × 4 096 population takes about 25 s on one core
(the data and 5 shuffles: z-scoring and PCA ~60 %, ripser ~25 %, the shuffles' copies the rest) and
~2 GB of memory.

Limits (measured on ideal populations): bumps much narrower than the unit cell (σ below ~0.2 rad of phase,
as the place torus's ~0.13 rad) spread their variance over many Fourier shells with nearly equal weights;
four components then mix shells and a few hundred points cannot resolve the torus (extra H1 bars). The
trajectory must cover the module's torus evenly: a k = 1 module whose period is the arena's size, walked for
5 minutes, shows a third H1 bar from the unevenly visited phases; 20 minutes remove it. A spacing larger
than the arena leaves the torus partly unvisited, and no topology can be read from it.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.recording.session import Recording

__all__ = [
    "RING_BETTI",
    "TORUS_BETTI",
    "TopologyError",
    "TopologyParams",
    "TopologyResult",
    "activity_topology",
    "population_topology",
    "write_topology_figure",
]

TORUS_BETTI = (1, 2, 1)
RING_BETTI = (1, 1, 0)
_MIN_POINTS = 20
"""Fewer kept time points than this leave nothing to take the shape of."""


class TopologyError(HippoNavError):
    """The population has too few active, moving time points or changing units to analyse."""


@dataclass(frozen=True)
class TopologyParams:
    """The pipeline's numbers (module doc, steps 1–8)."""

    smoothing_sigma_s: float = 0.05
    min_speed_m_s: float | None = 0.025
    """`None`: keep every time point whatever the speed (sleep-like sessions, a stationary ring)."""
    active_fraction: float = 0.1
    max_time_points: int = 15_000
    n_components: int = 4
    outlier_neighbours: int = 20
    outlier_factor: float = 3.0
    n_points: int = 600
    """Points of the cloud for H0 and H1 (step 6)."""
    n_points_h2: int = 250
    """The first points of the same greedy cover, for H2 (step 7): H2 costs ~30× H1 at equal size."""
    max_scale: float = 1.5
    """Where the filtration stops, in radii of the cloud (step 7)."""
    n_shuffles: int = 5
    coeff: int = 47
    seed: int = 0
    """Seeds the shuffles' offsets and the randomized PCA."""


@dataclass(frozen=True)
class TopologyResult:
    """Betti numbers and the persistence behind them.

    `diagrams[d]` is `(n_bars, 2)` (birth, death) in radii of the cloud, death `inf` for a bar still alive
    at `params.max_scale`; `lifetimes[d]` the matching `min(death, max_scale) − birth`, longest first (the
    diagrams are sorted the same way). `thresholds[d]` is the longest shuffled bar of dimension d over the
    shuffles, `shuffled_longest` `(n_shuffles, 3)` each shuffle's longest."""

    population: str
    betti: tuple[int, int, int]
    diagrams: tuple[np.ndarray, np.ndarray, np.ndarray]
    lifetimes: tuple[np.ndarray, np.ndarray, np.ndarray]
    thresholds: tuple[float, float, float]
    shuffled_longest: np.ndarray
    n_time_points: int
    """Time points kept (step 2) before downsampling."""
    n_units: int
    """Units that changed over the kept time points (step 3)."""
    explained_variance_ratio: np.ndarray
    params: TopologyParams = field(default_factory=TopologyParams)
    elapsed_s: float = 0.0

    @property
    def is_torus(self) -> bool:
        return self.betti == TORUS_BETTI

    @property
    def is_ring(self) -> bool:
        return self.betti == RING_BETTI

    def summary(self) -> dict[str, Any]:
        """A JSON-able digest: Betti numbers, thresholds, the five longest bars per dimension, parameters."""
        return {
            "population": self.population,
            "betti": list(self.betti),
            "thresholds": list(self.thresholds),
            "longest_lifetimes": [[float(x) for x in lt[:5]] for lt in self.lifetimes],
            "n_time_points": self.n_time_points,
            "n_units": self.n_units,
            "explained_variance_ratio": [float(x) for x in self.explained_variance_ratio],
            "elapsed_s": self.elapsed_s,
            "params": asdict(self.params),
        }


def population_topology(
    rec: Recording, population: str, params: TopologyParams | None = None
) -> TopologyResult:
    """The persistent homology of one of `rec`'s populations (module doc), with the animal's speed."""
    if population not in rec.populations:
        raise TopologyError(
            f"no population {population!r} in the recording (it has {sorted(rec.populations)})"
        )
    return activity_topology(
        rec.populations[population],
        sample_dt_s=rec.sample_dt_s,
        speed_m_s=rec.speed_m_s,
        params=params,
        name=population,
    )


def activity_topology(
    activity: np.ndarray,
    *,
    sample_dt_s: float,
    speed_m_s: np.ndarray | None = None,
    params: TopologyParams | None = None,
    name: str = "",
) -> TopologyResult:
    """The persistent homology of `activity` `(T, n_units)` sampled every `sample_dt_s` seconds, with
    `speed_m_s` `(T,)` for the moving-time rule (module doc; `None` keeps every time point)."""
    p = params or TopologyParams()
    started = time.perf_counter()
    rates = _checked(activity, speed_m_s)
    smoothed = _smooth(rates, p.smoothing_sigma_s / sample_dt_s if sample_dt_s > 0 else 0.0)
    if speed_m_s is not None and p.min_speed_m_s is not None:
        smoothed = smoothed[np.asarray(speed_m_s) >= p.min_speed_m_s]
    cloud, n_time, n_units, explained = _cloud(smoothed, p, name)
    diagrams = _persistence(cloud, p)
    longest = _null(smoothed, p, name)
    top = longest.max(axis=0, initial=0.0)  # no shuffles: every bar counts
    thresholds = (float(top[0]), float(top[1]), float(top[2]))
    h0, h1, h2 = (_lifetimes(d, p.max_scale) for d in diagrams)
    # The essential H0 class (the whole cloud, alive at every scale) always counts.
    betti = (
        max(int(np.sum(h0 > thresholds[0])), 1),
        int(np.sum(h1 > thresholds[1])),
        int(np.sum(h2 > thresholds[2])),
    )
    return TopologyResult(
        population=name,
        betti=betti,
        diagrams=diagrams,
        lifetimes=(h0, h1, h2),
        thresholds=thresholds,
        shuffled_longest=longest,
        n_time_points=n_time,
        n_units=n_units,
        explained_variance_ratio=explained,
        params=p,
        elapsed_s=time.perf_counter() - started,
    )


def _null(moving: np.ndarray, p: TopologyParams, name: str) -> np.ndarray:
    """Step 8: each shuffle's longest bar per dimension, `(n_shuffles, 3)`."""
    rng = np.random.default_rng(p.seed)
    rows = [
        _longest(_persistence(_cloud(_shuffled(moving, rng), p, name)[0], p), p) for _ in range(p.n_shuffles)
    ]
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def _checked(activity: np.ndarray, speed_m_s: np.ndarray | None) -> np.ndarray:
    rates = np.asarray(activity, dtype=np.float32)
    if rates.ndim != 2:
        raise TopologyError(f"activity must be (T, n_units), got shape {rates.shape}")
    if not np.all(np.isfinite(rates)):
        raise TopologyError("activity has NaN or infinite values; record the session again")
    if speed_m_s is not None and np.shape(speed_m_s) != (rates.shape[0],):
        raise TopologyError(f"speed_m_s has shape {np.shape(speed_m_s)}, expected ({rates.shape[0]},)")
    return rates


def _smooth(rates: np.ndarray, sigma_samples: float) -> np.ndarray:
    """Step 1: Gaussian smoothing along time, edges padded with the nearest value (no decay to zero)."""
    if sigma_samples < 0.5:
        return rates
    from scipy.ndimage import gaussian_filter1d

    return np.asarray(gaussian_filter1d(rates, sigma_samples, axis=0, mode="nearest"), dtype=np.float32)


def _cloud(moving: np.ndarray, p: TopologyParams, name: str) -> tuple[np.ndarray, int, int, np.ndarray]:
    """Steps 2–6: the downsampled, scaled point cloud, the time points and units kept, PCA's variance."""
    from sklearn.decomposition import PCA

    total = moving.sum(axis=1)
    # Indices, even when no time point is moving (an animal that never moved): an empty float array
    # would not index `moving`.
    active = (
        np.flatnonzero(total > p.active_fraction * np.median(total)) if total.size else np.zeros(0, np.intp)
    )
    if active.size > p.max_time_points:
        active = np.sort(active[np.argsort(total[active])[-p.max_time_points :]])
    z = moving[active]  # the one copy of the big array; standardised in place
    std = z.std(axis=0) if z.size else np.zeros(moving.shape[1], np.float32)
    changing = std > 1e-6 * max(float(std.max(initial=0.0)), 1e-30)
    if active.size < _MIN_POINTS or int(changing.sum()) <= p.n_components:
        raise TopologyError(
            f"population {name or '(unnamed)'}: {active.size} active, moving time points and "
            f"{int(changing.sum())} changing units; need at least {_MIN_POINTS} and {p.n_components + 1} "
            "(a lesioned or silent population has no shape; record a longer session or lower min_speed_m_s)"
        )
    if not changing.all():
        z = z[:, changing]
    z -= z.mean(axis=0)
    z /= std[changing]
    pca = PCA(n_components=p.n_components, svd_solver="randomized", random_state=p.seed)
    projected = np.asarray(pca.fit_transform(z), dtype=np.float64)
    cloud = projected[_inliers(projected, p)]
    cloud = cloud[_farthest_points(cloud, p.n_points, p.outlier_neighbours)]
    cloud -= cloud.mean(axis=0)
    radius = float(np.sqrt(np.mean(np.sum(cloud**2, axis=1))))
    return cloud / max(radius, 1e-30), int(active.size), int(changing.sum()), pca.explained_variance_ratio_


def _inliers(points: np.ndarray, p: TopologyParams) -> np.ndarray:
    """Step 5: the points whose mean distance to their nearest neighbours is under `outlier_factor`× the
    median (mask)."""
    from scipy.spatial import cKDTree

    k = min(p.outlier_neighbours, len(points) - 1)
    distances, _ = cKDTree(points).query(points, k + 1)
    spread = distances[:, 1:].mean(axis=1)
    return np.asarray(spread <= p.outlier_factor * np.median(spread))


def _farthest_points(points: np.ndarray, n: int, neighbours: int) -> np.ndarray:
    """Step 6: greedy max–min sampling of `n` indices, from the densest point (so the choice is
    deterministic and starts inside the cloud, not on an outlier)."""
    from scipy.spatial import cKDTree

    if len(points) <= n:
        return np.arange(len(points))
    k = min(neighbours, len(points) - 1)
    distances, _ = cKDTree(points).query(points, k + 1)
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = int(np.argmin(distances[:, 1:].mean(axis=1)))
    nearest = np.linalg.norm(points - points[chosen[0]], axis=1)
    for i in range(1, n):
        chosen[i] = int(np.argmax(nearest))
        np.minimum(nearest, np.linalg.norm(points - points[chosen[i]], axis=1), out=nearest)
    return chosen


def _persistence(cloud: np.ndarray, p: TopologyParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 7: the H0, H1 diagrams of the cloud and the H2 diagram of its first `n_points_h2` points (a
    greedy cover's prefix is the coarser cover), each sorted longest bar first."""
    from ripser import ripser

    h0, h1 = ripser(cloud, maxdim=1, coeff=p.coeff, thresh=p.max_scale)["dgms"]
    h2 = ripser(cloud[: p.n_points_h2], maxdim=2, coeff=p.coeff, thresh=p.max_scale)["dgms"][2]
    out = []
    for d in (h0, h1, h2):
        d = np.asarray(d, dtype=np.float64).reshape(-1, 2)
        out.append(d[np.argsort(-_lifetimes(d, p.max_scale), kind="stable")])
    return out[0], out[1], out[2]


def _lifetimes(diagram: np.ndarray, max_scale: float) -> np.ndarray:
    """`min(death, max_scale) − birth`: a bar alive at the last scale is cut there."""
    return np.minimum(diagram[:, 1], max_scale) - diagram[:, 0]


def _longest(diagrams: tuple[np.ndarray, np.ndarray, np.ndarray], p: TopologyParams) -> list[float]:
    """Each dimension's longest bar; for H0 the longest but the essential class (the first infinite bar)."""
    out = []
    for dim, d in enumerate(diagrams):
        lifetimes = _lifetimes(d, p.max_scale)
        if dim == 0:
            essential = np.flatnonzero(np.isinf(d[:, 1]))
            lifetimes = np.delete(lifetimes, essential[:1])
        out.append(float(lifetimes.max(initial=0.0)))
    return out


def _shuffled(moving: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Step 8: every unit circularly shifted in time by its own uniform offset (Gardner's shuffle)."""
    n_time, n_units = moving.shape
    offsets = np.asarray(rng.integers(0, n_time, size=n_units))
    out = np.empty_like(moving)
    for unit in range(n_units):  # one unit at a time: a (T, n) index array would be 2× the activity
        out[:, unit] = np.roll(moving[:, unit], int(offsets[unit]))
    return out


def write_topology_figure(result: TopologyResult, path_stem: str | Path) -> list[Path]:
    """The barcode (longest 20 bars per dimension, the shuffle threshold shaded, as Gardner's Fig. 1) and
    the persistence diagram, as `<stem>.png` and `<stem>.pdf`; returns the paths."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from hippo_nav.io.atomic import atomic_path

    figure = Figure(figsize=(9.0, 5.0), layout="constrained")
    FigureCanvasAgg(figure)
    grid = figure.add_gridspec(3, 2, width_ratios=(1.4, 1.0))
    colours = _dimension_colours()
    _draw_barcode(figure, grid, result, colours)
    _draw_diagram(figure.add_subplot(grid[:, 1]), result, colours)
    title = result.population or "population"
    figure.suptitle(
        f"{title}: Betti numbers {result.betti} (bars longer than the shuffled maximum)", fontsize=10
    )
    stem = Path(path_stem)
    paths = []
    for suffix in (".png", ".pdf"):
        path = stem.with_name(stem.name + suffix)
        with atomic_path(path) as tmp:
            figure.savefig(tmp, dpi=150)
        paths.append(path)
    return paths


def _dimension_colours() -> list[tuple[float, float, float, float]]:
    from matplotlib import colormaps

    viridis = colormaps["viridis"]  # perceptually uniform; three well-separated samples
    return [tuple(viridis(x)) for x in (0.05, 0.45, 0.8)]


def _draw_barcode(figure: Any, grid: Any, result: TopologyResult, colours: list[Any]) -> None:
    max_scale = result.params.max_scale
    for dim in range(3):
        ax = figure.add_subplot(grid[dim, 0])
        diagram = result.diagrams[dim][:20]
        births = diagram[:, 0]
        deaths = np.minimum(diagram[:, 1], max_scale)
        rows = np.arange(len(diagram))
        ax.hlines(rows, births, deaths, color=colours[dim], linewidth=2.5)
        alive = np.isinf(diagram[:, 1])
        ax.plot(deaths[alive], rows[alive], ">", color=colours[dim], markersize=4)
        # Gardner's shading: a bar must outlast the shuffles' longest, measured from its own birth.
        ax.barh(
            rows, np.full(len(rows), result.thresholds[dim]), left=births, height=0.8, color="0.85", zorder=0
        )
        ax.set_xlim(0.0, max_scale * 1.02)
        ax.set_yticks([])
        ax.invert_yaxis()
        ax.set_ylabel(f"H{dim}  (b{dim} = {result.betti[dim]})", fontsize=9)
        if dim < 2:
            ax.tick_params(labelbottom=False)
    ax.set_xlabel("scale (radii of the cloud)")


def _draw_diagram(ax: Any, result: TopologyResult, colours: list[Any]) -> None:
    max_scale = result.params.max_scale
    top = max_scale * 1.05
    ax.plot([0, top], [0, top], color="0.5", linewidth=0.8)
    for dim in range(3):
        diagram = result.diagrams[dim]
        deaths = np.where(np.isinf(diagram[:, 1]), top, diagram[:, 1])
        ax.scatter(diagram[:, 0], deaths, s=12, color=colours[dim], label=f"H{dim}", alpha=0.85)
        ax.plot(
            [0, top],
            [result.thresholds[dim], top + result.thresholds[dim]],
            color=colours[dim],
            linewidth=0.8,
            linestyle="--",
        )
    ax.axhline(top, color="0.7", linewidth=0.6)
    ax.set_xlim(0, top)
    ax.set_ylim(0, top * 1.02)
    ax.set_xlabel("birth")
    ax.set_ylabel("death (top line: alive at the last scale)")
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8, title="dashed: threshold", title_fontsize=7)
