"""A `Recording` as a Neurodata Without Borders file (NWB 2, written with pynwb), for the neuroscientist's own
tools (pynwb, pynapple, NWB Widgets), and back.

Layout of the file:

- `/processing/behavior` (the animal): `Position/position` (`SpatialSeries`, metres, `(T, 2)`, the arena's
  frame: x right, y up, as `Recording.position_m`), `CompassDirection/heading` (`SpatialSeries`, radians from
  +x, counter-clockwise), `speed` (`TimeSeries`, m/s). `position` holds the session's timestamps (seconds
  from the session start); the other behaviour series link to them.
- `/processing/network` (the model): one `TimeSeries` per population (`hd`, `grid_ventral`,
  `grid_intermediate`, `grid_dorsal`, `place`): data `(T, n_units)` float32, unit "a.u." (the network's
  own activity units), `starting_time` + `rate`, gzip-compressed; beside each a `DynamicTable`
  `<population>_units`, one row per column of the data: `population`, `module` (ventral, intermediate,
  dorsal, place, head direction), and for a torus `k` (bumps per torus axis), `spacing_m` (the lattice's
  design spacing P/k), `lesioned`, `phase_x_rad`, `phase_y_rad` (the unit's preferred phase on the torus),
  for the ring `preferred_heading_rad`. `decoded_position` (`Position`) and `decoded_heading`
  (`CompassDirection`) hold the networks' readout; the one-row table `session` keeps what makes the file a
  `Recording` again: the format name, `torus_period_m` and a JSON header (module k, lesions, population
  order, the session metadata).

Reproducible: the identifier is a UUID-5 of the session id and the metadata's canonical JSON, and the session
start and file creation times are a fixed epoch, 2000-01-01T00:00:00Z (a simulation has no wall-clock time;
all times are seconds from that start). Files are written atomically (`hippo_nav.io.atomic.atomic_path`):
a reader never sees half a file.

Reference: Rübel et al., "The Neurodata Without Borders ecosystem for neurophysiological data science",
eLife 11, e78362 (2022); pynapple: Viejo et al., eLife 12, RP85786 (2023).
"""

from __future__ import annotations

import hashlib
import json
import uuid
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from hippo_nav.io.errors import os_error_words
from hippo_nav.recording.session import GRID_POPULATIONS, Recording, RecordingError

__all__ = ["EPOCH", "NWB_FORMAT", "read_nwb", "write_nwb"]

NWB_FORMAT = "hippo_nav.recording.nwb/1"
EPOCH = datetime(2000, 1, 1, tzinfo=timezone.utc)
"""Every exported session starts here (module doc)."""

_BEHAVIOUR = "behavior"  # NWB's conventional (American) module name, which readers look for
_NETWORK = "network"
_MODULE_LABELS = {
    "hd": "head direction",
    "grid_ventral": "ventral",
    "grid_intermediate": "intermediate",
    "grid_dorsal": "dorsal",
    "place": "place",
}
_ARENA_FRAME = "arena frame: x right, y up, metres (hippo_nav.recording.Recording.position_m)"
_HEADING_FRAME = "radians from the arena's +x axis, counter-clockwise"


def write_nwb(rec: Recording, path: str | Path, *, session_id: str | None = None) -> Path:
    """Write `rec` as an NWB file at `path` (module doc), atomically; returns the path. `session_id`
    defaults to `seed<seed>-<digest>` (the seed at `metadata["seed"]` or `metadata["session"]["seed"]`, the
    digest of the metadata; `hippo_nav-<digest>` without a seed). A missing folder or a path that is a
    folder is a `RecordingError` saying what to do."""
    from pynwb import NWBHDF5IO

    from hippo_nav.io.atomic import WriteError, atomic_path

    path = Path(path)
    if path.is_dir():
        raise RecordingError(f"{path}: is a folder; give a file name such as {path / 'session.nwb'}")
    if not path.parent.is_dir():
        raise RecordingError(f"{path}: the folder {path.parent} does not exist; create it first")
    nwbfile = _nwbfile(rec, session_id)
    _add_behaviour(nwbfile, rec)
    _add_network(nwbfile, rec)
    try:
        with atomic_path(path) as tmp, NWBHDF5IO(str(tmp), "w") as io:
            io.write(nwbfile)
    except WriteError as err:
        raise RecordingError(f"{path}: cannot write the NWB file ({err.reason})") from None
    return path


def _header(rec: Recording) -> dict[str, Any]:
    return {
        "format": NWB_FORMAT,
        "torus_period_m": rec.torus_period_m,
        "module_k": list(rec.module_k),
        "lesioned": list(rec.lesioned),
        "populations": list(rec.populations),
        "metadata": rec.metadata,
    }


def _nwbfile(rec: Recording, session_id: str | None) -> Any:
    from pynwb import NWBFile

    canonical = json.dumps(_header(rec), sort_keys=True, default=str)
    digest = hashlib.sha256(canonical.encode()).hexdigest()
    session = rec.metadata.get("session")
    seed = rec.metadata.get("seed", session.get("seed") if isinstance(session, dict) else None)
    session_id = session_id or (
        f"seed{seed}-{digest[:10]}" if seed is not None else f"hippo_nav-{digest[:16]}"
    )
    return NWBFile(
        session_description="hippo_nav simulated session: head-direction ring, three grid modules and the "
        "CA3 place torus recorded while a simulated animal forages",
        identifier=str(uuid.uuid5(uuid.NAMESPACE_URL, f"hippo_nav/{session_id}/{digest}")),
        session_start_time=EPOCH,
        file_create_date=[EPOCH],
        session_id=session_id,
        source_script="hippo_nav.recording.nwb.write_nwb",
        source_script_file_name="hippo_nav/recording/nwb.py",
        notes=f"{NWB_FORMAT}; read back with hippo_nav.recording.nwb.read_nwb",
    )


def _uniform(rec: Recording) -> bool:
    """Sampled every `sample_dt_s` from `time_s[0]` (to float precision), so `starting_time` + `rate` say it."""
    if rec.time_s.size < 2 or rec.sample_dt_s <= 0:
        return False
    expected = rec.time_s[0] + np.arange(rec.time_s.size) * rec.sample_dt_s
    return bool(np.allclose(rec.time_s, expected, rtol=0.0, atol=1e-9 * max(1.0, float(rec.time_s[-1]))))


def _add_behaviour(nwbfile: Any, rec: Recording) -> None:
    from pynwb import TimeSeries
    from pynwb.behavior import CompassDirection, Position, SpatialSeries

    module = nwbfile.create_processing_module(_BEHAVIOUR, "the simulated animal's movement")
    position = SpatialSeries(
        name="position",
        data=np.asarray(rec.position_m),
        timestamps=np.asarray(rec.time_s, dtype=np.float64),
        reference_frame=_ARENA_FRAME,
        unit="meters",
        description="the animal's position (x, y)",
    )
    module.add(Position(spatial_series=position))
    heading = SpatialSeries(
        name="heading",
        data=np.asarray(rec.heading_rad),
        timestamps=position,
        reference_frame=_HEADING_FRAME,
        unit="radians",
        description="the animal's heading",
    )
    module.add(CompassDirection(spatial_series=heading))
    module.add(
        TimeSeries(
            name="speed",
            data=np.asarray(rec.speed_m_s),
            unit="m/s",
            timestamps=position,
            description="the animal's speed",
        )
    )


def _add_network(nwbfile: Any, rec: Recording) -> None:
    from pynwb.behavior import CompassDirection, Position, SpatialSeries

    module = nwbfile.create_processing_module(_NETWORK, "the hippo_nav networks' units and readout")
    position = nwbfile.processing[_BEHAVIOUR]["Position"]["position"]
    decoded = SpatialSeries(
        name="decoded_position",
        data=np.asarray(rec.decoded_position_m),
        timestamps=position,
        reference_frame=_ARENA_FRAME,
        unit="meters",
        description="the place code's unwrapped position (the network starts where the animal starts)",
    )
    module.add(Position(name="decoded_position", spatial_series=decoded))
    decoded_heading = SpatialSeries(
        name="decoded_heading",
        data=np.asarray(rec.decoded_heading_rad),
        timestamps=position,
        reference_frame=_HEADING_FRAME,
        unit="radians",
        description="the head-direction ring's heading",
    )
    module.add(CompassDirection(name="decoded_heading", spatial_series=decoded_heading))
    for name in rec.populations:
        module.add(_population_series(rec, name, position))
        module.add(_unit_table(rec, name))
    module.add(_session_table(rec))


def _population_series(rec: Recording, name: str, position: Any) -> Any:
    from hdmf.backends.hdf5.h5_utils import H5DataIO
    from pynwb import TimeSeries

    rates = np.ascontiguousarray(rec.populations[name])
    # gzip (every HDF5 reader has it), with byte shuffling, which helps on floats; chunks are hdmf's choice.
    data = H5DataIO(rates, compression="gzip", compression_opts=4, shuffle=True)
    timing: dict[str, Any] = (
        {"starting_time": float(rec.time_s[0]), "rate": 1.0 / rec.sample_dt_s}
        if _uniform(rec)
        else {"timestamps": position}
    )
    return TimeSeries(
        name=name,
        data=data,
        unit="a.u.",
        description=f"{_MODULE_LABELS.get(name, name)} population: activity of each unit (columns; see "
        f"{name}_units), in the network's own units (>= 0)",
        comments="one column per row of the unit table",
        continuity="continuous",
        **timing,
    )


def _unit_table(rec: Recording, name: str) -> Any:
    from hdmf.common import DynamicTable

    phase = np.asarray(rec.unit_phase_rad[name])
    n_units = phase.shape[0]
    table = DynamicTable(
        name=f"{name}_units",
        description=f"the units of population {name}, one row per column of its activity; phases in radians",
        id=np.arange(n_units),
    )
    table.add_column("population", "population name", data=[name] * n_units)
    table.add_column(
        "module", "the network the unit belongs to", data=[_MODULE_LABELS.get(name, name)] * n_units
    )
    if phase.ndim == 2:
        k = rec.module_k[GRID_POPULATIONS.index(name)] if name in GRID_POPULATIONS else 1
        lesioned = rec.lesioned[GRID_POPULATIONS.index(name)] if name in GRID_POPULATIONS else False
        table.add_column("k", "bumps per torus axis", data=np.full(n_units, k, dtype=np.int64))
        spacing_m = rec.spacing_m(name) if name in (*GRID_POPULATIONS, "place") else rec.torus_period_m
        table.add_column("spacing_m", "the lattice's design spacing P/k", data=np.full(n_units, spacing_m))
        table.add_column("lesioned", "the module is lesioned (silent)", data=np.full(n_units, lesioned))
        table.add_column("phase_x_rad", "preferred torus phase along x", data=phase[:, 0])
        table.add_column("phase_y_rad", "preferred torus phase along y", data=phase[:, 1])
    else:
        table.add_column("preferred_heading_rad", _HEADING_FRAME, data=phase.reshape(n_units))
    return table


def _session_table(rec: Recording) -> Any:
    from hdmf.common import DynamicTable

    table = DynamicTable(
        name="session",
        description="what makes this file a hippo_nav Recording again (hippo_nav.recording.nwb.read_nwb)",
        id=[0],
    )
    table.add_column("format", "the export's format name", data=[NWB_FORMAT])
    table.add_column("torus_period_m", "the networks' torus period P", data=[float(rec.torus_period_m)])
    table.add_column(
        "header_json",
        "module k, lesions, population order, session metadata",
        data=[json.dumps(_header(rec))],
    )
    return table


def read_nwb(path: str | Path) -> Recording:
    """The `Recording` that `write_nwb` wrote to `path`. A missing, truncated or foreign file is a
    `RecordingError` that names it and says what to do."""
    from pynwb import NWBHDF5IO

    path = Path(path)
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "no such file"
        raise RecordingError(f"{path}: {what}; give an NWB file written by hippo_nav (write_nwb)")
    try:
        with NWBHDF5IO(str(path), "r") as io:
            return _recording(io.read(), path)
    except RecordingError:
        raise
    except OSError as err:
        # h5py reports a damaged or foreign file as an OSError without an errno; a real one (permission,
        # a vanished file) has one and is said in words.
        why = "damaged, or not HDF5" if err.errno is None else os_error_words(err)
        raise RecordingError(
            f"{path}: not a readable NWB file ({why}); write it again with write_nwb"
        ) from None
    except (KeyError, ValueError, TypeError, AttributeError, IndexError) as err:
        # h5py and hdmf raise any of these for a damaged or foreign file (tests/recording/test_nwb.py)
        raise RecordingError(
            f"{path}: not a readable NWB file ({type(err).__name__}: {err}); write it again with write_nwb"
        ) from None


def _recording(nwbfile: Any, path: Path) -> Recording:
    if _NETWORK not in nwbfile.processing or "session" not in nwbfile.processing[_NETWORK].data_interfaces:
        raise RecordingError(
            f"{path}: an NWB file, but not a hippo_nav export (no processing/network/session table); "
            "write it with hippo_nav.recording.nwb.write_nwb"
        )
    network = nwbfile.processing[_NETWORK]
    header = json.loads(network["session"]["header_json"][0])
    if header.get("format") != NWB_FORMAT:
        raise RecordingError(f"{path}: format {header.get('format')!r}, expected {NWB_FORMAT!r}")
    behaviour = nwbfile.processing[_BEHAVIOUR]
    position = behaviour["Position"]["position"]
    populations, phases = {}, {}
    for name in header["populations"]:
        populations[name] = np.asarray(network[name].data[:])
        table = network[f"{name}_units"]
        if "phase_x_rad" in table.colnames:
            phases[name] = np.stack([table["phase_x_rad"][:], table["phase_y_rad"][:]], axis=1)
        else:
            phases[name] = np.asarray(table["preferred_heading_rad"][:])
    return Recording(
        time_s=np.asarray(position.timestamps[:]),
        position_m=np.asarray(position.data[:]),
        heading_rad=np.asarray(behaviour["CompassDirection"]["heading"].data[:]),
        speed_m_s=np.asarray(behaviour["speed"].data[:]),
        decoded_position_m=np.asarray(network["decoded_position"]["decoded_position"].data[:]),
        decoded_heading_rad=np.asarray(network["decoded_heading"]["decoded_heading"].data[:]),
        populations=populations,
        unit_phase_rad=phases,
        torus_period_m=float(header["torus_period_m"]),
        module_k=tuple(int(k) for k in header["module_k"]),
        lesioned=tuple(bool(b) for b in header["lesioned"]),
        metadata=dict(header["metadata"]),
    )
