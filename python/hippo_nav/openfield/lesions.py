"""The lesion study in the open field ("MEC inactivation"): each condition (intact, one module off) over
seeds, with the grid score of the modules left, the place field's width and the place code's error, as mean
and 95 % interval over seeds, against the order the 1-D theory predicts (`hippo_nav.theory.lesions`).

Measures per session:
- **grid score**: the mean 90° score (the model's square lattice, `recording.measures`) of each active
  module's measured units;
- **place-field width** σ (m): the place bump's width, which is a place cell's field width (the bump moves
  with the animal at the torus's metres per radian): per sample, the circular spread `sqrt(−2 ln R)` of the
  place activity's marginal along each axis, averaged over axes and samples, times `P/2π`;
- **module width** σ_m (m): the same for each grid module's bump at its wave number k (`R` of `e^{ikθ}`,
  `σ = sqrt(−2 ln R)/k`); the intact sessions' module widths give the theory's place width for every
  condition, `σ = (Σ_active 1/σ_m²)^(−1/2)`, and its order;
- **place-code error**: the RMS distance between the decoded and the true position (m).

Intervals: Student's t over seeds (`mean ± t₀.₉₇₅(n−1)·s/√n`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.openfield.config import LESIONS, OpenFieldConfig
from hippo_nav.openfield.session import record_session
from hippo_nav.recording import GRID_POPULATIONS, Recording

__all__ = [
    "LesionStudy",
    "bump_width_m",
    "lesion_session_measures",
    "run_lesion_study",
    "write_lesion_figure",
]


def bump_width_m(recording: Recording, population: str) -> float:
    """The population's bump width σ (m), averaged over axes and samples (module doc)."""
    rates = recording.populations[population].astype(np.float64)
    phases = recording.unit_phase_rad[population]
    k = 1 if population == "place" else recording.module_k[GRID_POPULATIONS.index(population)]
    total = rates.sum(axis=1)
    active = total > 0
    if not active.any():
        raise HippoNavError(f"{population}: no activity recorded (a lesioned module has no bump)")
    sigmas = []
    for axis in range(2):
        resultant = np.abs(rates[active] @ np.exp(1j * k * phases[:, axis])) / total[active]
        sigmas.append(np.sqrt(-2.0 * np.log(np.clip(resultant, 1e-12, 1.0))) / k)
    return float(np.mean(sigmas) * recording.torus_period_m / (2 * math.pi))


def lesion_session_measures(
    recording: Recording, units: int, shuffles: int, seed: int
) -> dict[str, float | None]:
    """One session's numbers of the study (module doc)."""
    from hippo_nav.recording.measures import measure_recording

    measures = measure_recording(
        recording,
        populations=[p for p, off in zip(GRID_POPULATIONS, recording.lesioned) if not off],
        units_per_population=units,
        shuffles=shuffles,
        seed=seed,
    ).to_dict()
    out: dict[str, float | None] = {}
    for population, off in zip(GRID_POPULATIONS, recording.lesioned):
        summary = measures["spatial"].get(population)
        units_rows = summary["units"] if summary and not off else []
        scores = [u["grid_score_90"] for u in units_rows if u.get("grid_score_90") is not None]
        out[f"{population}_grid_score_90"] = float(np.mean(scores)) if scores else None
        out[f"{population}_width_m"] = None if off else bump_width_m(recording, population)
    out["place_width_m"] = bump_width_m(recording, "place")
    error = np.linalg.norm(recording.decoded_position_m - recording.position_m, axis=1)
    out["place_error_m"] = float(np.sqrt(np.mean(error**2)))
    return out


@dataclass
class LesionStudy:
    """Per condition, per measure: the sessions' values (one per seed) and their mean and 95 % interval."""

    conditions: list[str]
    seeds: list[int]
    values: dict[str, dict[str, list[float | None]]] = field(default_factory=dict)

    def summary(self, condition: str, measure: str) -> tuple[float, float, int] | None:
        """(mean, 95 % half-width, n) over the seeds that have a value; None without one."""
        numbers = np.array([v for v in self.values[condition][measure] if v is not None], dtype=np.float64)
        if numbers.size == 0:
            return None
        if numbers.size == 1:
            return float(numbers[0]), math.nan, 1
        from scipy.stats import t

        half = float(t.ppf(0.975, numbers.size - 1) * numbers.std(ddof=1) / math.sqrt(numbers.size))
        return float(numbers.mean()), half, int(numbers.size)

    def theory_width_m(self) -> dict[str, float]:
        """The theory's place width per condition from the intact sessions' mean module widths."""
        from hippo_nav.theory.lesions import predicted_lesion_order

        sigmas = [self.summary("none", f"{p}_width_m") for p in GRID_POPULATIONS]
        if any(s is None for s in sigmas):
            raise HippoNavError("the theory's widths need the intact condition ('none') in the study")
        predicted = predicted_lesion_order([s[0] for s in sigmas if s is not None])
        return {
            c: predicted[tuple(i for i, name in enumerate(LESIONS[1:]) if name != c)] for c in self.conditions
        }

    def to_dict(self) -> dict[str, object]:
        measures = sorted({m for per in self.values.values() for m in per})
        return {
            "conditions": self.conditions,
            "seeds": self.seeds,
            "values": self.values,
            "summary": {
                c: {m: self.summary(c, m) for m in measures if m in self.values[c]} for c in self.conditions
            },
            "theory_place_width_m": self.theory_width_m() if "none" in self.conditions else None,
        }


def _one(job: tuple[OpenFieldConfig, int, int]) -> dict[str, float | None]:
    config, units, shuffles = job
    return lesion_session_measures(record_session(config), units, shuffles, config.seed)


def run_lesion_study(
    base: OpenFieldConfig,
    seeds: Sequence[int],
    conditions: Sequence[str] = LESIONS,
    *,
    units: int = 16,
    shuffles: int = 10,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> LesionStudy:
    """Every condition × seed as one session of `base` (its duration, arena, landmarks), on `workers`
    processes; sessions are independent and deterministic, so the result does not depend on `workers`."""
    unknown = sorted(set(conditions) - set(LESIONS))
    if unknown:
        raise HippoNavError(f"unknown lesion conditions {unknown}; choose from {list(LESIONS)}")
    jobs = [
        (base.model_copy(update={"lesion": c, "seed": int(s)}), units, shuffles)
        for c in conditions
        for s in seeds
    ]
    study = LesionStudy(list(conditions), [int(s) for s in seeds])
    pool = ProcessPoolExecutor(max_workers=workers) if workers > 1 else None
    try:
        results = pool.map(_one, jobs) if pool is not None else map(_one, jobs)
        for done, ((config, _, _), result) in enumerate(zip(jobs, results), start=1):
            per = study.values.setdefault(config.lesion, {})
            for measure, value in result.items():
                per.setdefault(measure, []).append(value)
            if progress is not None:
                progress(done, len(jobs))
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    return study


def write_lesion_figure(study: LesionStudy, stem: str | Path) -> list[Path]:
    """One report figure (PNG and PDF): the place field's width (with the theory's), the place code's error
    and each module's 90° grid score per condition, mean ± 95 % interval over seeds."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from hippo_nav.io.atomic import atomic_path

    figure = Figure(figsize=(7.1, 2.4), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(1, 3)
    x = np.arange(len(study.conditions))
    theory = study.theory_width_m() if "none" in study.conditions else {}
    panels = [
        ("place_width_m", "place-field width σ (m)"),
        ("place_error_m", "place-code error, RMS (m)"),
    ]
    for ax, (measure, label) in zip(axes[:2], panels):
        _bars(ax, study, [measure], x)
        ax.set_ylabel(label, fontsize=7)
    if theory:
        axes[0].plot(x, [theory[c] for c in study.conditions], "k_", markersize=14, label="1-D theory")
        axes[0].legend(frameon=False, fontsize=7)
    _bars(axes[2], study, [f"{p}_grid_score_90" for p in GRID_POPULATIONS], x)
    axes[2].set_ylabel("90° grid score", fontsize=7)
    axes[2].legend(
        [p.removeprefix("grid_") for p in GRID_POPULATIONS],
        frameon=False,
        fontsize=6,
        loc="upper left",
        bbox_to_anchor=(1.0, 1.0),
    )
    for ax in axes:
        ax.set_xticks(x, [c if c != "none" else "intact" for c in study.conditions], rotation=30)
        ax.set_xlabel("module off", fontsize=7)
        ax.tick_params(labelsize=7)
    written = []
    for suffix in (".png", ".pdf"):
        with atomic_path(Path(f"{stem}{suffix}")) as tmp:
            figure.savefig(tmp, dpi=300, format=suffix[1:])
        written.append(Path(f"{stem}{suffix}"))
    return written


def _bars(ax: object, study: LesionStudy, measures: list[str], x: np.ndarray) -> None:
    from matplotlib import colormaps

    width = 0.8 / len(measures)
    colours = colormaps["viridis"](np.linspace(0.15, 0.85, len(measures)))
    for j, measure in enumerate(measures):
        rows = [study.summary(c, measure) if measure in study.values[c] else None for c in study.conditions]
        mean = [r[0] if r else np.nan for r in rows]
        half = [r[1] if r and r[2] > 1 else 0.0 for r in rows]
        offset = (j - (len(measures) - 1) / 2) * width
        ax.bar(x + offset, mean, width, yerr=half, color=colours[j], capsize=2)  # type: ignore[attr-defined]
