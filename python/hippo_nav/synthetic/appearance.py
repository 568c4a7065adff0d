"""Appearance that changes between passes: light, shadows, shop fronts and posters, parked cars, camera effects.

The street of `world.py` looks the same on every pass. Here a place looks different each time it is passed,
as a street does on another day, under one of the levels `APPEARANCE_LEVELS` ("same", "mild", "strong"; the
numbers are in `LEVELS` and docs/render.md). "same" is the street as it always was, bit for bit.

Passes (`pass_indices`). The pass index of frame i is the number of earlier, separate visits to the place of
camera i: runs of consecutive frames j < i within `PASS_RADIUS_M` (horizontally) of camera i, not counting
the run that ends at i itself (the current visit). A frame of the first pass has pass 0; a street driven
again has pass 1, and so on; a U-turn within the radius is one visit. `smoothed_passes` blurs the index
over the path (a Gaussian of σ = `PASS_RAMP_M` metres of travel), so the light and the lane change over
~40 m of road instead of between two frames.

What changes, and with what (every random draw is a hash of the seed, the level and integer keys, so the
result depends on nothing else: not on the frames rendered, their order or the number of threads):
- Light (per pass p, interpolated at the smoothed pass): sun azimuth and elevation, the sun's share of the
  light, exposure (a gain on the whole image) and sky brightness. A surface of albedo a with visible normal n
  gets a · ((1 − share) + share · max(0, n·s) · lit) / ((1 − share) + share · 0.18) (s: towards the sun; 0.18
  is that mean over street renders with the sun at ~40°, so a frame keeps about its `same` gray level).
- Cast shadows (`lit`): the facades are walls of finite height H (9–21 m, per 5 m cell of the caster). A point
  at height h above the road is in shadow when the wall it meets walking horizontally towards the sun, at
  distance d across its street segment, rises above the sun ray: H − h − d·tan(elevation) > 0 (the street is
  taken straight across; corners are approximate). The edge is softened over `shadow_softness_m`.
- Shop fronts and posters: the facades are cut by a 5 m horizontal grid; a share of the cells carries a patch
  of other texture (a shop front: dark glass under a bright sign band; or a poster higher up).
- Parked cars: boxes at the kerb, on slots every 6.5 m of street (slots that a lane would cross are left
  out), each occupied or not, shifted along the kerb, of its own length, height and tone.
- Per object (a facade cell, a car slot) the state is the number of visits to it (camera within
  `OBJECT_RADIUS_M`) completed before the frame; each new state redraws the object with probability
  `patch_change` / `car_change`. An object therefore changes while the camera is away, never in view.
- Camera: motion blur along the image motion of each pixel while the shutter is open (a share of the frame
  interval, centred on the frame's pose), vignetting (brightness × (1 − v·r²), r = 1 in the image corners), a
  response with a knee (gray levels above 200 compressed, not clipped) and Gaussian sensor noise.
- Lane (`lane_offsets_m`): on later passes the camera drives `lane_offset_m` to one side (render_kitti).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hippo_nav.io.errors import DatasetError
from hippo_nav.synthetic.world import _DOWN, StreetWorld, _WaveBank

APPEARANCE_LEVELS = ("same", "mild", "strong")
PASS_RADIUS_M = 10.0
"""A frame revisits a place when the camera comes within this distance (horizontal) of an earlier visit."""
PASS_RAMP_M = 10.0
"""σ (metres of travel) of the Gaussian that smooths the pass index for the light and the lane offset."""
OBJECT_RADIUS_M = 15.0
"""A facade cell or car slot is visited while the camera is within this distance (covers a 7 m half street
and a 3.5 m lane offset from the cell centre)."""
CELL_M = 5.0
"""Facade cells for shop fronts and posters, and building heights for shadows: a horizontal world grid."""
CAR_SPACING_M = 6.5
_CAR_HALF_WIDTH_M = 0.9
_LANE_CLEARANCE_M = 4.4  # no car closer to a path than this: a 3.5 m lane offset + the right camera fits
_SUN_ON_STREET = 0.18
"""Mean of max(0, n·s)·lit over the pixels of street renders with the sun at about 40° (measured over six sun
azimuths on the demo loop and a KITTI 00 render: 0.035 at 15°, 0.11 at 30°, 0.20 at 45°, 0.26 at 60°). The
light is divided by (1 − share) + share · 0.18, so a frame keeps about its `same` gray level; a low sun
darkens it (strong, 15°: by ~20 %)."""
_KNEE = 200.0  # gray level above which the sensor's response bends over
_JUMP_M = 5.0  # a step longer than this between frames is a cut (e.g. a second pass), not motion to blur


@dataclass(frozen=True)
class AppearanceLevel:
    """What changes between passes at one level (docs/render.md has the table)."""

    name: str
    sun_turn_deg: tuple[float, float]  # the sun's azimuth turns by this much (either way) from pass to pass
    sun_elevation_deg: tuple[float, float]
    sun_share: float  # share of the light from the sun (the rest is ambient): how deep shadows are
    shadow_softness_m: float
    exposure: tuple[float, float]  # image gain per pass
    sky_gain: tuple[float, float]
    patch_share: float  # share of facade cells with a shop front or poster
    patch_change: float  # chance that a cell is redrawn at a new visit
    car_share: float  # share of car slots occupied
    car_change: float
    car_shift_m: float  # a car stands up to this far along the kerb from its slot centre
    noise_std: float  # gray levels
    shutter_share: float  # share of the frame interval the shutter is open (motion blur)
    vignetting: float  # brightness lost in the image corners
    lane_offset_m: float  # lateral offset of the camera on later passes (render_kitti)


LEVELS: dict[str, AppearanceLevel] = {
    # "same" never reaches the appearance code (it renders `StreetWorld.render`); its row says "no change".
    "same": AppearanceLevel(
        "same",
        sun_turn_deg=(0.0, 0.0),
        sun_elevation_deg=(90.0, 90.0),
        sun_share=0.0,
        shadow_softness_m=0.0,
        exposure=(1.0, 1.0),
        sky_gain=(1.0, 1.0),
        patch_share=0.0,
        patch_change=0.0,
        car_share=0.0,
        car_change=0.0,
        car_shift_m=0.0,
        noise_std=0.0,
        shutter_share=0.0,
        vignetting=0.0,
        lane_offset_m=0.0,
    ),
    "mild": AppearanceLevel(
        "mild",
        sun_turn_deg=(5.0, 15.0),
        sun_elevation_deg=(45.0, 60.0),
        sun_share=0.35,
        shadow_softness_m=1.5,
        exposure=(0.95, 1.05),
        sky_gain=(0.95, 1.05),
        patch_share=0.25,
        patch_change=0.2,
        car_share=0.35,
        car_change=0.2,
        car_shift_m=1.0,
        noise_std=1.5,
        shutter_share=0.0,
        vignetting=0.1,
        lane_offset_m=0.75,
    ),
    "strong": AppearanceLevel(
        "strong",
        sun_turn_deg=(60.0, 180.0),
        sun_elevation_deg=(15.0, 45.0),
        sun_share=0.65,
        shadow_softness_m=0.2,
        exposure=(0.8, 1.25),
        sky_gain=(0.7, 1.3),
        patch_share=0.5,
        patch_change=0.7,
        car_share=0.5,
        car_change=0.7,
        car_shift_m=3.0,
        noise_std=4.0,
        shutter_share=0.08,
        vignetting=0.35,
        lane_offset_m=3.5,
    ),
}

# Keys that keep the random streams of the factors apart.
_SUN, _SUN_SIGN, _ELEVATION, _EXPOSURE, _SKY, _LANE, _PATCH, _CAR, _HEIGHT, _CHANGE = range(1, 11)


def appearance_level(name: str) -> AppearanceLevel:
    """The level called `name`; a `DatasetError` that lists the levels for any other name."""
    try:
        return LEVELS[name]
    except (KeyError, TypeError):
        raise DatasetError(
            f"unknown appearance level {name!r}: choose one of {', '.join(APPEARANCE_LEVELS)}"
        ) from None


# ------------------------------------------------------------------------------------------- hashing
def _splitmix(x: np.ndarray) -> np.ndarray:
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _uniform(*keys: int | np.ndarray) -> np.ndarray:
    """Uniform numbers in [0, 1), a hash of integer keys (arrays broadcast): the same keys, the same number,
    whatever else is drawn (no generator state shared between frames or threads). At least 1-D."""
    arrays = np.broadcast_arrays(*(np.atleast_1d(np.asarray(k, dtype=np.int64)) for k in keys))
    h = np.full(arrays[0].shape, 0x243F6A8885A308D3, dtype=np.uint64)
    for key in arrays:
        h = _splitmix(h ^ key.astype(np.uint64))
    return (h >> np.uint64(11)).astype(np.float64) * 2.0**-53


def _cell_uniform(salt: int, ix: np.ndarray, iz: np.ndarray) -> np.ndarray:
    """A cheaper `_uniform` for the many points of an image: one mixing round of two cell indices."""
    h = ix.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    h ^= iz.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F) ^ np.uint64(salt)
    return (_splitmix(h) >> np.uint64(11)).astype(np.float64) * 2.0**-53


def _lerp(bounds: tuple[float, float], t: np.ndarray | float) -> np.ndarray:
    return bounds[0] + (bounds[1] - bounds[0]) * np.asarray(t, dtype=np.float64)


# -------------------------------------------------------------------------------------------- passes
def pass_indices(positions_m: np.ndarray, radius_m: float = PASS_RADIUS_M) -> np.ndarray:
    """Pass index of each frame (see the module doc): earlier separate visits within `radius_m` (horizontal)."""
    xz = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)[:, [0, 2]]
    n = len(xz)
    out = np.zeros(n, dtype=np.int64)
    index = np.arange(n)
    chunk = 512  # rows of the pairwise matrix held at once
    for lo in range(0, n, chunk):
        rows = index[lo : lo + chunk]
        earlier = index[None, :] <= rows[:, None]
        near = (((xz[rows, None, :] - xz[None, :, :]) ** 2).sum(-1) < radius_m**2) & earlier
        # The current visit: the run of near frames that ends at the frame itself.
        last_away = np.where(~near & earlier, index[None, :], -1).max(1)
        starts = near & np.concatenate([np.ones((len(rows), 1), dtype=bool), ~near[:, :-1]], axis=1)
        out[rows] = (starts & (index[None, :] <= last_away[:, None])).sum(1)
    return out


def smoothed_passes(positions_m: np.ndarray, passes: np.ndarray, ramp_m: float = PASS_RAMP_M) -> np.ndarray:
    """The pass index blurred along the path: a Gaussian of σ = `ramp_m` metres of (horizontal) travel."""
    xz = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)[:, [0, 2]]
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xz, axis=0), axis=1))])
    passes = np.asarray(passes, dtype=np.float64)
    out = np.empty(len(xz))
    chunk = 512
    for lo in range(0, len(xz), chunk):
        weight = np.exp(-0.5 * ((travelled[lo : lo + chunk, None] - travelled[None, :]) / ramp_m) ** 2)
        out[lo : lo + chunk] = weight @ passes / weight.sum(1)
    return out


def _pass_lane_m(level: AppearanceLevel, seed: int, pass_index: int) -> float:
    if pass_index == 0 or level.lane_offset_m == 0:
        return 0.0
    side = 1.0 if _uniform(seed, _code(level), _LANE, pass_index)[0] < 0.5 else -1.0
    return side * level.lane_offset_m


def lane_offsets_m(pass_values: np.ndarray, appearance: str, seed: int = 0) -> np.ndarray:
    """Lateral offset of each frame (m, along the camera's x axis, i.e. to its right) at the given (smoothed)
    passes: 0 on pass 0, ±`lane_offset_m` on every later pass (the side drawn per pass), linear in between."""
    level = appearance_level(appearance)
    values = np.asarray(pass_values, dtype=np.float64)
    below = np.floor(values).astype(np.int64)
    frac = values - below
    lanes = {p: _pass_lane_m(level, seed, int(p)) for p in np.unique(np.concatenate([below, below + 1]))}
    lane_below = np.array([lanes[p] for p in below])
    lane_above = np.array([lanes[p] for p in below + 1])
    return (1 - frac) * lane_below + frac * lane_above


def shift_sideways(world_from_camera: np.ndarray, offsets_m: np.ndarray) -> np.ndarray:
    """The poses moved by `offsets_m` along each camera's own x axis (to its right); headings kept."""
    poses = np.array(world_from_camera, dtype=np.float64)
    poses[:, :3, 3] += np.asarray(offsets_m, dtype=np.float64)[:, None] * poses[:, :3, 0]
    return poses


# ------------------------------------------------------------------------------------------- light
@dataclass(frozen=True)
class Lighting:
    """The light of one frame."""

    sun_azimuth_rad: float  # from world +z towards +x
    sun_elevation_rad: float
    exposure: float
    sky_gain: float

    @property
    def sun_direction(self) -> np.ndarray:
        """Unit vector towards the sun, world frame (y down)."""
        c = np.cos(self.sun_elevation_rad)
        return np.array(
            [
                c * np.sin(self.sun_azimuth_rad),
                -np.sin(self.sun_elevation_rad),
                c * np.cos(self.sun_azimuth_rad),
            ]
        )


def _code(level: AppearanceLevel) -> int:
    return APPEARANCE_LEVELS.index(level.name)


def _pass_lighting(level: AppearanceLevel, seed: int, pass_index: int) -> Lighting:
    code = _code(level)
    azimuth = 2 * np.pi * float(_uniform(seed, code, _SUN, 0)[0])
    for p in range(1, pass_index + 1):  # the sun moves on from where it was on the pass before
        turn = np.radians(float(_lerp(level.sun_turn_deg, _uniform(seed, code, _SUN, p))[0]))
        azimuth += turn if _uniform(seed, code, _SUN_SIGN, p)[0] < 0.5 else -turn
    return Lighting(
        sun_azimuth_rad=azimuth,
        sun_elevation_rad=np.radians(
            float(_lerp(level.sun_elevation_deg, _uniform(seed, code, _ELEVATION, pass_index))[0])
        ),
        exposure=float(_lerp(level.exposure, _uniform(seed, code, _EXPOSURE, pass_index))[0]),
        sky_gain=float(_lerp(level.sky_gain, _uniform(seed, code, _SKY, pass_index))[0]),
    )


def lighting_at(appearance: str, seed: int, pass_value: float) -> Lighting:
    """The light at a (smoothed, fractional) pass: each pass's light, linearly interpolated between passes."""
    level = appearance_level(appearance)
    below = int(np.floor(pass_value))
    frac = float(pass_value) - below
    a, b = _pass_lighting(level, seed, below), _pass_lighting(level, seed, below + 1)

    def mix(x: float, y: float) -> float:
        return (1 - frac) * x + frac * y

    return Lighting(
        mix(a.sun_azimuth_rad, b.sun_azimuth_rad),
        mix(a.sun_elevation_rad, b.sun_elevation_rad),
        mix(a.exposure, b.exposure),
        mix(a.sky_gain, b.sky_gain),
    )


# ----------------------------------------------------------------------------------- object states
class VisitHistory:
    """Which visits to a place were completed before a frame, for a camera driven along `positions_m`."""

    def __init__(self, positions_m: np.ndarray, radius_m: float = OBJECT_RADIUS_M) -> None:
        self._xz = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)[:, [0, 2]]
        self._radius_m = float(radius_m)

    def completed_visits(self, points_xz: np.ndarray, frame: int) -> np.ndarray:
        """For each point (n, 2): runs of frames ≤ `frame` within the radius that ended before `frame`."""
        if len(points_xz) == 0:
            return np.zeros(0, dtype=np.int64)
        track = self._xz[: frame + 1]
        # Only frames in the points' bounding box (grown by the radius) can be near any of them.
        lo, hi = points_xz.min(0) - self._radius_m, points_xz.max(0) + self._radius_m
        index = np.flatnonzero(np.all((track >= lo) & (track <= hi), axis=1))
        near = ((points_xz[:, None, :] - track[None, index, :]) ** 2).sum(-1) < self._radius_m**2
        # A visit ended at frame j when frame j + 1 (≤ `frame`) is not near; frames outside the box are not.
        near_next = np.zeros_like(near)
        follows = index[1:] == index[:-1] + 1
        near_next[:, :-1] = near[:, 1:] & follows
        ended = near & ~near_next & (index < frame)
        return ended.sum(1)


@dataclass(frozen=True)
class FrameAppearance:
    """The appearance of one frame: its (smoothed) pass and light, and how object states are found: visits
    completed before `frame`, or (`frame` None) every object in state `fixed_state`."""

    pass_value: float
    lighting: Lighting
    frame: int | None = None
    fixed_state: int = 0


@dataclass(frozen=True)
class _Cars:
    """Car boxes (one row each): centre (x, z), unit direction along the kerb, half sizes, ground y."""

    slot: np.ndarray
    centre_xz: np.ndarray
    along: np.ndarray
    half_length_m: np.ndarray
    height_m: np.ndarray
    ground_y: np.ndarray
    segment: np.ndarray
    tone: np.ndarray

    def __len__(self) -> int:
        return len(self.slot)

    def take(self, keep: np.ndarray) -> _Cars:
        return _Cars(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))


def _slab(offset: np.ndarray, rate: np.ndarray, lo: np.ndarray | float, hi: np.ndarray | float):
    """s where offset + s·rate lies in [lo, hi] (a near-zero rate: everything or nothing)."""
    rate = np.where(np.abs(rate) < 1e-12, 1e-12, rate)
    s1, s2 = (lo - offset) / rate, (hi - offset) / rate
    return np.minimum(s1, s2), np.maximum(s1, s2)


def _perpendicular(u: np.ndarray) -> np.ndarray:
    """The left normal (x, z) of directions u (x, z): the lateral axis of `StreetWorld`'s capsules."""
    return np.stack([-u[:, 1], u[:, 0]], axis=1)


def _segment_distance_m(points_xz: np.ndarray, world: StreetWorld) -> np.ndarray:
    """Horizontal distance of each point to the nearest path segment."""
    out = np.full(len(points_xz), np.inf)
    a = world.seg_a[:, [0, 2]]
    for lo in range(0, len(a), 256):
        rel = points_xz[:, None, :] - a[None, lo : lo + 256]
        t = np.clip((rel * world.seg_dir[None, lo : lo + 256]).sum(-1), 0.0, world.seg_length[lo : lo + 256])
        gap = rel - t[..., None] * world.seg_dir[None, lo : lo + 256]
        out = np.minimum(out, np.sqrt((gap**2).sum(-1)).min(1))
    return out


# ----------------------------------------------------------------------------------------- the model
class AppearanceModel:
    """The appearance of `world` at one level, for a camera driven along `world_from_camera` (N, 4, 4).

    `passes` (one per pose) replaces `pass_indices` of the camera positions (e.g. passes of the road path
    when the camera drives another lane). Without poses only `at_pass` can be used (every object in one
    state): the same place seen at pass 0 and pass 1.
    """

    def __init__(
        self,
        world: StreetWorld,
        appearance: str = "same",
        seed: int = 0,
        world_from_camera: np.ndarray | None = None,
        passes: np.ndarray | None = None,
    ) -> None:
        self.world = world
        self.level = appearance_level(appearance)
        self.seed = int(seed)
        self._code = _code(self.level)
        self.passes = np.zeros(0, dtype=np.int64)
        self.pass_values = np.zeros(0)
        self._history: VisitHistory | None = None
        if world_from_camera is not None:
            positions = np.asarray(world_from_camera, dtype=np.float64)[:, :3, 3]
            self.passes = pass_indices(positions) if passes is None else np.asarray(passes, dtype=np.int64)
            if len(self.passes) != len(positions):
                raise DatasetError(f"need one pass index per pose: {len(self.passes)} for {len(positions)}")
            self.pass_values = smoothed_passes(positions, self.passes)
            self._history = VisitHistory(positions)
        # The appearance's own random draws, apart from the world's (which stay those of `same`).
        rng = np.random.default_rng([self.seed, 0xA99, self._code])
        self._poster = _WaveBank.random(rng, 12, (0.15, 2.0))
        self._car_texture = _WaveBank.random(rng, 8, (0.1, 1.0))
        self._seg_a_xz = world.seg_a[:, [0, 2]]
        # Each segment's road plane n·(p − anchor) = 0 solved for y: y = c0 + c1·x + c2·z.
        normal = world.ground_normal
        anchor = world.seg_a + world.camera_height_m * _DOWN
        ny = np.maximum(normal[:, 1], 0.2)  # roads are no steeper than 1:4 (`StreetWorld`)
        self._road_planes = np.stack(
            [
                anchor[:, 1] + (normal[:, 0] * anchor[:, 0] + normal[:, 2] * anchor[:, 2]) / ny,
                -normal[:, 0] / ny,
                -normal[:, 2] / ny,
            ],
            axis=1,
        )
        self._slots = self._car_slots() if self.level.car_share > 0 else None
        self._height_salt = int(_uniform(self.seed, self._code, _HEIGHT)[0] * 2.0**53)

    # --------------------------------------------------------------------------------- per frame
    def frame(self, i: int) -> FrameAppearance:
        """The appearance of frame `i` of the trajectory."""
        if self._history is None:
            raise DatasetError(
                "this appearance model has no trajectory: give world_from_camera, or use at_pass"
            )
        pass_value = float(self.pass_values[i])
        return FrameAppearance(pass_value, lighting_at(self.level.name, self.seed, pass_value), frame=int(i))

    def at_pass(self, pass_index: int) -> FrameAppearance:
        """Every object and the light as on pass `pass_index` (a place seen for the (pass_index+1)-th time)."""
        p = int(pass_index)
        return FrameAppearance(float(p), lighting_at(self.level.name, self.seed, p), None, p)

    def _states(self, look: FrameAppearance, points_xz: np.ndarray) -> np.ndarray:
        if look.frame is None or self._history is None:
            return np.full(len(points_xz), look.fixed_state, dtype=np.int64)
        return self._history.completed_visits(points_xz, look.frame)

    def _variants(
        self, tag: int, keys: tuple[np.ndarray, ...], states: np.ndarray, change: float
    ) -> np.ndarray:
        """Which draw of each object holds in its state: state k redraws it with probability `change`."""
        variant = np.zeros(len(states), dtype=np.int64)
        for k in range(1, int(states.max(initial=0)) + 1):
            redraw = _uniform(self.seed, self._code, tag, _CHANGE, *keys, k) < change
            variant += redraw & (states >= k)
        return variant

    # ----------------------------------------------------------------------------------- render
    def render(
        self,
        world_from_camera: np.ndarray,
        K: np.ndarray,
        image_size_px: tuple[int, int],
        look: FrameAppearance,
        *,
        camera_from_next: np.ndarray | None = None,
        noise_rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """One (H, W) uint8 image at `look`. `camera_from_next` (4×4, the camera's motion to the next frame)
        gives the motion blur; `noise_rng` the sensor noise (none without it). At "same" this is exactly
        `StreetWorld.render`."""
        if self.level.name == "same":
            return self.world.render(world_from_camera, K, image_size_px)
        width, height = image_size_px
        world = self.world
        directions, level_columns = world.rays(world_from_camera, K, image_size_px)
        centre = world_from_camera[:3, 3]
        hits = world.cast(centre, directions, level_columns=level_columns)
        cars = self._cars_near(look, centre)
        hits["car"] = np.full(len(directions), -1)
        if cars is not None and len(cars):
            seen = _cast_cars(hits, cars, centre, directions, level_columns)
            hits["cars_seen"] = seen
        light = look.lighting

        def surface(hits: dict[str, np.ndarray], unit: np.ndarray, footprint: np.ndarray, value: np.ndarray):
            return self._surface(hits, footprint, value, look, cars)

        gray = world.shade(hits, directions, float(K[0, 0]), surface=surface, sky_gain=light.sky_gain)
        gray = (light.exposure * gray).reshape(height, width)
        if self.level.shutter_share > 0 and camera_from_next is not None:
            gray = _motion_blur(
                gray, hits["points"], world_from_camera, camera_from_next, K, self.level.shutter_share
            )
        if self.level.vignetting > 0:
            u, v = np.meshgrid(np.arange(width) - K[0, 2], np.arange(height) - K[1, 2])
            r2 = (u**2 + v**2) / (
                max(K[0, 2], width - 1 - K[0, 2]) ** 2 + max(K[1, 2], height - 1 - K[1, 2]) ** 2
            )
            gray = gray * (1 - self.level.vignetting * r2)
        # The sensor's response has a knee: highlights above 200 are compressed, not cut (sunlit texture stays).
        gray = np.where(gray > _KNEE, _KNEE + (255 - _KNEE) * np.tanh((gray - _KNEE) / (255 - _KNEE)), gray)
        if noise_rng is not None and self.level.noise_std > 0:
            gray = gray + noise_rng.normal(0.0, self.level.noise_std, gray.shape)
        return np.clip(np.rint(gray), 0, 255).astype(np.uint8)

    def _surface(
        self,
        hits: dict[str, np.ndarray],
        footprint: np.ndarray,
        value: np.ndarray,
        look: FrameAppearance,
        cars: _Cars | None,
    ) -> np.ndarray:
        kind, points = hits["kind"], hits["points"]
        solid = np.flatnonzero(kind > 0)
        segment = hits["segment"][solid]
        height = self._height_above_road_m(points[solid], segment)
        facade = np.flatnonzero(kind[solid] == 2)
        if len(facade) and self.level.patch_share > 0:
            on_facade = solid[facade]
            value[on_facade] = self._patches(
                points[on_facade], height[facade], footprint[on_facade], value[on_facade], look
            )
        if cars is not None and len(cars):
            car = kind == 3
            if car.any():
                value[car] = self._car_values(points[car], hits["car"][car], cars, footprint[car])
            ground = np.flatnonzero(kind == 1)
            seen = hits.get("cars_seen", np.zeros(0, dtype=np.int64))
            if len(ground) and len(seen):
                value[ground] *= _car_occlusion(points[ground], cars.take(seen))
        value[solid] *= self._illumination(
            points[solid], height, hits["normals"][solid], segment, footprint[solid], look
        )
        return value

    # ------------------------------------------------------------------------------------ light
    def _height_above_road_m(self, points: np.ndarray, segment: np.ndarray) -> np.ndarray:
        """Vertical distance from each point up from the road plane of its segment."""
        plane = self._road_planes[segment]  # road y = plane · (1, x, z)
        return plane[:, 0] + plane[:, 1] * points[:, 0] + plane[:, 2] * points[:, 2] - points[:, 1]

    def _illumination(
        self,
        points: np.ndarray,
        height_m: np.ndarray,
        normals: np.ndarray,
        segment: np.ndarray,
        footprint: np.ndarray,
        look: FrameAppearance,
    ) -> np.ndarray:
        world, level = self.world, self.level
        sun = look.lighting.sun_direction
        facing = np.maximum(-(normals @ sun), 0.0)  # the normals point away from the street
        sun_xz = sun[[0, 2]] / max(float(np.hypot(sun[0], sun[2])), 1e-9)
        across = _perpendicular(world.seg_dir[segment])
        points_xz = points[:, [0, 2]]
        lateral = ((points_xz - self._seg_a_xz[segment]) * across).sum(1)
        towards = across @ sun_xz  # the sun's share across the street
        towards = np.where(np.abs(towards) < 1e-3, np.where(towards < 0, -1e-3, 1e-3), towards)
        # Walk from the point towards the sun to the facade on that side of the street segment.
        distance = np.maximum((np.sign(towards) * world.street_half_width_m - lateral) / towards, 0.0)
        caster = points_xz + distance[:, None] * sun_xz
        cell = np.floor(caster / CELL_M).astype(np.int64)
        wall_m = 9.0 + 12.0 * _cell_uniform(self._height_salt, cell[:, 0], cell[:, 1])
        tan_elevation = np.tan(look.lighting.sun_elevation_rad)
        margin = wall_m - height_m - distance * tan_elevation
        # The edge is soft over the penumbra, and at least over a pixel's footprint (no aliasing).
        width = level.shadow_softness_m + footprint * tan_elevation / np.maximum(np.abs(towards), 0.2)
        lit = np.clip(0.5 - margin / width, 0.0, 1.0)
        ambient = 1 - level.sun_share
        return (ambient + level.sun_share * facing * lit) / (ambient + level.sun_share * _SUN_ON_STREET)

    # ---------------------------------------------------------------------- shop fronts, posters
    def _patches(
        self,
        points: np.ndarray,
        height: np.ndarray,
        footprint: np.ndarray,
        value: np.ndarray,
        look: FrameAppearance,
    ) -> np.ndarray:
        cell_xz = np.floor(points[:, [0, 2]] / CELL_M).astype(np.int64)
        # One integer per cell (a 1-D unique is much faster than unique rows).
        packed = (cell_xz[:, 0] << 32) + (cell_xz[:, 1] & 0xFFFFFFFF)
        _, first, inverse = np.unique(packed, return_index=True, return_inverse=True)
        cells = cell_xz[first]
        keys = (cells[:, 0], cells[:, 1])
        states = self._states(look, (cells + 0.5) * CELL_M)
        variant = self._variants(_PATCH, keys, states, self.level.patch_change)

        def draw(field: int) -> np.ndarray:
            return _uniform(self.seed, self._code, _PATCH, *keys, variant, field)[inverse]

        present = draw(0) < self.level.patch_share
        shop = draw(1) < 0.5
        bottom = np.where(shop, 0.3, 3.6 + 4.0 * draw(2))
        top = np.where(shop, 3.4, bottom + 1.6 + 1.6 * draw(3))
        corner = cell_xz * CELL_M
        inside = np.minimum.reduce(
            [
                points[:, 0] - corner[:, 0],
                corner[:, 0] + CELL_M - points[:, 0],
                points[:, 2] - corner[:, 1],
                corner[:, 1] + CELL_M - points[:, 2],
            ]
        )
        edge = np.maximum(footprint, 0.02)  # anti-aliased edges, a pixel wide
        mask = (
            present
            * np.clip((inside - 0.4) / edge + 0.5, 0.0, 1.0)
            * np.clip((height - bottom) / edge + 0.5, 0.0, 1.0)
            * np.clip((top - height) / edge + 0.5, 0.0, 1.0)
        )
        on = np.flatnonzero(mask > 0)
        if len(on) == 0:
            return value
        offset = 1000.0 * np.stack([draw(4), draw(5), draw(6)], axis=1)[on]  # another texture per draw
        texture = np.tanh(1.3 * self._poster(points[on] + offset, footprint[on]))
        tone = 60.0 + 150.0 * draw(7)[on]
        # A shop front: dark glass with reflections under a bright sign band 0.7 m high.
        glass = np.clip((top[on] - 0.7 - height[on]) / edge[on] + 0.5, 0.0, 1.0)
        shop_value = glass * (45 + 30 * texture) + (1 - glass) * (tone + 40 * texture)
        patch = np.where(shop[on], shop_value, tone + 70 * texture)
        out = value.copy()
        out[on] = (1 - mask[on]) * value[on] + mask[on] * patch
        return out

    # ---------------------------------------------------------------------------------- cars
    def _car_slots(self) -> _Cars:
        """Kerb slots every `CAR_SPACING_M` on both sides of every segment, deduplicated where streets are
        driven again, kept only where the car (at any shift) stays inside the street and clear of every lane."""
        world = self.world
        lateral = world.street_half_width_m - 0.4 - _CAR_HALF_WIDTH_M
        centres, along, segment = [], [], []
        for k in range(len(world.seg_a)):
            count = int(world.seg_length[k] // CAR_SPACING_M)
            if count == 0:
                continue
            t = (np.arange(count) + 0.5) * world.seg_length[k] / count
            u = world.seg_dir[k]
            left = np.array([-u[1], u[0]])
            for side in (-1.0, 1.0):
                centres.append(world.seg_a[k, [0, 2]] + t[:, None] * u + side * lateral * left)
                along.append(np.tile(u, (count, 1)))
                segment.append(np.full(count, k))
        if not centres:
            centres, along, segment = [np.zeros((0, 2))], [np.zeros((0, 2))], [np.zeros(0, dtype=np.int64)]
        centre_xz, along_xz, seg = np.concatenate(centres), np.concatenate(along), np.concatenate(segment)
        # A street driven twice has its slots twice: keep the first of any within 3.5 m.
        keep = np.ones(len(centre_xz), dtype=bool)
        taken: dict[tuple[int, int], list[int]] = {}
        for i, (x, z) in enumerate(centre_xz):
            cx, cz = int(np.floor(x / 4.0)), int(np.floor(z / 4.0))
            close = [j for dx in (-1, 0, 1) for dz in (-1, 0, 1) for j in taken.get((cx + dx, cz + dz), [])]
            if any(np.hypot(*(centre_xz[j] - (x, z))) < 3.5 for j in close):
                keep[i] = False
            else:
                taken.setdefault((cx, cz), []).append(i)
        # Sample the box (corners, edge midpoints, centre) at the largest shift.
        reach = 2.4 + self.level.car_shift_m
        offsets = [(a, b) for a in (-reach, 0.0, reach) for b in (-_CAR_HALF_WIDTH_M, 0.0, _CAR_HALF_WIDTH_M)]
        left_xz = _perpendicular(along_xz)
        for a, b in offsets:
            sample = centre_xz + a * along_xz + b * left_xz
            distance = _segment_distance_m(sample, world)
            keep &= (distance >= _LANE_CLEARANCE_M) & (distance <= world.street_half_width_m - 0.2)
        centre_xz, along_xz, seg = centre_xz[keep], along_xz[keep], seg[keep]
        plane = self._road_planes[seg]
        ground_y = plane[:, 0] + plane[:, 1] * centre_xz[:, 0] + plane[:, 2] * centre_xz[:, 1]
        n = len(centre_xz)
        return _Cars(np.arange(n), centre_xz, along_xz, np.zeros(n), np.zeros(n), ground_y, seg, np.zeros(n))

    def _cars_near(self, look: FrameAppearance, centre_m: np.ndarray) -> _Cars | None:
        """The parked cars within range of the camera, as they stand at `look`."""
        if self._slots is None or len(self._slots) == 0:
            return None
        reach = self.world.max_range_m + 5.0
        near = np.flatnonzero(((self._slots.centre_xz - centre_m[[0, 2]]) ** 2).sum(1) < reach**2)
        slots = self._slots.take(near)
        states = self._states(look, slots.centre_xz)
        variant = self._variants(_CAR, (slots.slot,), states, self.level.car_change)

        def draw(field: int) -> np.ndarray:
            return _uniform(self.seed, self._code, _CAR, slots.slot, variant, field)

        shift = self.level.car_shift_m * (2 * draw(1) - 1)
        cars = _Cars(
            slots.slot,
            slots.centre_xz + shift[:, None] * slots.along,
            slots.along,
            1.9 + 0.5 * draw(2),
            1.35 + 0.35 * draw(3),
            slots.ground_y,
            slots.segment,
            40.0 + 180.0 * draw(4),
        )
        return cars.take(draw(0) < self.level.car_share)

    def _car_values(
        self, points: np.ndarray, car: np.ndarray, cars: _Cars, footprint: np.ndarray
    ) -> np.ndarray:
        rel = points[:, [0, 2]] - cars.centre_xz[car]
        along = (rel * cars.along[car]).sum(1)
        across = (rel * _perpendicular(cars.along)[car]).sum(1)
        height = cars.ground_y[car] - points[:, 1]
        # Texture fixed to the car (it moves with it), a different one per car.
        local = np.stack([along, height, across], axis=1) + 100.0 * cars.slot[car, None]
        value = cars.tone[car] + 18.0 * np.tanh(self._car_texture(local, footprint))
        edge = np.maximum(footprint, 0.02)
        frac = height / cars.height_m[car]
        windows = (
            np.clip((frac - 0.6) * cars.height_m[car] / edge + 0.5, 0.0, 1.0)
            * np.clip((0.92 - frac) * cars.height_m[car] / edge + 0.5, 0.0, 1.0)
            * np.clip((cars.half_length_m[car] - 0.5 - np.abs(along)) / edge + 0.5, 0.0, 1.0)
        )
        wheels = np.clip((0.45 - height) / edge + 0.5, 0.0, 1.0) * np.clip(
            (0.45 - np.abs(cars.half_length_m[car] - 0.85 - np.abs(along))) / edge + 0.5, 0.0, 1.0
        )
        value = (1 - windows) * value + windows * (35.0 + 0.15 * value)
        return (1 - wheels) * value + wheels * 25.0


# --------------------------------------------------------------------------- cars: rays and shade
# The model draws which cars stand where (`AppearanceModel._cars_near`); these only need the boxes.
def _cast_cars(
    hits: dict[str, np.ndarray],
    cars: _Cars,
    centre: np.ndarray,
    directions: np.ndarray,
    level_columns: int,
) -> np.ndarray:
    """Put the cars into `hits` where a ray meets a car before anything else; return the cars (indices)
    that some image column meets."""
    horizontal = np.maximum(np.hypot(directions[:, 0], directions[:, 2]), 1e-12)
    step = directions / horizontal[:, None]  # per metre of horizontal distance, as in `cast`
    n_rays = len(step)
    flat = step[:level_columns, [0, 2]] if level_columns else step[:, [0, 2]]
    left = _perpendicular(cars.along)
    rel = centre[[0, 2]] - cars.centre_xz
    in_u, out_u = _slab(
        (rel * cars.along).sum(1), flat @ cars.along.T, -cars.half_length_m, cars.half_length_m
    )
    in_v, out_v = _slab((rel * left).sum(1), flat @ left.T, -_CAR_HALF_WIDTH_M, _CAR_HALF_WIDTH_M)
    side_in, side_out = np.maximum(in_u, in_v), np.minimum(out_u, out_v)
    # Only (ray, car) pairs whose column meets the car in the horizontal plane need the vertical test.
    meets = (side_in < side_out) & (side_out > 0)
    seen = np.flatnonzero(meets.any(0))
    column, car = np.nonzero(meets)
    if len(column) == 0:
        return seen
    if level_columns:  # every row of a column: ray = row · W + column
        rows = n_rays // level_columns
        ray = (np.arange(rows)[:, None] * level_columns + column[None, :]).ravel()
        column, car = np.tile(column, rows), np.tile(car, rows)
    else:
        ray = column
    y_top = cars.ground_y[car] - cars.height_m[car]
    in_y, out_y = _slab(np.full(len(ray), centre[1]), step[ray, 1], y_top, cars.ground_y[car])
    s_in = np.maximum(side_in[column, car], in_y)
    hit = np.flatnonzero((s_in < np.minimum(side_out[column, car], out_y)) & (s_in > 1e-6))
    if len(hit) == 0:
        return seen
    ray, column, car, s_in, in_y = ray[hit], column[hit], car[hit], s_in[hit], in_y[hit]
    # The nearest car of each ray, if nearer than the street.
    order = np.lexsort((s_in, ray))
    _, first = np.unique(ray[order], return_index=True)
    pick = order[first]
    step_norm = np.linalg.norm(step[ray[pick]], axis=1)
    nearer = pick[s_in[pick] * step_norm < hits["range_m"][ray[pick]]]
    if len(nearer) == 0:
        return seen
    closer, c, q = ray[nearer], car[nearer], column[nearer]
    s_best = s_in[nearer]
    top = in_y[nearer] >= side_in[q, c]
    lengthwise = in_u[q, c] >= in_v[q, c]  # which side face the ray enters by
    # Normals point away from the camera, as the street's do.
    rate_u = (flat[q] * cars.along[c]).sum(1)
    rate_v = (flat[q] * left[c]).sum(1)
    face_xz = np.where(
        lengthwise[:, None], np.sign(rate_u)[:, None] * cars.along[c], np.sign(rate_v)[:, None] * left[c]
    )
    normal = np.where(
        top[:, None], [0.0, 1.0, 0.0], np.stack([face_xz[:, 0], np.zeros(len(c)), face_xz[:, 1]], axis=1)
    )
    step_near = step[closer]
    hits["kind"][closer] = 3
    hits["range_m"][closer] = s_best * np.linalg.norm(step_near, axis=1)
    hits["points"][closer] = centre + s_best[:, None] * step_near
    hits["normals"][closer] = normal
    hits["segment"][closer] = cars.segment[c]
    hits["car"][closer] = c
    return seen


def _car_occlusion(points: np.ndarray, cars: _Cars) -> np.ndarray:
    """Darkening of the road under and beside each car (ambient occlusion: no light from below)."""
    shade = np.ones(len(points))
    xz = points[:, [0, 2]]
    left = _perpendicular(cars.along)
    for k in range(len(cars)):
        reach = cars.half_length_m[k] + 1.5  # beyond 1.5 m the darkening is below 0.1 %
        box = np.flatnonzero(np.all(np.abs(xz - cars.centre_xz[k]) < reach, axis=1))
        rel = xz[box] - cars.centre_xz[k]
        along = np.abs(rel @ cars.along[k]) - cars.half_length_m[k]
        across = np.abs(rel @ left[k]) - _CAR_HALF_WIDTH_M
        outside = np.hypot(np.maximum(along, 0.0), np.maximum(across, 0.0))
        shade[box] *= 1 - 0.55 * np.exp(-((outside / 0.5) ** 2))
    return shade


# ----------------------------------------------------------------------------------------- camera
def _motion_blur(
    gray: np.ndarray,
    points: np.ndarray,
    world_from_camera: np.ndarray,
    camera_from_next: np.ndarray,
    K: np.ndarray,
    shutter_share: float,
) -> np.ndarray:
    """Average the image along each pixel's motion while the shutter is open (centred on the frame)."""
    rotation = cv2.Rodrigues(cv2.Rodrigues(camera_from_next[:3, :3])[0] * shutter_share)[0]
    shift = camera_from_next[:3, 3] * shutter_share
    camera = (points - world_from_camera[:3, 3]) @ world_from_camera[:3, :3]
    moved = (camera - shift) @ rotation  # the same points, seen at the end of the shutter time

    def project(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        depth = np.maximum(p[:, 2], 0.1)
        u = K[0, 0] * p[:, 0] / depth + K[0, 1] * p[:, 1] / depth + K[0, 2]
        v = K[1, 1] * p[:, 1] / depth + K[1, 2]
        return u, v

    (u0, v0), (u1, v1) = project(camera), project(moved)
    flow_u = (u1 - u0).reshape(gray.shape).astype(np.float32)
    flow_v = (v1 - v0).reshape(gray.shape).astype(np.float32)
    longest = float(np.sqrt(flow_u**2 + flow_v**2).max(initial=0.0))
    if longest < 0.05:
        return gray
    taps = int(np.clip(np.ceil(longest) + 1, 2, 9))
    grid_u, grid_v = np.meshgrid(
        np.arange(gray.shape[1], dtype=np.float32), np.arange(gray.shape[0], dtype=np.float32)
    )
    source = gray.astype(np.float32)
    total = np.zeros_like(source)
    for t in np.linspace(-0.5, 0.5, taps, dtype=np.float32):
        total += cv2.remap(
            source,
            grid_u + t * flow_u,
            grid_v + t * flow_v,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT,
        )
    return total.astype(np.float64) / taps


def shutter_motion(world_from_camera: np.ndarray, i: int) -> np.ndarray | None:
    """Camera i's motion over one frame interval (camera_i_from_next, 4×4), for motion blur: the step to the
    next frame, else the step from the previous one; None where both are cuts (longer than 5 m)."""
    poses = np.asarray(world_from_camera, dtype=np.float64)
    for a, b in ((i, i + 1), (i - 1, i)):
        if 0 <= a and b < len(poses):
            step = np.linalg.inv(poses[a]) @ poses[b]
            if np.linalg.norm(step[:3, 3]) < _JUMP_M:
                return step
    return None
