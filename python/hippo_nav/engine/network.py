"""The spatial-memory network (Rust engine) with a typed Python face.

`SpatialMemory.step(yaw_rate_rad_s, speed_m_s, dt_s, view)` advances one camera frame and returns a
`SpatialReadout` (frozen, built in Rust: `Bump`, `ModuleReadout` and `SpatialReadout` are the native
classes); the activity getters return numpy arrays (float64) for plots and view cells.
Angles are radians on the neural torus/ring; positions are metres in the map frame of the engine
(x along the initial heading, y to its left).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from hippo_nav import _core
from hippo_nav._core import Bump, HippoNavError, ModuleReadout, SpatialReadout
from hippo_nav.engine.config import N_MODULES, EngineConfig

__all__ = ["Bump", "ModuleReadout", "SpatialMemory", "SpatialReadout", "ViewPatterns"]


@dataclass
class ViewPatterns:
    """What a view cell stores and injects back (docs/spec.md §7): the HD θ-profile and each grid module's
    layer-II pattern (None skips a module), injected at `strength`."""

    hd_profile: np.ndarray
    grid_layer2: list[np.ndarray | None]
    strength: float = 1.0


MAX_SEED_ANGLE_RAD = 1.0e6
"""The largest angle `SpatialMemory.reset` takes (rad): beyond, too few of its digits lie below 2π."""


class SpatialMemory:
    """HD ring + `N_MODULES` grid modules + CA3 place torus, stepped per camera frame."""

    def __init__(self, config: EngineConfig | None = None, dtype: str = "float32") -> None:
        if config is not None and not isinstance(config, EngineConfig):
            raise TypeError(
                f"config must be an EngineConfig, got {type(config).__name__} (settings from a file: "
                "hippo_nav.load_config(path).engine, which checks every key)"
            )
        self.config = config if config is not None else EngineConfig()
        self._net = _core._SpatialMemory(self.config.to_json(), dtype)

    def step(
        self, yaw_rate_rad_s: float, speed_m_s: float, dt_s: float, view: ViewPatterns | None = None
    ) -> SpatialReadout:
        packed = None
        if view is not None:
            packed = (
                np.asarray(view.hd_profile, dtype=np.float64),
                [None if g is None else np.asarray(g, dtype=np.float64) for g in view.grid_layer2],
                float(view.strength),
            )
        return self._net.step(float(yaw_rate_rad_s), float(speed_m_s), float(dt_s), packed)

    def readout(self) -> SpatialReadout:
        """The current readout, without integrating."""
        return self._net.readout()

    def reset(self, heading_rad: float = 0.0, phase_rad: tuple[float, float] = (0.0, 0.0)) -> None:
        """Seed one bump per network: the heading (rad) and the place phase on the torus (rad, x and y)."""
        values = np.asarray([heading_rad, *np.asarray(phase_rad, dtype=np.float64).reshape(-1)], np.float64)
        if values.size != 3:
            raise HippoNavError(f"phase_rad must be two angles (x, y) in rad, got {phase_rad!r}")
        if not (np.isfinite(values).all() and np.abs(values).max() <= MAX_SEED_ANGLE_RAD):
            # An angle of 1e17 rad has no digits left below 2π: it seeded a flat ring or striped bumps.
            raise HippoNavError(
                f"reset angles (heading {heading_rad!r}, phase {phase_rad!r}) must be finite and within "
                f"±{MAX_SEED_ANGLE_RAD:g} rad"
            )
        self._net.reset(float(values[0]), (float(values[1]), float(values[2])))

    def set_lesions(self, ventral: bool = False, intermediate: bool = False, dorsal: bool = False) -> None:
        """Switch grid modules off ("MEC inactivation"); a lesioned module leaves the fusion. `config` says so
        too (its `lesioned`), so a state saved from it is restored only into a network lesioned alike."""
        flags = _lesion_flags(ventral, intermediate, dorsal)
        self._net.set_lesions(flags)
        self.config = self.config.with_lesions(*flags)

    def hd_activity(self) -> np.ndarray:
        """HD-by-velocity activity, shape (Nν, Nθ)."""
        return self._net.hd_activity()

    def hd_profile(self) -> np.ndarray:
        """HD θ-profile: the activity summed over the velocity axis, shape (Nθ,)."""
        return self._net.hd_profile()

    def grid_activity(self, module: int) -> np.ndarray:
        """Conjunctive activity, shape (M, M, N, N) = (νy, νx, θy, θx)."""
        return self._net.grid_activity(_module_index(module))

    def grid_layer2(self, module: int) -> np.ndarray:
        """Layer-II ("pure grid cell") pattern, shape (N, N) = (θy, θx)."""
        return self._net.grid_layer2(_module_index(module))

    def place_activity(self) -> np.ndarray:
        return self._net.place_activity()

    def place_input(self) -> np.ndarray:
        return self._net.place_input()

    def view_patterns(self) -> ViewPatterns:
        """The patterns a new view cell stores (docs/spec.md §7)."""
        return ViewPatterns(
            hd_profile=self.hd_profile(),
            grid_layer2=[self.grid_layer2(i) for i in range(N_MODULES)],
        )

    def state(self) -> dict:
        """Full network state, for saving and resuming: activity arrays plus `aux` (JSON text)."""
        return {
            "hd": self.hd_activity(),
            "grid": [self.grid_activity(i) for i in range(N_MODULES)],
            "place": self.place_activity(),
            "aux": self._net.aux_state_json(),
        }

    def set_state(self, state: dict) -> None:
        """Restore `state()`; validated as a whole before anything changes."""
        missing = [key for key in ("hd", "grid", "place", "aux") if key not in state]
        if missing:
            raise HippoNavError(f"the network state lacks {', '.join(missing)}; give a dict made by state()")
        _check_same_lesions(str(state["aux"]), list(self.config.lesioned))
        self._net.set_state(
            np.asarray(state["hd"], dtype=np.float64),
            [np.asarray(g, dtype=np.float64) for g in state["grid"]],
            np.asarray(state["place"], dtype=np.float64),
            str(state["aux"]),
        )

    @property
    def meters_per_rad(self) -> float:
        return self.config.torus_period_m / (2 * np.pi)


def _check_same_lesions(aux_json: str, lesioned: list[bool]) -> None:
    """A state carries its network's lesions: restoring one saved with other lesions would lesion this network
    (or heal it) behind its config's back. Refused, naming both; a malformed `aux` is left to the engine's
    own check, which says what is wrong with it."""
    try:
        saved = json.loads(aux_json).get("lesioned")
    except (ValueError, AttributeError):
        return
    if isinstance(saved, list) and len(saved) == len(lesioned) and [bool(x) for x in saved] != lesioned:
        names = ("ventral", "intermediate", "dorsal")

        def shown(flags: list[bool]) -> str:
            return ", ".join(n for n, f in zip(names, flags, strict=True) if f) or "none"

        raise HippoNavError(
            f"the state was saved from a network with lesions {shown([bool(x) for x in saved])}; this one has "
            f"{shown(lesioned)}: call set_lesions(...) to match before set_state"
        )


def _lesion_flags(ventral: object, intermediate: object, dorsal: object) -> list[bool]:
    """Each flag a real boolean: `dorsal="no"` is a non-empty string, true to `bool`, a lesion not asked for."""
    flags = {"ventral": ventral, "intermediate": intermediate, "dorsal": dorsal}
    for name, value in flags.items():
        if not isinstance(value, bool | np.bool_):
            raise TypeError(f"{name} must be True or False, got {value!r}")
    return [bool(v) for v in flags.values()]


def _module_index(module: object) -> int:
    """A grid module's index (0 = coarsest) as an int the native call takes, or an error naming it."""
    if isinstance(module, bool) or not isinstance(module, int | np.integer):
        raise TypeError(f"module must be a grid module index (0 = coarsest), got {module!r}")
    if not 0 <= int(module) < N_MODULES:
        raise HippoNavError(f"grid module index {module} out of range: there are {N_MODULES} (0 = coarsest)")
    return int(module)
