"""The neural engine from Python: configuration, stepping, arrays, fusion, lesions, errors."""

from __future__ import annotations

import json
import math

import hippo_nav
import numpy as np
import pytest
from hippo_nav import _core
from hippo_nav.engine import EngineConfig, SpatialMemory, ViewPatterns, find_bumps, fuse_modules


@pytest.fixture(scope="module")
def settled() -> SpatialMemory:
    return SpatialMemory()


def test_python_config_defaults_are_the_rust_defaults():
    from_rust = json.loads(_core.default_engine_config_json())
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
        {"grid": [{"n_theta": 32, "n_nu": 5}] * 3, "place": {"n_theta": 32}, "hd": {"n_theta": 64}}
    )
    a, b = SpatialMemory(cfg, "float32"), SpatialMemory(cfg, "float64")
    for _ in range(20):
        ra, rb = a.step(0.2, 8.0, 0.1), b.step(0.2, 8.0, 0.1)
    assert ra.heading_rad == pytest.approx(rb.heading_rad, abs=1e-3)
    assert ra.place_position_m == pytest.approx(rb.place_position_m, abs=0.05)


def test_state_round_trip_resumes_identically():
    cfg = EngineConfig.model_validate({"grid": [{"n_theta": 32, "n_nu": 5}] * 3, "place": {"n_theta": 32}})
    a = SpatialMemory(cfg)
    a.step(0.3, 10.0, 0.1)
    b = SpatialMemory(cfg)
    b.set_state(a.state())
    ra, rb = a.step(0.1, 5.0, 0.1), b.step(0.1, 5.0, 0.1)
    # Identical up to single-precision rounding (the implicit solve starts from a different guess).
    np.testing.assert_allclose(a.place_activity(), b.place_activity(), rtol=1e-4, atol=1e-6)
    assert ra.heading_rad == pytest.approx(rb.heading_rad, abs=1e-6)
    assert ra.place_position_m == pytest.approx(rb.place_position_m, abs=1e-4)


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
    with pytest.raises(hippo_nav.HippoNavError, match="hd.n_theta"):
        SpatialMemory(EngineConfig.model_validate({"hd": {"n_theta": 0}}))
    with pytest.raises(hippo_nav.HippoNavError, match="max_substep_s"):
        SpatialMemory(EngineConfig.model_validate({"max_substep_s": 1.0}))
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
