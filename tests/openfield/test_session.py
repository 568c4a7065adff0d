"""Open-field sessions: the networks follow a foraging rat, every unit is recorded, the landmarks recall the
state stored at a place moved by the pose between then and now, and bad input is a clear error."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("ratinabox")

from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.engine import SpatialMemory
from hippo_nav.openfield import (
    LandmarkConfig,
    LandmarkViews,
    OpenFieldConfig,
    engine_config,
    foraging_trajectory,
    record_session,
    trajectory_from_csv,
)
from hippo_nav.recording import Recording, RecordingError


def _short(**given: object) -> OpenFieldConfig:
    return OpenFieldConfig.model_validate({"duration_s": 20.0, **given})


@pytest.fixture(scope="module")
def session() -> Recording:
    return record_session(_short(duration_s=40.0, seed=1))


def test_every_unit_of_every_population_is_recorded(session: Recording):
    t = len(session.time_s)
    assert t == 401 and session.sample_dt_s == pytest.approx(0.1)
    # The k² copies of a grid unit are identical by construction: one unit cell (N/k)² per module.
    sizes = {name: rates.shape for name, rates in session.populations.items()}
    assert sizes == {
        "hd": (t, 128),
        "grid_ventral": (t, 64 * 64),
        "grid_intermediate": (t, 32 * 32),
        "grid_dorsal": (t, 16 * 16),
        "place": (t, 64 * 64),
    }
    assert all(np.isfinite(r).all() and r.min() >= 0 for r in session.populations.values())
    assert session.unit_phase_rad["grid_dorsal"].max() < 2 * math.pi / 4


def test_the_networks_follow_the_rat(session: Recording):
    error_m = np.linalg.norm(session.decoded_position_m - session.position_m, axis=1)
    heading_error = np.angle(np.exp(1j * (session.decoded_heading_rad - session.heading_rad)))
    path_m = np.sum(np.linalg.norm(np.diff(session.position_m, axis=0), axis=1))
    assert path_m > 3.0  # the rat moved: ~0.16 m/s for 40 s
    # Path integration's error grows ~1 % of the path (openfield/config.py); the landmarks bound it.
    assert error_m.max() < 0.02 * path_m, (error_m.max(), path_m)
    assert np.degrees(np.abs(heading_error)).max() < 5.0


def test_a_dorsal_unit_fires_where_its_phase_says(session: Recording):
    """Unit θ of module k fires where 2π·(x − x₀)/P ≡ θ (mod 2π/k) on both axes (recording/session.py), x the
    position the networks hold (the place code's; the true one differs by their error)."""
    rates = session.populations["grid_dorsal"]
    period = 2 * math.pi / 4
    held = session.decoded_position_m - session.position_m[0]
    travelled = 2 * math.pi * held / session.torus_period_m
    for i in range(50, len(rates), 50):
        theta = session.unit_phase_rad["grid_dorsal"][int(np.argmax(rates[i]))]
        offset = (travelled[i] - theta + period / 2) % period - period / 2
        assert np.abs(offset).max() < 0.1 * period, (i, offset)


def test_a_session_is_deterministic_per_seed():
    a, b, c = (record_session(_short(duration_s=4.0, seed=s)) for s in (3, 3, 4))
    assert np.array_equal(a.position_m, b.position_m)
    assert np.array_equal(a.populations["place"], b.populations["place"])
    assert not np.array_equal(a.position_m, c.position_m)


def test_a_circular_arena_keeps_the_rat_inside():
    cfg = _short(arena_shape="circle", arena_size_m=1.0, duration_s=60.0, landmarks={"enabled": False})
    traj = foraging_trajectory(cfg)
    radius = np.linalg.norm(traj.position_m - 0.5, axis=1)
    assert radius.max() <= 0.5 + 1e-6 and radius.max() > 0.3


def test_a_landmark_recalls_the_stored_state_moved_by_the_pose_since():
    cfg = LandmarkConfig(cell_size_m=0.5, heading_sectors=4, revisit_gap_s=1.0)
    engine = SpatialMemory(engine_config(OpenFieldConfig()))
    views = LandmarkViews(cfg, torus_period_m=0.8)
    stored = np.array([0.1, 0.1])
    assert views.recall(stored, 0.1, 0.0) is None  # never seen
    views.remember(engine, stored, 0.1, 0.0)
    assert views.recall(stored, 0.1, 0.5) is None  # the same passage: nothing
    assert views.recall(np.array([2.0, 2.0]), 0.1, 1.0) is None  # elsewhere
    here = np.array([0.3, 0.2])
    patterns = views.recall(here, 0.3, 3.0)  # back after the gap, 0.2 m and 0.2 rad away
    assert patterns is not None and patterns.strength == pytest.approx(1.0)
    hd = patterns.hd_profile
    peak = 2 * math.pi * np.argmax(hd) / hd.size
    stored_peak = 2 * math.pi * np.argmax(engine.hd_profile()) / hd.size
    assert abs(np.angle(np.exp(1j * (peak - stored_peak - 0.2)))) < 2 * math.pi / hd.size * 1.5
    ventral = patterns.grid_layer2[0]
    shift_units = np.array(np.unravel_index(np.argmax(ventral), ventral.shape))[::-1]
    stored_units = np.array(np.unravel_index(np.argmax(engine.grid_layer2(0)), ventral.shape))[::-1]
    expected = 64 * (here - stored) / 0.8  # 2π·d/P on a torus of 64 units per 2π
    assert np.allclose((shift_units - stored_units) % 64, np.round(expected) % 64, atol=1)
    follow_up = views.recall(here, 0.3, 3.02)
    assert follow_up is not None and follow_up.strength == pytest.approx(0.7)  # decays while it stays
    assert views.recalls == 1


def test_landmarks_recall_during_a_session(session: Recording):
    assert session.metadata["landmark_cells"] > 10
    off = record_session(_short(duration_s=4.0, landmarks={"enabled": False}))
    assert off.metadata["landmark_cells"] == 0 and off.metadata["landmark_recalls"] == 0


def test_a_csv_trajectory_drives_a_session(tmp_path):
    t = np.arange(0.0, 10.0, 0.05)
    x, y = 0.5 + 0.3 * np.cos(0.5 * t), 0.5 + 0.3 * np.sin(0.5 * t)
    csv = tmp_path / "path.csv"
    csv.write_text("t,x,y\n" + "".join(f"{a},{b},{c}\n" for a, b, c in zip(t, x, y)))
    traj = trajectory_from_csv(csv, 0.02)
    # Without a heading column, the direction of motion: tangent to the circle, counter-clockwise.
    tangent = np.arctan2(traj.position_m[250, 1] - 0.5, traj.position_m[250, 0] - 0.5) + math.pi / 2
    assert abs(np.angle(np.exp(1j * (traj.head_direction_rad[250] - tangent)))) < 0.1
    rec = record_session(_short(duration_s=traj.time_s[-1]), traj)
    assert np.linalg.norm(rec.decoded_position_m - rec.position_m, axis=1).max() < 0.05
    # The trajectory sets the length: a config asking for less does not make the metadata say so.
    shorter = record_session(_short(duration_s=1.0), traj)
    assert shorter.time_s[-1] == pytest.approx(traj.time_s[-1], abs=0.1)
    assert shorter.metadata["session"]["duration_s"] == pytest.approx(traj.time_s[-1] - traj.time_s[0])


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("a,b\n1,2\n", "columns t, x, y"),
        ("t,x,y\n0,0,0\n1,nan,0\n", "finite"),
        ("t,x,y\n0,0,0\n0,1,0\n", "increasing"),
        ("t,x,y\n0,zero,0\n1,1,0\n", "not a number"),
        ("t,x,y\n0,0,0\n1e9,1,1\n", "more than a session"),  # milliseconds, or a typo: 373 GiB of steps
        ("t,x,y\n0,0,0\n\n1,1\n2,2,0\n", r"line 4 has 2 values where the header names 3$"),
        ("t,x,y\n0,0,0\n1,1,0,7\n", "line 3 has 4 values"),  # not silently the first three
        (
            "t,x,y\n0,0,0\n0.5,0.5,0\n1,1",
            r"line 4 has 2 values .*bad.csv does not end with a line break: was it cut",
        ),
        ("t,x,y\n0,0,0\n1,1,0\n\xff", "not UTF-8"),
    ],
)
def test_a_bad_trajectory_csv_says_what_is_wrong(tmp_path, text, words):
    csv = tmp_path / "bad.csv"
    csv.write_bytes(text.encode("latin-1") if "\xff" in text else text.encode())
    with pytest.raises(HippoNavError, match=words):
        trajectory_from_csv(csv, 0.02)


@pytest.mark.parametrize(
    ("step_dt_s", "words"),
    [
        (0.0, "finite and > 0 s, got 0.0"),  # was numpy's "Maximum allowed size exceeded"
        (float("nan"), "finite and > 0 s, got nan"),  # was "arange: cannot compute length"
        (-0.02, "finite and > 0 s, got -0.02"),  # was "shorter than two steps of -0.02 s"
        ("0.02", "a number of seconds, got '0.02'"),  # was a TypeError
        (None, "a number of seconds, got None"),
    ],
)
def test_a_bad_resampling_step_says_what_to_fix(tmp_path, step_dt_s, words):
    csv = tmp_path / "walk.csv"
    csv.write_text("t,x,y\n0,0,0\n1,0.5,0\n2,1,0\n")
    with pytest.raises(HippoNavError, match=words):
        trajectory_from_csv(csv, step_dt_s)
    assert len(trajectory_from_csv(csv, 0.02).time_s) > 50


def test_a_trajectory_cut_inside_its_last_number_is_named_in_the_error_it_causes(tmp_path):
    """A file cut mid-write inside its last number still parses (10.56 → 1): the jump it makes is refused
    by the networks, and the error says the file may have been cut short; a whole file is not suspected."""
    rows = "".join(f"{0.02 * i:.2f},0,{10.5 + 0.01 * i:.2f}\n" for i in range(40))
    whole, cut = tmp_path / "whole.csv", tmp_path / "cut.csv"
    whole.write_text("t,x,y\n" + rows + "0.80,0,1\n")
    cut.write_text("t,x,y\n" + rows + "0.80,0,1")
    with pytest.raises(HippoNavError, match=r"outside the range.*cut\.csv does not end with a line break"):
        record_session(_short(duration_s=0.8), trajectory_from_csv(cut, 0.02))
    with pytest.raises(HippoNavError, match=r"outside the range the network can represent \(.*\)$"):
        record_session(_short(duration_s=0.8), trajectory_from_csv(whole, 0.02))


def test_a_recording_round_trips_and_a_truncated_file_is_refused(session: Recording, tmp_path):
    path = session.save(tmp_path / "recording.npz")
    back = Recording.load(path)
    assert back.module_k == (1, 2, 4) and back.torus_period_m == 0.8
    assert all(np.array_equal(back.populations[n], session.populations[n]) for n in session.populations)
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(RecordingError, match="not a readable"):
        Recording.load(path)


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (
            lambda a: a.update({"rates/grid_dorsal": a["rates/grid_dorsal"][:10]}),
            r"rates/grid_dorsal has shape",
        ),
        (lambda a: a.update({"position_m": a["position_m"][:, :1]}), r"position_m has shape"),
        (lambda a: a.update({"phase/place": a["phase/place"][:3]}), r"phase/place has shape"),
        (lambda a: a.pop("decoded_heading_rad"), r"no decoded_heading_rad array"),
    ],
)
def test_a_recording_whose_arrays_disagree_is_refused_naming_the_array(
    session: Recording, tmp_path, edit, words
):
    # Before, `figures --run` on such a file failed deep inside a rate map with numpy's reshape error.
    path = session.save(tmp_path / "recording.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    edit(arrays)
    np.savez(path, **arrays)
    with pytest.raises(RecordingError, match=words + ".*write the recording again"):
        Recording.load(path)


def test_record_writes_a_session_and_keeps_it(tmp_path, capsys):
    out = tmp_path / "s"
    args = ["record", "--out", str(out), "--duration", "2", "--no-analysis", "--no-progress"]
    assert main(args) == 0
    rec = Recording.load(out / "recording.npz")
    assert rec.time_s[-1] == pytest.approx(2.0) and (out / "session.json").is_file()
    before = (out / "recording.npz").read_bytes()
    assert main(args) == 2  # refused: a session is there
    assert "already holds a session" in capsys.readouterr().err
    assert (out / "recording.npz").read_bytes() == before
    assert main([*args, "--overwrite", "--seed", "5"]) == 0


def test_record_refuses_a_runs_results_folder_even_with_overwrite(tmp_path, capsys):
    """A run's folder holds its own recording.npz, which `figures --run` reads with the run's other files."""
    run = tmp_path / "run"
    assert main(["run", "--out", str(run), "--stop", "5", "--no-progress", "--no-figures"]) == 0
    before = (run / "recording.npz").read_bytes()
    capsys.readouterr()
    args = ["record", "--out", str(run), "--duration", "2", "--no-analysis", "--no-progress"]
    assert main([*args, "--overwrite"]) == 2
    assert "results folder of a `hippo-nav run`" in capsys.readouterr().err
    assert (run / "recording.npz").read_bytes() == before


@pytest.mark.parametrize(
    ("flags", "words"),
    [
        (["--period", "0.01"], "--period: '0.01' is out of range"),
        (["--duration", "0.05"], "fewer than two samples"),
        (["--arena-size", "nan"], "--arena-size: 'nan' is out of range"),
        (["--config", "missing.json"], "--config: no such file or directory: missing.json"),
    ],
)
def test_record_refuses_bad_settings_before_simulating(tmp_path, capsys, flags, words):
    assert main(["record", "--out", str(tmp_path / "x"), "--no-progress", *flags]) == 2
    assert words in capsys.readouterr().err


@pytest.mark.slow
def test_record_measures_a_session_and_exports_it(tmp_path):
    pytest.importorskip("opexebo")
    out = tmp_path / "s"
    assert main(["record", "--out", str(out), "--duration", "30", "--units", "2", "--shuffles", "2"]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"recording.npz", "session.json", "measures.json", "topology.json", "session.nwb"} <= names
    assert {"measures_rate_maps.pdf", "topology_grid_dorsal.png", "topology_hd.pdf"} <= names
    import json

    topology = json.loads((out / "topology.json").read_text())
    assert set(topology) == {"hd", "grid_ventral", "grid_intermediate", "grid_dorsal", "place"}
    from hippo_nav.recording.nwb import read_nwb

    back = read_nwb(out / "session.nwb")
    assert np.array_equal(
        back.populations["grid_dorsal"], Recording.load(out / "recording.npz").populations["grid_dorsal"]
    )


def test_without_the_neuro_extra_the_recording_is_kept_and_the_error_says_what_to_install(
    tmp_path, monkeypatch, capsys
):
    from hippo_nav.openfield import folder

    def missing(*args: object, **kwargs: object) -> None:
        raise ModuleNotFoundError("No module named 'ripser'", name="ripser")

    monkeypatch.setattr(folder, "_analyse", missing)
    out = tmp_path / "s"
    assert main(["record", "--out", str(out), "--duration", "1", "--no-progress"]) == 2
    assert "pip install 'hippo-nav[neuro]'" in capsys.readouterr().err
    assert Recording.load(out / "recording.npz").time_s[-1] == pytest.approx(1.0)
