"""Bird's-eye submaps: a heading-invariant description of a place from stereo depth, and its registration.

A view cell is directional: driven the other way, a street shows a forward camera other images and no view is
familiar (KITTI 08). Its 3-D structure is the same from either direction, and a stereo camera measures it. So a
place is also described from above (docs/map.md, "Bird's-eye closures"):

- **Structure points.** The stereo points a vertex's keyframe already keeps (`keyframes.py`) that stand above
  the road (`min_height_m` over a road `camera_height_m` below the camera) and lie within
  `max_depth_m` (farther stereo depths are metres uncertain), dropped to the plane of the map:
  (forward, left) in the vertex's frame. Nothing more is stored per vertex.
- **Submap.** The structure points of the vertices within a stretch of path, placed by the map's vertex poses
  (locally as good as the odometry) in the frame of one vertex (`Submap`). A stored place uses the vertices
  `submap_m / 2` on either side of it; the query, the newest vertex, the `submap_m` behind it.
- **Weights** (`structure_weights`): each point weighs by how isotropic the structure around it is (the
  structure tensor of the blurred occupancy, least over greatest eigenvalue): a wall's points little, a post's,
  a corner's or a junction's fully, so that what tells stretches of street apart decides the registration.
- **Search** (`BirdsEyeSearch`): the query is registered at once onto the map's whole structure around where the
  odometry puts it (`search_m`, `search_rad`, or the loop gate if smaller): one correlation
  per heading over that area, so the peak must stand out from every other place the agent may be, not from a
  few ranked candidates. The place found is then registered again onto the submap of the old vertex nearest to
  it (far from that vertex the old stretch bends with the odometry's drift); that is the measurement.
- **Self-similarity** (`self_similarity`): a straight street of walls slides along itself, and no registration
  can place it along its length; such a submap (`max_self_similarity`) is not registered at all.
- **Registration** (`register`): an exhaustive rotation search (the headings the loop gate admits, in
  5° steps; every translation at once by FFT cross-correlation of blurred, weighted occupancy images at
  0.5 m) finds the alignment; Gauss–Newton on the target's distance transform refines it,
  and its Hessian gives the information. A registration is refused when the correlation peak is not distinct
  from the best alignment elsewhere (`min_peak_ratio`: a symmetric square or junction), when too few
  query points land on the target's structure (`min_overlap`, `min_inliers`), or when the
  refined pose is uncertain along some direction (0.3 m).
- **Confirmation** (`BirdsEyeSearch`, `confirm`): a registration is proposed only when an earlier one
  from another stretch of path implies the same correction of the map.
"""

from __future__ import annotations

import functools
import json
import logging
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection
from hippo_nav.closure.base import NO_ATTEMPT, ClosureAttempt, ClosureContext, ProposedClosure
from hippo_nav.geometry import se2_between, se2_compose, wrap_angle
from hippo_nav.map import MapFrameOutcome

log = logging.getLogger("hippo_nav.pipeline")

__all__ = [
    "BirdsEyeConfig",
    "BirdsEyeProposer",
    "BirdsEyeRegistration",
    "BirdsEyeSearch",
    "Submap",
    "register",
    "self_similarity",
    "structure_points",
    "submap",
]

# Fixed choices of the registration (docs/map.md, "Bird's-eye closures"):
_MAX_HEIGHT_M = 4.0  # structure points higher than this over the camera are left out
_ROTATIONS = 72  # headings of the rotation search (5° steps; the fine stage refines)
_COARSE_CELL_M = 0.5  # cell of the rotation search's occupancy images
_BLUR_M = 0.5  # Gaussian blur of those images (a point's stereo scatter)
_MAX_SHIFT_M = 15.0  # the search's reach without a prior
_INLIER_M = 0.75  # a registered point this close to target structure fits
_MAX_SIGMA_M = 0.3  # a registration less certain than this in some direction is refused
_POINT_SIGMA_M = 0.2  # least residual of a registered point
_COVARIANCE_INFLATION = 10.0  # the registration's points are not independent
_SIGMA_FLOOR_M, _SIGMA_FLOOR_RAD = 0.3, np.radians(1.0)  # a registration is no more certain than this
_PROBE_M = 5.0  # shift at which a submap's self-similarity is probed
_CONFIRM_WINDOW_M = 30.0  # travel within which two registrations confirm each other
_AGREEMENT_M, _AGREEMENT_RAD = 1.5, 0.05  # confirming registrations place the agent this close
_OFF_PATH_M = 8.0  # a registration this far from every old vertex is not on the old path
_LOCAL_REACH_M, _LOCAL_REACH_RAD = 3.0, 0.1  # the local registration's search around the place found

# The fine stage's distance-transform cell (m) and Gauss–Newton iterations.
_FINE_CELL_M = 0.2
_ITERATIONS = 12
# Query points farther than this (m) from any target structure are outside what the target saw: they are
# neither inliers nor count against the overlap.
_SHARED_M = 3.0
# Alignments this far apart (cells of the coarse image; rotation steps) count as "elsewhere" for the peak ratio.
_ELSEWHERE_CELLS = 3
_ELSEWHERE_STEPS = 3
# Structure weights on (`structure_weights`). Off, every point weighs 1: on the 08 render every search was then
# ambiguous and nothing closed (docs/results.md, "Reverse loops (08)"); kept to measure that again.
_WEIGHTED = True


class BirdsEyeConfig(ConfigSection):
    """`closure.birdseye`: bird's-eye submaps and their registration (module doc)."""

    model_config = ConfigDict(frozen=True)

    submap_m: float = Field(
        40.0, gt=0.0, description="path a submap spans: the query's behind it, a stored place's around it"
    )
    radius_m: float = Field(30.0, gt=0.0, description="a submap keeps points this close to its centre")
    max_depth_m: float = Field(
        15.0,
        gt=0.0,
        description="stereo points deeper than this are left out: a post seen from several vertices smears "
        "along the line of sight by its depth error (0.3 px of disparity is 0.7 m at 15 m on a 320-px render)",
    )
    camera_height_m: float = Field(1.65, gt=0.0, description="the camera's height over the road")
    min_height_m: float = Field(
        0.5, description="points lower than this over the road are road, and left out"
    )
    spacing_m: float = Field(
        3.0, gt=0.0, description="travel between bird's-eye attempts (one per new vertex at most)"
    )
    search_m: float = Field(
        40.0,
        gt=0.0,
        description="the registration searches the map this far around where the odometry puts the agent (or "
        "the loop gate, if smaller): the odometry's likely drift between closures, not the gate's bound",
    )
    search_rad: float = Field(
        0.35,
        gt=0.0,
        description="… and within this heading of the odometry's (or the loop gate's, if smaller)",
    )
    min_points: int = Field(
        150,
        ge=10,
        le=100_000,
        description="a submap with fewer structure points neither proposes nor is proposed",
    )
    min_peak_ratio: float = Field(
        1.15, ge=1.0, description="the correlation peak over the best alignment elsewhere, at least"
    )
    min_inliers: int = Field(150, ge=3, le=100_000, description="fitting query points a registration needs")
    min_overlap: float = Field(
        0.5, ge=0.0, le=1.0, description="fitting share of the query points on the shared area, at least"
    )
    max_self_similarity: float = Field(
        1.0,
        ge=0.0,
        le=1.0,
        description="a submap whose structure correlates with itself shifted 5 m more than this slides along "
        "itself (a straight street of walls) and is not registered",
    )
    confirm: bool = Field(
        True,
        description="a bird's-eye registration is proposed only when an earlier one, from another stretch of "
        "path within 30 m of travel, implies the same correction of the map (within 1.5 m and 0.05 rad)",
    )


def structure_points(points_camera_m: np.ndarray, config) -> np.ndarray:
    """(n, 2) float32 planar (forward, left) points of a keyframe's camera-frame stereo points (x right,
    y down, z forward) that stand above the road and lie within `max_depth_m` (module doc)."""
    p = np.asarray(points_camera_m, dtype=np.float32).reshape(-1, 3)
    height_m = -p[:, 1]  # above the camera
    keep = (
        (p[:, 2] > 0.5)
        & (p[:, 2] <= config.max_depth_m)
        & (height_m >= config.min_height_m - config.camera_height_m)
        & (height_m <= _MAX_HEIGHT_M)
    )
    return np.stack([p[keep, 2], -p[keep, 0]], axis=1).astype(np.float32)


@dataclass(frozen=True)
class Submap:
    """Structure points (n, 2) float32 (forward, left) in the frame of its centre vertex, within
    `radius_m` of it."""

    points_m: np.ndarray
    radius_m: float

    def __len__(self) -> int:
        return len(self.points_m)

    @cached_property
    def weights(self) -> np.ndarray:
        """`structure_weights` of its points (computed once: a query is registered twice)."""
        return structure_weights(self.points_m, self.radius_m)


def submap(
    centre_pose: np.ndarray, member_poses: np.ndarray, member_points: list[np.ndarray], radius_m: float
) -> Submap:
    """The members' structure points (each in its own vertex's frame, `member_poses` (k, 3) world poses)
    placed in the frame of `centre_pose` (world (x, y, yaw)), keeping those within `radius_m`."""
    parts = []
    c, s = np.cos(centre_pose[2]), np.sin(centre_pose[2])
    for pose, pts in zip(np.asarray(member_poses, np.float64).reshape(-1, 3), member_points):
        if not len(pts):
            continue
        cy, sy = np.cos(pose[2]), np.sin(pose[2])
        world = np.stack(
            [pose[0] + cy * pts[:, 0] - sy * pts[:, 1], pose[1] + sy * pts[:, 0] + cy * pts[:, 1]], axis=1
        )
        dx, dy = world[:, 0] - centre_pose[0], world[:, 1] - centre_pose[1]
        parts.append(np.stack([c * dx + s * dy, -s * dx + c * dy], axis=1))
    points = np.concatenate(parts).astype(np.float32) if parts else np.zeros((0, 2), np.float32)
    points = points[np.hypot(points[:, 0], points[:, 1]) <= radius_m]
    return Submap(points, float(radius_m))


def self_similarity(sub: Submap, cfg) -> float:
    """The submap's blurred occupancy correlated with itself shifted 5 m in the direction where
    that correlation is greatest, over its value unshifted: near 1 where the structure slides along itself (a
    straight street: walls and nothing across them), lower where a bend, a junction or a gap pins it down.
    A registration cannot be trusted along a direction the structure slides in (module doc)."""
    if not len(sub):
        return 1.0
    cell = _COARSE_CELL_M
    f, _, size = _blurred_occupancy_spectra(sub.points_m[None], sub.radius_m)
    auto = _correlations(f, f[0])[0].astype(np.float64)
    shift = np.fft.fftfreq(size, 1.0 / size) * cell
    ring = np.abs(np.hypot(shift[:, None], shift[None, :]) - _PROBE_M) <= 0.5 * cell
    return float(auto[ring].max() / auto[0, 0]) if auto[0, 0] > 0 else 1.0


@dataclass(frozen=True)
class BirdsEyeRegistration:
    """The pose of the query submap's centre in the target submap's frame, and how well it is determined."""

    target_from_query: tuple[float, float, float]  # planar (forward m, left m, yaw rad)
    information: np.ndarray  # (3, 3) inverse covariance of target_from_query
    inliers: int  # query points within 0.75 m of target structure
    overlap: float  # inliers / query points on the shared area (within `_SHARED_M` of target structure)
    peak_ratio: float  # the correlation peak over the best one elsewhere
    sigma_max_m: float  # the refined position's largest standard deviation (m), before inflation


def register(
    query: Submap,
    target: Submap,
    config,
    prior: tuple[np.ndarray, float, float] | None = None,
) -> tuple[BirdsEyeRegistration | None, str]:
    """(registration, "ok") or (None, why not) of `query` onto `target` (module doc). `prior`: (predicted
    target_from_query (x, y, yaw), its radius m, its yaw window rad), the loop gate around where the odometry
    puts the query; the search keeps to it (None: every heading, shifts up to `_MAX_SHIFT_M`)."""
    cfg = config
    if len(query) < cfg.min_points or len(target) < cfg.min_points:
        return None, "birdseye_few_points"
    weights_q, weights_t = _weights(query), _weights(target)
    yaw_rad, shift_m, ratio = _coarse(
        query.points_m,
        target.points_m,
        query.radius_m,
        cfg,
        prior,
        target_radius_m=target.radius_m,
        query_weights=weights_q,
        target_weights=weights_t,
    )
    if ratio < cfg.min_peak_ratio:
        return None, "birdseye_ambiguous"
    fine = _refine(query.points_m, target.points_m, np.array([shift_m[0], shift_m[1], yaw_rad]), cfg)
    if fine is None:
        return None, "birdseye_no_overlap"
    pose, hessian, inliers, overlap, sigma_m = fine
    if inliers < cfg.min_inliers or overlap < cfg.min_overlap:
        return None, "birdseye_no_overlap"
    try:
        covariance = np.linalg.inv(hessian) * sigma_m**2
    except np.linalg.LinAlgError:
        return None, "birdseye_degenerate"
    sigma_max_m = float(np.sqrt(max(np.linalg.eigvalsh(covariance[:2, :2]).max(), 0.0)))
    if not np.isfinite(sigma_max_m) or sigma_max_m > _MAX_SIGMA_M:
        return None, "birdseye_degenerate"
    # The floor is the submaps' own accuracy, whatever the number of points: a post smears along the line
    # of sight by its stereo depth error, the same way in every point of it (registrations of the 08 render
    # were 0.1-2.3 m off, median 0.4 m).
    floor_m, floor_rad = _SIGMA_FLOOR_M, _SIGMA_FLOOR_RAD
    covariance = covariance * _COVARIANCE_INFLATION + np.diag([floor_m**2, floor_m**2, floor_rad**2])
    registration = BirdsEyeRegistration(
        (float(pose[0]), float(pose[1]), float(wrap_angle(pose[2]))),
        np.linalg.inv(covariance),
        int(inliers),
        float(overlap),
        float(ratio),
        sigma_max_m,
    )
    return registration, "ok"


def _raster(
    points_m: np.ndarray,
    cell_m: float,
    half_cells: int,
    size: int,
    stack: int = 1,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """(stack, size, size) counts of (stack, n, 2) points in cells of `cell_m`, the centre at
    (half_cells, half_cells); axis 1 forward, axis 2 left. Points outside are dropped. With `weights` (n,),
    the same for every layer, a cell holds the largest weight of its points instead of their count."""
    idx = np.floor(points_m / cell_m).astype(np.int64) + half_cells
    inside = ((idx >= 0) & (idx < 2 * half_cells)).all(axis=-1)
    layer = np.broadcast_to(np.arange(stack)[:, None], inside.shape)
    flat = ((layer * size + idx[..., 0]) * size + idx[..., 1])[inside]
    if weights is None:
        image = np.bincount(flat, minlength=stack * size * size).astype(np.float32)
    else:
        image = np.zeros(stack * size * size, np.float32)
        np.maximum.at(image, flat, np.broadcast_to(np.asarray(weights, np.float32), inside.shape)[inside])
    return image.reshape(stack, size, size)


def _blurred_spectra(points_m: np.ndarray, weights: np.ndarray | None, half: int, size: int) -> np.ndarray:
    """Spectra (stack, size, size) float32 of the images of (stack, n, 2) points in `_COARSE_CELL_M` cells,
    the centre at cell (half, half), blurred by a Gaussian of `_BLUR_M` (one product in the Fourier domain).
    A cell holds the largest weight of its points (`weights` (n,), the same for every layer; None: 1):
    occupancy, not counts, so that a wall seen from many vertices does not outweigh a post seen once.
    The spectra are OpenCV's packed ones of a real image (`cv2.dft`; `_packed_layout`): in single precision
    they cost about a third of numpy's double-precision `rfft2`, and the search is mostly these transforms."""
    cell = _COARSE_CELL_M
    image = np.minimum(_raster(points_m, cell, half, size, len(points_m), weights), 1.0)
    spectra = np.empty_like(image)
    for layer, spectrum in zip(image, spectra):
        cv2.dft(layer, dst=spectrum)
    spectra *= _packed_layout(size).blur
    return spectra


def _correlations(query: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(stack, size, size) float32 `corr[k, s] = Σ_x Q_k(x)·T(x + s)` (circular) of the packed spectra of a
    stack of query images (`_blurred_spectra`) and of one target image."""
    flags = cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE
    corr = np.empty_like(query)
    for spectrum, out in zip(query, corr):
        cv2.idft(cv2.mulSpectrums(target, spectrum, 0, conjB=True), dst=out, flags=flags)
    return corr


def _energy(spectra: np.ndarray) -> np.ndarray:
    """Σ_x image(x)² of each packed spectrum in (stack, size, size), by Parseval."""
    size = spectra.shape[-1]
    rows = np.einsum("kij,kij,ij->ki", spectra, spectra, _packed_layout(size).parseval)
    return rows.sum(axis=1, dtype=np.float64) / size**2  # rows in single precision, their sum in double


@dataclass(frozen=True)
class _PackedLayout:
    blur: np.ndarray  # (size, size) float32: the Gaussian of `_BLUR_M` at each packed entry's frequency
    parseval: np.ndarray  # (size, size) float32: 2 where the entry's conjugate is not stored, else 1


@functools.lru_cache(maxsize=8)
def _packed_layout(size: int) -> _PackedLayout:
    """Where each entry of OpenCV's packed spectrum ("CCS") of a real size × size image sits in frequency.
    The inner columns hold (Re, Im) pairs of column frequency k = (c + 1) // 2 at every row frequency; the
    first column (frequency 0) and, for an even size, the last (size / 2) are packed down the rows the same
    way: the real DC entry, then (Re, Im) pairs, then, for an even size, the real Nyquist entry. Every
    stored complex entry stands for itself and its unstored conjugate (Parseval weight 2) except the real ones."""
    n = int(size)
    column_k = np.broadcast_to(((np.arange(n) + 1) // 2)[None, :], (n, n)).copy()
    row_k = np.broadcast_to(np.arange(n)[:, None], (n, n)).copy()
    parseval = np.full((n, n), 2.0, np.float32)
    for c in [0, n - 1] if n % 2 == 0 else [0]:
        column_k[:, c] = 0 if c == 0 else n // 2
        row_k[:, c] = (np.arange(n) + 1) // 2
        parseval[0, c] = 1.0
        if n % 2 == 0:
            parseval[n - 1, c] = 1.0
    fy, fx = np.minimum(row_k, n - row_k) / n, column_k / n
    blur = np.exp(-2 * (np.pi * _BLUR_M / _COARSE_CELL_M) ** 2 * (fx**2 + fy**2)).astype(np.float32)
    return _PackedLayout(blur, parseval)


def _blurred_occupancy_spectra(points_m: np.ndarray, radius_m: float) -> tuple[np.ndarray, int, int]:
    """(spectra, half cells, size) of the blurred occupancy images of (stack, n, 2) points within `radius_m`
    (`_blurred_spectra`), zero-padded to `size` ≥ 4·half so that correlations of two of them do not wrap."""
    half = int(np.ceil(radius_m / _COARSE_CELL_M))
    size = int(2 ** np.ceil(np.log2(4 * half)))
    return _blurred_spectra(points_m, None, half, size), half, size


_CORNER_BLOCK_CELLS = 9  # the structure tensor's window (4.5 m: a post and the wall behind it)
_ISOTROPY_FULL = 0.5  # a point whose structure tensor is this isotropic (least over greatest) weighs fully


def structure_weights(points_m: np.ndarray, radius_m: float) -> np.ndarray:
    """(n,) float32 weight in [0, 1] of each point: how firmly the structure around it is pinned in every
    direction — the ratio of the least to the greatest eigenvalue of the structure tensor of the blurred
    occupancy at its cell (over a 4.5 m window), over `_ISOTROPY_FULL`. A wall's points slide along the wall
    and weigh little (median 0.14 on a noisy straight wall); a post's, a corner's or a junction's weigh fully.
    Weighted, a registration is decided by what tells stretches of street apart rather than by the walls
    every street has (docs/map.md, "Bird's-eye closures"). Heading-invariant: the weights are computed in the
    submap's own frame and travel with its points."""
    pts = np.asarray(points_m, np.float32).reshape(-1, 2)
    if not len(pts):
        return np.zeros(0, np.float32)
    cell = _COARSE_CELL_M
    half = int(np.ceil(radius_m / cell)) + _CORNER_BLOCK_CELLS
    image = np.minimum(_raster(pts[None], cell, half, 2 * half), 1.0)[0]
    blurred = cv2.GaussianBlur(image, (0, 0), _BLUR_M / cell)
    # The structure tensor as `cv2.cornerEigenValsAndVecs(blurred, block, 3)` builds it (Sobel gradients
    # scaled by 1 / (4·block), their products summed over the block), but its eigenvalues only at the
    # points' cells and without eigenvectors: the same values bit for bit at a third of the cost (the region
    # of a bird's-eye search is 300 × 300 cells, its points a few hundred).
    block = _CORNER_BLOCK_CELLS
    dx = cv2.Sobel(blurred, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / (4 * block))
    dy = cv2.Sobel(blurred, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / (4 * block))
    tensor = cv2.boxFilter(np.dstack([dx * dx, dx * dy, dy * dy]), -1, (block, block), normalize=False)
    idx = np.clip(np.floor(pts / cell).astype(np.int64) + half, 0, 2 * half - 1)
    a, b, c = tensor[idx[:, 0], idx[:, 1]].astype(np.float64).T
    mean, spread = (a + c) * 0.5, np.sqrt((a - c) * (a - c) * 0.25 + b * b)
    first, second = (mean + spread).astype(np.float32), (mean - spread).astype(np.float32)
    least = np.minimum(first, second)
    greatest = np.maximum(np.maximum(first, second), 1e-12)
    isotropy = least / greatest
    return np.clip(isotropy / _ISOTROPY_FULL, 0.0, 1.0).astype(np.float32)


def _weights(sub: Submap) -> np.ndarray | None:
    return sub.weights if _WEIGHTED else None


def _coarse(
    query_m: np.ndarray,
    target_m: np.ndarray,
    radius_m: float,
    cfg,
    prior,
    target_radius_m: float | None = None,
    query_weights: np.ndarray | None = None,
    target_weights: np.ndarray | None = None,
) -> tuple[float, np.ndarray, float]:
    """(yaw rad, shift m, peak ratio) of the best alignment target ≈ R(yaw)·query + shift, searched over the
    headings and translations the prior admits (module doc); the ratio is over the best alignment elsewhere
    that the prior admits too. `radius_m`: the query's extent; `target_radius_m`: the target's (None: the
    same); weights: per point (`structure_weights`), None: plain occupancy."""
    cell = _COARSE_CELL_M
    steps = int(_ROTATIONS)
    all_angles = 2 * np.pi * np.arange(steps) / steps
    if prior is None:
        centre, reach_m, headings = np.zeros(2), _MAX_SHIFT_M, np.ones(steps, bool)
    else:
        centre, reach_m = np.asarray(prior[0][:2], np.float64), float(prior[1])
        headings = np.abs(wrap_angle(all_angles - prior[0][2])) <= prior[2] + np.pi / steps
    half_q = int(np.ceil(radius_m / cell))
    half_t = int(np.ceil((radius_m if target_radius_m is None else target_radius_m) / cell))
    half = max(half_q, half_t)
    # Shifts up to `reach` (around the prior's centre) must not wrap around: size ≥ half_t + half_q + reach.
    reach_cells = int(np.ceil((reach_m + np.hypot(*centre)) / cell))
    size = _fast_length(max(2 * half, half_t + half_q + reach_cells + 1))
    # Only the headings the prior admits are searched (the costly part: one image and FFT each).
    index = np.flatnonzero(headings)
    if not len(index):
        return 0.0, np.zeros(2), 0.0
    angles = all_angles[index]
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    rotated = np.stack(
        [c * query_m[:, 0] - s * query_m[:, 1], s * query_m[:, 0] + c * query_m[:, 1]], axis=-1
    )
    fq = _blurred_spectra(rotated, query_weights, half, size)
    ft = _blurred_spectra(target_m[None], target_weights, half, size)
    corr = _correlations(fq, ft[0])  # corr[k, s] = Σ_x Q_k(x)·T(x + s)
    norm_q = np.sqrt(np.maximum(_energy(fq), 1e-12))
    # One norm for the whole target: a shift's score is how much of the query's structure the target holds
    # there (occupancy is clipped, so a stretch seen on several passes weighs no more than one seen once).
    norm_t_at = np.sqrt(max(float(_energy(ft)[0]), 1e-12))
    # Only the shifts within reach (around the prior's centre) are scored: the correlation cropped to them,
    # in order from -reach to +reach (the sizes above keep them from wrapping around).
    ring = np.arange(-reach_cells, reach_cells + 1)
    crop = corr.take(ring % size, axis=1).take(ring % size, axis=2).astype(np.float64)
    window = np.hypot(ring[:, None] * cell - centre[0], ring[None, :] * cell - centre[1]) <= reach_m
    score = np.where(window[None], crop, -np.inf) / (norm_q[:, None, None] * norm_t_at)
    best = np.unravel_index(int(np.argmax(score)), score.shape)
    k, i, j = (int(v) for v in best)
    peak = float(score[k, i, j])
    if not np.isfinite(peak) or peak <= 0:
        return 0.0, np.zeros(2), 0.0  # nothing admitted overlaps
    # The best alignment elsewhere: another heading, or this heading away from the peak.
    # The peak's neighbourhood (within a few headings and cells) is struck out and the rest's best taken.
    dk = np.abs((index - index[k] + steps // 2) % steps - steps // 2)
    di, dj = np.abs(ring - ring[i]), np.abs(ring - ring[j])
    score[np.ix_(dk <= _ELSEWHERE_STEPS, di <= _ELSEWHERE_CELLS, dj <= _ELSEWHERE_CELLS)] = -np.inf
    other = float(score.max(initial=-np.inf))
    ratio = peak / other if other > 0 else np.inf
    return float(angles[k]), np.array([ring[i] * cell, ring[j] * cell]), float(ratio)


def _fast_length(n: int) -> int:
    """The least n' ≥ n whose only prime factors are 2, 3 and 5 (a size the FFT handles fast)."""
    m = int(n)
    while True:
        rest = m
        for p in (2, 3, 5):
            while rest % p == 0:
                rest //= p
        if rest == 1:
            return m
        m += 1


def _refine(query_m: np.ndarray, target_m: np.ndarray, start: np.ndarray, cfg):
    """Gauss–Newton of target ≈ R(yaw)·query + t on the target's distance transform, from `start`
    (t_forward, t_left, yaw): (pose, Hessian, inliers, overlap, residual sigma m), or None."""
    cell = _FINE_CELL_M
    lo = target_m.min(axis=0) - _SHARED_M - 1.0
    shape = np.ceil((target_m.max(axis=0) + _SHARED_M + 1.0 - lo) / cell).astype(np.int64) + 1
    image = np.full((int(shape[0]), int(shape[1])), 255, np.uint8)
    idx = np.floor((target_m - lo) / cell).astype(np.int64)
    image[idx[:, 0], idx[:, 1]] = 0
    distance = cv2.distanceTransform(image, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64) * cell
    grad_0, grad_1 = np.gradient(distance, cell)
    pose = start.astype(np.float64).copy()

    def residuals(reach_m: float):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rq = np.stack([c * query_m[:, 0] - s * query_m[:, 1], s * query_m[:, 0] + c * query_m[:, 1]], axis=1)
        d, g0, g1, valid = _sample(distance, grad_0, grad_1, (rq + pose[:2] - lo) / cell)
        inlier = valid & (d <= reach_m)
        jac = np.stack([g0, g1, -g0 * rq[:, 1] + g1 * rq[:, 0]], axis=1)[inlier]
        return d, valid, inlier, jac

    for iteration in range(_ITERATIONS):
        # Trimmed: twice the inlier bar while the alignment settles (the coarse step's blur), then the bar.
        reach = _INLIER_M if iteration >= _ITERATIONS // 2 else 2.0 * _INLIER_M
        d, _, inlier, jac = residuals(reach)
        if inlier.sum() < 3:
            return None
        try:
            delta = np.linalg.solve(jac.T @ jac + 1e-6 * np.eye(3), -jac.T @ d[inlier])
        except np.linalg.LinAlgError:
            return None
        pose += delta
        if iteration >= _ITERATIONS // 2 and np.abs(delta[:2]).max() < 1e-3 and abs(delta[2]) < 1e-4:
            break
    d, valid, inlier, jac = residuals(_INLIER_M)
    if inlier.sum() < 3:
        return None
    hessian = jac.T @ jac
    sigma_m = float(np.sqrt(np.mean(d[inlier] ** 2)))
    shared = valid & (d <= _SHARED_M)
    inliers = int(inlier.sum())
    overlap = inliers / max(int(shared.sum()), 1)
    return pose, hessian, inliers, overlap, max(sigma_m, _POINT_SIGMA_M)


def _sample(distance: np.ndarray, grad_0: np.ndarray, grad_1: np.ndarray, at: np.ndarray):
    """Bilinear samples of the distance transform and its gradient at fractional cells `at` (n, 2)."""
    n0, n1 = distance.shape
    valid = (at[:, 0] >= 0) & (at[:, 0] < n0 - 1) & (at[:, 1] >= 0) & (at[:, 1] < n1 - 1)
    a = np.where(valid[:, None], at, 0.0)
    i, j = np.floor(a[:, 0]).astype(np.int64), np.floor(a[:, 1]).astype(np.int64)
    fi, fj = a[:, 0] - i, a[:, 1] - j
    out = []
    for field in (distance, grad_0, grad_1):
        out.append(
            field[i, j] * (1 - fi) * (1 - fj)
            + field[i + 1, j] * fi * (1 - fj)
            + field[i, j + 1] * (1 - fi) * fj
            + field[i + 1, j + 1] * fi * fj
        )
    return out[0], out[1], out[2], valid


class BirdsEyeSearch:
    """Bird's-eye closure proposals for a map whose vertices keep stereo keyframes (module doc).

    `propose(experience_map, planar_step, keyframe_of)` registers the submap behind the newest vertex against
    the submaps of gated places, at most once per `spacing_m` of travel and once per vertex:
    (target vertex, agent_from_target, information, why) or (None, None, None, why). `keyframe_of(vertex)`
    gives a vertex's keyframe (or None). What it keeps per vertex: its structure points (float32, 8 bytes a
    point; `stored_bytes`) and its submap's ring key once known."""

    def __init__(self, config) -> None:
        self.config = config
        self.points: dict[int, np.ndarray] = {}  # vertex → structure points (forward, left) in its frame
        self._separation_m: float | None = None
        self._last_odometer_m = -np.inf
        self._last_vertex = -1
        # Registrations not yet confirmed: (odometer m, the map correction it implies (x, y, yaw)).
        self._hypotheses: list[tuple[float, np.ndarray]] = []

    def forget(self) -> None:
        """Drop unconfirmed registrations (a closure moved the map: the corrections they imply are stale)."""
        self._hypotheses = []

    @property
    def stored_bytes(self) -> int:
        return int(sum(p.nbytes for p in self.points.values()))

    def _points(self, vertex: int, keyframe_of) -> np.ndarray:
        pts = self.points.get(vertex)
        if pts is None:
            keyframe = keyframe_of(vertex)
            if keyframe is None:
                return np.zeros((0, 2), np.float32)
            pts = structure_points(keyframe.points_m, self.config)
            self.points[vertex] = pts
        return pts

    def _submap(self, centre: int, lo_m: float, hi_m: float, poses, path_m, keyframe_of) -> Submap:
        members = np.flatnonzero((path_m >= path_m[centre] + lo_m) & (path_m <= path_m[centre] + hi_m))
        return submap(
            poses[centre],
            poses[members],
            [self._points(int(u), keyframe_of) for u in members],
            self.config.radius_m,
        )

    def propose(self, experience_map, planar_step, keyframe_of, max_distance_m: float):
        cfg = self.config
        none = (None, None, None)
        newest = len(experience_map) - 1
        odometer = experience_map.odometer_m
        if newest < 1 or newest == self._last_vertex or odometer - self._last_odometer_m < cfg.spacing_m:
            return (*none, "")
        self._last_vertex, self._last_odometer_m = newest, odometer
        poses = np.asarray(experience_map.poses(), np.float64)
        # Path length along the vertices (a session's jump counts as a long path: no submap spans it).
        path_m = np.r_[0.0, np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))]
        query = self._submap(newest, -cfg.submap_m, 0.0, poses, path_m, keyframe_of)
        if len(query) < cfg.min_points:
            return (*none, "birdseye_few_points")
        if cfg.max_self_similarity < 1.0 and self_similarity(query, cfg) > cfg.max_self_similarity:
            return (*none, "birdseye_featureless")
        radius_m, yaw_rad = experience_map.loop_gate()
        # Where the agent may be: the loop gate, but no farther than the odometry's own likely drift
        # (`search_m`): the search is one correlation over that whole area, not a few candidates.
        search_m = min(radius_m, cfg.search_m)
        here = experience_map.world_from_agent
        if here is None:
            return (*none, "")
        old, region, why = self._old_structure(
            experience_map, planar_step, poses, path_m, search_m, keyframe_of
        )
        if region is None:
            return (*none, why)
        prior = (np.zeros(3), search_m, min(yaw_rad, cfg.search_rad))
        yaw_found, shift_found, ratio = _coarse(
            query.points_m,
            region.points_m,
            query.radius_m,
            cfg,
            prior,
            target_radius_m=region.radius_m,
            query_weights=_weights(query),
            target_weights=_weights(region),
        )
        # The closure joins the agent to the old vertex nearest to where the search puts the query's centre.
        # Far from that vertex the map's old stretch bends with the odometry's drift, so the measurement is
        # the registration onto that vertex's own submap, starting from the place found.
        at = se2_compose(poses[newest], np.array([shift_found[0], shift_found[1], yaw_found]))
        # Where the agent (up to a vertex spacing past the newest vertex) then is in the map.
        agent = se2_compose(np.array(here), np.array(planar_step))
        agent_from_newest = se2_between(agent, poses[newest])
        agent_at = se2_compose(at, se2_between(agent_from_newest, np.zeros(3)))
        distance = np.hypot(*(poses[old, :2] - agent_at[:2]).T)
        w = int(old[np.argmin(distance)])
        log.debug(
            "vertex %d: bird's-eye search found vertex %d at %.1f m, peak ratio %.2f",
            newest,
            w,
            float(distance.min()),
            ratio,
        )
        if ratio < cfg.min_peak_ratio:
            return (*none, "birdseye_ambiguous")
        if distance.min() > _OFF_PATH_M:
            return (*none, "birdseye_off_path")
        measured, why = self._register_onto(
            w, at, query, (poses, path_m, keyframe_of), (agent, odometer), max_distance_m
        )
        if measured is None:
            return (*none, why)
        return (w, *measured, "measured")

    def _register_onto(self, w: int, at: np.ndarray, query: Submap, path, agent_at, max_distance_m: float):
        """((agent_from_target, information), "measured") of the query registered onto vertex `w`'s own submap,
        starting from where the search put it (`at`), or (None, why not). `path`: the map's vertex poses, path
        length and keyframes; `agent_at`: where the odometry puts the agent in the map, and the odometer."""
        cfg = self.config
        poses, path_m, keyframe_of = path
        agent, odometer = agent_at
        newest = len(poses) - 1
        agent_from_newest = se2_between(agent, poses[newest])
        half = 0.5 * cfg.submap_m
        target = self._submap(w, -half, half, poses, path_m, keyframe_of)
        local_prior = (se2_between(poses[w], at), _LOCAL_REACH_M, _LOCAL_REACH_RAD)
        registration, why = register(query, target, cfg, local_prior)
        if registration is None:
            return None, why
        w_from_newest = np.array(registration.target_from_query)
        agent_from_target, information = _agent_from_target(
            agent_from_newest, w_from_newest, registration.information
        )
        # As for every metric closure (`closure.max_distance_m`): a link longer than this joins places.
        if np.hypot(agent_from_target[0], agent_from_target[1]) > max_distance_m:
            return None, "birdseye_far"
        log.debug(
            "vertex %d: bird's-eye registration onto %d: %s (inliers %d, overlap %.2f, peak ratio %.2f)",
            newest,
            w,
            np.round(w_from_newest, 2),
            registration.inliers,
            registration.overlap,
            registration.peak_ratio,
        )
        if cfg.confirm and not self._confirmed(odometer, poses[w], agent_from_target, agent):
            return None, "birdseye_unconfirmed"
        return (agent_from_target, information), "measured"

    def _old_structure(self, experience_map, planar_step, poses, path_m, search_m: float, keyframe_of):
        """(the old vertices within reach, the map's structure around them in the newest vertex's frame, "")
        or (…, None, why not). The identity of that frame is where the odometry puts the query; the
        registration says how far the map has drifted from it."""
        cfg = self.config
        newest = len(poses) - 1
        # Structure farther than this from the newest vertex cannot meet the query's at any shift searched.
        reach_m = search_m + cfg.radius_m
        # Old enough: its structure cannot overlap the query's own stretch of path.
        separation_m = max(self._min_separation_m(experience_map), cfg.submap_m + 2 * cfg.max_depth_m)
        near = experience_map.vertices_near(reach_m + cfg.max_depth_m, planar_step)
        old = np.array([v for v in near if path_m[newest] - path_m[v] >= separation_m], np.int64)
        if not len(old):
            return old, None, "birdseye_no_candidate"
        region = submap(poses[newest], poses[old], [self._points(int(u), keyframe_of) for u in old], reach_m)
        if len(region) < cfg.min_points:
            return old, None, "birdseye_few_points"
        return old, region, ""

    def _min_separation_m(self, experience_map) -> float:
        if self._separation_m is None:
            self._separation_m = float(json.loads(experience_map.params_json())["min_loop_separation_m"])
        return self._separation_m

    def _confirmed(self, odometer_m, world_from_target, agent_from_target, agent) -> bool:
        """Whether an earlier registration, within 30 m of travel, implies the same correction of the map as
        this one (each puts the agent within 1.5 m and 0.05 rad of the other's placement); this one is kept for
        the next. Meant for a look-alike junction or bend, which fits one query while the next query, 3 m on,
        sees its surroundings differ; consecutive queries along one street can fit the same wrong street
        alike, and then only the map's consistency check stops them."""
        measured = se2_compose(world_from_target, se2_between(np.asarray(agent_from_target), np.zeros(3)))
        correction = se2_compose(measured, se2_between(agent, np.zeros(3)))
        self._hypotheses = [h for h in self._hypotheses if odometer_m - h[0] <= _CONFIRM_WINDOW_M]
        agreeing = False
        for _, earlier in self._hypotheses:
            off = se2_between(se2_compose(correction, agent), se2_compose(earlier, agent))
            if np.hypot(off[0], off[1]) <= _AGREEMENT_M and abs(off[2]) <= _AGREEMENT_RAD:
                agreeing = True
        self._hypotheses.append((odometer_m, correction))
        return agreeing


def _agent_from_target(
    agent_from_newest: np.ndarray, target_from_newest: np.ndarray, information: np.ndarray
):
    """agent_from_target = agent_from_newest ⊕ (target_from_newest)⁻¹ and its information, propagated through
    the inverse and composition by their (numerical) Jacobian."""

    def f(p: np.ndarray) -> np.ndarray:
        return se2_compose(agent_from_newest, se2_between(p, np.zeros(3)))

    value = f(target_from_newest)
    jac = np.empty((3, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        diff = f(target_from_newest + d) - value
        diff[2] = wrap_angle(diff[2])
        jac[:, k] = diff / 1e-6
    covariance = jac @ np.linalg.inv(information) @ jac.T
    return tuple(float(x) for x in value), np.linalg.inv(covariance)


class BirdsEyeProposer:
    """Closures by registering bird's-eye submaps of stereo structure (`"birdseye"`; heading invariant, for
    streets driven the other way; module doc). A bird's-eye closure recalls no network state: no view is
    familiar, and on a street driven the other way the stored state holds the opposite heading."""

    def __init__(self, config: BirdsEyeConfig | None = None) -> None:
        self.config = config if config is not None else BirdsEyeConfig()
        self.search = BirdsEyeSearch(self.config)

    def propose(self, context: ClosureContext) -> ClosureAttempt:
        if context.lost or not context.spaced:
            return NO_ATTEMPT
        store = context.keyframes
        try:
            vertex, agent_from_target, information, why = self.search.propose(
                context.experience_map,
                context.planar_step,
                store.keyframe,
                store.config.max_distance_m,
            )
        except Exception as err:  # noqa: BLE001 - a failed registration closes no loop; the run goes on
            log.warning("frame %s: bird's-eye attempt failed (%s); no closure", context.frame.index, err)
            return NO_ATTEMPT
        if vertex is None:
            return ClosureAttempt(None, why)
        return ClosureAttempt(ProposedClosure(vertex, agent_from_target, information, "birdseye"), "measured")

    def after_map(self, outcome: MapFrameOutcome) -> None:
        if outcome.loop_closure is not None:
            self.search.forget()
