"""The neural engine from Python: configuration, stepping, arrays, fusion, lesions, errors."""

from __future__ import annotations

import json
import math
import sys

import hippo_nav
import numpy as np
import pytest
from hippo_nav import _core
from hippo_nav.engine import (
    MODULE_NAMES,
    N_MODULES,
    Bump,
    CompactView,
    EngineConfig,
    ModuleReadout,
    SpatialMemory,
    SpatialReadout,
    ViewPatterns,
    find_bumps,
    fuse_modules,
)


@pytest.fixture(scope="module")
def settled() -> SpatialMemory:
    return SpatialMemory()


def test_python_config_defaults_are_the_rust_defaults():
    from_rust = json.loads(_core.default_params_json("engine"))
    from_python = json.loads(EngineConfig().to_json())
    assert from_python == from_rust
    # Partial configs fill the rest from the Rust defaults.
    c = EngineConfig.model_validate(
        {"grid": [{"n_theta": 32}, {"n_theta": 32}, {"n_theta": 32}], "place": {"n_theta": 32}}
    )
    assert c.grid[2].k == 4 and c.grid[0].n_theta == 32 and c.hd.n_theta == from_rust["hd"]["n_theta"]


def test_every_module_has_its_bumps_and_the_place_code_one(settled: SpatialMemory):
    r = settled.readout()
    assert [len(m.bumps) for m in r.modules] == [1, 4, 16]
    assert [m.k for m in r.modules] == [1, 2, 4]
    assert r.place is not None and r.fused is not None
    # Finer modules have narrower bumps, and the fused estimate is narrower than any module.
    widths = [m.bumps[0].width_rad for m in r.modules]
    assert widths[0] > widths[1] > widths[2] > r.fused.width_rad


def test_readouts_are_frozen_typed_objects_built_in_rust(settled: SpatialMemory):
    r = settled.readout()
    assert isinstance(r, SpatialReadout) and type(r) is _core.SpatialReadout
    assert N_MODULES == _core.N_MODULES == len(MODULE_NAMES) == len(r.modules) == len(settled.config.grid)
    module = r.modules[0]
    assert isinstance(module, ModuleReadout) and isinstance(module.bumps, tuple)
    assert isinstance(module.bumps[0], Bump) and isinstance(r.place, Bump)
    assert isinstance(r.time_s, float) and isinstance(r.substeps, int) and isinstance(module.k, int)
    assert isinstance(r.place_position_m, tuple) and len(module.tracked_rad) == 2
    for obj, name in ((r, "heading_rad"), (r, "modules"), (module, "bumps"), (r.place, "mean_rad")):
        with pytest.raises(AttributeError):
            setattr(obj, name, None)
    assert r == settled.readout() and r.modules[1] == settled.readout().modules[1]
    assert "SpatialReadout(" in repr(r) and "Bump(" in repr(r.place)
    b = Bump((1.0, 2.0), (0.2, 0.4))
    assert b.mass == 1.0 and b.width_rad == pytest.approx(0.3) and b == Bump((1.0, 2.0), (0.2, 0.4), 1.0)


def test_activity_arrays_have_documented_shapes(settled: SpatialMemory):
    c = settled.config
    assert settled.hd_activity().shape == (c.hd.n_nu, c.hd.n_theta)
    g = c.grid[1]
    act = settled.grid_activity(1)
    assert act.shape == (g.n_nu, g.n_nu, g.n_theta, g.n_theta)
    np.testing.assert_allclose(act.sum(axis=(0, 1)), settled.grid_layer2(1), rtol=1e-5, atol=1e-9)
    assert settled.place_activity().shape == (c.place.n_theta,) * 2
    with pytest.raises(hippo_nav.HippoNavError, match="module index 3"):
        settled.grid_activity(3)


def test_path_integration_from_python_follows_a_drive():
    sm = SpatialMemory()
    x = y = yaw = dist = 0.0
    for f in range(150):
        t = f * 0.1
        w, v = 0.5 * math.sin(0.4 * t), 12.0 + 8.0 * math.cos(0.3 * t)
        r = sm.step(w, v, 0.1)
        for _ in range(r.substeps):
            yaw += w * 0.1 / r.substeps
            x += v * math.cos(yaw) * 0.1 / r.substeps
            y += v * math.sin(yaw) * 0.1 / r.substeps
        dist += v * 0.1
    for m in r.modules:
        assert math.hypot(m.position_m[0] - x, m.position_m[1] - y) < 0.02 * dist
    assert math.hypot(r.place_position_m[0] - x, r.place_position_m[1] - y) < 0.02 * dist


def test_fusion_reproduces_the_papers_table():
    # Bold bumps of the paper's table, coarsest module first: ((μx, μy), (σx, σy)).
    coarse = [((1.77, 0.34), (21.39, 20.48))]
    mid = [((1.75, 6.17), (5.42, 10.84))]
    fine = [((1.71, 6.20), (1.16, 2.02))]
    mean, std, chosen = fuse_modules([coarse, mid, fine])
    assert mean == pytest.approx((1.712, 6.203), abs=1e-3)
    assert std == pytest.approx((1.133, 1.977), abs=1e-3)
    assert len(chosen) == 3


def test_find_bumps_accepts_any_layout():
    n = 32
    t = 2 * np.pi * np.arange(n) / n
    pattern = np.maximum(
        np.cos(2 * t)[None, :] * np.cos(2 * t)[:, None], 0.0
    )  # 4 positive lobes... and 4 more
    base = find_bumps(np.ascontiguousarray(pattern))
    transposed = find_bumps(np.ascontiguousarray(pattern.T).T)  # Fortran order, same values
    assert len(base) == len(transposed) == 8
    strided = np.zeros((n, 2 * n))
    strided[:, ::2] = pattern
    assert len(find_bumps(strided[:, ::2])) == 8
    with pytest.raises(hippo_nav.HippoNavError, match="square"):
        find_bumps(np.zeros((4, 5)))
    with pytest.raises(hippo_nav.HippoNavError, match="NaN"):
        find_bumps(np.full((4, 4), np.nan))


def test_lesions_widen_the_place_field_dorsal_most():
    sm = SpatialMemory()

    def width(**lesions: bool) -> float:
        sm.set_lesions(**lesions)
        rs = [sm.step(0.0, 0.0, 0.1) for _ in range(8)]
        return float(np.mean([r.place.width_rad for r in rs[4:]]))

    red = width()
    green = width(ventral=True)
    yellow = width(dorsal=True)
    assert yellow > green > red


def test_view_injection_accepts_non_contiguous_arrays_and_pulls_back():
    sm = SpatialMemory()
    stored = sm.view_patterns()
    start = sm.readout().heading_rad
    for _ in range(5):
        sm.step(1.0, 10.0, 0.1)
    away = abs(math.remainder(sm.readout().heading_rad - start, 2 * math.pi))
    # Same values through a strided view: layout must not matter.
    hd = np.zeros(2 * stored.hd_profile.size)
    hd[::2] = stored.hd_profile
    view = ViewPatterns(
        hd_profile=hd[::2], grid_layer2=[np.asfortranarray(g) for g in stored.grid_layer2], strength=3.0
    )
    for _ in range(10):
        r = sm.step(0.0, 0.0, 0.1, view)
    back = abs(math.remainder(r.heading_rad - start, 2 * math.pi))
    assert back < 0.25 * away


def test_float64_engine_agrees_with_float32():
    cfg = EngineConfig.model_validate(
        {"grid": [{"n_theta": 32, "n_nu": 5}] * N_MODULES, "place": {"n_theta": 32}, "hd": {"n_theta": 64}}
    )
    a, b = SpatialMemory(cfg, "float32"), SpatialMemory(cfg, "float64")
    for _ in range(20):
        ra, rb = a.step(0.2, 8.0, 0.1), b.step(0.2, 8.0, 0.1)
    assert ra.heading_rad == pytest.approx(rb.heading_rad, abs=1e-3)
    assert ra.place_position_m == pytest.approx(rb.place_position_m, abs=0.05)


def test_state_round_trip_resumes_identically():
    cfg = EngineConfig.model_validate(
        {"grid": [{"n_theta": 32, "n_nu": 5}] * N_MODULES, "place": {"n_theta": 32}}
    )
    a = SpatialMemory(cfg)
    a.step(0.3, 10.0, 0.1)
    b = SpatialMemory(cfg)
    b.set_state(a.state())
    ra, rb = a.step(0.1, 5.0, 0.1), b.step(0.1, 5.0, 0.1)
    # Identical up to single-precision rounding (the implicit solve starts from a different guess).
    np.testing.assert_allclose(a.place_activity(), b.place_activity(), rtol=1e-4, atol=1e-6)
    assert ra.heading_rad == pytest.approx(rb.heading_rad, abs=1e-6)
    assert ra.place_position_m == pytest.approx(rb.place_position_m, abs=1e-4)


def test_a_state_is_restored_only_into_a_network_lesioned_alike():
    # Before: a lesioned network's state lesioned an intact one while its config still said intact.
    cfg = EngineConfig.model_validate(
        {"grid": [{"n_theta": 32, "n_nu": 5}] * N_MODULES, "place": {"n_theta": 32}}
    )
    lesioned = SpatialMemory(cfg)
    lesioned.set_lesions(ventral=True, dorsal=True)
    assert lesioned.config.lesioned == [True, False, True]
    lesioned.step(0.3, 10.0, 0.1)
    intact = SpatialMemory(cfg)
    before = intact.state()
    with pytest.raises(
        hippo_nav.HippoNavError, match="lesions ventral, dorsal; this one has none: call set_lesions"
    ):
        intact.set_state(lesioned.state())
    assert [m.lesioned for m in intact.readout().modules] == [False, False, False]
    np.testing.assert_array_equal(intact.place_activity(), before["place"])
    intact.set_lesions(ventral=True, dorsal=True)
    intact.set_state(lesioned.state())
    assert [m.lesioned for m in intact.readout().modules] == [True, False, True]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((float("nan"), 1.0, 0.1), "yaw_rate_rad_s"),
        ((0.0, float("inf"), 0.1), "speed_m_s"),
        ((0.0, 400.0, 0.1), "m/s"),
        ((0.0, 1.0, 0.0), "dt_s"),
        ((30.0, 1.0, 0.1), "rad/s"),
    ],
)
def test_bad_motion_inputs_raise_clear_errors_and_keep_the_state(settled: SpatialMemory, args, message):
    before = settled.readout()
    with pytest.raises(hippo_nav.HippoNavError, match=message):
        settled.step(*args)
    assert settled.readout() == before


def test_bad_configs_and_views_raise_clear_errors(settled: SpatialMemory):
    # Refused by the config model, naming the field; and by the engine for a config made without checks.
    default = EngineConfig()
    for data, unchecked, field in (
        (
            {"hd": {"n_theta": 0}},
            default.model_copy(update={"hd": default.hd.model_copy(update={"n_theta": 0})}),
            "hd.n_theta",
        ),
        ({"max_substep_s": 1.0}, default.model_copy(update={"max_substep_s": 1.0}), "max_substep_s"),
    ):
        with pytest.raises(ValueError, match=field):
            EngineConfig.model_validate(data)
        with pytest.raises(hippo_nav.HippoNavError, match=f"invalid engine config: engine.{field} = "):
            SpatialMemory(unchecked)
    with pytest.raises(hippo_nav.HippoNavError, match="dtype"):
        SpatialMemory(dtype="float16")
    with pytest.raises(ValueError):
        EngineConfig.model_validate({"hd": {"no_such_field": 1}})
    good = settled.view_patterns()
    with pytest.raises(hippo_nav.HippoNavError, match="shape"):
        settled.step(0.0, 0.0, 0.1, ViewPatterns(hd_profile=np.zeros(5), grid_layer2=good.grid_layer2))
    bad = good.grid_layer2[0].copy()
    bad[3, 3] = np.nan
    with pytest.raises(hippo_nav.HippoNavError, match="NaN"):
        settled.step(0.0, 0.0, 0.1, ViewPatterns(hd_profile=good.hd_profile, grid_layer2=[bad, None, None]))
    # A view 1e40 strong overflowed f32 and left every later step failing, blamed on the velocity: refused, the
    # networks as they were.
    before = settled.readout()
    strong = ViewPatterns(hd_profile=good.hd_profile, grid_layer2=good.grid_layer2, strength=1e40)
    with pytest.raises(hippo_nav.HippoNavError, match="view strength.*must lie in"):
        settled.step(0.0, 1.0, 0.1, strong)
    assert settled.readout() == before
    settled.step(0.0, 1.0, 0.1)
    # Gains a typo made absurd are refused by the config model and by the engine alike.
    with pytest.raises(ValueError, match="hd.j1"):
        EngineConfig.model_validate({"hd": {"j1": 1e300}})
    absurd = default.model_copy(update={"hd": default.hd.model_copy(update={"j1": 1e300})})
    with pytest.raises(hippo_nav.HippoNavError, match="engine.hd.j1 = "):
        SpatialMemory(absurd)


def test_the_fusion_refuses_a_prior_or_a_width_it_cannot_use():
    one = [((0.1, 0.2), (0.3, 0.3))]
    two = [((0.1, 0.2), (0.3, 0.3)), ((3.0, 3.0), (0.3, 0.3))]
    with pytest.raises(hippo_nav.HippoNavError, match="prior"):
        fuse_modules([two, one, two], (math.nan, math.nan))
    with pytest.raises(hippo_nav.HippoNavError, match="at least 1e-12 rad"):
        fuse_modules([[((0.1, 0.2), (1e-160, 1e-160))], one, one])  # its precision overflowed: NaN


# --- compact stored views -------------------------------------------------------------------------------


def _driven(steps: int = 6) -> SpatialMemory:
    """An engine away from its seed (heading and lattice phases not at 0)."""
    sm = SpatialMemory()
    for _ in range(steps):
        sm.step(0.4, 11.0, 0.1)
    return sm


def _circular_offset_units(a: int, b: int, n: int) -> int:
    return min((a - b) % n, (b - a) % n)


def test_compact_view_regenerates_the_stored_patterns():
    sm = _driven()
    full = sm.view_patterns()
    view = CompactView.from_engine(sm)
    regenerated = view.patterns()
    hd, hd_full = regenerated.hd_profile, full.hd_profile
    assert hd.shape == hd_full.shape
    assert np.corrcoef(hd, hd_full)[0, 1] > 0.95
    assert _circular_offset_units(int(np.argmax(hd)), int(np.argmax(hd_full)), hd.size) <= 1
    assert view.hd.heading_rad == pytest.approx(sm.readout().heading_rad % (2 * math.pi), abs=1e-3)
    for i, (code, g, g_full) in enumerate(zip(view.modules, regenerated.grid_layer2, full.grid_layer2)):
        assert code is not None and g is not None and g.shape == g_full.shape
        assert code.k == sm.config.grid[i].k
        assert np.corrcoef(g.ravel(), g_full.ravel())[0, 1] > 0.95, i
        # Peaks agree within one unit per axis, on the module's lattice (any of its k² copies).
        cell = g.shape[0] // code.k
        (y, x), (yf, xf) = (np.unravel_index(int(np.argmax(a)), a.shape) for a in (g, g_full))
        assert (
            _circular_offset_units(int(x), int(xf), cell) <= 1
            and _circular_offset_units(int(y), int(yf), cell) <= 1
        )
        # The code's phase is the readout's bump centre, folded onto the lattice.
        bump = sm.readout().modules[i].bumps[0].mean_rad
        period = 2 * math.pi / code.k
        for a in range(2):
            assert abs(math.remainder(code.phase_rad[a] - bump[a], period)) < 0.02, (i, a)
        assert 0 < code.width_rad[0] < period and code.amplitude > 0
    # Widths follow the modules' bump widths (finer modules, narrower bumps).
    widths = [m.width_rad[0] for m in view.modules if m is not None]
    assert widths[0] > widths[1] > widths[2]


def test_compact_view_is_a_few_dozen_bytes():
    sm = _driven(2)
    view = CompactView.from_engine(sm)
    full = sm.view_patterns()
    full_bytes = np.asarray(full.hd_profile, np.float32).nbytes + sum(
        np.asarray(g, np.float32).nbytes for g in full.grid_layer2 if g is not None
    )
    assert view.nbytes == 88 and full_bytes > 49_000

    def deep_size(obj: object) -> int:
        size = sys.getsizeof(obj)
        for name in getattr(type(obj), "__slots__", ()):
            value = getattr(obj, name)
            size += sys.getsizeof(value)  # an owning numpy array counts its data
            if isinstance(value, tuple):
                size += sum(sys.getsizeof(v) for v in value)
        return size

    assert deep_size(view) < 1024, deep_size(view)


def test_compact_view_recalls_heading_and_place_like_the_full_patterns():
    """Store a view, drive away, then inject either the full stored patterns or the compact view's
    regenerated ones into the same drifted state: both pull heading and place back, to within a small
    tolerance of each other, at a strong and at a weak injection."""
    sm = _driven(4)
    start = sm.readout()
    full = sm.view_patterns()
    view = CompactView.from_engine(sm)
    for _ in range(5):
        sm.step(1.0, 12.0, 0.1)
    away = sm.state()

    def gaps(r) -> tuple[float, float]:
        heading = abs(math.remainder(r.heading_rad - start.heading_rad, 2 * math.pi))
        (ax, ay), (bx, by) = r.place.mean_rad, start.place.mean_rad
        return heading, math.hypot(math.remainder(ax - bx, 2 * math.pi), math.remainder(ay - by, 2 * math.pi))

    def recall(patterns: ViewPatterns, steps: int) -> tuple[float, float]:
        net = SpatialMemory()
        net.set_state(away)
        for _ in range(steps):
            r = net.step(0.0, 0.0, 0.1, patterns)
        return gaps(r)

    away_gaps = gaps(sm.readout())
    assert away_gaps[0] > 0.3 and away_gaps[1] > 0.2
    for strength, steps in [(3.0, 10), (0.1, 3)]:
        stored = ViewPatterns(full.hd_profile, full.grid_layer2, strength=strength)
        with_full = recall(stored, steps)
        with_compact = recall(view.patterns(strength), steps)
        print(f"strength {strength}: away {away_gaps}, full {with_full}, compact {with_compact}")
        for a in range(2):
            assert with_full[a] < 0.25 * away_gaps[a]
            assert with_compact[a] < 0.25 * away_gaps[a]
            # Measured (rad, full vs compact): strength 3 → all ≤ 0.007; strength 0.1 after 0.3 s →
            # heading 0.003 vs 0.001, place 0.052 vs 0.047.
            assert abs(with_compact[a] - with_full[a]) < 0.02, (strength, a)


def test_compact_view_codes_round_trip_lesions_and_heading_offset():
    sm = _driven(3)
    sm.set_lesions(intermediate=True)
    view = CompactView.from_engine(sm)
    assert view.modules[1] is None and view.grid_layer2(1) is None
    assert view.patterns().grid_layer2[1] is None
    # Regenerated patterns are exact periodic Gaussians: compressing them again gives the same codes.
    again = CompactView.from_patterns(view.patterns(), [1, 2, 4])
    assert again.hd == pytest.approx(view.hd, rel=1e-3, abs=1e-4)
    for a, b in zip(again.modules, view.modules):
        assert (a is None) == (b is None)
        if a is not None and b is not None:
            assert a.phase_rad == pytest.approx(b.phase_rad, abs=1e-4)
            assert a.width_rad == pytest.approx(b.width_rad, rel=1e-3)
            assert a.amplitude == pytest.approx(b.amplitude, rel=1e-3)
    # A heading offset turns the HD bump counter-clockwise by that angle.
    n = sm.config.hd.n_theta
    turned = view.hd_profile(heading_offset_rad=0.5)
    theta = 2 * np.pi * np.arange(n) / n
    mean = float(np.angle(np.sum(turned * np.exp(1j * theta))))
    assert math.remainder(mean - view.hd.heading_rad - 0.5, 2 * math.pi) == pytest.approx(0.0, abs=1e-3)
    # What it injects is accepted by the engine, and bad inputs are refused with a reason.
    sm.step(0.0, 0.0, 0.1, view.patterns(0.5))
    good = sm.view_patterns()
    with pytest.raises(hippo_nav.HippoNavError, match="3 grid patterns for 2 modules"):
        CompactView.from_patterns(good, [1, 2])
    with pytest.raises(hippo_nav.HippoNavError, match="square array"):
        CompactView.from_patterns(ViewPatterns(good.hd_profile, [np.zeros((64, 63)), None, None]), [1, 2, 4])
    with pytest.raises(hippo_nav.HippoNavError, match="HD profile"):
        CompactView.from_patterns(ViewPatterns(np.full(128, np.nan), [None] * N_MODULES), [1, 2, 4])
    with pytest.raises(hippo_nav.HippoNavError, match="module index 3"):
        view.grid_layer2(3)


def test_a_recalled_view_shifted_by_a_displacement_is_the_state_there():
    """Store a view, drive 16 m straight on: the stored view's bumps shifted by 2π·d/P (d the displacement
    in the engine frame, P the torus period) sit where the driven network's bumps are, in every module —
    the shift `placement = "measured"` applies to a recalled state (docs/spec.md §3)."""
    sm = _driven(3)
    before, start = CompactView.from_engine(sm), sm.readout()
    for _ in range(20):
        sm.step(0.0, 8.0, 0.1)
    after, end = CompactView.from_engine(sm), sm.readout()
    d = np.subtract(end.place_position_m, start.place_position_m)
    heading = start.heading_rad
    assert np.linalg.norm(d) == pytest.approx(16.0, rel=0.03)
    assert math.atan2(d[1], d[0]) == pytest.approx(heading, abs=0.02)  # along the heading code
    shift = tuple(2 * math.pi * d / sm.config.torus_period_m)
    for m, code in enumerate(after.modules):
        assert code is not None
        moved = before.grid_layer2(m, shift)
        unmoved = before.grid_layer2(m)
        target = after.grid_layer2(m)
        assert moved is not None and unmoved is not None and target is not None
        # The shifted pattern matches the driven one; the unshifted one is a bump elsewhere.
        assert np.corrcoef(moved.ravel(), target.ravel())[0, 1] > 0.97, code.k
        assert np.corrcoef(unmoved.ravel(), target.ravel())[0, 1] < 0.8, code.k
