"""Figures of a recording's measures (`hippo_nav.recording.measures`), each written as PNG (300 dpi) and PDF
(vector), sized for a two-column journal page (7.1 in wide), 8 pt text, perceptually uniform colour maps:

- `measures_rate_maps`: example rate maps, one row per spatial population (grid modules coarsest first, then
  the place torus), the first measured units of each (viridis, one scale per row, unvisited bins grey).
- `measures_autocorrelograms`: their spatial autocorrelograms (magma, r from −1 to 1, lag in metres), the
  lattice's 4 nearest peaks marked.
- `measures_grid_scores`: per population, the units' 60° and 90° scores against the pooled shuffled scores,
  with the shuffle threshold (95th percentile) dashed.
- `measures_hd_tuning`: polar tuning curves of example head-direction units, their preferred direction
  (solid) and designed direction (dashed).

Every figure is drawn on its own `matplotlib.figure.Figure` with an Agg canvas (no pyplot, no global backend)
and written atomically (`hippo_nav.io.atomic`). matplotlib is imported inside the functions: importing this
module costs nothing until a figure is drawn.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hippo_nav.recording.measures import (
    SPATIAL_POPULATIONS,
    RateMaps,
    RecordingMeasures,
    autocorrelogram,
    hd_tuning,
    rate_maps,
    square_lattice,
)
from hippo_nav.recording.session import Recording

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["write_measure_figures"]

PAGE_WIDTH_IN = 7.1
"""A two-column journal figure (180 mm)."""
PNG_DPI = 300
_MAP_PANEL_IN = 1.6
"""A map panel's side with its title; three across plus labels and colour bar fit 1.5 journal columns."""
EXAMPLE_MAPS = 3
EXAMPLE_HD_UNITS = 4
RATE_CMAP = "viridis"
ACORR_CMAP = "magma"
SHUFFLE_GREY = "0.6"
UNIT_COLOUR = "#3b528b"
"""viridis at 0.25: the units' scores, against the shuffles' grey."""
_STYLE = {
    "font.size": 8,
    "axes.titlesize": 8,
    "axes.labelsize": 8,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "legend.fontsize": 7,
    "pdf.fonttype": 42,
}
"""8 pt text and TrueType fonts embedded in the PDF (editable text, as journals ask)."""


def write_measure_figures(rec: Recording, measures: RecordingMeasures, out_dir: str | Path) -> list[Path]:
    """Write the figures (module doc) of `measures`, measured on `rec`, into `out_dir` (created when
    missing); returns the files written, PNG and PDF of each."""
    import matplotlib

    from hippo_nav.io.atomic import output_folder

    out = output_folder(out_dir, "the measures' figures")
    written: list[Path] = []
    with matplotlib.rc_context(_STYLE):
        spatial = [name for name in SPATIAL_POPULATIONS if name in measures.spatial]
        if spatial:
            settings = measures.settings
            maps = {
                name: rate_maps(
                    rec,
                    name,
                    [u.unit for u in measures.spatial[name].units[:EXAMPLE_MAPS]],
                    bin_size_m=settings.bin_size_m,
                    sigma_bins=settings.sigma_bins,
                )
                for name in spatial
            }
            written += _save_both(rate_map_figure(maps, measures), out / "measures_rate_maps")
            written += _save_both(autocorrelogram_figure(maps, measures), out / "measures_autocorrelograms")
            written += _save_both(grid_score_figure(measures), out / "measures_grid_scores")
        if measures.head_direction is not None and measures.head_direction.units:
            written += _save_both(hd_tuning_figure(rec, measures), out / "measures_hd_tuning")
    return written


def _new_figure(width_in: float, height_in: float) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(figure)  # our own canvas: no pyplot, no global backend
    return figure


def _save_both(figure: Figure, stem: Path) -> list[Path]:
    from hippo_nav.io.atomic import atomic_path

    paths = []
    for suffix, options in ((".png", {"dpi": PNG_DPI}), (".pdf", {"metadata": {"CreationDate": None}})):
        path = stem.with_suffix(suffix)
        with atomic_path(path) as tmp:
            figure.savefig(tmp, **options)
        paths.append(path)
        # The layout of the first file holds for the second: solving it again costs as much as drawing.
        figure.set_layout_engine("none")
    return paths


def _map_axes(ax: Axes, first_column: bool, last_row: bool) -> None:
    """Tick labels on the outer panels only, three ticks an axis: a grid of maps reads like one figure."""
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(3))
    ax.yaxis.set_major_locator(MaxNLocator(3))
    ax.tick_params(labelbottom=last_row, labelleft=first_column)


def _population_label(measures: RecordingMeasures, name: str) -> str:
    """A row's name, above its y-axis label: the population and its design spacing, on two lines."""
    design = "P" if name == "place" else "P/k"
    title = "place" if name == "place" else f"{name.removeprefix('grid_')} module"
    return f"{title}\n{design} = {measures.spatial[name].design_spacing_m:.2f} m"


def rate_map_figure(maps: dict[str, RateMaps], measures: RecordingMeasures) -> Figure:
    """Example rate maps: one row per population, one scale per row."""
    from matplotlib import colormaps

    cmap = colormaps[RATE_CMAP].with_extremes(bad="0.88")
    figure = _new_figure(_MAP_PANEL_IN * EXAMPLE_MAPS + 1.3, _MAP_PANEL_IN * len(maps) + 0.3)
    axes = np.atleast_2d(figure.subplots(len(maps), EXAMPLE_MAPS, squeeze=False))
    for row, (name, rm) in enumerate(maps.items()):
        finite = rm.maps[np.isfinite(rm.maps)]
        vmax = float(finite.max()) if finite.size else 1.0
        image = None
        units = {u.unit: u for u in measures.spatial[name].units}
        for column, ax in enumerate(axes[row]):
            if column >= len(rm.units):
                ax.set_axis_off()
                continue
            image = ax.imshow(
                rm.maps[column],
                origin="lower",
                extent=rm.binning.extent_m,
                cmap=cmap,
                vmin=0.0,
                vmax=vmax,
                interpolation="nearest",
            )
            measured = units[int(rm.units[column])]
            ax.set_title(f"unit {measured.unit}: 90° score {measured.grid_score_90:.2f}")
            ax.set_xlabel("x (m)" if row == len(maps) - 1 else "")
            ax.set_ylabel(f"{_population_label(measures, name)}\ny (m)" if column == 0 else "")
            _map_axes(ax, column == 0, row == len(maps) - 1)
        if image is not None:
            figure.colorbar(image, ax=list(axes[row]), label="activity (a.u.)", shrink=0.9)
    return figure


def autocorrelogram_figure(maps: dict[str, RateMaps], measures: RecordingMeasures) -> Figure:
    """The example maps' autocorrelograms, with the square lattice's 4 nearest peaks marked."""
    from matplotlib import colormaps

    cmap = colormaps[ACORR_CMAP].with_extremes(bad="0.88")
    figure = _new_figure(_MAP_PANEL_IN * EXAMPLE_MAPS + 1.3, _MAP_PANEL_IN * len(maps) + 0.3)
    axes = np.atleast_2d(figure.subplots(len(maps), EXAMPLE_MAPS, squeeze=False))
    bin_m = measures.settings.bin_size_m
    for row, (name, rm) in enumerate(maps.items()):
        image = None
        for column, ax in enumerate(axes[row]):
            if column >= len(rm.units):
                ax.set_axis_off()
                continue
            acorr = autocorrelogram(rm.maps[column])
            h, w = acorr.shape
            cy, cx = (h + 1) // 2 - 1, (w + 1) // 2 - 1
            extent = (
                -(cx + 0.5) * bin_m,
                (w - cx - 0.5) * bin_m,
                -(cy + 0.5) * bin_m,
                (h - cy - 0.5) * bin_m,
            )
            image = ax.imshow(
                acorr, origin="lower", extent=extent, cmap=cmap, vmin=-1.0, vmax=1.0, interpolation="nearest"
            )
            lattice = square_lattice(acorr, bin_m)
            if len(lattice.peaks_m):
                ax.plot(lattice.peaks_m[:, 0], lattice.peaks_m[:, 1], "+", color="white", ms=5, mew=0.8)
            ax.set_title(f"unit {int(rm.units[column])}: spacing {lattice.spacing_m:.2f} m")
            ax.set_xlabel("x lag (m)" if row == len(maps) - 1 else "")
            ax.set_ylabel(f"{_population_label(measures, name)}\ny lag (m)" if column == 0 else "")
            _map_axes(ax, column == 0, row == len(maps) - 1)
        if image is not None:
            figure.colorbar(image, ax=list(axes[row]), label="correlation r", shrink=0.9)
    return figure


def grid_score_figure(measures: RecordingMeasures) -> Figure:
    """Each population's 60° and 90° scores against its pooled shuffles and their threshold."""
    names = [name for name in SPATIAL_POPULATIONS if name in measures.spatial]
    figure = _new_figure(PAGE_WIDTH_IN * 0.75, 1.35 * len(names) + 0.4)
    axes = np.atleast_2d(figure.subplots(len(names), 2, squeeze=False))
    for row, name in enumerate(names):
        population = measures.spatial[name]
        for column, angle in enumerate(("60", "90")):
            ax = axes[row, column]
            threshold = float(getattr(population, f"threshold_{angle}"))
            shuffled = np.asarray(getattr(population, f"shuffled_{angle}"), dtype=np.float64)
            observed = np.asarray(
                [getattr(u, f"grid_score_{angle}") for u in population.units], dtype=np.float64
            )
            _score_panel(ax, shuffled, observed, threshold)
            passing = float(getattr(population, f"fraction_passing_{angle}"))
            # The fraction of units whose score is above the population's shuffle threshold (and zero).
            bar = max(threshold, 0.0) if np.isfinite(threshold) else threshold
            ax.set_title(f"{name.replace('_', ' ')}, {angle}°: {passing:.0%} above {bar:.2f}")
            ax.set_xlabel(f"{angle}° grid score" if row == len(names) - 1 else "")
            ax.set_ylabel("density" if column == 0 else "")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=3, frameon=False)
    return figure


def _score_panel(ax: Axes, shuffled: np.ndarray, observed: np.ndarray, threshold: float) -> None:
    shuffled, observed = shuffled[np.isfinite(shuffled)], observed[np.isfinite(observed)]
    values = np.concatenate([shuffled, observed])
    low = min(-0.5, float(values.min())) if values.size else -0.5
    high = max(1.5, float(values.max())) if values.size else 1.5
    bins = np.linspace(low, high, 41)
    # A density of no values divides by zero (numpy warns on a short session whose maps have no score).
    if shuffled.size:
        ax.hist(shuffled, bins=bins, density=True, color=SHUFFLE_GREY, label="shuffled")
    if observed.size:
        ax.hist(observed, bins=bins, density=True, color=UNIT_COLOUR, alpha=0.85, label="units")
    if np.isfinite(threshold):
        ax.axvline(threshold, color="black", ls="--", lw=0.9, label="threshold: 95th percentile of shuffles")


def hd_tuning_figure(rec: Recording, measures: RecordingMeasures) -> Figure:
    """Polar tuning curves of example HD units: preferred (solid) and designed (dashed) directions."""
    hd = measures.head_direction
    if hd is None:
        raise ValueError("these measures have no head-direction population")
    examples = hd.units[:EXAMPLE_HD_UNITS]
    settings = measures.settings
    curves = hd_tuning(
        rec, [u.unit for u in examples], bin_deg=settings.hd_bin_deg, sigma_bins=settings.hd_sigma_bins
    )
    columns = min(len(examples), 2)
    rows = (len(examples) + columns - 1) // columns
    figure = _new_figure(4.2, 2.0 * rows + 0.5)
    axes = np.atleast_1d(
        figure.subplots(rows, columns, squeeze=False, subplot_kw={"projection": "polar"})
    ).ravel()
    theta = np.append(curves.bin_centres_rad, curves.bin_centres_rad[0] + 2 * np.pi)
    for ax, unit, curve in zip(axes, examples, curves.curves):
        values = np.append(curve, curve[0])
        top = float(np.nanmax(values)) if np.isfinite(values).any() else 1.0
        ax.plot(theta, values, color=UNIT_COLOUR, lw=1.0)
        ax.plot(
            [np.radians(unit.preferred_direction_deg)] * 2, [0, top], color="black", lw=1.0, label="preferred"
        )
        ax.plot(
            [np.radians(unit.design_direction_deg)] * 2,
            [0, top],
            color="black",
            lw=1.0,
            ls="--",
            label="design",
        )
        ax.set_title(
            f"unit {unit.unit}: R = {unit.mean_vector_length:.2f}, error {unit.direction_error_deg:+.1f}°"
        )
        ax.set_yticklabels([])
    for ax in axes[len(examples) :]:
        ax.set_axis_off()
    handles, labels = axes[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside upper center", ncols=2, frameon=False)
    figure.supxlabel("heading (° counter-clockwise from +x); radius: activity (a.u.)", fontsize=8)
    return figure
