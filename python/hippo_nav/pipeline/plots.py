"""Figures of a run: the cognitive map, the neural state panels, the firing-rate maps.

Every figure is drawn on its own `matplotlib.figure.Figure` with an Agg canvas, so writing figures never
switches the global matplotlib backend nor touches pyplot's figure list (a notebook keeps its inline
backend). The `*_figure` functions return the `Figure` (for a notebook or a test); `plot_*` write a PNG.

Positions are in the map frame (x forward along the initial heading, y left, metres; `hippo_nav.geometry`),
all sharing the first processed frame as origin; no trajectory is aligned to another.

- `cognitive_map.png` (the paper's cognitive-map figures): left, the corrected experience map — vertices,
  odometric links thin grey, loop links red — over the ground truth; right, the estimates against the
  ground truth: the corrected map at every frame, the odometry alone and the networks' own estimate
  (unwrapped place code), labelled with their ATE (SE(3)-aligned, ground plane) when the run has one.
  Vertex markers shrink with the vertices' spacing on the page, so a 4 000-vertex map stays a readable
  chain of dots rather than a smear.
- `neural_state_NNNNNN.png` (one per snapshot frame), like the paper's neural-representation figure: the
  HD-by-velocity ring (θ × ν), each grid module's conjunctive activity as a ν-grid of θ-planes (each small
  square is one velocity unit's (θx, θy) plane), the three layer-II ("pure grid cell") patterns, and the
  CA3 place bump.
- `rate_maps.png` (the paper's firing-rate maps), one column per network (grid k = 1, 2, 4, place):
  top row, one unit's mean activity in each spatial bin the agent visited over the whole road network,
  drawn as activity-coloured squares along the path (field bins larger and on top) so thin roads and
  few-metre fields stay visible at any scale; positions from the ground truth when there is one (as in a
  rat experiment), else from the corrected trajectory. Bottom row, the same unit's activity folded onto
  one torus period: positions modulo P, averaged in bins over the P × P square. A unit of grid module k
  fires wherever one of its k × k bumps passes, i.e. every P/k metres along both axes, so the folded map
  shows k² fields (1, 4, 16) and a place unit one. The folded positions are by default the networks' own
  estimate (the unwrapped place code), whose phase is the torus phase by construction; folding the
  ground-truth track instead (`fold_positions="track"`) blurs the fields by the networks' drift from the
  ground truth, which over a kilometre reaches the dorsal module's P/4 field spacing.
  The unit shown per network is, among the recorded regular sub-grid of its units, the one whose rate
  map varies most over the visited bins (it fires in some places and is silent in others).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.colors import Colormap
from matplotlib.figure import Figure

from hippo_nav.engine.config import MODULE_NAMES, N_MODULES, EngineConfig
from hippo_nav.geometry import planar_xy
from hippo_nav.io.atomic import atomic_path
from hippo_nav.recording.session import GRID_POPULATIONS

DEFAULT_TORUS_PERIOD_M = 100.0
# The paper colour-codes rates "by the jet colormap from blue (zero) to red (high)"; kept for comparison.
RATE_CMAP = "jet"
UNVISITED_GREY = "0.88"


def _new_figure(width_in: float, height_in: float) -> Figure:
    figure = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(figure)  # our own canvas: no pyplot, no global backend
    return figure


def _save(figure: Figure, path: Path, dpi: int) -> Path:
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=dpi)
    return path


def _axis_span_m(xy: np.ndarray) -> float:
    finite = xy[np.isfinite(xy).all(axis=1)]
    return float(np.ptp(finite, axis=0).max()) if len(finite) else 0.0


# ------------------------------------------------------------------------------------------------
# Cognitive map


def vertex_marker_diameter_pt(path_length_m: float, n_vertices: int, points_per_m: float) -> float:
    """Marker diameter (points) for `n_vertices` spread along `path_length_m` drawn at `points_per_m`.

    0.6 of the mean spacing of consecutive vertices on the page, so neighbours stay apart, clipped to
    [1, 5] pt so a short map is not drawn with blobs and a long one does not vanish."""
    spacing_pt = path_length_m / max(n_vertices, 1) * points_per_m
    return float(np.clip(0.6 * spacing_pt, 1.0, 5.0))


def _link_segments(poses: np.ndarray, links: np.ndarray) -> np.ndarray:
    """(links, 2, 2) end points of every link, for a LineCollection (one artist for thousands of links)."""
    return np.stack([poses[links[:, 0], :2], poses[links[:, 1], :2]], axis=1).reshape(-1, 2, 2)


def _ate_label(result: Any, name: str, label: str) -> str:
    errors = (result.metrics or {}).get("errors", {})
    entry = errors.get(name) if isinstance(errors, dict) else None
    ate = entry.get("ate_2d_m") if isinstance(entry, dict) else None
    return f"{label} (ATE {ate:.1f} m)" if isinstance(ate, (int, float)) and np.isfinite(ate) else label


def cognitive_map_figure(result: Any, estimates: bool = True) -> Figure:
    """The corrected experience map over the ground truth; with `estimates`, a second panel comparing the
    map's per-frame estimate, the odometry alone and the networks' estimate with the ground truth."""
    export = result.map_export
    poses = np.asarray(export["poses"], dtype=np.float64).reshape(-1, 3)
    links = np.asarray(export["links"], dtype=np.int64).reshape(-1, 2)
    is_loop = np.asarray(export["link_is_loop"], dtype=bool).reshape(-1)
    gt = planar_xy(result.ground_truth) if result.ground_truth is not None else None
    panel_in = 6.5
    figure = _new_figure(panel_in * (2 if estimates else 1) + 0.3, panel_in + 0.4)
    axes = figure.subplots(1, 2 if estimates else 1, squeeze=False)[0]

    ax = axes[0]
    if gt is not None:
        ax.plot(
            gt[:, 0], gt[:, 1], color="0.45", lw=3.0, alpha=0.35, solid_capstyle="round", label="ground truth"
        )
    segments = _link_segments(poses, links)
    odometric, loop = segments[~is_loop], segments[is_loop]
    odometric_label = f"odometric links ({len(odometric)})"
    ax.add_collection(
        LineCollection(odometric, colors="0.5", linewidths=0.5, zorder=2, label=odometric_label)
    )
    # Vertex size from the vertices' spacing on the page: the panel spans the map's extent.
    span_m = max(_axis_span_m(poses[:, :2]), _axis_span_m(gt) if gt is not None else 0.0, 1.0)
    points_per_m = 0.85 * panel_in * 72.0 / span_m
    path_m = (
        float(np.linalg.norm(odometric[:, 1] - odometric[:, 0], axis=1).sum()) if len(odometric) else span_m
    )
    diameter_pt = vertex_marker_diameter_pt(path_m, len(poses), points_per_m)
    ax.scatter(poses[:, 0], poses[:, 1], s=diameter_pt**2, color="tab:green", linewidths=0, zorder=3)
    # The legend's vertex marker at a legible size, whatever size the map needed.
    ax.plot([], [], "o", color="tab:green", ms=4, label=f"vertices ({len(poses)})")
    if len(loop):
        loop_label = f"loop links ({len(loop)})"
        ax.add_collection(LineCollection(loop, colors="red", linewidths=1.2, zorder=4, label=loop_label))
    ax.plot(poses[:1, 0], poses[:1, 1], "k^", ms=7, zorder=5, label="start")
    ax.autoscale_view()
    ax.set_title(
        f"{result.name}: cognitive map — {len(poses)} vertices, {len(links)} links ({len(loop)} loop)",
        fontsize=10,
    )

    if estimates:
        ax = axes[1]
        if gt is not None:
            ax.plot(gt[:, 0], gt[:, 1], color="black", lw=1.8, alpha=0.6, label="ground truth")
        traces = {
            "vo": ("odometry alone", {"color": "tab:orange", "lw": 1.0, "ls": "--"}),
            "neural": ("networks (place code)", {"color": "tab:purple", "lw": 0.7, "ls": ":"}),
            "corrected": ("cognitive map (per frame)", {"color": "tab:blue", "lw": 1.1}),
        }
        for name, (label, style) in traces.items():
            xy = planar_xy(result.estimates[name])
            ax.plot(xy[:, 0], xy[:, 1], label=_ate_label(result, name, label), **style)
        ax.plot([0.0], [0.0], "k^", ms=7, label="start")
        compared = "ground truth vs odometry" if gt is not None else "odometry (no ground truth)"
        ax.set_title(f"{result.name}: map estimate vs {compared}, {len(result.record)} frames", fontsize=10)

    for ax in axes:
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m, initial heading)")
        ax.set_ylabel("y (m, left)")
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(loc="best", fontsize=8, framealpha=0.85)
    return figure


def plot_cognitive_map(result: Any, path: Path, estimates: bool = True) -> Path:
    return _save(cognitive_map_figure(result, estimates), path, dpi=120)


# ------------------------------------------------------------------------------------------------
# Neural state


def tile_conjunctive(activity: np.ndarray) -> np.ndarray:
    """(M, M, N, N) = (νy, νx, θy, θx) → an (M·N, M·N) image: row block νy, column block νx."""
    m_y, m_x, n_y, n_x = activity.shape
    return activity.transpose(0, 2, 1, 3).reshape(m_y * n_y, m_x * n_x)


def _lesioned(ax: Axes, what: str) -> None:
    ax.text(0.5, 0.5, f"{what}\nlesioned", ha="center", va="center", transform=ax.transAxes)
    ax.set_xticks([])
    ax.set_yticks([])


def neural_state_figure(snapshot: dict[str, Any], title: str) -> Figure:
    figure = _new_figure(16, 8)
    axes = figure.subplots(2, N_MODULES + 1)
    hd = snapshot["hd"]
    nu = snapshot["hd_nu_max"]
    ax = axes[0, 0]
    ax.imshow(hd, origin="lower", aspect="auto", cmap="viridis", extent=(0, 360, -nu, nu))
    ax.set_title("HD-by-velocity ring")
    ax.set_xlabel("θ (deg)")
    ax.set_ylabel("ν (angular velocity axis)")
    for m in range(N_MODULES):
        ax = axes[0, m + 1]
        act = snapshot["grid"][m]
        k = snapshot["k"][m]
        ax.set_title(f"grid k={k}: conjunctive (νy, νx blocks of θ planes)", fontsize=9)
        if act is None:
            _lesioned(ax, f"grid k={k}")
            continue
        ax.imshow(tile_conjunctive(act), origin="lower", cmap="viridis", interpolation="nearest")
        n = act.shape[2]
        for b in range(1, act.shape[0]):
            ax.axhline(b * n - 0.5, color="white", lw=0.4)
            ax.axvline(b * n - 0.5, color="white", lw=0.4)
        ax.set_xticks([])
        ax.set_yticks([])
    for m in range(N_MODULES):
        ax = axes[1, m]
        pattern = snapshot["layer2"][m]
        k = snapshot["k"][m]
        ax.set_title(f"grid k={k}: layer II")
        if pattern is None:
            _lesioned(ax, f"grid k={k}")
            continue
        ax.imshow(pattern, origin="lower", cmap="viridis", extent=(0, 2 * np.pi, 0, 2 * np.pi))
        ax.set_xlabel("θx (rad)")
        ax.set_ylabel("θy (rad)")
    ax = axes[1, N_MODULES]
    ax.imshow(snapshot["place"], origin="lower", cmap="viridis", extent=(0, 2 * np.pi, 0, 2 * np.pi))
    ax.set_title("CA3 place torus")
    ax.set_xlabel("θx (rad)")
    ax.set_ylabel("θy (rad)")
    figure.suptitle(title)
    return figure


def plot_neural_state(snapshot: dict[str, Any], path: Path, title: str) -> Path:
    return _save(neural_state_figure(snapshot, title), path, dpi=80)


# ------------------------------------------------------------------------------------------------
# Firing-rate maps


def path_rate_map(
    positions_m: np.ndarray, activity: np.ndarray, bin_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Mean activity in every square spatial bin of side `bin_m` that the path visited.

    `positions_m` (n, 2), `activity` (n,) or (n, units). Returns the visited bins' centres (B, 2) in metres
    and their mean activity (B,) or (B, units); bins never visited are absent, so a thin road network costs
    only its own bins. Frames with a non-finite position or activity are left out."""
    positions_m = np.asarray(positions_m, dtype=np.float64)
    values = np.asarray(activity, dtype=np.float64)
    column = values.ndim == 1
    values = values.reshape(len(values), -1)
    keep = np.isfinite(positions_m).all(axis=1) & np.isfinite(values).all(axis=1)
    positions_m, values = positions_m[keep], values[keep]
    if not len(positions_m):
        return np.zeros((0, 2)), np.zeros((0,) if column else (0, values.shape[1]))
    cells = np.floor(positions_m / bin_m).astype(np.int64)
    occupied, which = np.unique(cells, axis=0, return_inverse=True)
    which = which.reshape(-1)
    sums = np.zeros((len(occupied), values.shape[1]))
    np.add.at(sums, which, values)
    means = sums / np.bincount(which, minlength=len(occupied))[:, None]
    centres = (occupied + 0.5) * bin_m
    return centres, (means[:, 0] if column else means)


def folded_rate_map(
    positions_m: np.ndarray, activity: np.ndarray, period_m: float, bins_per_period: int = 40
) -> np.ndarray:
    """Mean activity over positions folded onto one torus period: (bins, bins) image, row = y, column = x,
    both from 0 to `period_m`; NaN where no folded position fell."""
    positions_m = np.asarray(positions_m, dtype=np.float64)
    values = np.asarray(activity, dtype=np.float64).reshape(-1)
    keep = np.isfinite(positions_m).all(axis=1) & np.isfinite(values)
    folded = np.remainder(positions_m[keep], period_m)
    cells = np.minimum((folded / period_m * bins_per_period).astype(np.int64), bins_per_period - 1)
    flat = cells[:, 1] * bins_per_period + cells[:, 0]
    size = bins_per_period * bins_per_period
    visits = np.bincount(flat, minlength=size)
    sums = np.bincount(flat, weights=values[keep], minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        rates = np.where(visits > 0, sums / visits, np.nan)
    return rates.reshape(bins_per_period, bins_per_period)


def most_selective_unit(bin_rates: np.ndarray) -> int:
    """The unit (column of (bins, units) mean rates) whose rate map varies most over the visited bins:
    one that fires in some places and is silent in others. A constantly active or silent unit scores 0;
    ties go to the lowest index."""
    if bin_rates.size == 0:
        return 0
    return int(np.argmax(np.nanstd(bin_rates, axis=0)))


def _networks(record: Any) -> list[tuple[str, int | None, str]]:
    """(name in unit_activity, k or None for place, title) of every network, lesioned modules included."""
    snapshot = next(iter(record.snapshots.values()), None) if record.snapshots else None
    if snapshot is not None and "k" in snapshot:
        ks = [int(k) for k in snapshot["k"]]
    else:
        ks = [grid.k for grid in EngineConfig().grid]
    networks = [
        (GRID_POPULATIONS[m], k, f"grid k={k} ({MODULE_NAMES[m]})") for m, k in enumerate(ks[:N_MODULES])
    ]
    return networks + [("place", None, "CA3 place")]


def _fields_note(k: int | None) -> str:
    fields = 1 if k is None else k * k
    return f"{fields} field{'s' * (fields != 1)} per period expected"


def rate_maps_figure(
    result: Any,
    bin_m: float = 4.0,
    torus_period_m: float = DEFAULT_TORUS_PERIOD_M,
    fold_positions: Literal["neural", "track"] = "neural",
    fold_bins: int = 40,
) -> Figure:
    """Firing-rate maps of one unit per network over the road network (top) and folded onto one torus
    period (bottom); module doc. `bin_m` is the smallest spatial bin; it grows with the trajectory's extent
    so that a long run keeps about 300 bins across."""
    record = result.record
    n = len(record)
    source = "ground truth" if result.ground_truth is not None else "corrected trajectory"
    track = result.ground_truth if result.ground_truth is not None else result.corrected_world_from_camera
    positions = planar_xy(track)[:n]
    if fold_positions == "neural":
        folded_positions, fold_source = planar_xy(result.neural_world_from_camera)[:n], "networks' estimate"
    elif fold_positions == "track":
        folded_positions, fold_source = positions, source
    else:
        raise ValueError(f"fold_positions must be 'neural' or 'track', not {fold_positions!r}")
    span_m = max(_axis_span_m(positions), 1.0)
    bin_m = max(float(bin_m), span_m / 300.0)
    networks = _networks(record)
    columns = len(networks)
    panel_in = 4.2
    figure = _new_figure(panel_in * columns, 2 * panel_in + 0.6)
    axes = figure.subplots(2, columns, squeeze=False)
    # Page scale of the top-row panels (equal aspect, the whole extent in about 80 % of a panel): a bin is
    # drawn as a square of its own size, at least 2.5 pt so a single pass along a road stays visible.
    points_per_m = 0.8 * panel_in * 72.0 / (span_m + 2 * bin_m)
    square_pt = max(bin_m * points_per_m, 2.5)
    for column, (name, k, title) in enumerate(networks):
        top, bottom = axes[0, column], axes[1, column]
        rows = record.unit_activity.get(name)
        if not rows:
            for ax in (top, bottom):
                ax.set_title(title, fontsize=9)
                _lesioned(ax, title)
            continue
        activity = np.stack(rows)[:n].astype(np.float64)  # (frames, units)
        # The unit is chosen on the road-network map; the folded map shows the same unit.
        unit = _draw_path_rate_map(figure, top, title, positions[: len(activity)], activity, bin_m, square_pt)
        _draw_folded_rate_map(
            figure, bottom, title, k, unit, folded_positions[: len(activity)], activity[:, unit],
            torus_period_m, fold_bins,
        )  # fmt: skip
    figure.suptitle(
        f"{result.name}: firing-rate maps over {n} frames\ntop: positions from the {source}, {bin_m:.3g} m bins; "
        f"bottom: the {fold_source} folded onto the P = {torus_period_m:g} m torus period, "
        f"{torus_period_m / fold_bins:.3g} m bins (grey: never visited)"
    )
    return figure


def _draw_path_rate_map(
    figure: Figure,
    ax: Axes,
    title: str,
    positions_m: np.ndarray,
    activity: np.ndarray,
    bin_m: float,
    square_pt: float,
) -> int:
    """Draw the rate map over the visited `bin_m` bins (map frame, m) of the network's most selective unit
    (`activity`: frames × units) as squares of at least `square_pt`, with its colour bar; returns the unit."""
    centres, bin_rates = path_rate_map(positions_m, activity, bin_m)
    unit = most_selective_unit(bin_rates)
    rates = bin_rates[:, unit] if len(bin_rates) else np.zeros(0)
    peak = float(np.nanmax(rates)) if len(rates) else 0.0
    order = np.argsort(rates, kind="stable")  # fields on top where passes overlap
    scale = peak if peak > 0 else 1.0
    # Field bins drawn up to twice as large: a few-metre field on a kilometre map stays visible.
    side_pt = square_pt * (1.0 + rates[order] / scale)
    dots = ax.scatter(
        *centres[order].T, c=rates[order], s=side_pt**2, marker="s", cmap=RATE_CMAP, vmin=0.0, vmax=scale,
        linewidths=0,
    )  # fmt: skip
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{title}: unit {unit} of {activity.shape[1]} sampled", fontsize=9)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    figure.colorbar(dots, ax=ax, shrink=0.8, label="mean activity (a.u.)")
    return unit


def _draw_folded_rate_map(
    figure: Figure,
    ax: Axes,
    title: str,
    k: int | None,
    unit: int,
    positions_m: np.ndarray,
    unit_activity: np.ndarray,
    torus_period_m: float,
    fold_bins: int,
) -> None:
    """Draw one unit's activity with the positions (map frame, m) folded modulo `torus_period_m` into
    `fold_bins` × `fold_bins` bins (grey where never visited), with its colour bar."""
    folded = folded_rate_map(positions_m, unit_activity, torus_period_m, fold_bins)
    image = ax.imshow(
        np.ma.masked_invalid(folded), origin="lower", extent=(0, torus_period_m, 0, torus_period_m),
        cmap=_cmap_with_unvisited(), vmin=0.0, interpolation="nearest",
    )  # fmt: skip
    if k is not None and k > 1:
        # Ticks every P/k: one period of the module's fields per tick interval.
        ticks = np.linspace(0.0, torus_period_m, k + 1)
        ax.set_xticks(ticks)
        ax.set_yticks(ticks)
    ax.set_title(f"{title}: unit {unit} folded mod P\n{_fields_note(k)}", fontsize=9)
    ax.set_xlabel(f"x mod {torus_period_m:g} m")
    ax.set_ylabel(f"y mod {torus_period_m:g} m")
    figure.colorbar(image, ax=ax, shrink=0.8, label="mean activity (a.u.)")


def _cmap_with_unvisited() -> Colormap:
    return colormaps[RATE_CMAP].with_extremes(bad=UNVISITED_GREY)


def plot_rate_maps(
    result: Any,
    path: Path,
    bin_m: float = 4.0,
    torus_period_m: float = DEFAULT_TORUS_PERIOD_M,
    fold_positions: Literal["neural", "track"] = "neural",
) -> Path:
    return _save(rate_maps_figure(result, bin_m, torus_period_m, fold_positions), path, dpi=100)


def write_run_figures(
    result: Any,
    out: Path,
    rate_map_bin_m: float = 4.0,
    torus_period_m: float = DEFAULT_TORUS_PERIOD_M,
    written: list[Path] | None = None,
) -> list[Path]:
    """Every figure of a run into `out`; returns their paths. `torus_period_m`: the engine's
    `torus_period_m` (the folded rate maps fold positions modulo it). `written`, when given, gets each
    path as soon as its file is written (so an interrupted call still tells which are there)."""
    out = Path(out)
    paths = written if written is not None else []
    paths.append(plot_cognitive_map(result, out / "cognitive_map.png"))
    for position, snapshot in sorted(result.record.snapshots.items()):
        frame = snapshot["frame_index"]
        paths.append(
            plot_neural_state(
                snapshot,
                out / f"neural_state_{frame:06d}.png",
                f"{result.name}: neural state at frame {frame} (run position {position})",
            )
        )
    if len(result.record) >= 2:
        paths.append(plot_rate_maps(result, out / "rate_maps.png", rate_map_bin_m, torus_period_m))
    return paths
