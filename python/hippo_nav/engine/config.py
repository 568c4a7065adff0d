"""Typed engine configuration. The defaults live in Rust (`SpatialMemoryParams::default()`); this model
fills every field it is not given from them, so there is a single source of defaults."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from hippo_nav import _core
from hippo_nav._defaults import rust_default, rust_defaults

N_MODULES: int = _core.N_MODULES
"""Grid modules of the network (the Rust engine's `N_MODULES`)."""

MODULE_NAMES = ("ventral", "intermediate", "dorsal")
"""Grid modules from coarsest (k = 1, ventral MEC) to finest (k = 4, dorsal MEC), one name per module."""


def _merge(defaults: Any, given: Any) -> Any:
    if isinstance(defaults, dict) and isinstance(given, dict):
        return {k: _merge(defaults.get(k), given[k]) if k in defaults else given[k] for k in given} | {
            k: v for k, v in defaults.items() if k not in given
        }
    if isinstance(defaults, list) and isinstance(given, list) and len(defaults) == len(given):
        return [_merge(d, g) for d, g in zip(defaults, given)]
    return given


def _grid_overrides(given: dict[str, Any]) -> list[dict[str, Any]]:
    """`grid` given by module name instead of as a list of all three: `{"dorsal": {"nu_max": 0.1}}`
    changes one field of one module, `{"all": {...}}` the same fields of every module."""
    known = {"all", *MODULE_NAMES}
    unknown = sorted(set(given) - known)
    if unknown:
        raise ValueError(
            f"grid modules are named {', '.join(MODULE_NAMES)} (or 'all'), not {', '.join(unknown)}"
        )
    common = given.get("all", {})
    return [{**common, **given.get(name, {})} for name in MODULE_NAMES]


class _Section(BaseModel):
    # NaN and infinity are refused here, naming the field, rather than reaching the engine as JSON nulls.
    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)


def _d(*path: str | int) -> Any:
    return rust_default("engine", *path)


class HdConfig(_Section):
    """Head-direction-by-velocity ring (docs/spec.md §2)."""

    n_theta: int = Field(_d("hd", "n_theta"), description="units around the ring (Nθ)")
    n_nu: int = Field(_d("hd", "n_nu"), description="units along the angular-velocity axis (Nν)")
    nu_max: float = Field(
        _d("hd", "nu_max"), description="half-range L_r of the velocity axis (neural units)"
    )
    lambda_: float = Field(_d("hd", "lambda"), alias="lambda", description="velocity tuning spread λ")
    j0: float = Field(_d("hd", "j0"), description="uniform inhibition J0 ≤ 0")
    j1: float = Field(_d("hd", "j1"), description="interaction strength J1 > 0")
    input_amp: float = Field(_d("hd", "input_amp"), description="velocity input amplitude I_r")
    input_tuning: float = Field(
        _d("hd", "input_tuning"), description="velocity tuning strength ε_r in [0, 1]"
    )
    input_sigma: float = Field(_d("hd", "input_sigma"), description="velocity tuning width σ_r")
    pin_gain: float = Field(
        _d("hd", "pin_gain"), description="velocity-pinning gain (0 = the paper's plain model)"
    )


class GridConfig(_Section):
    """One grid-by-velocity module (docs/spec.md §3). Defaults differ per module, so they come with the
    module list (`EngineConfig.grid`); a module given by name or partly is completed from its own."""

    k: int = Field(description="bumps per torus axis (1, 2, 4)")
    n_theta: int = Field(description="units per torus axis (N)")
    n_nu: int = Field(description="units per velocity axis (M)")
    nu_max: float = Field(description="half-range L_t of each velocity axis")
    lambda_: float = Field(alias="lambda", description="velocity tuning spread λ of the weights")
    j0: float
    jk: float
    input_amp: float
    input_tuning: float
    input_sigma: float
    pin_gain: float


class PlaceConfig(_Section):
    """CA3 place torus (docs/spec.md §5)."""

    n_theta: int = _d("place", "n_theta")
    j0: float = _d("place", "j0")
    j1: float = _d("place", "j1")
    input_amp: float = _d("place", "input_amp")


def _default_grid() -> list[GridConfig]:
    return [GridConfig.model_validate(g) for g in rust_defaults("engine")["grid"]]


class EngineConfig(_Section):
    """The whole spatial-memory network; every default comes from the Rust engine."""

    # Bounds that keep a typo from hanging a run: a sub-step of 1e-9 s would mean 10⁸ sub-steps per frame
    # before the first frame is done (and no Ctrl-C until then).
    tau_s: float = Field(_d("tau_s"), ge=1e-4, le=10.0, description="membrane time constant τ (s)")
    max_substep_s: float = Field(
        _d("max_substep_s"), ge=1e-4, le=1.0, description="longest integration sub-step (s)"
    )
    torus_period_m: float = Field(
        _d("torus_period_m"), ge=1.0, le=1e5, description="side of the square the torus stands for (m)"
    )
    hd: HdConfig = Field(default_factory=HdConfig)
    grid: list[GridConfig] = Field(default_factory=_default_grid, min_length=N_MODULES, max_length=N_MODULES)
    place: PlaceConfig = Field(default_factory=PlaceConfig)
    bump_threshold_frac: float = _d("bump_threshold_frac")
    lesioned: list[bool] = Field(
        default_factory=lambda: [False] * N_MODULES,
        min_length=N_MODULES,
        max_length=N_MODULES,
        description="ventral, intermediate, dorsal",
    )
    settle_s: float = _d("settle_s")

    @model_validator(mode="before")
    @classmethod
    def _complete_grid_modules(cls, data: Any) -> Any:
        # A module given partly (in the list, or by name) is completed from that module's own defaults.
        if isinstance(data, dict) and "grid" in data:
            given = data["grid"]
            if isinstance(given, dict):
                given = _grid_overrides(given)
            defaults = rust_defaults("engine")["grid"]
            if isinstance(given, list) and len(given) == len(defaults):
                data = {**data, "grid": [_merge(d, g) for d, g in zip(defaults, given)]}
        return data

    def to_json(self) -> str:
        return self.model_dump_json(by_alias=True)

    def with_lesions(
        self, ventral: bool = False, intermediate: bool = False, dorsal: bool = False
    ) -> EngineConfig:
        return self.model_copy(update={"lesioned": [ventral, intermediate, dorsal]})
