"""A procedurally textured street world around a trajectory, and an exact pinhole ray caster for it.

Geometry (world frame of the trajectory: KITTI camera-0 convention, x right, y down, z forward).
The path is the polyline of camera centres, simplified by Douglas–Peucker in 3-D (tolerance
`simplify_tolerance_m`). Each path segment AB sweeps a *capsule*: the horizontal (x–z) stadium of points
within `street_half_width_m` of AB. Free space is the union of the capsules; its boundary carries vertical,
infinitely tall facades. The ground under each capsule is the plane through A and B shifted down by
`camera_height_m`, tilted along AB and level across it. Everything is a function of world position only,
so every pass along a street, from either direction, sees the same facades and the same road: revisits look
the same, as in a real city. (`appearance.py` makes passes differ on purpose — light, shadows, posters, parked
cars — on top of this street; docs/render.md.)

Ray casting (per pixel, vectorised over pixels × nearby capsules). A ray c + s·D is parametrised by its
horizontal distance s (D = d / |d_xz|). For capsule k its entry/exit interval [in_k, out_k] is the hull of
the intervals of its rectangle and its two end discs (a capsule is convex). The facade hit is the end of
the connected union of intervals that contains s = 0 (fixed-point iteration s ← max{out_k : in_k ≤ s < out_k}).
The ground hit is the nearest plane intersection of a capsule that lies inside that capsule's interval and
before the facade. Both are closed-form, so projections are exact to floating-point precision and a point
seen by the left and right cameras (or by two frames) is the same world point: stereo and motion are
geometrically exact.

Texture. Intensity is a smooth function of the world point (facades, ground) or of the ray direction
(the sky beyond `max_range_m`): sums of random 3-D plane waves (wavelengths 0.2–6 m) whose mix varies with
position through 40–150 m "district" waves, plus a window grid on facades. Each wave is attenuated by a
Gaussian prefilter of the pixel footprint (range / (f · |cos incidence|)), so the image is band-limited:
no aliasing or flicker, and features localise to sub-pixel accuracy. All random choices come from `seed`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hippo_nav.io.errors import DatasetError

_DOWN = np.array([0.0, 1.0, 0.0])  # world "down" (KITTI y axis)


def simplify_polyline(points: np.ndarray, tolerance_m: float) -> np.ndarray:
    """Indices of the Douglas–Peucker simplification of a 3-D polyline (first and last always kept)."""
    keep = np.zeros(len(points), dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(points) - 1)]
    while stack:
        lo, hi = stack.pop()
        if hi - lo < 2:
            continue
        a, b = points[lo], points[hi]
        ab = b - a
        length2 = float(ab @ ab)
        rel = points[lo + 1 : hi] - a
        if length2 > 0:
            t = np.clip(rel @ ab / length2, 0.0, 1.0)
            dist = np.linalg.norm(rel - t[:, None] * ab, axis=1)
        else:
            dist = np.linalg.norm(rel, axis=1)
        worst = int(np.argmax(dist))
        if dist[worst] > tolerance_m:
            mid = lo + 1 + worst
            keep[mid] = True
            stack.append((lo, mid))
            stack.append((mid, hi))
    return np.flatnonzero(keep)


@dataclass(frozen=True)
class _WaveBank:
    """Sum of plane waves Σ aᵢ cos(kᵢ·p + φᵢ), each attenuated by a Gaussian footprint prefilter."""

    wavevectors: np.ndarray  # (3, M) rad per unit
    phases: np.ndarray  # (M,)
    amplitudes: np.ndarray  # (M,)
    wavenumbers: np.ndarray  # (M,) |k|

    @staticmethod
    def random(
        rng: np.random.Generator, count: int, wavelength_range: tuple[float, float], dims: int = 3
    ) -> _WaveBank:
        wavelengths = np.exp(rng.uniform(np.log(wavelength_range[0]), np.log(wavelength_range[1]), count))
        directions = rng.normal(size=(3, count))
        if dims == 2:  # horizontal waves only (x, z): a texture painted on the ground
            directions[1] = 0.0
        directions /= np.linalg.norm(directions, axis=0)
        wavenumbers = 2 * np.pi / wavelengths
        # A mildly red spectrum: coarse waves a bit stronger, fine ones still visible close up.
        amplitudes = wavelengths**0.35
        amplitudes /= np.sqrt(np.sum(amplitudes**2) / 2)
        return _WaveBank(directions * wavenumbers, rng.uniform(0, 2 * np.pi, count), amplitudes, wavenumbers)

    def __call__(self, points: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        # Phases are formed in float64 about a local origin (world coordinates reach kilometres), so the
        # per-pixel work runs in float32, in place: this loop is most of the rendering time.
        origin = points[0] if len(points) else np.zeros(3)
        phase = np.mod(origin @ self.wavevectors + self.phases, 2 * np.pi)
        local = np.empty((len(points), 4), dtype=np.float32)
        local[:, :3] = points - origin
        local[:, 3] = 1.0  # carries the phase through the matrix product
        waves = np.vstack([self.wavevectors, phase]).astype(np.float32)
        # Prefilter σ = footprint/2: gain exp(−σ²k²/2), so waves shorter than ~2 pixels fade to their mean.
        k2 = (self.wavenumbers**2).astype(np.float32)
        gain = np.multiply.outer((-0.125 * footprint * footprint).astype(np.float32), k2)
        np.exp(gain, out=gain)
        arg = local @ waves
        np.cos(arg, out=arg)
        gain *= arg
        return (gain @ self.amplitudes.astype(np.float32)).astype(np.float64)


def _smooth_box(x: np.ndarray, lo: float, hi: float, width: np.ndarray) -> np.ndarray:
    """≈1 inside [lo, hi] of a unit period, 0 outside, with edges `width` wide (anti-aliased)."""
    rise = np.clip((x - lo) / width + 0.5, 0.0, 1.0)
    fall = np.clip((hi - x) / width + 0.5, 0.0, 1.0)
    return rise * fall


_POLE_RADIUS_M = 0.25
_POLE_CELL_M = 5.0  # one candidate post per cell of this grid (world-fixed)
_POLE_BAND_M = (1.0, 2.5)  # posts stand this far in from the facades


def _pole_positions(seg_a: np.ndarray, seg_b: np.ndarray, half_width_m: float) -> np.ndarray:
    """(K, 2) horizontal (x, z) centres of the posts: one candidate per `_POLE_CELL_M` cell of a world-fixed
    grid, placed in its cell by a hash of the cell's integer coordinates (so a post depends on its world
    position only, never on the trajectory's extent or order), kept where its distance to the street's axis
    (the nearest path segment) puts it `_POLE_BAND_M` in from the facade: on a pavement, off every lane."""
    a, b = seg_a[:, [0, 2]], seg_b[:, [0, 2]]
    lo = np.floor((np.minimum(a, b).min(0) - half_width_m) / _POLE_CELL_M).astype(np.int64)
    hi = np.ceil((np.maximum(a, b).max(0) + half_width_m) / _POLE_CELL_M).astype(np.int64)
    grid_i, grid_j = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]), indexing="ij")
    ii, jj = grid_i.ravel().astype(np.float64), grid_j.ravel().astype(np.float64)

    def unit_hash(k: float) -> np.ndarray:
        return np.modf(np.abs(np.sin(ii * 12.9898 + jj * 78.233 + k) * 43758.5453))[0]

    centres = np.stack([ii + unit_hash(0.0), jj + unit_hash(1.7)], axis=1) * _POLE_CELL_M
    # Distance to the nearest segment, in chunks of segments (a long drive has thousands).
    nearest = np.full(len(centres), np.inf)
    ab = b - a
    length2 = np.maximum((ab * ab).sum(1), 1e-12)
    for start in range(0, len(a), 256):
        sl = slice(start, start + 256)
        rel = centres[:, None, :] - a[None, sl]
        t = np.clip((rel * ab[None, sl]).sum(2) / length2[None, sl], 0.0, 1.0)
        d = np.linalg.norm(rel - t[..., None] * ab[None, sl], axis=2)
        nearest = np.minimum(nearest, d.min(1))
    keep = (nearest >= half_width_m - _POLE_BAND_M[1]) & (nearest <= half_width_m - _POLE_BAND_M[0])
    return centres[keep]


class StreetWorld:
    """The textured street around `path_m` (N, 3 camera centres); see the module doc."""

    def __init__(
        self,
        path_m: np.ndarray,
        *,
        street_half_width_m: float = 7.0,
        camera_height_m: float = 1.65,
        max_range_m: float = 90.0,
        simplify_tolerance_m: float = 0.1,
        seed: int = 0,
        poles: bool = False,
    ) -> None:
        path = np.asarray(path_m, dtype=np.float64).reshape(-1, 3)
        if len(path) == 0 or not np.all(np.isfinite(path)):
            raise DatasetError("the trajectory is empty or holds NaN/inf positions")
        if street_half_width_m <= 1.0 or camera_height_m <= 0 or max_range_m <= street_half_width_m:
            raise DatasetError(
                "street_half_width_m must exceed 1 m (the right camera must fit), camera_height_m must be "
                "positive and max_range_m larger than the street half width"
            )
        self.street_half_width_m = float(street_half_width_m)
        self._max_climb = -0.25  # steepest road slope considered (dy per metre, y down)
        self.camera_height_m = float(camera_height_m)
        self.max_range_m = float(max_range_m)
        vertices = path[simplify_polyline(path, simplify_tolerance_m)] if len(path) > 1 else path
        if len(vertices) == 1:
            vertices = np.vstack([vertices, vertices])  # a parked camera: a round plaza
        self.seg_a = vertices[:-1]
        self.seg_b = vertices[1:]
        ab = (self.seg_b - self.seg_a)[:, [0, 2]]
        self.seg_length = np.linalg.norm(ab, axis=1)
        safe = np.where(self.seg_length > 1e-9, self.seg_length, 1.0)
        self.seg_dir = np.where(self.seg_length[:, None] > 1e-9, ab / safe[:, None], [1.0, 0.0])
        # Ground plane normal: across the segment it is level, along it it follows the road's slope.
        along = self.seg_b - self.seg_a
        across = np.stack([self.seg_dir[:, 1], np.zeros(len(ab)), -self.seg_dir[:, 0]], axis=1)
        normal = np.cross(along, across)
        norm = np.linalg.norm(normal, axis=1)
        self.ground_normal = np.where(
            norm[:, None] > 1e-9, normal / np.where(norm > 0, norm, 1)[:, None], _DOWN
        )

        # Street furniture (`poles`): vertical posts on the pavements, where a real street has trees, lamp
        # posts and signs. Walls alone give a street no structure along its length (a straight street seen
        # from above is two parallel lines); posts do, in either direction of travel.
        self.poles_xz = _pole_positions(self.seg_a, self.seg_b, self.street_half_width_m) if poles else None

        rng = np.random.default_rng(seed)
        self._facade_fine = _WaveBank.random(rng, 16, (0.2, 1.5))
        self._facade_coarse = _WaveBank.random(rng, 10, (0.8, 6.0))
        self._ground_fine = _WaveBank.random(rng, 16, (0.12, 1.0), dims=2)
        self._ground_coarse = _WaveBank.random(rng, 10, (0.6, 5.0), dims=2)
        self._district = _WaveBank.random(rng, 4, (40.0, 150.0), dims=2)
        self._sky = _WaveBank.random(rng, 16, (0.04, 0.6))  # wavelengths in radians of direction
        self._window_period_m = rng.uniform(2.2, 4.0, size=2)

    # ----------------------------------------------------------------------------------- ray casting
    def _capsules_near(self, centre: np.ndarray, ray_dirs_xz: np.ndarray) -> np.ndarray:
        """Capsules a ray can meet: segment within max range, and not wholly behind a forward-looking camera."""
        rel = centre[[0, 2]] - self.seg_a[:, [0, 2]]
        t = np.clip(np.einsum("kj,kj->k", rel, self.seg_dir), 0.0, self.seg_length)
        dist = np.linalg.norm(rel - t[:, None] * self.seg_dir, axis=1)
        keep = dist < self.max_range_m + self.street_half_width_m
        forward = ray_dirs_xz.mean(0)
        forward /= max(np.linalg.norm(forward), 1e-12)
        if (ray_dirs_xz @ forward).min() > 0:
            # Every ray advances along `forward`, so a capsule lying wholly behind the camera (both ends
            # more than a half width behind) can hold no point of any ray.
            behind = -self.street_half_width_m - 1e-6
            ahead_a = (self.seg_a[:, [0, 2]] - centre[[0, 2]]) @ forward
            ahead_b = (self.seg_b[:, [0, 2]] - centre[[0, 2]]) @ forward
            keep &= (ahead_a > behind) | (ahead_b > behind)
        return np.flatnonzero(keep)

    def _intervals(self, near: np.ndarray, centre_m: np.ndarray, e: np.ndarray):
        """Per horizontal ray direction e (Q, 2) and capsule: [in, out] and the facade distance s_wall."""
        half_width = self.street_half_width_m
        a = self.seg_a[near][:, [0, 2]] - centre_m[[0, 2]]  # (K, 2) capsule ends, camera-relative
        b = self.seg_b[near][:, [0, 2]] - centre_m[[0, 2]]
        u = self.seg_dir[near]
        v = np.stack([-u[:, 1], u[:, 0]], axis=1)
        length = self.seg_length[near]

        def slab(offset: np.ndarray, rate: np.ndarray, lo, hi):
            # s where offset + s·rate crosses [lo, hi]; a near-zero rate gives an interval at ±1e12
            # that is either the whole line (inside) or far outside the range (outside).
            rate = np.where(np.abs(rate) < 1e-12, 1e-12, rate)
            s1, s2 = (lo - offset) / rate, (hi - offset) / rate
            return np.minimum(s1, s2), np.maximum(s1, s2)

        lo_m, hi_m = slab(-(a * u).sum(1), e @ u.T, 0.0, length)
        lo_l, hi_l = slab(-(a * v).sum(1), e @ v.T, -half_width, half_width)
        rect_in, rect_out = np.maximum(lo_m, lo_l), np.minimum(hi_m, hi_l)
        empty = rect_in >= rect_out
        cap_in = np.where(empty, np.inf, rect_in)
        cap_out = np.where(empty, -np.inf, rect_out)
        for end in (a, b):
            proj = e @ end.T
            disc = proj * proj - ((end * end).sum(1) - half_width * half_width)
            hit = disc >= 0
            root = np.sqrt(np.where(hit, disc, 0.0))
            cap_in = np.where(hit, np.minimum(cap_in, proj - root), cap_in)
            cap_out = np.where(hit, np.maximum(cap_out, proj + root), cap_out)

        # The facade: end of the connected union of capsule intervals that holds the camera (s = 0).
        s_wall = np.zeros(len(e))
        for _ in range(64):
            reach = np.where(
                (cap_in <= s_wall[:, None] + 1e-9) & (cap_out > s_wall[:, None]), cap_out, -np.inf
            )
            s_next = np.maximum(s_wall, reach.max(1))
            if np.array_equal(s_next, s_wall):
                break
            s_wall = s_next

        # Facade normal: from the nearest point of the capsule that bounds the ray, towards the street.
        bound = np.argmin(np.abs(cap_out - s_wall[:, None]), axis=1)
        rel = s_wall[:, None] * e - a[bound]
        along = np.clip((rel * u[bound]).sum(1), 0.0, length[bound])
        outward = rel - along[:, None] * u[bound]
        outward /= np.maximum(np.linalg.norm(outward, axis=1), 1e-9)[:, None]
        if self.poles_xz is not None and len(self.poles_xz):
            # A post in front of the facade hides it: the nearest circle the ray enters (from outside).
            c = self.poles_xz - centre_m[[0, 2]]
            c = c[np.einsum("kj,kj->k", c, c) < (self.max_range_m + _POLE_RADIUS_M) ** 2]
            if len(c):
                proj = e @ c.T
                disc = proj * proj - ((c * c).sum(1) - _POLE_RADIUS_M**2)
                enter = proj - np.sqrt(np.maximum(disc, 0.0))
                enter = np.where((disc >= 0) & (enter > 1e-6), enter, np.inf)
                k = np.argmin(enter, axis=1)
                s_pole = enter[np.arange(len(e)), k]
                hit = s_pole < s_wall
                if hit.any():
                    into = c[k[hit]] - s_pole[hit, None] * e[hit]  # from the hit into the post
                    outward[hit] = into / _POLE_RADIUS_M
                    s_wall = np.where(hit, s_pole, s_wall)
        return cap_in, cap_out, s_wall, outward, bound

    def cast(
        self, centre_m: np.ndarray, directions: np.ndarray, level_columns: int = 0
    ) -> dict[str, np.ndarray]:
        """Cast rays from `centre_m` along `directions` (P, 3): hit kind (0 sky, 1 ground, 2 facade), range,
        point, surface normal (pointing away from the street: down for the road, into the building for a
        facade) and the path segment of the hit.

        `level_columns` = W > 0 says the rays are a row-major (H, W) image of a level camera (no roll or
        pitch), so every column shares one horizontal direction and the 2-D part is solved once per
        column; the result is identical, only faster.
        """
        horizontal = np.maximum(np.hypot(directions[:, 0], directions[:, 2]), 1e-12)
        step = directions / horizontal[:, None]  # advance per metre of horizontal distance
        near = self._capsules_near(centre_m, step[:, [0, 2]])
        if near.size == 0:
            raise DatasetError("the camera is outside the synthetic world (no street within range)")
        normal = self.ground_normal[near]
        anchor = self.seg_a[near] + self.camera_height_m * _DOWN - centre_m
        n_rays = len(step)
        if level_columns:
            # One horizontal direction per column: solve the 2-D part per column, index it per ray.
            ray_q = np.tile(np.arange(level_columns), n_rays // level_columns)
            cap_in, cap_out, s_wall_q, outward_q, bound_q = self._intervals(
                near, centre_m, step[:level_columns, [0, 2]]
            )
        else:
            ray_q = np.arange(n_rays)
            cap_in, cap_out, s_wall_q, outward_q, bound_q = self._intervals(near, centre_m, step[:, [0, 2]])
        s_wall, outward = s_wall_q[ray_q], outward_q[ray_q]

        # The ground: nearest capsule plane crossed inside that capsule and before the facade. Only the
        # few capsules a direction passes through before the facade can hold its ground hit: compact them.
        relevant = (cap_in < s_wall_q[:, None] + 1e-9) & (cap_out > 0)
        width = max(int(relevant.sum(1).max()), 1)
        order = np.argsort(~relevant, axis=1, kind="stable")[:, :width]  # (Q, width) indices into `near`
        kept = np.take_along_axis(relevant, order, axis=1)
        lo = np.where(kept, np.take_along_axis(cap_in, order, axis=1), np.inf)
        hi = np.where(kept, np.take_along_axis(cap_out, order, axis=1), -np.inf)
        offset = (anchor * normal).sum(1)[order]
        # Rays climbing faster than any road (here 1:4) cannot meet it.
        rays = np.flatnonzero(step[:, 1] > self._max_climb)
        q = ray_q[rays]
        denom = np.einsum("rj,rkj->rk", step[rays], normal[order[q]])
        s_plane = offset[q] / np.where(np.abs(denom) < 1e-12, 1e-12, denom)
        valid = (s_plane > 1e-6) & (s_plane >= lo[q] - 1e-9) & (s_plane <= hi[q] + 1e-9)
        s_plane = np.where(valid, s_plane, np.inf)
        ground_idx = np.zeros(n_rays, dtype=np.int64)
        s_ground = np.full(n_rays, np.inf)
        if len(rays):
            best = np.argmin(s_plane, axis=1)
            ground_idx[rays] = order[q, best]
            s_ground[rays] = s_plane[np.arange(len(rays)), best]

        step_norm = np.linalg.norm(step, axis=1)
        kind = np.where(s_ground < s_wall, 1, 2)  # 1 ground, 2 facade, 0 sky (beyond max range)
        s_hit = np.minimum(s_ground, s_wall)
        kind = np.where(s_hit * step_norm > self.max_range_m, 0, kind)
        s_hit = np.where(kind == 0, self.max_range_m / step_norm, s_hit)
        facade_normal = np.stack([outward[:, 0], np.zeros(len(outward)), outward[:, 1]], axis=1)
        surface_normal = np.where((kind == 1)[:, None], normal[ground_idx], facade_normal)
        return {
            "kind": kind,
            "range_m": s_hit * step_norm,
            "points": centre_m + s_hit[:, None] * step,
            "normals": surface_normal,
            # The path segment whose capsule holds the hit (its road plane, or the facade it bounds).
            "segment": near[np.where(kind == 1, ground_idx, bound_q[ray_q])],
        }

    # ----------------------------------------------------------------------------------- shading
    def shade(
        self,
        hits: dict[str, np.ndarray],
        directions: np.ndarray,
        focal_px: float,
        surface: Callable[[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray], np.ndarray]
        | None = None,
        sky_gain: float = 1.0,
    ) -> np.ndarray:
        """Gray level (float, ~0–255) of each ray's hit.

        `surface(hits, unit_directions, footprint_m, value)` (appearance, `synthetic/appearance.py`) may
        change the surfaces' gray levels before the fog is laid over them; `sky_gain` scales the sky (and so
        the fog's colour). Without them the street looks as it always has."""
        kind, points, normals, range_m = hits["kind"], hits["points"], hits["normals"], hits["range_m"]
        unit = directions / np.linalg.norm(directions, axis=1)[:, None]
        cos_incidence = np.maximum(np.abs((unit * normals).sum(1)), 0.08)
        footprint = range_m / (focal_px * cos_incidence)
        district = np.tanh(1.5 * self._district(points, np.zeros(len(points))))  # −1..1, slowly varying
        mix = 0.5 + 0.5 * district
        value = np.full(len(points), 128.0)

        facade = kind == 2
        if facade.any():
            p, fp, m = points[facade], footprint[facade], mix[facade]
            n = normals[facade]
            texture = m * self._facade_fine(p, fp) + (1 - m) * self._facade_coarse(p, fp)
            shade = 128 + 25 * district[facade] + 70 * np.tanh(0.9 * texture)
            # Windows: a grid in (along-facade, height); the period depends on the district.
            tangent = np.stack([-n[:, 2], n[:, 0]], axis=1)
            along = (p[:, [0, 2]] * tangent).sum(1)
            period = np.where(m > 0.5, self._window_period_m[0], self._window_period_m[1])
            col, row = along / period, p[:, 1] / 3.0
            width_col, width_row = np.maximum(fp / period, 0.02), np.maximum(fp / 3.0, 0.02)
            window = _smooth_box(col - np.floor(col), 0.25, 0.75, width_col) * _smooth_box(
                row - np.floor(row), 0.3, 0.8, width_row
            )
            tone = 45 + 30 * np.cos(np.floor(col) * 12.9898 + np.floor(row) * 78.233)
            contrast = np.exp(-((fp / period) ** 2) * 4)  # a far grid fades to its mean, not to moiré
            value[facade] = shade - window * tone * contrast
        ground = kind == 1
        if ground.any():
            p, fp, m = points[ground], footprint[ground], mix[ground]
            texture = m * self._ground_fine(p, fp) + (1 - m) * self._ground_coarse(p, fp)
            value[ground] = 110 - 15 * district[ground] + 60 * np.tanh(0.9 * texture)
        if surface is not None:
            value = surface(hits, unit, footprint, value)
        # Fog over the last 30 % of the range hides the range cut-off (it would be an edge that moves).
        fog = np.clip((range_m - 0.7 * self.max_range_m) / (0.3 * self.max_range_m), 0.0, 1.0)
        fog = np.where(kind == 0, 1.0, fog * fog * (3 - 2 * fog))
        misty = fog > 0
        if misty.any():
            sky = self._sky(unit[misty], np.full(int(misty.sum()), 1.0 / focal_px))
            sky_value = 170 + 35 * np.tanh(sky)
            if sky_gain != 1.0:
                sky_value = sky_gain * sky_value
            value[misty] = (1 - fog[misty]) * value[misty] + fog[misty] * sky_value
        return value

    @staticmethod
    def rays(
        world_from_camera: np.ndarray, K: np.ndarray, image_size_px: tuple[int, int]
    ) -> tuple[np.ndarray, int]:
        """World directions (H·W, 3) of the pixels of a pinhole camera (pixel centres at integer coordinates,
        row-major), and `level_columns` for `cast` (the width for a level camera, else 0)."""
        width, height = image_size_px
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        rays_camera = np.stack(
            [(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1], np.ones(u.size)], axis=1
        )
        rays_camera[:, 0] -= K[0, 1] * rays_camera[:, 1] / K[0, 0]  # skew, zero for KITTI-style K
        directions = rays_camera @ world_from_camera[:3, :3].T
        rotation = world_from_camera[:3, :3]
        level = abs(rotation[1, 0]) < 1e-12 and abs(rotation[1, 2]) < 1e-12 and K[0, 1] == 0
        return directions, width if level else 0

    def render(
        self, world_from_camera: np.ndarray, K: np.ndarray, image_size_px: tuple[int, int]
    ) -> np.ndarray:
        """Render one (H, W) uint8 image of a pinhole camera (pixel centres at integer coordinates)."""
        width, height = image_size_px
        directions, level_columns = self.rays(world_from_camera, K, image_size_px)
        hits = self.cast(world_from_camera[:3, 3], directions, level_columns=level_columns)
        gray = self.shade(hits, directions, float(K[0, 0]))
        return np.clip(np.rint(gray), 0, 255).astype(np.uint8).reshape(height, width)
