"""A session's folder: the recording first (minutes of simulation are never lost to a failed analysis), then
what is measured from it, each file written whole or not at all (`hippo_nav.io.atomic`)."""

from __future__ import annotations

import json
from pathlib import Path

from hippo_nav._core import HippoNavError
from hippo_nav.io.atomic import RESULTS_MARK, output_folder, write_text
from hippo_nav.recording import Recording

__all__ = ["SESSION_FILES", "SessionFolder", "analyse_session"]

SESSION_FILES = ("recording.npz", "session.json", "measures.json", "topology.json", "session.nwb")
"""What `hippo-nav record` writes besides its figures (`measures_*`, `topology_*`, PNG and PDF)."""


class SessionFolder:
    """`--out` of `hippo-nav record`, checked before the session is simulated: a folder that already holds
    a session is refused unless `overwrite` (which replaces only the session's own files)."""

    def __init__(self, out: str | Path, overwrite: bool = False) -> None:
        self.path = output_folder(out, "the session's files")
        if (self.path / RESULTS_MARK).exists():
            # A run's results folder holds a recording.npz of its own, which `figures --run` reads with the
            # run's other files: a session written over it would break the run, --overwrite or not.
            raise HippoNavError(
                f"--out {out} is the results folder of a `hippo-nav run` (it holds {RESULTS_MARK}); a session "
                "goes into a folder of its own: give another --out"
            )
        existing = [name for name in SESSION_FILES if (self.path / name).exists()]
        if existing and not overwrite:
            raise HippoNavError(
                f"--out {out} already holds a session ({', '.join(existing)}); give another folder or "
                "--overwrite"
            )

    def write(
        self,
        recording: Recording,
        *,
        analysis: bool = True,
        units_per_population: int = 32,
        shuffles: int = 25,
        seed: int = 0,
    ) -> list[Path]:
        """The recording and `session.json`, then (with `analysis`) the measures, topology, NWB file and
        figures; returns every path written."""
        written = [recording.save(self.path / "recording.npz")]
        written.append(
            write_text(self.path / "session.json", json.dumps(recording.metadata, indent=2) + "\n")
        )
        if analysis:
            written += analyse_session(
                recording, self.path, units_per_population=units_per_population, shuffles=shuffles, seed=seed
            )
        return written


def analyse_session(
    recording: Recording, out: Path, *, units_per_population: int = 32, shuffles: int = 25, seed: int = 0
) -> list[Path]:
    """Measures (`measures.json`), their figures, each population's topology (`topology.json`) and the NWB
    file of a recording, into `out`; without the neuro extra, an error saying what to install."""
    try:
        return _analyse(
            recording, out, units_per_population=units_per_population, shuffles=shuffles, seed=seed
        )
    except ModuleNotFoundError as err:
        raise HippoNavError(
            f"the analysis needs {err.name} (the neuro extra): pip install 'hippo-nav[neuro]'; the recording "
            "is written, analyse it again with hippo_nav.openfield.analyse_session"
        ) from None


def _analyse(
    recording: Recording, out: Path, *, units_per_population: int = 32, shuffles: int = 25, seed: int = 0
) -> list[Path]:
    """Measures (`measures.json`), their figures, each population's topology (`topology.json`) and the NWB
    file of a recording, into `out`."""
    # Each module imports its library (opexebo, ripser, pynwb) when called: without the neuro extra the
    # first call says what to install, after the recording is written.
    from hippo_nav.recording.figures import write_measure_figures
    from hippo_nav.recording.measures import measure_recording
    from hippo_nav.recording.nwb import write_nwb
    from hippo_nav.recording.topology import TopologyError, population_topology, write_topology_figure

    measures = measure_recording(
        recording, units_per_population=units_per_population, shuffles=shuffles, seed=seed
    )
    written = [measures.write_json(out / "measures.json")]
    written += write_measure_figures(recording, measures, out)
    topology: dict[str, object] = {}
    for name in recording.populations:
        try:
            result = population_topology(recording, name)
        except TopologyError as err:  # a lesioned module is silent: it has no shape to measure
            topology[name] = {"error": str(err)}
            continue
        topology[name] = result.summary()
        written += write_topology_figure(result, out / f"topology_{name}")
    written.append(write_text(out / "topology.json", json.dumps(topology, indent=2) + "\n"))
    written.append(write_nwb(recording, out / "session.nwb"))
    return written
