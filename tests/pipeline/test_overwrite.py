"""`--overwrite` never destroys what it replaces before the new results are written whole: the map a run
reads from the same folder (`--map X --out X --overwrite`), the earlier results, and another run's map
reached through a link. And a second Ctrl-C while the run is finishing never costs the results."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest
from conftest import Frames
from hippo_nav.cli import main
from hippo_nav.io import DatasetError
from hippo_nav.memory import SavedMemoryError, read_memory
from hippo_nav.pipeline.results import PREVIOUS_RESULTS, RESULTS_MARK, prepare_results_folder

FRAMES = 12


def _fingerprint(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.fixture
def first_run(demo, tmp_path, monkeypatch) -> Path:
    """A finished run of the first frames of the demo, with its memory."""
    monkeypatch.setattr("hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES))
    out = tmp_path / "X"
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out)]) == 0
    read_memory(out)  # whole
    return out


def _rerun_into_itself(out: Path) -> int:
    return main(["run", "--no-progress", "--no-figures", "--map", str(out), "--out", str(out), "--overwrite"])


def test_a_map_read_from_the_folder_it_overwrites_survives_a_stop_before_the_first_frame(
    demo, first_run, monkeypatch, capsys
):
    before = _fingerprint(first_run)

    def ctrl_c(i):
        raise KeyboardInterrupt

    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES, on_load=ctrl_c)
    )
    assert _rerun_into_itself(first_run) == 130
    after = _fingerprint(first_run)
    after.pop(RESULTS_MARK), before.pop(RESULTS_MARK)  # the lock's pid
    assert after == before, "the earlier results and map came back byte for byte"
    assert not (first_run / PREVIOUS_RESULTS).exists()


def test_a_map_read_from_the_folder_it_overwrites_survives_a_run_that_fails(demo, first_run, monkeypatch):
    """A bug (any exception) mid-run: nothing new was written, so the earlier map is put back."""
    memory_before = _fingerprint(first_run / "memory")

    def crash(i):
        if i == 5:
            raise RuntimeError("a bug in a part")

    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES, on_load=crash)
    )
    with pytest.raises(RuntimeError, match="a bug in a part"):
        _rerun_into_itself(first_run)
    assert _fingerprint(first_run / "memory") == memory_before
    read_memory(first_run)


def _corrupt_frame_5(i):
    if i == 5:
        raise DatasetError("frame 000005.png: image is corrupt (truncated); re-copy it")


@pytest.mark.parametrize("stop", ["corrupt_frame", "ctrl_c"])
def test_an_overwrite_that_stops_before_its_last_frame_keeps_the_earlier_run_whole(
    demo, first_run, monkeypatch, capsys, stop
):
    """A run stopped mid-sequence (an unreadable frame, Ctrl-C) with --overwrite: a part of a run never
    replaces a whole one — the earlier results and map stay byte for byte, the part goes beside them."""
    before = _fingerprint(first_run)

    def ctrl_c_at_frame_5(i):
        if i == 5:
            raise KeyboardInterrupt

    on_load = _corrupt_frame_5 if stop == "corrupt_frame" else ctrl_c_at_frame_5
    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES, on_load=on_load)
    )
    assert _rerun_into_itself(first_run) == (2 if stop == "corrupt_frame" else 130)
    after = _fingerprint(first_run)
    after.pop(RESULTS_MARK), before.pop(RESULTS_MARK)  # the lock's pid
    assert after == before, "the earlier results and map stayed byte for byte"
    assert not (first_run / PREVIOUS_RESULTS).exists()
    (stopped,) = first_run.parent.glob(f"{first_run.name}.stopped-*")
    assert json.loads((stopped / "metrics.json").read_text())["frames"] == 5
    assert read_memory(stopped).info["counts"]["frames"] == 5
    said = capsys.readouterr()
    assert (
        str(stopped) in said.err + said.out
        and f"earlier results in {first_run} are kept" in said.err + said.out
    )


def test_an_overwrite_that_stops_mid_run_keeps_the_run_a_killed_overwrite_set_aside(
    demo, first_run, monkeypatch
):
    """A run killed outright left the earlier complete run set aside; the next --overwrite stops on a corrupt
    frame: that complete run comes back, and the stopped run's part goes beside it."""
    memory_before = _fingerprint(first_run / "memory")
    _, lock, _ = prepare_results_folder(first_run, overwrite=True)  # the run that will be killed
    (first_run / "metrics.json").write_text('{"frames": 3, "trunc')  # what it part-wrote before the kill
    lock.close()
    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES, on_load=_corrupt_frame_5)
    )
    assert main(["run", "--no-progress", "--no-figures", "--out", str(first_run), "--overwrite"]) == 2
    assert _fingerprint(first_run / "memory") == memory_before
    assert json.loads((first_run / "metrics.json").read_text())["frames"] == FRAMES
    assert not (first_run / PREVIOUS_RESULTS).exists()
    assert len(list(first_run.parent.glob(f"{first_run.name}.stopped-*"))) == 1


def test_an_overwrite_that_stops_mid_run_replaces_an_earlier_part_in_place(demo, tmp_path, monkeypatch):
    """The earlier results are themselves a stopped run's (a sweep's interrupted attempt, retried): no whole
    run to keep, so the new part replaces the old one where it was asked for."""
    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES, on_load=_corrupt_frame_5)
    )
    out = tmp_path / "attempts"
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out)]) == 2
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out), "--overwrite"]) == 2
    assert json.loads((out / "metrics.json").read_text())["interrupted"]
    assert not list(tmp_path.glob("attempts.stopped-*")) and not (out / PREVIOUS_RESULTS).exists()


def test_an_overwrite_that_stops_mid_run_in_a_folder_without_an_earlier_run_writes_there(
    demo, tmp_path, monkeypatch
):
    """Nothing to keep: the stopped run's results go where they were asked for."""
    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, FRAMES, on_load=_corrupt_frame_5)
    )
    out = tmp_path / "fresh"
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out), "--overwrite"]) == 2
    assert json.loads((out / "metrics.json").read_text())["frames"] == 5
    assert not list(tmp_path.glob("fresh.stopped-*"))


def test_overwriting_a_folder_with_its_own_map_writes_the_new_map_and_drops_the_old(first_run):
    old_manifest = json.loads((first_run / "memory" / "memory.json").read_text())
    assert _rerun_into_itself(first_run) == 0
    metrics = json.loads((first_run / "metrics.json").read_text())
    assert metrics["loaded_map"]["vertices"] == old_manifest["counts"]["vertices"]
    new = read_memory(first_run)
    # The new memory is the loaded map extended by this session (lost or joined, its vertices are added).
    assert new.info["counts"]["vertices"] > old_manifest["counts"]["vertices"]
    assert not (first_run / PREVIOUS_RESULTS).exists()
    assert not [p for p in first_run.iterdir() if p.name.startswith(".memory.")], "no staging folder left"


def test_a_killed_overwrite_leaves_the_earlier_run_set_aside_and_the_next_one_keeps_it(first_run):
    """A run killed outright (no code runs): its part-written files are dropped by the next --overwrite,
    and the earlier complete run it had set aside stays until that next run is written whole."""
    memory_before = _fingerprint(first_run / "memory")
    _, lock, previous = prepare_results_folder(first_run, overwrite=True)  # the run that will be killed
    assert previous is not None and _fingerprint(first_run / PREVIOUS_RESULTS / "memory") == memory_before
    (first_run / "metrics.json").write_text('{"frames": 3, "trunc')  # what it part-wrote before the kill
    lock.close()
    # The earlier map is still readable where it was set aside, e.g. to start the next run from it, and a
    # --map of the folder itself says where it is.
    read_memory(first_run / PREVIOUS_RESULTS)
    with pytest.raises(SavedMemoryError, match=f"give --map {first_run / PREVIOUS_RESULTS}"):
        read_memory(first_run)
    assert (
        main(["run", "--no-progress", "--no-figures", "--map", str(first_run / PREVIOUS_RESULTS),
              "--out", str(first_run), "--overwrite"])
        == 0
    )  # fmt: skip
    assert json.loads((first_run / "metrics.json").read_text())["frames"] == FRAMES
    assert not (first_run / PREVIOUS_RESULTS).exists()


def test_overwrite_replaces_a_linked_memory_folder_never_the_folder_it_points_to(first_run, tmp_path):
    other = tmp_path / "other_run_memory"
    (first_run / "memory").rename(other)
    (first_run / "memory").symlink_to(other, target_is_directory=True)
    other_before = _fingerprint(other)
    assert main(["run", "--no-progress", "--no-figures", "--out", str(first_run), "--overwrite"]) == 0
    assert _fingerprint(other) == other_before, "another run's map is untouched"
    assert not (first_run / "memory").is_symlink() and (first_run / "memory" / "memory.json").is_file()
    read_memory(first_run)


def test_a_memory_written_over_a_link_replaces_the_link(tmp_path):
    from hippo_nav.memory import SavedMemory, write_memory

    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "keep.txt").write_text("theirs")
    (tmp_path / "memory").symlink_to(target, target_is_directory=True)
    write_memory(SavedMemory(b"map", {}, {}, {}), tmp_path / "memory")
    assert (target / "keep.txt").read_text() == "theirs" and sorted(p.name for p in target.iterdir()) == [
        "keep.txt"
    ]
    assert not (tmp_path / "memory").is_symlink()
    assert (tmp_path / "memory" / "map.bin").read_bytes() == b"map"


# --- a second signal while the run finishes -------------------------------------------------------------
def _kill_self(signame: str = "SIGINT") -> None:
    os.kill(os.getpid(), getattr(signal, signame))
    time.sleep(0.05)  # the handler runs in the main thread at its next bytecode


@pytest.mark.parametrize("where", ["front_end_exit", "save_memory", "assemble"])
def test_a_second_ctrl_c_while_finishing_never_costs_the_results(
    demo, tmp_path, monkeypatch, disposition, where
):
    """The first Ctrl-C stops the frames; the second lands in a step between the frames and the written
    files (the front end's shutdown, the memory's export, the trajectories' assembly): the run still writes
    everything, memory included, and exits 130."""
    disposition("SIGINT", signal.default_int_handler)
    from hippo_nav.pipeline import frontend, runner
    from hippo_nav.system.slam import SlamSystem

    if where == "front_end_exit":
        real = frontend.FrontEnd.__exit__

        def exit_interrupted(self, *exc):
            _kill_self()
            return real(self, *exc)

        monkeypatch.setattr(frontend.FrontEnd, "__exit__", exit_interrupted)
    elif where == "save_memory":
        real_save = SlamSystem.save_memory

        def save_interrupted(self):
            _kill_self()
            return real_save(self)

        monkeypatch.setattr(SlamSystem, "save_memory", save_interrupted)
    else:
        real_assemble = runner.assemble_result

        def assemble_interrupted(*args, **kwargs):
            _kill_self()
            return real_assemble(*args, **kwargs)

        monkeypatch.setattr(runner, "assemble_result", assemble_interrupted)

    def ctrl_c_at_frame_6(i):
        if i == 6:
            _kill_self()

    monkeypatch.setattr(
        "hippo_nav.pipeline.runner.open_input", lambda *a, **k: Frames(demo, 20, on_load=ctrl_c_at_frame_6)
    )
    out = tmp_path / "out"
    assert main(["run", "--no-progress", "--no-figures", "--out", str(out)]) == 130
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["interrupted"] and metrics["interrupted_by"] == "SIGINT"
    assert read_memory(out).info["counts"]["frames"] == metrics["frames"] < 20


def test_an_overwrite_that_cannot_move_every_file_aside_puts_back_those_it_moved(
    first_run, monkeypatch, capsys
):
    """A set-aside that fails part-way (a read-only memory folder cannot be renamed) leaves the earlier run
    whole where it was: a retry then sets it aside again rather than taking the half moved for a killed run's
    results and removing the rest."""
    before = _fingerprint(first_run)
    real_rename = os.rename

    def rename(src, dst):
        if Path(src).name == "memory" and Path(dst).parent.name == PREVIOUS_RESULTS:
            raise PermissionError(13, "Permission denied", str(src))
        return real_rename(src, dst)

    monkeypatch.setattr("hippo_nav.pipeline.results.os.rename", rename)
    assert main(["run", "--no-progress", "--no-figures", "--out", str(first_run), "--overwrite"]) == 2
    assert "nothing was removed" in capsys.readouterr().err
    assert _fingerprint(first_run) == before
    assert not (first_run / PREVIOUS_RESULTS).exists()
    monkeypatch.setattr("hippo_nav.pipeline.results.os.rename", real_rename)
    assert _rerun_into_itself(first_run) == 0  # the retry, once the folder can be moved
    read_memory(first_run)


def test_earlier_results_split_between_the_folder_and_the_set_aside_one_are_refused_not_removed(
    first_run, capsys
):
    """A folder a set-aside left split (before the put-back above): its set-aside half has no metrics.json
    while the folder still has one. Neither half is a killed run's part-written files; both are kept."""
    aside = first_run / PREVIOUS_RESULTS
    aside.mkdir()
    for name in ("frames.csv", "config.json"):
        os.rename(first_run / name, aside / name)
    before = _fingerprint(first_run)
    assert main(["run", "--no-progress", "--no-figures", "--out", str(first_run), "--overwrite"]) == 2
    assert "are split" in capsys.readouterr().err
    assert _fingerprint(first_run) == before
