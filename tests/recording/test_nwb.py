"""NWB export (`hippo_nav.recording.nwb`): a recording survives the round trip, and the neuroscientist's own
readers (pynwb, pynapple) find the animal's behaviour and every population in it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pynwb")

from hippo_nav.recording import GRID_POPULATIONS, Recording, RecordingError
from hippo_nav.recording.nwb import EPOCH, read_nwb, write_nwb

DT_S = 0.02


def small_session(n_time: int = 500, seed: int = 0) -> Recording:
    """A short session with idealised tuning: a smooth walk in a 1.5 m box; 8×8-unit grid modules and place
    torus (von Mises bumps on the module's phase 2πk·x/P), a 36-unit head-direction ring; one lesion."""
    rng = np.random.default_rng(seed)
    period_m, module_k = 1.5, (1, 2, 4)
    heading = np.mod(np.cumsum(rng.normal(0.0, 0.1, n_time)), 2 * np.pi)
    position = 0.75 + np.cumsum(0.25 * DT_S * np.stack([np.cos(heading), np.sin(heading)], axis=1), axis=0)
    theta = 2 * np.pi * np.arange(8) / 8
    tx, ty = np.meshgrid(theta, theta)
    torus_phase = np.stack([tx.ravel(), ty.ravel()], axis=1)
    populations, phases = {}, {}
    for name, k in [*zip(GRID_POPULATIONS, module_k), ("place", 1)]:
        d = 2 * np.pi * k * position[:, None, :] / period_m - torus_phase[None]
        populations[name] = np.exp(3.0 * (np.cos(d).sum(axis=2) - 2)).astype(np.float32)
        phases[name] = torus_phase
    populations["grid_dorsal"][:] = 0.0  # lesioned: silent
    ring_phase = 2 * np.pi * np.arange(36) / 36
    populations["hd"] = np.exp(4.0 * (np.cos(heading[:, None] - ring_phase[None]) - 1)).astype(np.float32)
    phases["hd"] = ring_phase
    return Recording(
        time_s=np.arange(n_time) * DT_S,
        position_m=position,
        heading_rad=heading,
        speed_m_s=np.full(n_time, 0.25),
        decoded_position_m=position + rng.normal(0.0, 0.01, position.shape),
        decoded_heading_rad=np.mod(heading + rng.normal(0.0, 0.05, n_time), 2 * np.pi),
        populations=populations,
        unit_phase_rad=phases,
        torus_period_m=period_m,
        module_k=module_k,
        lesioned=(False, False, True),
        metadata={"seed": seed, "arena": {"shape": "square", "size_m": 1.5}, "source": "test"},
    )


@pytest.fixture(scope="module")
def session() -> Recording:
    return small_session()


@pytest.fixture(scope="module")
def nwb_path(session: Recording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_nwb(session, tmp_path_factory.mktemp("nwb") / "session.nwb")


def test_the_round_trip_gives_the_same_recording(session: Recording, nwb_path: Path) -> None:
    back = read_nwb(nwb_path)
    for name in (
        "time_s",
        "position_m",
        "heading_rad",
        "speed_m_s",
        "decoded_position_m",
        "decoded_heading_rad",
    ):
        expected, got = getattr(session, name), getattr(back, name)
        np.testing.assert_array_equal(got, expected, err_msg=name)
        assert got.dtype == expected.dtype, name
    assert list(back.populations) == list(session.populations)
    for name, rates in session.populations.items():
        np.testing.assert_array_equal(back.populations[name], rates, err_msg=name)
        assert back.populations[name].dtype == np.float32
        np.testing.assert_array_equal(back.unit_phase_rad[name], session.unit_phase_rad[name], err_msg=name)
        assert back.unit_phase_rad[name].shape == session.unit_phase_rad[name].shape
    assert back.torus_period_m == session.torus_period_m
    assert back.module_k == session.module_k and back.lesioned == session.lesioned
    assert back.metadata == session.metadata
    assert back.sample_dt_s == pytest.approx(DT_S)


def test_the_file_is_reproducible_and_written_atomically(session: Recording, tmp_path: Path) -> None:
    from pynwb import NWBHDF5IO

    first = write_nwb(session, tmp_path / "a.nwb")
    write_nwb(session, tmp_path / "a.nwb")  # over the first: replaced whole
    other = write_nwb(small_session(seed=1), tmp_path / "b.nwb", session_id="rat-7")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.nwb", "b.nwb"]  # no temporary left behind
    with NWBHDF5IO(str(first), "r") as io:
        a = io.read()
        identifier, start, session_id = a.identifier, a.session_start_time, a.session_id
        assert a.file_create_date[0] == EPOCH
    assert start == EPOCH and session_id.startswith("seed0-")
    with NWBHDF5IO(str(write_nwb(session, tmp_path / "c.nwb")), "r") as io:
        assert io.read().identifier == identifier  # same session, same identifier
    with NWBHDF5IO(str(other), "r") as io:
        b = io.read()
        assert b.identifier != identifier and b.session_id == "rat-7"


def test_pynwb_finds_the_behaviour_and_the_populations(session: Recording, nwb_path: Path) -> None:
    from pynwb import NWBHDF5IO

    n_time = session.time_s.size
    with NWBHDF5IO(str(nwb_path), "r") as io:
        nwb = io.read()
        behaviour = nwb.processing["behavior"]
        position = behaviour["Position"]["position"]
        assert position.data.shape == (n_time, 2) and position.unit == "meters"
        assert "x right, y up" in position.reference_frame
        np.testing.assert_array_equal(position.timestamps[:], session.time_s)
        heading = behaviour["CompassDirection"]["heading"]
        assert heading.unit == "radians" and heading.data.shape == (n_time,)
        assert behaviour["speed"].unit == "m/s"
        network = nwb.processing["network"]
        for name, rates in session.populations.items():
            series = network[name]
            assert series.data.shape == rates.shape and series.unit == "a.u."
            assert series.rate == pytest.approx(1 / DT_S) and series.starting_time == 0.0
            units = network[f"{name}_units"].to_dataframe()
            assert len(units) == rates.shape[1] and set(units["population"]) == {name}
        ventral = network["grid_ventral_units"].to_dataframe()
        assert (
            set(ventral["k"]) == {1} and set(ventral["spacing_m"]) == {1.5} and not ventral["lesioned"].any()
        )
        dorsal = network["grid_dorsal_units"].to_dataframe()
        assert set(dorsal["k"]) == {4} and set(dorsal["spacing_m"]) == {0.375} and dorsal["lesioned"].all()
        assert set(dorsal["module"]) == {"dorsal"}
        np.testing.assert_array_equal(
            dorsal[["phase_x_rad", "phase_y_rad"]].to_numpy(), session.unit_phase_rad["grid_dorsal"]
        )
        hd = network["hd_units"].to_dataframe()
        np.testing.assert_array_equal(hd["preferred_heading_rad"].to_numpy(), session.unit_phase_rad["hd"])


def test_pynapple_reads_the_series_with_their_timestamps(session: Recording, nwb_path: Path) -> None:
    nap = pytest.importorskip("pynapple")

    data = nap.load_file(str(nwb_path))
    position = data["position"]
    assert isinstance(position, nap.TsdFrame) and position.shape == (session.time_s.size, 2)
    np.testing.assert_array_equal(position.t, session.time_s)
    np.testing.assert_array_equal(position.values, session.position_m)
    heading = data["heading"]
    assert isinstance(heading, nap.Tsd) and heading.shape == session.heading_rad.shape
    for name, rates in session.populations.items():
        series = data[name]
        assert isinstance(series, nap.TsdFrame) and series.shape == rates.shape, name
        np.testing.assert_allclose(series.t, session.time_s, atol=1e-9)
        np.testing.assert_array_equal(series.values, rates)


def test_damaged_and_foreign_files_are_recording_errors(nwb_path: Path, tmp_path: Path) -> None:
    data = nwb_path.read_bytes()
    truncated = tmp_path / "truncated.nwb"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="truncated.nwb: not a readable NWB file.*write it again"):
        read_nwb(truncated)
    text = tmp_path / "notes.nwb"
    text.write_text("not HDF5")
    with pytest.raises(RecordingError, match="not a readable NWB file"):
        read_nwb(text)
    with pytest.raises(RecordingError, match="no such file"):
        read_nwb(tmp_path / "missing.nwb")
    with pytest.raises(RecordingError, match="is a folder"):
        read_nwb(tmp_path)


def test_an_nwb_file_from_elsewhere_is_named_as_such(tmp_path: Path) -> None:
    from pynwb import NWBHDF5IO, NWBFile

    path = tmp_path / "other_lab.nwb"
    with NWBHDF5IO(str(path), "w") as io:
        io.write(
            NWBFile(session_description="another lab's session", identifier="x", session_start_time=EPOCH)
        )
    with pytest.raises(RecordingError, match="not a hippo_nav export"):
        read_nwb(path)


def test_bad_targets_are_recording_errors(session: Recording, tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="does not exist; create it"):
        write_nwb(session, tmp_path / "no" / "such" / "folder.nwb")
    with pytest.raises(RecordingError, match="is a folder"):
        write_nwb(session, tmp_path)
    assert list(tmp_path.iterdir()) == []
