"""`hippo-nav sweep` on a local Ray: a small sweep of the demo loop with a worker killed mid-run, a run that
fails in the middle of a sweep, Ctrl-C and resume. Each test starts and stops its own Ray (a few seconds)."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

from hippo_nav.cli import main
from hippo_nav.sweep import SweepOptions, build_space, plan, run_sweep
from hippo_nav.synthetic import demo_sequence

pytestmark = pytest.mark.slow
TWO_WORKERS = SweepOptions(cpus_per_run=1, workers=2, progress=False)


def _manifests(out: Path) -> dict[str, dict]:
    return {p.parent.name: json.loads(p.read_text()) for p in sorted(out.glob("runs/*/manifest.json"))}


def _wait_for(condition, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def test_a_local_sweep_survives_a_killed_worker_and_its_table_is_the_runs_metrics(tmp_path, demo):
    """4 runs of 40 demo frames on 2 workers; the first run's worker is killed mid-run: Ray restarts the
    run, every run ends done, the manifests say what ran where, and the report's table is metrics.json."""
    import threading

    space = build_space(lesions="none,dorsal", seeds="0-1", dataset={"stop": 40}, no_figures=True)
    out = tmp_path / "sweep"
    killed: dict[str, int] = {}

    def kill_the_first_running_worker():
        def running():
            return next(((k, m) for k, m in _manifests(out).items() if m.get("status") == "running"), None)

        run_id, manifest = _wait_for(running, 120, "a run to start")
        os.kill(manifest["pid"], signal.SIGKILL)
        killed[run_id] = manifest["pid"]

    killer = threading.Thread(target=kill_the_first_running_worker, daemon=True)
    killer.start()
    summary = run_sweep(space, out, TWO_WORKERS, echo=lambda line: None)
    killer.join(5)
    assert killed, "no worker was killed"
    assert summary.done == 4 and not summary.failed and not summary.interrupted
    manifests = _manifests(out)
    assert len(manifests) == 4 and {m["status"] for m in manifests.values()} == {"done"}
    ((run_id, pid),) = killed.items()
    assert manifests[run_id]["attempt"] == 2 and manifests[run_id]["pid"] != pid  # rerun in a new worker
    for m in manifests.values():
        assert m["exit_status"] == 0 and m["cpus"] == 1 and m["wall_s"] > 0 and m["peak_rss_mb"] > 10
        assert m["dataset"]["checksum"]["frames"] == 40 and len(m["config_sha256"]) == 64
        assert m["package"]["version"] and m["config"]["lesions"]["dorsal"] == (m["lesion"] == "dorsal")
    # Every run has the ordinary results folder, evo-readable trajectories included.
    assert all((out / "runs" / k / "trajectory_corrected.kitti.txt").is_file() for k in manifests)
    # The report's table against the runs' metrics.json.
    assert main(["report", str(out), "--no-figures"]) == 0
    with (out / "report" / "table.csv").open() as f:
        rows = {r["run_id"]: r for r in csv.DictReader(f)}
    assert set(rows) == set(manifests)
    for run_id, row in rows.items():
        metrics = json.loads((out / "runs" / run_id / "metrics.json").read_text())
        assert float(row["ate_2d_vo_m"]) == pytest.approx(metrics["errors"]["vo"]["ate_2d_m"], rel=1e-9)
        assert float(row["ate_2d_corrected_m"]) == pytest.approx(
            metrics["errors"]["corrected"]["ate_2d_m"], rel=1e-9
        )
        assert float(row["wall_s"]) == pytest.approx(manifests[run_id]["wall_s"])
        assert row["lesion"] == manifests[run_id]["lesion"] and int(row["seed"]) == manifests[run_id]["seed"]
    # Resume: the same space into the same folder has nothing left to do.
    assert not plan(space.runs(), out).todo


def _two_sequences_one_broken(root: Path, demo_root: Path) -> Path:
    """A KITTI root with the demo loop as sequences 00 and 01; frame 10 of 01 is a truncated PNG."""
    for sequence in ("00", "01"):
        (root / "poses").mkdir(parents=True, exist_ok=True)
        shutil.copy(demo_root / "poses" / "00.txt", root / "poses" / f"{sequence}.txt")
        shutil.copytree(demo_root / "sequences" / "00", root / "sequences" / sequence)
    broken = root / "sequences" / "01" / "image_0" / "000010.png"
    broken.write_bytes(broken.read_bytes()[:40])
    return root


def test_a_run_that_fails_mid_sequence_is_listed_and_the_others_finish(tmp_path, demo, capsys):
    root = _two_sequences_one_broken(tmp_path / "kitti", Path(demo_sequence()))
    out = tmp_path / "sweep"
    args = ["sweep", "--dataset", str(root), "--sequence", "01,00", "--stop", "20", "--seeds", "0-1",
            "--no-figures", "--no-progress", "--cpus-per-run", "1", "--workers", "2", "--out", str(out)]  # fmt: skip
    assert main(args) == 1  # some runs failed
    printed = capsys.readouterr().out
    manifests = _manifests(out)
    failed = {k: m for k, m in manifests.items() if m["status"] == "failed"}
    done = {k: m for k, m in manifests.items() if m["status"] == "done"}
    assert len(failed) == 2 and len(done) == 2
    assert {m["sequence"] for m in failed.values()} == {"01"} and {m["sequence"] for m in done.values()} == {
        "00"
    }
    for run_id, m in failed.items():
        assert m["exit_status"] == 2 and "000010.png" in m["error"] and f"failed: {run_id}" in printed
        # The frames before the broken one are written, and counted in the checksum.
        assert json.loads((out / "runs" / run_id / "metrics.json").read_text())["frames"] == 10
        assert m["dataset"]["checksum"]["frames"] == 10
    # The report lists the failed runs with their error, beside the done ones.
    assert main(["report", str(out), "--no-figures"]) == 0
    with (out / "report" / "table.csv").open() as f:
        statuses = {r["run_id"]: (r["status"], r["error"]) for r in csv.DictReader(f)}
    assert {k: s for k, (s, _) in statuses.items()} == {k: m["status"] for k, m in manifests.items()}
    assert all("000010.png" in statuses[k][1] for k in failed)
    # A rerun keeps both: the done runs, and the failed ones unless asked to retry them.
    assert main(args + ["--dry-run"]) == 0
    assert "0 to run, 2 done earlier (kept), 2 failed earlier (kept" in capsys.readouterr().out


def test_ctrl_c_keeps_what_finished_and_the_same_command_goes_on(tmp_path, demo, disposition):
    # SIGINT handled here, so the sweep's process starts with it at its default: a suite started in the
    # background (CI's `cmd &`) runs with SIGINT ignored, which a child inherits and (rightly) keeps.
    disposition("SIGINT", signal.default_int_handler)
    out = tmp_path / "sweep"
    # One run at a time, each long enough (150 frames, seconds) that Ctrl-C sent when the first is done finds the
    # second running on any machine: with two at a time on an idle machine all four finished before it came.
    command = [sys.executable, "-m", "hippo_nav.cli", "sweep", "--stop", "150", "--seeds", "0-3", "--no-figures",
               "--no-progress", "--cpus-per-run", "1", "--workers", "1", "--out", str(out)]  # fmt: skip
    sweep = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        _wait_for(lambda: any(m["status"] == "done" for m in _manifests(out).values()), 180, "a finished run")
        sweep.send_signal(signal.SIGINT)
        printed, _ = sweep.communicate(timeout=120)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    assert sweep.returncode == 130, printed
    assert "interrupted" in printed and "rerun the same command" in printed
    before = _manifests(out)
    finished = {k: m for k, m in before.items() if m["status"] == "done"}
    assert finished and len(finished) < 4
    assert all(m["status"] in ("done", "interrupted") for m in before.values())
    for m in before.values():
        if m["status"] == "interrupted":  # stopped after its current frame, its frames so far written
            assert m["exit_status"] == 130
    again = subprocess.run(command, check=False, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stdout + again.stderr
    assert f"{len(finished)} done earlier (kept)" in again.stdout
    after = _manifests(out)
    assert len(after) == 4 and {m["status"] for m in after.values()} == {"done"}
    for run_id, m in finished.items():
        assert after[run_id]["started_utc"] == m["started_utc"]  # kept, not run again
    rerun = [m for k, m in after.items() if k not in finished]
    assert all(m["sweep_session"] != next(iter(finished.values()))["sweep_session"] for m in rerun)
