"""A recording of the networks: every unit's activity over time, with the animal's (or car's) position and
heading, as a neuroscientist's session is kept.

Populations and their units (`Recording.populations`, each `(T, n_units)` float32, activity in the network's
own units, ≥ 0):

- `hd`: the head-direction ring's θ-profile (the activity summed over the angular-velocity axis), `Nθ` units;
  unit i prefers heading `2πi/Nθ` (`unit_phase_rad["hd"]`, shape `(Nθ,)`).
- `grid_ventral`, `grid_intermediate`, `grid_dorsal` (k = 1, 2, 4 bumps per torus axis): each module's
  layer-II ("pure grid cell") pattern. The dynamics run in the lattice-symmetric subspace (docs/model.md),
  so the k² copies of a unit on the N×N torus are identical by construction; a recording keeps one unit
  cell of `(N/k)²` units. Unit `(i, j)` (row-major, θy then θx) sits at `θ = (2πj/N, 2πi/N)` (θx, θy) in
  `[0, 2π/k)²`, `unit_phase_rad[name]` shape `(n, 2)`. Every module's bumps move by `2π·d/P` on the shared
  torus for a displacement d (P = `torus_period_m`), and module k's repeat every `2π/k`, so a unit fires
  where `2π·x/P ≡ θ (mod 2π/k)` per axis: a square lattice of fields with spacing `P/k`.
- `place`: the CA3 place torus, `N²` units, phase as above with k = 1 (fields repeat with period P).

Positions are metres in the arena's frame (x right, y up); headings radians from +x, counter-clockwise.
`decoded_position_m` is the place code's unwrapped position in the same frame (the network starts where
the animal starts), `decoded_heading_rad` the ring's. Sampling is uniform: `time_s[i] = i·sample_dt_s`.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.io.errors import os_error_words

__all__ = ["GRID_POPULATIONS", "Recording", "RecordingError"]

GRID_POPULATIONS = ("grid_ventral", "grid_intermediate", "grid_dorsal")
"""The grid modules' populations, coarsest (k = 1) first, as `hippo_nav.engine.MODULE_NAMES`."""

_FORMAT = "hippo_nav.recording/1"


class RecordingError(HippoNavError):
    """A recording file could not be read (missing, truncated, another format)."""


@dataclass
class Recording:
    """One session: time, position, heading and every population's activity (see the module doc)."""

    time_s: np.ndarray
    position_m: np.ndarray
    heading_rad: np.ndarray
    speed_m_s: np.ndarray
    decoded_position_m: np.ndarray
    decoded_heading_rad: np.ndarray
    populations: dict[str, np.ndarray]
    unit_phase_rad: dict[str, np.ndarray]
    torus_period_m: float
    module_k: tuple[int, ...]
    """Bumps per torus axis of each grid module, in `GRID_POPULATIONS` order."""
    lesioned: tuple[bool, ...]
    metadata: dict[str, Any] = field(default_factory=dict)
    """Where the session came from: arena (shape, size), seed, trajectory source, engine config (JSON)."""

    @property
    def sample_dt_s(self) -> float:
        return float(self.time_s[1] - self.time_s[0]) if self.time_s.size > 1 else 0.0

    def spacing_m(self, population: str) -> float:
        """The design spacing of a grid module's lattice (`P/k`), or P for the place torus."""
        if population == "place":
            return self.torus_period_m
        return self.torus_period_m / self.module_k[GRID_POPULATIONS.index(population)]

    def save(self, path: str | Path) -> Path:
        """Write the recording as one `.npz` file, atomically (a reader never sees half of it)."""
        from hippo_nav.io.atomic import open_atomic

        arrays: dict[str, np.ndarray] = {
            "time_s": self.time_s,
            "position_m": self.position_m,
            "heading_rad": self.heading_rad,
            "speed_m_s": self.speed_m_s,
            "decoded_position_m": self.decoded_position_m,
            "decoded_heading_rad": self.decoded_heading_rad,
        }
        for name, rates in self.populations.items():
            arrays[f"rates/{name}"] = rates
            arrays[f"phase/{name}"] = self.unit_phase_rad[name]
        header = {
            "format": _FORMAT,
            "torus_period_m": self.torus_period_m,
            "module_k": list(self.module_k),
            "lesioned": list(self.lesioned),
            "metadata": self.metadata,
        }
        arrays["header_json"] = np.array(json.dumps(header))
        with open_atomic(path, "wb") as f:
            np.savez_compressed(f, **arrays)  # type: ignore[arg-type]
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> Recording:
        """Read `save`'s file; a missing, truncated or foreign file is a `RecordingError` naming it."""
        path = Path(path)
        try:
            # np.load given a name leaves the file open when it is not a zip archive: open it here.
            with path.open("rb") as f, np.load(f, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            header = json.loads(str(arrays.pop("header_json")))
        except FileNotFoundError:
            raise RecordingError(f"{path}: no such recording (write one with `hippo-nav record`)") from None
        except OSError as err:
            raise RecordingError(f"{path}: not readable ({os_error_words(err)})") from None
        except (ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
            raise RecordingError(
                f"{path}: not a readable hippo_nav recording ({err}); write it again with `hippo-nav record`"
            ) from None
        if header.get("format") != _FORMAT:
            raise RecordingError(f"{path}: format {header.get('format')!r}, expected {_FORMAT!r}")
        names = [k.split("/", 1)[1] for k in arrays if k.startswith("rates/")]
        _check_shapes(path, arrays, names)
        return cls(
            time_s=arrays["time_s"],
            position_m=arrays["position_m"],
            heading_rad=arrays["heading_rad"],
            speed_m_s=arrays["speed_m_s"],
            decoded_position_m=arrays["decoded_position_m"],
            decoded_heading_rad=arrays["decoded_heading_rad"],
            populations={n: arrays[f"rates/{n}"] for n in names},
            unit_phase_rad={n: arrays[f"phase/{n}"] for n in names},
            torus_period_m=float(header["torus_period_m"]),
            module_k=tuple(int(k) for k in header["module_k"]),
            lesioned=tuple(bool(b) for b in header["lesioned"]),
            metadata=dict(header["metadata"]),
        )


_PER_SAMPLE = {  # array: its columns (0: one value a sample)
    "time_s": 0,
    "position_m": 2,
    "heading_rad": 0,
    "speed_m_s": 0,
    "decoded_position_m": 2,
    "decoded_heading_rad": 0,
}


def _check_shapes(path: Path, arrays: dict[str, np.ndarray], populations: list[str]) -> None:
    """Every array of a loaded recording of the shape the others imply (one row a sample, one phase a unit):
    a file whose arrays disagree (edited, or joined from two runs) is a `RecordingError` naming the array,
    not a failure deep inside a figure."""

    def refuse(what: str) -> RecordingError:
        return RecordingError(
            f"{path}: {what}; write the recording again (`hippo-nav run` or `hippo-nav record`)"
        )

    missing = [name for name in _PER_SAMPLE if name not in arrays]
    missing += [f"phase/{name}" for name in populations if f"phase/{name}" not in arrays]
    if missing:
        raise refuse(f"no {', '.join(missing)} array")
    samples = arrays["time_s"].shape[0] if arrays["time_s"].ndim == 1 else -1
    if samples < 0:
        raise refuse(f"time_s has shape {arrays['time_s'].shape}, not one time a sample")
    for name, columns in _PER_SAMPLE.items():
        expected = (samples,) if columns == 0 else (samples, columns)
        if arrays[name].shape != expected:
            raise refuse(f"{name} has shape {arrays[name].shape}, expected {expected} ({samples} samples)")
    for name in populations:
        rates, phases = arrays[f"rates/{name}"], arrays[f"phase/{name}"]
        if rates.ndim != 2 or rates.shape[0] != samples:
            raise refuse(f"rates/{name} has shape {rates.shape}, expected ({samples}, units)")
        if phases.ndim == 0 or phases.shape[0] != rates.shape[1]:
            raise refuse(
                f"phase/{name} has shape {phases.shape}, expected one phase for each of {rates.shape[1]} units"
            )
