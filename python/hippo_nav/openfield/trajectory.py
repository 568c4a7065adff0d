"""Where the animal goes: a RatInABox foraging trajectory, or one a user gives as a CSV file.

The network is driven as a head-direction system is: by the head's angular velocity and the speed along the
head's direction. RatInABox's head direction is its velocity direction smoothed over 0.15 s; its velocity
direction itself jumps at walls (turns of 40–60 rad/s within a step), which no HD ring integrates. Moving
only along the head direction loses the sideways component of each step, which over a 10-minute RatInABox
session displaces the integrated path by < 0.1 m against the true one (measured: 0.02–0.09 m), below one
bin of a rate map; the networks' own error is what a session measures.

Head directions are smoothed by a Gaussian of `HEAD_SMOOTHING_S` (on the unwrapped angle) whatever their
source. RatInABox's head direction reverses its turn from one 20 ms step to the next when the animal nearly
stops (+7.7 then −7.7 rad/s: angular accelerations of ~800 rad/s², which no head makes); each such reversal
could split the ring's bump and flip the decoded heading by ~170° (measured: 9–93 flips in 10 minutes). With
50 ms of smoothing the peak acceleration is ~100 rad/s² and the ring tracks a 5-minute session to 0.6° RMS
with no flip; the turn over any longer stretch is unchanged. The speed is smoothed alike: RatInABox stops the
animal at a wall within one step (0.5 m/s to −0.1 m/s in 40 ms, ~12 m/s²), and such a stop made the place
code jump by 0.53 m (seed 0 at 7.2 s); with 50 ms of smoothing it followed the first minute of each seed
tried to < 0.09 m without landmarks.
"""

from __future__ import annotations

import csv
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.openfield.config import OpenFieldConfig

__all__ = ["HEAD_SMOOTHING_S", "Trajectory", "foraging_trajectory", "trajectory_from_csv"]

HEAD_SMOOTHING_S = 0.05
"""σ of the Gaussian that smooths every trajectory's head direction (module doc)."""


@dataclass(frozen=True)
class Trajectory:
    """Positions (m, arena frame: x right, y up) and head directions (rad from +x) at uniform times."""

    time_s: np.ndarray
    position_m: np.ndarray
    head_direction_rad: np.ndarray
    source: str
    cut_short_hint: str = ""
    """Words to add to an error the trajectory's values cause, when its file may have been cut short."""

    @property
    def step_dt_s(self) -> float:
        return float(self.time_s[1] - self.time_s[0])

    def drive(self) -> tuple[np.ndarray, np.ndarray]:
        """Per step i → i+1: the head's angular velocity (rad/s) and the speed along the head's direction
        at the step's end (m/s, negative when the animal backs)."""
        dt = np.diff(self.time_s)
        heading = np.unwrap(self.head_direction_rad)
        yaw_rate = np.diff(heading) / dt
        unit = np.stack([np.cos(heading[1:]), np.sin(heading[1:])], axis=1)
        speed = np.sum(np.diff(self.position_m, axis=0) * unit, axis=1) / dt
        return yaw_rate, smooth(speed, HEAD_SMOOTHING_S / self.step_dt_s)


def foraging_trajectory(config: OpenFieldConfig) -> Trajectory:
    """RatInABox's random foraging (its default thigmotaxis and wall repulsion) in the configured arena,
    `duration_s` long at `step_dt_s`; deterministic per `seed` (RatInABox draws from numpy's global
    generator, which is seeded here and restored afterwards)."""
    try:
        from ratinabox.Agent import Agent
        from ratinabox.Environment import Environment
    except ImportError:
        raise HippoNavError(
            "open-field sessions need RatInABox: pip install 'hippo-nav[neuro]' (or give a trajectory CSV)"
        ) from None
    size = config.arena_size_m
    params: dict[str, object] = {"scale": size, "boundary_conditions": "solid"}
    if config.arena_shape == "circle":
        # RatInABox's circular arenas are polygons of many walls inscribed in the unit box.
        angles = np.linspace(0.0, 2.0 * np.pi, 65)[:-1]
        params["boundary"] = (size * (0.5 + 0.5 * np.stack([np.cos(angles), np.sin(angles)], 1))).tolist()
    saved = np.random.get_state()
    np.random.seed(config.seed)
    try:
        with warnings.catch_warnings():
            # RatInABox warns about its own defaults (e.g. plotting style); nothing here depends on them.
            warnings.simplefilter("ignore")
            env = Environment(params=params)
            agent = Agent(
                env,
                params={
                    "dt": config.step_dt_s,
                    "speed_mean": config.speed_mean_m_s,
                    "speed_std": config.speed_std_m_s,
                    "rotational_velocity_std": config.rotational_velocity_std_rad_s,
                },
            )
            start = (np.array(agent.pos, dtype=np.float64), np.array(agent.head_direction, dtype=np.float64))
            steps = round(config.duration_s / config.step_dt_s)
            for _ in range(steps):
                agent.update()
    finally:
        np.random.set_state(saved)
    # The history holds the pose after each update: the start comes first, so a session spans duration_s.
    position = np.vstack([start[0], np.asarray(agent.history["pos"], dtype=np.float64)])
    head = np.vstack([start[1], np.asarray(agent.history["head_direction"], dtype=np.float64)])
    time = np.arange(len(position)) * config.step_dt_s
    heading = smooth_heading(np.arctan2(head[:, 1], head[:, 0]), config.step_dt_s)
    return Trajectory(time, position, heading, f"ratinabox seed {config.seed}")


def smooth(values: np.ndarray, sigma_steps: float) -> np.ndarray:
    """`values` convolved with a Gaussian of `sigma_steps` (the ends padded with their own values, so a
    constant stays constant and the sum over the interior is kept)."""
    radius = math.ceil(4 * sigma_steps)
    values = np.asarray(values, dtype=np.float64)
    if radius < 1 or len(values) < 2:
        return values
    kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma_steps) ** 2)
    return np.convolve(np.pad(values, radius, mode="edge"), kernel / kernel.sum(), mode="valid")


def smooth_heading(heading_rad: np.ndarray, step_dt_s: float) -> np.ndarray:
    """The head direction smoothed by a Gaussian of `HEAD_SMOOTHING_S` on the unwrapped angle, wrapped back
    to (−π, π]."""
    return np.angle(np.exp(1j * smooth(np.unwrap(heading_rad), HEAD_SMOOTHING_S / step_dt_s)))


MAX_SESSION_S = 86_400.0
"""The longest session (a day, as `record --duration`): the networks are stepped every `step_dt_s` of it."""


def trajectory_from_csv(path: str | Path, step_dt_s: float) -> Trajectory:
    """A trajectory from a CSV file with a header naming `t` (s), `x`, `y` (m) and optionally `heading`
    (rad); resampled to `step_dt_s` by linear interpolation (headings on the circle). Without a heading,
    the direction of motion smoothed over 0.15 s is taken, as RatInABox does."""
    path = Path(path)
    # Checked first: 0 asked numpy for an endless time axis, NaN for a length it cannot compute.
    if isinstance(step_dt_s, bool) or not isinstance(step_dt_s, (int, float, np.integer, np.floating)):
        raise HippoNavError(f"step_dt_s must be a number of seconds, got {step_dt_s!r}")
    if not (math.isfinite(step_dt_s) and step_dt_s > 0.0):
        raise HippoNavError(f"step_dt_s must be finite and > 0 s, got {step_dt_s}")
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            rows, lines = [], []
            for row in reader:
                rows.append(row)
                lines.append(reader.line_num)
        with path.open("rb") as raw:
            size = raw.seek(0, 2)
            ends_with_line_break = size == 0 or raw.seek(size - 1) >= 0 and raw.read(1) in (b"\n", b"\r")
    except (OSError, UnicodeDecodeError) as err:
        why = err.strerror if isinstance(err, OSError) else "not UTF-8 text"
        raise HippoNavError(f"{path}: cannot read the trajectory ({why or err})") from None
    need = {"t", "x", "y"}
    if not rows or not need <= set(rows[0]):
        raise HippoNavError(
            f"{path}: a trajectory CSV needs a header with columns t, x, y (and optionally heading)"
        )
    # A file cut mid-write ends inside its last line: no line break, and perhaps a short row or a number
    # cut to fewer digits (which parses, so the hint goes with any error the values cause later).
    hint = "" if ends_with_line_break else f" ({path.name} does not end with a line break: was it cut short?)"
    columns = len(reader.fieldnames or ())
    for n, row in enumerate(rows):
        extra = row.pop(None, None)  # DictReader's key for values past the header
        values = sum(v is not None for v in row.values()) + len(extra or ())
        if values != columns:
            cut = hint if n == len(rows) - 1 else ""
            raise HippoNavError(
                f"{path}: line {lines[n]} has {values} value{'s' * (values != 1)} where the header names "
                f"{columns}{cut}"
            )
    try:
        table = np.array([[float(r[c]) for c in ("t", "x", "y")] for r in rows])
        heading = np.array([float(r["heading"]) for r in rows]) if "heading" in rows[0] else None
    except (TypeError, ValueError) as err:
        raise HippoNavError(f"{path}: a value is not a number ({err})") from None
    t = table[:, 0]
    if len(t) < 2 or not np.isfinite(table).all() or np.any(np.diff(t) <= 0):
        raise HippoNavError(f"{path}: needs ≥ 2 rows of finite values with strictly increasing t")
    if t[-1] - t[0] > MAX_SESSION_S:
        raise HippoNavError(
            f"{path}: spans {t[-1] - t[0]:.6g} s, more than a session's {MAX_SESSION_S:g} s (a day); is t in "
            "seconds? Split a longer trajectory into sessions"
        )
    time = np.arange(0.0, t[-1] - t[0] + 1e-9, step_dt_s)
    if len(time) < 2:
        raise HippoNavError(f"{path}: shorter than two steps of {step_dt_s} s")
    position = np.stack([np.interp(time, t - t[0], table[:, i]) for i in (1, 2)], axis=1)
    if heading is None:
        heading = _smoothed_motion_direction(position, step_dt_s)
    else:
        if not np.isfinite(heading).all():
            raise HippoNavError(f"{path}: the heading column has a value that is not finite")
        heading = np.interp(time, t - t[0], np.unwrap(heading))
    return Trajectory(time, position, smooth_heading(heading, step_dt_s), f"csv {path.name}", hint)


def _smoothed_motion_direction(position_m: np.ndarray, step_dt_s: float) -> np.ndarray:
    velocity = np.gradient(position_m, step_dt_s, axis=0)
    alpha = min(1.0, step_dt_s / 0.15)
    smoothed = np.empty_like(velocity)
    smoothed[0] = velocity[0]
    for i in range(1, len(velocity)):
        smoothed[i] = (1 - alpha) * smoothed[i - 1] + alpha * velocity[i]
    stopped = np.hypot(smoothed[:, 0], smoothed[:, 1]) < 1e-9
    heading = np.arctan2(smoothed[:, 1], smoothed[:, 0])
    heading[stopped] = 0.0 if not np.any(~stopped) else heading[~stopped][0]
    return heading if math.isfinite(float(heading.sum())) else np.zeros(len(position_m))
