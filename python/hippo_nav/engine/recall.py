"""What a view cell remembers of the network: the few numbers that recall its state (docs/spec.md §7).

A view cell stores the network state at the moment its view was first seen and injects it back on a revisit
(`ViewPatterns`: the HD θ-profile and each grid module's layer-II pattern). In full that is ~50 kB a cell
(float32), which grows without bound over a long run. But every stored pattern is one bump of a known
shape, so `CompactView` keeps only its parameters and regenerates the patterns when they are injected:

- HD ring: heading ψ (circular mean of the θ-profile), width σ (its circular standard deviation),
  amplitude A and baseline b. Regenerated profile: `b + A·exp(−wrap(θ − ψ)² / 2σ²)` on `θ_i = 2πi/Nθ`.
- Grid module k: the layer-II pattern repeats with period `P = 2π/k` along both torus axes (the dynamics run
  in that lattice-symmetric subspace, `GridModule::fold` in grid.rs), so it is folded onto one `(N/k)²`
  unit cell (mean over the k² copies) and described by the bump phase `φ ∈ [0, P)²` (per-axis circular
  mean at wave number k), per-axis widths `σ = (σx, σy)` (activity-weighted standard deviations of the
  lattice-wrapped offsets), amplitude and baseline. Regenerated pattern, on `θ_j = 2πj/N`:
  `b + A·exp(−wrapP(θx − φx)² / 2σx²)·exp(−wrapP(θy − φy)² / 2σy²)`, a periodic Gaussian on the lattice.
- The baseline is the pattern's minimum; the amplitude is the least-squares fit of the Gaussian above it
  (between the bump's peak and the value that would match its mass: the network's bumps are a little
  flatter-topped than a Gaussian of the same standard deviation). A lesioned module stores nothing (None).

Regenerated patterns correlate with the stored ones at ≈ 0.98–0.99 and pull heading and place back as the
full patterns do (`tests/test_engine.py`). The 22 numbers are float32: 88 bytes a view.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine.network import SpatialMemory, ViewPatterns

__all__ = ["CompactView", "GridBumpCode", "HdBumpCode"]

_TAU = 2.0 * math.pi
_HD_FIELDS = 4  # heading, width, amplitude, baseline
_GRID_FIELDS = 6  # phase x, phase y, width x, width y, amplitude, baseline


class HdBumpCode(NamedTuple):
    """The HD θ-profile as one bump: `baseline + amplitude·exp(−wrap(θ − heading)² / 2 width²)`."""

    heading_rad: float
    width_rad: float
    amplitude: float
    baseline: float


class GridBumpCode(NamedTuple):
    """A module's layer-II pattern as a periodic Gaussian on its lattice (period 2π/k on both axes)."""

    k: int
    phase_rad: tuple[float, float]
    """Bump centre (θx, θy) in the unit cell [0, 2π/k)²: the lattice offset."""
    width_rad: tuple[float, float]
    amplitude: float
    baseline: float


def _wrap_period(delta: np.ndarray, period: float) -> np.ndarray:
    """Offsets wrapped into [−period/2, period/2)."""
    return (delta + 0.5 * period) % period - 0.5 * period


def _phase_and_width(weights: np.ndarray, n_theta: int, k: int) -> tuple[float, float]:
    """Circular mean (at wave number k, in [0, 2π/k)) and standard deviation of a marginal profile whose
    unit i sits at θ = 2πi/n_theta; the width is floored at half a unit so a one-unit spike stays finite."""
    period = _TAU / k
    theta = _TAU * np.arange(weights.size) / n_theta
    z = np.sum(weights * np.exp(1j * k * theta))
    phase = float(np.angle(z) / k) % period
    variance = float(np.sum(weights * _wrap_period(theta - phase, period) ** 2) / np.sum(weights))
    return phase, max(math.sqrt(variance), math.pi / n_theta)


def _fit_amplitude(pattern: np.ndarray, shape: np.ndarray, baseline: float) -> float:
    """Least-squares amplitude of `shape` (peak 1) over `pattern − baseline`."""
    return float(np.sum(shape * (pattern - baseline)) / np.sum(shape * shape))


def _hd_shape(n_theta: int, heading_rad: float, width_rad: float) -> np.ndarray:
    theta = _TAU * np.arange(n_theta) / n_theta
    return np.exp(-(_wrap_period(theta - heading_rad, _TAU) ** 2) / (2.0 * width_rad**2))


def _grid_shape(
    n_theta: int, k: int, phase_rad: tuple[float, float], width_rad: tuple[float, float]
) -> np.ndarray:
    """Periodic Gaussian of peak 1, shape (N, N) = (θy, θx)."""
    theta = _TAU * np.arange(n_theta) / n_theta
    period = _TAU / k
    gx = np.exp(-(_wrap_period(theta - phase_rad[0], period) ** 2) / (2.0 * width_rad[0] ** 2))
    gy = np.exp(-(_wrap_period(theta - phase_rad[1], period) ** 2) / (2.0 * width_rad[1] ** 2))
    return np.outer(gy, gx)


def _encode_hd(profile: np.ndarray) -> list[float]:
    baseline = float(profile.min())
    weights = profile - baseline
    if not np.sum(weights) > 0:  # a flat profile: no bump, only the baseline
        return [0.0, math.pi, 0.0, baseline]
    heading, width = _phase_and_width(weights, profile.size, 1)
    amplitude = _fit_amplitude(profile, _hd_shape(profile.size, heading, width), baseline)
    return [heading, width, amplitude, baseline]


def _encode_grid(pattern: np.ndarray, k: int) -> list[float]:
    n = pattern.shape[0]
    cell = n // k
    # Mean over the k² lattice copies: the unit cell the module integrates (GridModule::fold).
    folded = pattern.reshape(k, cell, k, cell).mean(axis=(0, 2))
    baseline = float(folded.min())
    weights = folded - baseline
    if not np.sum(weights) > 0:
        return [0.0, 0.0, math.pi / k, math.pi / k, 0.0, baseline]
    phase_x, width_x = _phase_and_width(weights.sum(axis=0), n, k)
    phase_y, width_y = _phase_and_width(weights.sum(axis=1), n, k)
    shape = _grid_shape(n, k, (phase_x, phase_y), (width_x, width_y))
    amplitude = _fit_amplitude(pattern, shape, baseline)
    return [phase_x, phase_y, width_x, width_y, amplitude, baseline]


class CompactView:
    """A stored view in 22 float32 numbers (88 bytes), regenerating `ViewPatterns` for injection.

    Build it with `CompactView.from_engine(engine)` right after the step on which the view cell is created
    (or `from_patterns` to compress full stored patterns); inject `view.patterns(strength)`.
    """

    __slots__ = ("_grid_n_theta", "_hd_n_theta", "_ks", "_values")

    def __init__(self, values: np.ndarray, hd_n_theta: int, grid_n_theta: int, ks: Sequence[int]) -> None:
        values = np.asarray(values, dtype=np.float32)
        expected = _HD_FIELDS + _GRID_FIELDS * len(ks)
        if values.shape != (expected,):
            raise HippoNavError(
                f"compact view values have shape {values.shape}, expected ({expected},) for {len(ks)} modules"
            )
        if not (hd_n_theta > 0 and grid_n_theta > 0 and all(k > 0 and grid_n_theta % k == 0 for k in ks)):
            raise HippoNavError(
                f"bad compact view sizes: hd_n_theta={hd_n_theta}, grid_n_theta={grid_n_theta}, k={list(ks)} "
                "(need positive sizes and N a multiple of every k)"
            )
        if not np.isfinite(values[:_HD_FIELDS]).all():
            raise HippoNavError("compact view HD code is not finite")
        self._values = values
        self._values.flags.writeable = False
        self._hd_n_theta = int(hd_n_theta)
        self._grid_n_theta = int(grid_n_theta)
        self._ks = tuple(int(k) for k in ks)

    @classmethod
    def from_patterns(
        cls, patterns: ViewPatterns, ks: Sequence[int], lesioned: Sequence[bool] | None = None
    ) -> CompactView:
        """Compress full patterns (an HD θ-profile and one N×N layer-II pattern per module, None for a
        module that stores nothing); `ks` are the modules' wave numbers, `lesioned` marks modules to skip."""
        hd = np.asarray(patterns.hd_profile, dtype=np.float64)
        if hd.ndim != 1 or hd.size < 4 or not np.isfinite(hd).all():
            raise HippoNavError(f"HD profile must be a finite 1-D array of ≥ 4 units, got shape {hd.shape}")
        if len(patterns.grid_layer2) != len(ks):
            raise HippoNavError(f"{len(patterns.grid_layer2)} grid patterns for {len(ks)} modules")
        skip = list(lesioned) if lesioned is not None else [False] * len(ks)
        values = _encode_hd(hd)
        n_theta = 0
        for pattern, k, off in zip(patterns.grid_layer2, ks, skip):
            if pattern is None or off:
                values += [math.nan] * _GRID_FIELDS
                continue
            g = np.asarray(pattern, dtype=np.float64)
            if g.ndim != 2 or g.shape[0] != g.shape[1] or g.shape[0] % k or not np.isfinite(g).all():
                raise HippoNavError(
                    f"layer-II pattern of module k={k} must be a finite square array with a side that k "
                    f"divides, got shape {g.shape}"
                )
            if n_theta and g.shape[0] != n_theta:
                raise HippoNavError("every layer-II pattern must have the same size (one shared torus)")
            n_theta = g.shape[0]
            values += _encode_grid(g, k)
        return cls(np.array(values), hd.size, n_theta or math.lcm(*ks), ks)

    @classmethod
    def from_engine(cls, engine: SpatialMemory) -> CompactView:
        """The view of the engine's current state (what a new view cell stores); lesioned modules store
        nothing."""
        lesioned = [m.lesioned for m in engine.readout().modules]
        ks = [g.k for g in engine.config.grid]
        patterns = ViewPatterns(
            hd_profile=engine.hd_profile(),
            grid_layer2=[None if off else engine.grid_layer2(i) for i, off in enumerate(lesioned)],
        )
        return cls.from_patterns(patterns, ks, lesioned)

    @property
    def hd(self) -> HdBumpCode:
        v = self._values[:_HD_FIELDS].tolist()
        return HdBumpCode(*v)

    @property
    def modules(self) -> list[GridBumpCode | None]:
        """One code per grid module, coarsest first; None for a module that stores nothing."""
        out: list[GridBumpCode | None] = []
        for i, k in enumerate(self._ks):
            v = self._values[_HD_FIELDS + i * _GRID_FIELDS : _HD_FIELDS + (i + 1) * _GRID_FIELDS].tolist()
            if math.isnan(v[0]):
                out.append(None)
            else:
                out.append(GridBumpCode(k, (v[0], v[1]), (v[2], v[3]), v[4], v[5]))
        return out

    @property
    def values(self) -> np.ndarray:
        """The stored codes (read-only float32): HD fields, then each module's (NaN for one storing nothing)."""
        return self._values

    @property
    def sizes(self) -> tuple[int, int, tuple[int, ...]]:
        """(Nθ of the HD ring, N of the grid torus, the modules' k): the engine's, shared by all views."""
        return self._hd_n_theta, self._grid_n_theta, self._ks

    @property
    def nbytes(self) -> int:
        """Bytes of the stored codes (float32); the sizes Nθ, N and k are the engine's, shared by all views."""
        return self._values.nbytes

    def hd_profile(self, heading_offset_rad: float = 0.0) -> np.ndarray:
        """The HD θ-profile (Nθ,), float64; `heading_offset_rad` turns the bump counter-clockwise (e.g.
        by a view match's relative heading: the camera faces that much further than when stored)."""
        code = self.hd
        shape = _hd_shape(self._hd_n_theta, code.heading_rad + heading_offset_rad, code.width_rad)
        return code.baseline + code.amplitude * shape

    def grid_layer2(self, module: int, shift_rad: tuple[float, float] = (0.0, 0.0)) -> np.ndarray | None:
        """Module `module`'s layer-II pattern (N, N) = (θy, θx), float64; None if it stores nothing.
        `shift_rad` moves the bump along (θx, θy): every module's bumps move alike on the shared torus, by
        `2π·d/torus_period_m` for a displacement d in the engine's frame (docs/spec.md §3)."""
        if not 0 <= module < len(self._ks):
            raise HippoNavError(f"module index {module} out of range (there are {len(self._ks)})")
        code = self.modules[module]
        if code is None:
            return None
        phase = (code.phase_rad[0] + shift_rad[0], code.phase_rad[1] + shift_rad[1])
        shape = _grid_shape(self._grid_n_theta, code.k, phase, code.width_rad)
        return code.baseline + code.amplitude * shape

    def patterns(
        self,
        strength: float = 1.0,
        heading_offset_rad: float = 0.0,
        shift_rad: tuple[float, float] = (0.0, 0.0),
    ) -> ViewPatterns:
        """The patterns to inject, at `strength` (see `hd_profile` for `heading_offset_rad`, `grid_layer2`
        for `shift_rad`)."""
        return ViewPatterns(
            hd_profile=self.hd_profile(heading_offset_rad),
            grid_layer2=[self.grid_layer2(i, shift_rad) for i in range(len(self._ks))],
            strength=float(strength),
        )

    def __repr__(self) -> str:
        hd = self.hd
        mods = ", ".join(
            "None"
            if m is None
            else f"k={m.k} φ=({m.phase_rad[0]:.3f}, {m.phase_rad[1]:.3f}) σ=({m.width_rad[0]:.3f}, "
            f"{m.width_rad[1]:.3f}) A={m.amplitude:.3g}"
            for m in self.modules
        )
        return f"CompactView(heading={hd.heading_rad:.3f} rad, σ={hd.width_rad:.3f}, A={hd.amplitude:.3g}; {mods})"
