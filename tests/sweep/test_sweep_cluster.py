"""`hippo-nav sweep --address` against a Ray cluster the test starts (`ray start --head`) on 127.0.0.1 and stops.

Kept on loopback (`RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`: the node advertises 127.0.0.1, not the machine's
interface) and with the same `RAY_AUTH_MODE` for the head and the sweep (docs/sweep.md). The head runs with
`--block` in its own session: stopping that one process stops every Ray process it started, and the test
stops it whatever happens (its whole process group is killed if it does not stop)."""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("ray")

pytestmark = pytest.mark.slow

LOOPBACK_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_AUTH_MODE": "token"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def ray_head(env: dict[str, str], log: Path, num_cpus: int = 2) -> Iterator[str]:
    """A Ray head on 127.0.0.1 (its address), its output in `log`, stopped on exit."""
    port = _free_port()
    ray_command = str(Path(sys.executable).with_name("ray"))
    with log.open("w") as output:
        head = subprocess.Popen(
            [ray_command, "start", "--head", f"--port={port}", f"--num-cpus={num_cpus}",
             "--include-dashboard=false", "--disable-usage-stats", "--block"],
            env=env, stdout=output, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while "Ray runtime started" not in log.read_text():
            assert head.poll() is None, f"ray start --head ended:\n{log.read_text()[-3000:]}"
            assert time.monotonic() < deadline, f"ray start --head did not start:\n{log.read_text()[-3000:]}"
            time.sleep(0.2)
        yield f"127.0.0.1:{port}"
    finally:
        head.send_signal(signal.SIGTERM)  # --block: stops the processes this head started
        try:
            head.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
            head.wait(10)
        # `ray start` leaves its address for `ray.init()` to find; a stopped head's address is left to no one.
        current = Path(tempfile.gettempdir()) / "ray" / "ray_current_cluster"
        with contextlib.suppress(OSError):
            if current.read_text().strip() == f"127.0.0.1:{port}":
                current.unlink()


def test_a_sweep_on_a_cluster_started_on_loopback(tmp_path):
    # The head and the sweep share a token of the test's own: with none given, Ray reads ~/.ray/auth_token,
    # which a fresh machine does not have yet (`ray start` then ended with "no authentication token").
    env = {**os.environ, **LOOPBACK_ENV, "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    out = tmp_path / "sweep"
    with ray_head(env, tmp_path / "head.log") as address:
        done = subprocess.run(
            [sys.executable, "-m", "hippo_nav.cli", "sweep", "--address", address, "--stop", "20", "--seeds", "0-1",
             "--lesion", "none,ventral", "--no-figures", "--no-progress", "--out", str(out)],
            env=env, capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "4 runs: 4 to run" in done.stdout and "4 runs done" in done.stdout
    manifests = [json.loads(p.read_text()) for p in out.glob("runs/*/manifest.json")]
    assert len(manifests) == 4 and {m["status"] for m in manifests} == {"done"}
    assert all((out / "runs" / m["run_id"] / "metrics.json").is_file() for m in manifests)
