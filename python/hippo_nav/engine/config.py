"""Typed engine configuration. The defaults live in Rust (`SpatialMemoryParams::default()`); this model
fills every field it is not given from them, so there is a single source of defaults."""

from __future__ import annotations

import json
from functools import cache
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from hippo_nav import _core

MODULE_NAMES = ("ventral", "intermediate", "dorsal")
"""Grid modules from coarsest (k = 1, ventral MEC) to finest (k = 4, dorsal MEC)."""


@cache
def rust_defaults() -> dict[str, Any]:
    return json.loads(_core.default_engine_config_json())


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


class HdConfig(_Section):
    """Head-direction-by-velocity ring (docs/spec.md §2)."""

    n_theta: int = Field(description="units around the ring (Nθ)")
    n_nu: int = Field(description="units along the angular-velocity axis (Nν)")
    nu_max: float = Field(description="half-range L_r of the velocity axis (neural units)")
    lambda_: float = Field(alias="lambda", description="velocity tuning spread λ of the weights")
    j0: float = Field(description="uniform inhibition J0 ≤ 0")
    j1: float = Field(description="interaction strength J1 > 0")
    input_amp: float = Field(description="velocity input amplitude I_r")
    input_tuning: float = Field(description="velocity tuning strength ε_r in [0, 1]")
    input_sigma: float = Field(description="velocity tuning width σ_r")
    pin_gain: float = Field(description="velocity-pinning feedback gain (0 = the paper's plain model)")


class GridConfig(_Section):
    """One grid-by-velocity module (docs/spec.md §3)."""

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

    n_theta: int
    j0: float
    j1: float
    input_amp: float


class EngineConfig(_Section):
    """The whole spatial-memory network. Unset fields take the Rust defaults."""

    tau_s: float = Field(description="membrane time constant τ (s)")
    max_substep_s: float = Field(description="longest integration sub-step (s)")
    torus_period_m: float = Field(description="side of the square the neural torus stands for (m)")
    hd: HdConfig
    grid: list[GridConfig] = Field(min_length=3, max_length=3)
    place: PlaceConfig
    bump_threshold_frac: float
    lesioned: list[bool] = Field(min_length=3, max_length=3, description="ventral, intermediate, dorsal")
    settle_s: float

    @model_validator(mode="before")
    @classmethod
    def _fill_from_rust_defaults(cls, data: Any) -> Any:
        if isinstance(data, dict):
            if isinstance(data.get("grid"), dict):
                data = {**data, "grid": _grid_overrides(data["grid"])}
            return _merge(rust_defaults(), data)
        return data

    def to_json(self) -> str:
        return self.model_dump_json(by_alias=True)

    def with_lesions(
        self, ventral: bool = False, intermediate: bool = False, dorsal: bool = False
    ) -> EngineConfig:
        return self.model_copy(update={"lesioned": [ventral, intermediate, dorsal]})
