"""Run figures (`hippo_nav.pipeline.plots`): rate maps that show the modules' fields, a cognitive map that
stays readable at full length, lesioned modules, no global matplotlib state; and the CLI's bump table.

The runs here are built directly (no pipeline): positions along a street grid and unit activities that
are exact functions of position, so what a figure must show is known in advance."""

from __future__ import annotations

import cv2
import matplotlib
import numpy as np
import pytest
from hippo_nav.cli import main
from hippo_nav.geometry import pose_from_planar
from hippo_nav.pipeline.plots import (
    cognitive_map_figure,
    folded_rate_map,
    most_selective_unit,
    neural_state_figure,
    path_rate_map,
    rate_maps_figure,
    vertex_marker_diameter_pt,
    write_run_figures,
)
from hippo_nav.pipeline.records import RunRecord, RunResult
from hippo_nav.recording import GRID_POPULATIONS
from hippo_nav.system.records import FrameRecord

PERIOD_M = 100.0
KS = (1, 2, 4)
SAMPLED_SIDE = 8  # the pipeline records an 8 × 8 sub-grid of every torus (of a module's unit cell)
FOLD_BINS = 40  # 2.5 m bins over the 100 m period


def _field_activity(positions_m: np.ndarray, period_m: float, phase_m: np.ndarray) -> np.ndarray:
    """A grid unit's firing: von Mises bumps every `period_m` along both axes, centred at `phase_m`."""
    angle = 2 * np.pi * (positions_m - phase_m) / period_m
    return np.exp(4.0 * (np.cos(angle) - 1.0)).prod(axis=-1)


def _unit_activities(positions_m: np.ndarray, k: int | None) -> np.ndarray:
    """(n, 64) activity of the sampled units of grid module k (None: the place torus, one bump per P)."""
    field_period_m = PERIOD_M / (k or 1)
    rows, cols = np.divmod(np.arange(SAMPLED_SIDE**2), SAMPLED_SIDE)
    # Unit (row, col) sits at torus angle 2π·(col, row)/8; its fields are offset by that share of a period,
    # plus half a 2.5 m bin so every field is centred on a bin of the folded map.
    phases_m = np.stack([cols, rows], axis=1) * field_period_m / SAMPLED_SIDE + 1.25
    return _field_activity(positions_m[:, None, :], field_period_m, phases_m[None]).astype(np.float32)


def _street_grid(extent_m: float, street_spacing_m: float, step_m: float = 1.0) -> np.ndarray:
    """(n, 2) positions of a drive along east-west streets `street_spacing_m` apart (boustrophedon)."""
    xs = np.arange(0.0, extent_m, step_m)
    lanes = [np.column_stack([xs[:: 1 - 2 * (j % 2)], np.full_like(xs, y)]) for j, y in
             enumerate(np.arange(1.25, extent_m, street_spacing_m))]  # fmt: skip
    return np.concatenate(lanes)


def _frame(position: int) -> FrameRecord:
    return FrameRecord(
        frame_index=position, timestamp_s=0.1 * position, vo_world_from_camera=np.eye(4), vo_status="ok",
        motion_flag="ok", yaw_rate_rad_s=0.0, speed_m_s=10.0, view_cell=-1, view_status="none",
        view_difference=0.0, injection_strength=0.0, heading_rad=0.0, place_code_rad=(0.0, 0.0),
        place_position_m=(0.0, 0.0), vertex=0, vertex_created=False, loop_closure=None, closure_note="",
        data_flags="",
        online_pose=np.zeros(3), vertex_from_agent=np.zeros(3),
    )  # fmt: skip


def _snapshot(frame: int, lesioned: tuple[bool, bool, bool]) -> dict:
    rng = np.random.default_rng(frame)
    return {
        "frame_index": frame,
        "hd": rng.random((9, 36)),
        "hd_nu_max": 0.1,
        "grid": [None if off else rng.random((3, 3, 16, 16)) for off in lesioned],
        "layer2": [None if off else rng.random((16, 16)) for off in lesioned],
        "place": rng.random((16, 16)),
        "k": list(KS),
        "nu_max": [1.0, 1.0, 1.0],
        "readout": None,
    }


def _map_along(xy: np.ndarray, spacing_m: float, loops: int) -> dict[str, np.ndarray]:
    """A map export with a vertex every `spacing_m` of the drive, chained, plus `loops` loop links."""
    path_m = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    at = np.searchsorted(path_m, np.arange(0.0, path_m[-1], spacing_m))
    poses = np.column_stack([xy[at], np.zeros(len(at))])
    chain = np.column_stack([np.arange(len(at) - 1), np.arange(1, len(at))])
    ends = np.linspace(len(at) // 2, len(at) - 1, loops).astype(int)
    links = np.concatenate([chain, np.column_stack([ends, ends - len(at) // 2])]).reshape(-1, 2)
    is_loop = np.concatenate([np.zeros(len(chain), bool), np.ones(loops, bool)])
    return {"poses": poses, "links": links, "link_is_loop": is_loop}


def _run_result(
    xy: np.ndarray,
    lesioned: tuple[bool, bool, bool] = (False, False, False),
    ground_truth: bool = True,
    vertex_spacing_m: float = 4.0,
    loops: int = 12,
) -> RunResult:
    """A finished run along `xy` whose networks fire exactly as `_unit_activities` says."""
    n = len(xy)
    yaw = np.arctan2(np.gradient(xy[:, 1]), np.gradient(xy[:, 0]))
    poses = pose_from_planar(np.column_stack([xy, yaw]))
    drifted = pose_from_planar(np.column_stack([xy * 1.02 + [0.0, 3.0], yaw]))
    record = RunRecord(frames=[_frame(i) for i in range(n)])
    for m, k in enumerate(KS):
        if not lesioned[m]:
            record.unit_activity[GRID_POPULATIONS[m]] = list(_unit_activities(xy, k))
    record.unit_activity["place"] = list(_unit_activities(xy, None))
    record.snapshots = {0: _snapshot(0, lesioned), n - 1: _snapshot(n - 1, lesioned)}
    metrics = {"errors": {"vo": {"ate_2d_m": 3.0}, "corrected": {"ate_2d_m": 0.5}}} if ground_truth else {}
    return RunResult(
        name="street grid", record=record, metrics=metrics, vo_world_from_camera=drifted,
        online_world_from_camera=poses, corrected_world_from_camera=poses, neural_world_from_camera=poses,
        ground_truth=poses if ground_truth else None, map_export=_map_along(xy, vertex_spacing_m, loops),
        interrupted=False,
    )  # fmt: skip


def _count_fields(rates: np.ndarray) -> int:
    """Separate fields of a folded (periodic) rate map: connected regions above half its peak."""
    above = np.nan_to_num(rates, nan=0.0) > 0.5 * np.nanmax(rates)
    # Roll an empty row and column to the edges so that no field is cut by the fold's wrap-around.
    empty_row, empty_col = np.flatnonzero(~above.any(axis=1)), np.flatnonzero(~above.any(axis=0))
    assert len(empty_row) and len(empty_col), "fields overlap across the whole period"
    above = np.roll(above, (-empty_row[0], -empty_col[0]), axis=(0, 1))
    labels, _ = cv2.connectedComponents(above.astype(np.uint8), connectivity=8)
    return labels - 1


@pytest.fixture(scope="module")
def street_run() -> RunResult:
    # Streets every 2.5 m over two periods: every bin of the folded map is visited.
    return _run_result(_street_grid(2 * PERIOD_M, 2.5))


@pytest.mark.parametrize("k", KS)
def test_folded_rate_map_of_module_k_shows_k_squared_fields(k):
    # Any positions over several periods fold onto one: here a lattice not aligned with the period.
    axis_m = np.arange(-1.5 * PERIOD_M + 0.3, 1.5 * PERIOD_M, 0.7)
    positions = np.stack(np.meshgrid(axis_m, axis_m), axis=-1).reshape(-1, 2)
    phase_m = np.array([1.25, 1.25 + 2.5 * k])
    activity = _field_activity(positions, PERIOD_M / k, phase_m)
    rates = folded_rate_map(positions, activity, PERIOD_M, FOLD_BINS)
    assert rates.shape == (FOLD_BINS, FOLD_BINS) and np.isfinite(rates).all()
    assert _count_fields(rates) == k * k
    # The strongest bin is a field centre: the phase, modulo the field spacing (row = y, column = x).
    row, col = np.unravel_index(np.argmax(rates), rates.shape)
    centre_m = (np.array([col, row]) + 0.5) * PERIOD_M / FOLD_BINS
    offset_m = np.remainder(centre_m - phase_m + 0.5 * PERIOD_M / k, PERIOD_M / k) - 0.5 * PERIOD_M / k
    np.testing.assert_allclose(offset_m, 0.0, atol=1e-9)


def test_folding_with_the_wrong_period_loses_the_fields():
    xy = _street_grid(3 * PERIOD_M, 2.5)
    activity = _field_activity(xy, PERIOD_M / 4, np.array([1.25, 1.25]))
    right = folded_rate_map(xy, activity, PERIOD_M, FOLD_BINS)
    wrong = folded_rate_map(xy, activity, 0.9 * PERIOD_M, FOLD_BINS)
    # Folded at the torus period every visit to a field lands in the same bin; at another period they smear.
    assert np.nanmax(right) > 0.8 and np.nanmax(wrong) < 0.6 * np.nanmax(right)


def test_path_rate_map_averages_passes_and_keeps_only_visited_bins():
    road = np.column_stack([np.arange(0.0, 40.0, 0.5), np.full(80, 1.0)])
    positions = np.concatenate([road, road[::-1], [[np.nan, 0.0]]])
    activity = np.concatenate([np.full(80, 1.0), np.full(80, 3.0), [100.0]])  # the NaN frame is left out
    centres, rates = path_rate_map(positions, activity, bin_m=4.0)
    assert len(centres) == 10  # a 40 m road in 4 m bins, nothing around it
    np.testing.assert_allclose(np.sort(centres[:, 0]), np.arange(2.0, 40.0, 4.0))
    np.testing.assert_allclose(centres[:, 1], 2.0)
    np.testing.assert_allclose(rates, 2.0)  # mean of the two passes
    # Several units at once give the same as one at a time.
    both = np.column_stack([activity, 2 * activity])
    _, rates_2 = path_rate_map(positions, both, bin_m=4.0)
    np.testing.assert_allclose(rates_2, np.column_stack([rates, 2 * rates]))


def test_the_unit_shown_is_one_that_fires_in_places():
    xy = _street_grid(PERIOD_M, 10.0)
    field = _field_activity(xy, PERIOD_M, np.array([50.0, 50.0]))
    units = np.column_stack([np.zeros(len(xy)), np.full(len(xy), 9.0), field])  # silent, always on, field
    _, bin_rates = path_rate_map(xy, units, bin_m=4.0)
    assert most_selective_unit(bin_rates) == 2


def test_rate_maps_show_every_network_with_colour_bars_and_the_modules_field_counts(street_run):
    figure = rate_maps_figure(street_run, bin_m=4.0, torus_period_m=PERIOD_M)
    panels = [ax for ax in figure.axes if ax.get_label() != "<colorbar>"]
    colour_bars = [ax for ax in figure.axes if ax.get_label() == "<colorbar>"]
    assert len(panels) == 8 and len(colour_bars) == 8
    assert all("(a.u.)" in bar.get_ylabel() for bar in colour_bars)
    top, bottom = panels[:4], panels[4:]
    for ax in top:
        (dots,) = ax.collections
        # One square per visited 4 m bin of the 200 m × 200 m grid of streets, coloured by activity.
        assert len(dots.get_offsets()) > 1000 and np.ptp(dots.get_array()) > 0.5 * dots.get_array().max()
        assert ax.get_xlabel() == "x (m)"
    for ax, fields in zip(bottom, [1, 4, 16, 1]):
        (image,) = ax.images
        assert image.get_array().shape == (FOLD_BINS, FOLD_BINS)
        assert _count_fields(image.get_array().filled(np.nan)) == fields, ax.get_title()
        assert f"{fields} field" in ax.get_title()


@pytest.mark.slow
def test_run_figures_are_written_as_non_trivial_images(street_run, tmp_path):
    paths = write_run_figures(street_run, tmp_path, rate_map_bin_m=4.0, torus_period_m=PERIOD_M)
    n = len(street_run.record)
    names = {"cognitive_map.png", "rate_maps.png", "neural_state_000000.png", f"neural_state_{n - 1:06d}.png"}
    assert {p.name for p in paths} == names
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        assert image is not None, path.name
        assert min(image.shape[:2]) >= 600, path.name
        assert len(np.unique(image.reshape(-1, 3), axis=0)) > 100, f"{path.name} is nearly blank"
        assert np.any(image < 200, axis=2).mean() > 0.05, f"{path.name}: little is drawn"


def test_a_lesioned_module_is_shown_as_lesioned(tmp_path):
    run = _run_result(_street_grid(PERIOD_M, 10.0), lesioned=(False, False, True))
    assert {p.name for p in write_run_figures(run, tmp_path)} >= {"rate_maps.png", "cognitive_map.png"}
    figure = rate_maps_figure(run)
    panels = [ax for ax in figure.axes if ax.get_label() != "<colorbar>"]
    dorsal = [panels[2], panels[6]]
    for ax in dorsal:
        assert "k=4" in ax.get_title() and not ax.images and not ax.collections
        assert any("lesioned" in text.get_text() for text in ax.texts)
    assert all(ax.images or ax.collections for ax in panels if ax not in dorsal)
    # Only the live networks have colour bars.
    assert sum(ax.get_label() == "<colorbar>" for ax in figure.axes) == 6
    state = neural_state_figure(run.record.snapshots[0], "lesioned dorsal")
    assert sum(any("lesioned" in t.get_text() for t in ax.texts) for ax in state.axes) == 2


def test_cognitive_map_stays_readable_at_full_length():
    # A 4 500-vertex map (KITTI 00 has 4 541 frames) along ~9 km of streets.
    run = _run_result(_street_grid(900.0, 90.0, step_m=2.0), vertex_spacing_m=2.0, loops=40)
    n_vertices = len(run.map_export["poses"])
    assert n_vertices >= 4500
    figure = cognitive_map_figure(run)
    map_ax, estimates_ax = figure.axes
    assert f"{n_vertices} vertices" in map_ax.get_title() and "(40 loop)" in map_ax.get_title()
    links, vertices, loop_links = map_ax.collections  # odometric links, vertices, loop links
    assert len(links.get_segments()) == n_vertices - 1 and len(loop_links.get_segments()) == 40
    assert np.allclose(loop_links.get_colors()[0][:3], (1.0, 0.0, 0.0))
    # Small markers for a long map: neighbouring vertices (2 m apart) must not merge into a band.
    assert vertices.get_sizes()[0] < 4.0
    assert map_ax.get_aspect() == 1.0 and estimates_ax.get_aspect() == 1.0
    legend = [t.get_text() for t in map_ax.get_legend().get_texts()]
    assert f"vertices ({n_vertices})" in legend and "loop links (40)" in legend and "ground truth" in legend
    traces = [t.get_text() for t in estimates_ax.get_legend().get_texts()]
    assert "odometry alone (ATE 3.0 m)" in traces and "cognitive map (per frame) (ATE 0.5 m)" in traces
    # Without ground truth the map and the estimates are still drawn.
    alone = cognitive_map_figure(_run_result(_street_grid(200.0, 50.0), ground_truth=False), estimates=False)
    (only,) = alone.axes
    assert "ground truth" not in [t.get_text() for t in only.get_legend().get_texts()]


def test_vertex_markers_shrink_as_vertices_crowd_but_stay_visible():
    sizes = [vertex_marker_diameter_pt(2000.0, n, points_per_m=0.8) for n in (50, 500, 5000, 50000)]
    assert sizes == sorted(sizes, reverse=True)
    assert sizes[0] == 5.0 and sizes[-1] == 1.0


def test_figures_leave_the_global_backend_and_pyplot_alone(street_run, tmp_path, monkeypatch):
    original = matplotlib.get_backend()
    matplotlib.use("svg")  # a backend the figures must not replace (a notebook's inline backend, say)
    try:
        with monkeypatch.context() as patch:
            patch.setattr(matplotlib, "use", lambda *a, **k: pytest.fail("figures switched the backend"))
            write_run_figures(street_run, tmp_path)
        assert matplotlib.get_backend() == "svg"
        import matplotlib.pyplot as plt

        assert plt.get_fignums() == []  # nothing left open in pyplot's figure list
    finally:
        matplotlib.use(original)


def test_run_prints_the_bump_table_of_the_last_frame(tmp_path, capsys):
    args = ["run", "--out", str(tmp_path / "demo"), "--no-progress", "--no-figures", "--stop", "6"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    table = printed[printed.index("bump table at frame 5") :]
    rows = [line.split() for line in table.splitlines()[2:] if line.strip() and "results written" not in line]
    # One row per bump: 1 + 4 + 16 grid bumps, the fused estimate and the place bump.
    assert [r[0] for r in rows].count("grid") == 21 and [r[0] for r in rows][-2:] == ["fused", "place"]
    assert "frame 0:" not in table  # the other snapshot frames are in bump_table.csv only
