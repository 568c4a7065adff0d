"""Typed engine configuration. The defaults live in Rust (`SpatialMemoryParams::default()`); this model
fills every field it is not given from them, so there is a single source of defaults."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from hippo_nav import _core
from hippo_nav._defaults import ConfigSection, rust_default, rust_defaults

N_MODULES: int = _core.N_MODULES
"""Grid modules of the network (the Rust engine's `N_MODULES`)."""

MODULE_NAMES = ("ventral", "intermediate", "dorsal")
"""Grid modules from coarsest (k = 1, ventral MEC) to finest (k = 4, dorsal MEC), one name per module."""


# Sizes the Rust engine accepts (`hd.rs`, `grid.rs`, `place.rs`, `spatial_memory.rs` validate the same): a
# typo of a few digits must be refused here, not allocate gigabytes in the engine.
MAX_HD_UNITS = 1 << 20
"""Units of the head-direction ring at most (`n_theta · n_nu`; the default has 1 920)."""
MAX_GRID_UNITS = 1 << 22
"""Units of one grid module at most (`n_theta² · n_nu²`; the default has 331 776)."""


def _merge(defaults: Any, given: Any) -> Any:
    if isinstance(defaults, dict) and isinstance(given, dict):
        return {k: _merge(defaults.get(k), given[k]) if k in defaults else given[k] for k in given} | {
            k: v for k, v in defaults.items() if k not in given
        }
    if isinstance(defaults, list) and isinstance(given, list) and len(defaults) == len(given):
        return [_merge(d, g) for d, g in zip(defaults, given)]
    return given


_ALIASES = {"lambda_": "lambda"}
"""Field names a user may write for an alias (`lambda` is a Python keyword): merged under the alias."""


def _grid_fields() -> set[str]:
    return {n for name, field in GridConfig.model_fields.items() for n in (name, field.alias) if n}


def _grid_overrides(given: dict[str, Any]) -> list[dict[str, Any]]:
    """`grid` given as an object instead of a list of all three modules: grid fields change every module
    (`{"n_theta": 32}`), a module name one module (`{"dorsal": {"nu_max": 0.1}}`), `all` every module
    (`{"all": {...}}`, like bare fields); a named module wins over `all` and bare fields."""
    fields = _grid_fields()
    unknown = sorted(set(given) - {"all", *MODULE_NAMES} - fields)
    if unknown:
        names = ", ".join(sorted(_ALIASES.get(f, f) for f in GridConfig.model_fields))
        raise ValueError(
            f"grid: {', '.join(repr(u) for u in unknown)} is neither a module ({', '.join(MODULE_NAMES)} or "
            f"'all') nor a grid field ({names}); e.g. "
            '{"grid": {"n_theta": 32}} for every module, {"grid": {"dorsal": {"nu_max": 0.1}}} for one'
        )
    for name in ("all", *MODULE_NAMES):
        if name in given and not isinstance(given[name], dict):
            raise ValueError(f"grid.{name} must be an object of grid fields, got {given[name]!r}")
    common = {**{k: v for k, v in given.items() if k in fields}, **given.get("all", {})}
    return [{**common, **given.get(name, {})} for name in MODULE_NAMES]


def _given_n_theta(section: Any) -> Any:
    """The `n_theta` a user gave for a grid module or the place torus (a dict or a model), else None."""
    if isinstance(section, dict):
        return section.get("n_theta")
    if isinstance(section, BaseModel) and "n_theta" in section.model_fields_set:
        return getattr(section, "n_theta", None)
    return None


class _Section(ConfigSection):
    model_config = ConfigDict(populate_by_name=True)


def _d(*path: str | int) -> Any:
    return rust_default("engine", *path)


# Upper bounds that keep a typo (1e300) from validating and then leaving the networks with no bump or NaN
# activity: the defaults are gains up to 6 000, velocity half-ranges 0.06–0.1 (at most 1 for the open field)
# and tuning spreads about 13.
_MAX_GAIN = 1.0e6
_MAX_NU = 10.0
_MAX_LAMBDA = 1.0e4


class HdConfig(_Section):
    """Head-direction-by-velocity ring (docs/spec.md §2)."""

    n_theta: int = Field(_d("hd", "n_theta"), ge=4, le=1 << 16, description="units around the ring (Nθ)")
    n_nu: int = Field(
        _d("hd", "n_nu"), ge=1, le=1024, description="units along the angular-velocity axis (Nν)"
    )
    nu_max: float = Field(
        _d("hd", "nu_max"),
        gt=0.0,
        le=_MAX_NU,
        description="half-range L_r of the velocity axis (neural units)",
    )
    lambda_: float = Field(
        _d("hd", "lambda"), gt=0.0, le=_MAX_LAMBDA, alias="lambda", description="velocity tuning spread λ"
    )
    j0: float = Field(_d("hd", "j0"), ge=-_MAX_GAIN, le=0.0, description="uniform inhibition J0 ≤ 0")
    j1: float = Field(_d("hd", "j1"), gt=0.0, le=_MAX_GAIN, description="interaction strength J1 > 0")
    input_amp: float = Field(
        _d("hd", "input_amp"), gt=0.0, le=_MAX_GAIN, description="velocity input amplitude I_r"
    )
    input_tuning: float = Field(
        _d("hd", "input_tuning"), ge=0.0, le=1.0, description="velocity tuning strength ε_r in [0, 1]"
    )
    input_sigma: float = Field(
        _d("hd", "input_sigma"), gt=0.0, le=_MAX_NU, description="velocity tuning width σ_r"
    )
    pin_gain: float = Field(
        _d("hd", "pin_gain"),
        ge=0.0,
        le=1.0,
        description="velocity-pinning gain (0 = the paper's plain model)",
    )

    @model_validator(mode="after")
    def _fits_in_memory(self) -> HdConfig:
        if self.n_theta * self.n_nu > MAX_HD_UNITS:
            raise ValueError(
                f"n_theta · n_nu = {self.n_theta} · {self.n_nu} = {self.n_theta * self.n_nu} units; the ring "
                f"may have {MAX_HD_UNITS} at most (the default has {_d('hd', 'n_theta') * _d('hd', 'n_nu')})"
            )
        return self


class GridConfig(_Section):
    """One grid-by-velocity module (docs/spec.md §3). Defaults differ per module, so they come with the
    module list (`EngineConfig.grid`); a module given by name or partly is completed from its own."""

    k: int = Field(ge=1, le=16, description="bumps per torus axis (1, 2, 4)")
    n_theta: int = Field(
        ge=4, le=1024, description="units per torus axis (N; shared with the place torus, `place.n_theta`)"
    )
    n_nu: int = Field(ge=1, le=64, description="units per velocity axis (M)")
    nu_max: float = Field(gt=0.0, le=_MAX_NU, description="half-range L_t of each velocity axis")
    lambda_: float = Field(
        gt=0.0, le=_MAX_LAMBDA, alias="lambda", description="velocity tuning spread λ of the weights"
    )
    j0: float = Field(ge=-_MAX_GAIN, le=0.0, description="uniform inhibition J0 ≤ 0")
    jk: float = Field(gt=0.0, le=_MAX_GAIN, description="interaction strength Jk > 0")
    input_amp: float = Field(gt=0.0, le=_MAX_GAIN)
    input_tuning: float = Field(ge=0.0, le=1.0)
    input_sigma: float = Field(gt=0.0, le=_MAX_NU)
    pin_gain: float = Field(ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _bumps_fit_the_torus(self) -> GridConfig:
        if self.n_theta % self.k != 0 or self.n_theta // self.k < 2:
            raise ValueError(
                f"n_theta = {self.n_theta} must be a multiple of k = {self.k} with at least 2 units per bump "
                "cell"
            )
        units = self.n_theta**2 * self.n_nu**2
        if units > MAX_GRID_UNITS:
            raise ValueError(
                f"n_theta² · n_nu² = {self.n_theta}² · {self.n_nu}² = {units} units; a module may have "
                f"{MAX_GRID_UNITS} at most (the default has 64² · 9² = 331776)"
            )
        return self


class PlaceConfig(_Section):
    """CA3 place torus (docs/spec.md §5)."""

    n_theta: int = Field(
        _d("place", "n_theta"), ge=4, le=4096, description="units per torus axis (the grid modules' N)"
    )
    j0: float = Field(_d("place", "j0"), ge=-_MAX_GAIN, le=0.0)
    j1: float = Field(_d("place", "j1"), gt=0.0, le=_MAX_GAIN)
    input_amp: float = Field(_d("place", "input_amp"), gt=0.0, le=_MAX_GAIN)


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
        _d("torus_period_m"), ge=0.1, le=1e5, description="side of the square the torus stands for (m)"
    )
    hd: HdConfig = Field(default_factory=HdConfig)
    grid: list[GridConfig] = Field(default_factory=_default_grid, min_length=N_MODULES, max_length=N_MODULES)
    place: PlaceConfig = Field(default_factory=PlaceConfig)
    bump_threshold_frac: float = Field(
        _d("bump_threshold_frac"),
        ge=0.0,
        le=1.0,
        description="fraction of a pattern's peak that seeds a bump",
    )
    lesioned: list[bool] = Field(
        default_factory=lambda: [False] * N_MODULES,
        min_length=N_MODULES,
        max_length=N_MODULES,
        description="ventral, intermediate, dorsal",
    )
    settle_s: float = Field(
        _d("settle_s"), ge=0.0, le=10.0, description="simulated time the seeded bumps settle at reset (s)"
    )

    @model_validator(mode="before")
    @classmethod
    def _complete_grid_modules(cls, data: Any) -> Any:
        # A module given partly (in the list, or by name) is completed from that module's own defaults; the
        # torus size is one setting shared by the grid modules and the place torus, so giving it on one side
        # (every module alike, or the place torus) sets the other.
        if not isinstance(data, dict):
            return data
        given = data.get("grid", [{}] * N_MODULES)
        if isinstance(given, dict):
            given = _grid_overrides(given)
        if not isinstance(given, list):
            return data
        if len(given) != N_MODULES:
            raise ValueError(
                f"grid: a list gives all {N_MODULES} modules ({', '.join(MODULE_NAMES)}), got {len(given)}; "
                'write {} for a module left as it is, or name the modules: {"grid": {"dorsal": {...}}}'
            )
        given = [{_ALIASES.get(k, k): v for k, v in m.items()} if isinstance(m, dict) else m for m in given]
        place = data.get("place")
        place_n = _given_n_theta(place)
        grid_n = [_given_n_theta(m) for m in given]
        if place_n is None and None not in grid_n and len(set(grid_n)) == 1:
            if place is None or isinstance(place, dict):
                data = {**data, "place": {**(place or {}), "n_theta": grid_n[0]}}
            elif isinstance(place, PlaceConfig):
                data = {**data, "place": place.model_copy(update={"n_theta": grid_n[0]})}
        elif place_n is not None and grid_n == [None] * N_MODULES:
            given = [{**m, "n_theta": place_n} if isinstance(m, dict) else m for m in given]
        defaults = rust_defaults("engine")["grid"]
        return {**data, "grid": [_merge(d, g) for d, g in zip(defaults, given)]}

    @model_validator(mode="after")
    def _one_torus(self) -> EngineConfig:
        if self.max_substep_s > 5.0 * self.tau_s:
            raise ValueError(
                f"max_substep_s = {self.max_substep_s} s is longer than 5·tau_s = {5.0 * self.tau_s:g} s: such "
                "sub-steps do not resolve the attractor dynamics"
            )
        for i, g in enumerate(self.grid):
            if g.n_theta != self.place.n_theta:
                raise ValueError(
                    f"grid[{i}] ({MODULE_NAMES[i]}).n_theta = {g.n_theta} differs from place.n_theta = "
                    f"{self.place.n_theta}: the grid modules and the place torus share one torus; set its size "
                    'once, e.g. {"grid": {"n_theta": 32}} (every module and the place torus follow)'
                )
        return self

    def to_json(self) -> str:
        return self.model_dump_json(by_alias=True)

    def with_lesions(
        self, ventral: bool = False, intermediate: bool = False, dorsal: bool = False
    ) -> EngineConfig:
        # Validated as a config file's `lesioned` is (model_copy would take `dorsal="no"` as it comes).
        return type(self).model_validate({**self.model_dump(), "lesioned": [ventral, intermediate, dorsal]})
