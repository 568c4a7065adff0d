"""`hippo-nav sweep` under what goes wrong: links planted in a sweep folder, stop signals, a cluster address
where nothing listens, spaces too big to expand, half-written files on resume, folders that are not a sweep's,
and malformed sweep files, manifests and metrics (property-based, Hypothesis).

Ray is replaced by `FakeRay` (tasks on threads of this process, the real `execute_run`), so these tests need no
Ray start: a run's pipeline runs in a worker thread, and a signal sent to this process reaches the driver's
handlers in the main thread, as in a real sweep."""

from __future__ import annotations

import concurrent.futures
import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import types
from pathlib import Path

import pytest
import yaml
from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.sweep import build_space, plan, run_sweep
from hippo_nav.sweep import scheduler as scheduler_module
from hippo_nav.sweep import space as space_module
from hippo_nav.sweep.manifest import read_manifest, write_json_atomic
from hippo_nav.sweep.scheduler import SweepOptions, SweepSummary, describe
from hippo_nav.sweep.space import config_hash, parse_seeds
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ONE_AT_A_TIME = SweepOptions(cpus_per_run=1, workers=1, progress=False)
FINISHED_METRICS = {"frames": 6, "interrupted": False, "stopped_by_error": None}


# ------------------------------------------------------------------------------------------------
# A stand-in for Ray: tasks on threads, the real worker code


class _Error(Exception):
    pass


class FakeRay(types.ModuleType):
    """What the scheduler and the worker use of Ray, run on a thread pool of this process. `init` with an
    address is refused: the address tests must end before it."""

    def __init__(self, workers: int = 1) -> None:
        super().__init__("ray")
        self.pool = concurrent.futures.ThreadPoolExecutor(workers)
        self.cpus = workers
        self.initialized = False
        self.init_calls: list[dict] = []
        self.exceptions = types.SimpleNamespace(
            RayError=_Error, TaskCancelledError=type("TaskCancelledError", (_Error,), {}),
            RaySystemError=type("RaySystemError", (_Error,), {}),
        )  # fmt: skip

    def is_initialized(self) -> bool:
        return self.initialized

    def init(self, address=None, **kwargs) -> None:
        self.init_calls.append({"address": address, **kwargs})
        if address not in (None, "local"):
            raise AssertionError(f"ray.init reached with address {address}")
        self.initialized = True

    def shutdown(self) -> None:
        self.initialized = False
        self.pool.shutdown(wait=True)

    def cluster_resources(self) -> dict:
        return {"CPU": self.cpus}

    def nodes(self) -> list[dict]:
        return [{"Alive": True, "Resources": {"CPU": self.cpus}}]

    def remote(self, *args, **kwargs):
        if args and callable(args[0]):
            return self._remote(args[0])
        return self._remote

    def _remote(self, target):
        ray = self

        if isinstance(target, type):  # an actor: its methods answer at once

            class Actor:
                @staticmethod
                def remote(*a, **k):
                    instance = target(*a, **k)
                    methods = {
                        n: types.SimpleNamespace(remote=getattr(instance, n))
                        for n in dir(target)
                        if not n.startswith("_")
                    }
                    return types.SimpleNamespace(**methods)

            return Actor

        class Task:
            @staticmethod
            def options(**_kwargs):
                return Task

            @staticmethod
            def remote(*a, **k):
                return ray.pool.submit(target, *a, **k)

        return Task

    def wait(self, refs, num_returns=1, timeout=None):
        try:
            done, _ = concurrent.futures.wait(
                refs, timeout=timeout, return_when=concurrent.futures.FIRST_COMPLETED
            )
        except KeyboardInterrupt:
            # As Ray 2.60's does: a signal handler's exception inside `wait` comes out as a plain
            # KeyboardInterrupt (`check_signals`), whatever the handler raised.
            raise KeyboardInterrupt from None
        ready = [r for r in refs if r in done][:num_returns]
        return ready, [r for r in refs if r not in ready]

    def get(self, ref):
        return ref.result() if isinstance(ref, concurrent.futures.Future) else ref


@pytest.fixture
def fake_ray(monkeypatch):
    ray = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", ray)
    yield ray
    ray.pool.shutdown(wait=True)


pytestmark = pytest.mark.usefixtures("thread_limits_restored")


def _manifests(out: Path) -> dict[str, dict]:
    return {p.parent.name: json.loads(p.read_text()) for p in sorted(out.glob("runs/*/manifest.json"))}


# ------------------------------------------------------------------------------------------------
# 1. Every file through the atomic writer; no link written through


def test_links_planted_in_a_sweep_folder_are_never_written_through(tmp_path, fake_ray, demo):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    space = build_space(dataset={"stop": 6}, no_figures=True)
    (spec,) = space.runs()
    out = tmp_path / "sweep"
    folder = out / "runs" / spec.run_id
    folder.mkdir(parents=True)
    write_json_atomic(out / "sweep.json", {})
    for name in (
        out / ".sweep_session",
        folder / "manifest.json",
        folder / "run.log",
        folder / ".hippo_nav_results",
    ):
        name.symlink_to(victim)
    summary = run_sweep(space, out, ONE_AT_A_TIME, echo=lambda line: None)
    assert summary.done == 1 and victim.read_text() == "keep me\n"
    assert not (out / ".sweep_session").is_symlink() and not (folder / "run.log").is_symlink()
    assert _manifests(out)[spec.run_id]["status"] == "done"


def test_a_link_at_the_lock_or_in_place_of_a_run_folder_is_refused(tmp_path, fake_ray):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    space = build_space(dataset={"stop": 6}, no_figures=True)
    out = tmp_path / "sweep"
    out.mkdir()
    (out / ".sweep.lock").symlink_to(victim)
    with pytest.raises(HippoNavError, match=r"\.sweep\.lock.*symbolic link"):
        run_sweep(space, out, ONE_AT_A_TIME, echo=lambda line: None)
    (out / ".sweep.lock").unlink()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (out / "runs").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(HippoNavError, match=r"runs is a symbolic link"):
        run_sweep(space, out, ONE_AT_A_TIME, echo=lambda line: None)
    assert victim.read_text() == "keep me\n" and not list(elsewhere.iterdir())


def test_files_shipped_back_replace_a_planted_link_instead_of_following_it(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    folder = tmp_path / "sweep" / "runs" / "r1"
    folder.parent.mkdir(parents=True)
    (folder.parent / ".r1.incoming").symlink_to(elsewhere, target_is_directory=True)
    scheduler_module._write_shipped(folder, {"metrics.json": b"{}", "memory/state.npz": b"x"})
    assert not list(elsewhere.iterdir()) and (folder / "metrics.json").read_bytes() == b"{}"
    assert (folder / "memory" / "state.npz").is_file()


# ------------------------------------------------------------------------------------------------
# 2. SIGINT, SIGTERM and SIGHUP stop a sweep the same careful way


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_each_stop_signal_keeps_the_runs_in_flight_as_interrupted_and_names_itself(
    signame, tmp_path, fake_ray, demo, disposition, capsys
):
    def not_handled(signum, _frame):
        raise AssertionError(f"{signal.Signals(signum).name} reached the test, not the sweep")

    disposition(signame, not_handled)  # without the sweep's own handler the test fails (never dies)
    out = tmp_path / "sweep"
    started = threading.Event()

    def send_when_a_run_runs():
        while not started.is_set():
            if any(m["status"] == "running" for m in _manifests(out).values()):
                started.set()
            started.wait(0.02)
        os.kill(os.getpid(), getattr(signal, signame))

    sender = threading.Thread(target=send_when_a_run_runs, daemon=True)
    sender.start()
    code = main(["sweep", "--seeds", "0-1", "--stop", "150", "--no-figures", "--no-progress",
                 "--workers", "1", "--out", str(out)])  # fmt: skip
    sender.join(10)
    number = int(getattr(signal, signame))
    assert code == 128 + number
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1].startswith(f"interrupted by {signame}:") and "rerun the same command" in printed[-1]
    manifests = _manifests(out)
    assert [m["status"] for m in manifests.values()] == ["interrupted"]  # the second run never started
    (manifest,) = manifests.values()
    assert manifest["exit_status"] == 128 + number and signame in manifest["error"]
    # Resume runs both again: the interrupted one is not kept as failed.
    runs = build_space(seeds="0-1", dataset={"stop": 150}, no_figures=True).runs()
    assert len(plan(runs, out).todo) == 2


def test_a_worker_that_ends_while_the_sweep_stops_is_interrupted_not_failed(tmp_path):
    (spec,) = build_space(dataset={"stop": 6}).runs()
    summary = SweepSummary(tmp_path, 1, interrupted=True, signal="SIGHUP")
    ray = FakeRay()
    failed = concurrent.futures.Future()
    failed.set_exception(_Error("the worker died"))
    scheduler_module._finished(ray, failed, spec, tmp_path, "s1", summary)
    manifest = read_manifest(tmp_path / "runs" / spec.run_id)
    assert manifest["status"] == "interrupted" and manifest["exit_status"] == 129 and not summary.failed
    assert "interrupted by SIGHUP" in describe(summary)


# ------------------------------------------------------------------------------------------------
# 3. A cluster address where nothing listens


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_an_address_where_nothing_listens_ends_in_one_line_naming_it(tmp_path, fake_ray, monkeypatch, capsys):
    monkeypatch.setattr(scheduler_module, "CONNECT_TIMEOUT_S", 0.3)
    address = f"127.0.0.1:{_free_port()}"
    code = main(["sweep", "--address", address, "--stop", "6", "--no-progress", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and not fake_ray.init_calls
    assert err.startswith(f"hippo-nav: error: --address {address}: no Ray head answered at {address}")
    assert "ray start --head" in err and "0.3 s" in err
    with pytest.raises(HippoNavError, match="give auto or HOST:PORT"):
        scheduler_module.wait_for_address("no-port-here", 1.0)


def test_sigterm_stops_the_wait_for_a_cluster_at_once(tmp_path, fake_ray, monkeypatch, capsys, disposition):
    disposition("SIGTERM", signal.SIG_DFL)
    monkeypatch.setattr(scheduler_module, "CONNECT_TIMEOUT_S", 600.0)
    trying = threading.Event()

    def refused(*_args, **_kwargs):
        trying.set()
        raise ConnectionRefusedError(111, "Connection refused")

    monkeypatch.setattr(scheduler_module.socket, "create_connection", refused)
    sender = threading.Thread(target=lambda: trying.wait(60) and os.kill(os.getpid(), signal.SIGTERM))
    sender.start()
    code = main(
        ["sweep", "--address", "127.0.0.1:9", "--stop", "6", "--no-progress", "--out", str(tmp_path / "s")]
    )
    sender.join(10)
    err = capsys.readouterr().err.strip()
    assert code == 143 and err.splitlines() == [
        "hippo-nav: interrupted (SIGTERM) before any run started; nothing was lost: rerun the same command"
    ]


# ------------------------------------------------------------------------------------------------
# 4. Sizes bounded before anything is expanded


def test_a_huge_seed_range_is_refused_from_its_ends_without_expanding_it(tmp_path):
    """Run with its address space capped at 3 GiB: the 2**31 seeds of 0-2147483647 (all valid seeds) would
    need 80 GiB as a list, so expanding them first ends in MemoryError instead of the one-line error."""
    code = textwrap.dedent(
        """
        import resource
        from hippo_nav._core import HippoNavError
        resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))
        from hippo_nav.sweep.space import parse_seeds
        try:
            parse_seeds("0-2147483647")
        except HippoNavError as err:
            print(err)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == (
        f"seeds '0-2147483647': 2147483648 seeds, and a sweep makes at most {space_module.MAX_RUNS} runs; check the range for a typo"
    )
    with pytest.raises(HippoNavError, match="seed 1000000000000: give integers from 0 to"):
        parse_seeds("0-1000000000000")
    with pytest.raises(HippoNavError, match="the range is empty"):
        parse_seeds("5-2")


def test_a_cross_product_too_big_is_refused_with_its_size_before_any_run_is_made(monkeypatch):
    def expanded(*_args, **_kwargs):
        raise AssertionError("runs were expanded before the size was checked")

    monkeypatch.setattr(space_module, "_expand", expanded)
    values = ",".join(f"0.{i:03d}" for i in range(1, 201))  # 200 values × 100 seeds
    with pytest.raises(HippoNavError, match="the sweep would make 20000 runs; a sweep makes at most 10000"):
        build_space(sets=[f"views.novelty_threshold={values}"], seeds="0-99")


def test_seeds_are_deduplicated_by_hashing_not_by_comparing_every_pair():
    comparisons = [0]

    class Seed(int):
        def __eq__(self, other):
            comparisons[0] += 1
            return int.__eq__(self, other)

        __hash__ = int.__hash__

    seeds = parse_seeds([Seed(i) for i in range(3000)] + [Seed(7)])
    assert len(seeds) == 3000 and comparisons[0] < 3000  # pairwise: 4.5 million


def test_a_long_validation_says_what_it_does(monkeypatch):
    monkeypatch.setattr(space_module, "VALIDATION_NOTICE_RUNS", 4)
    told: list[str] = []
    runs = build_space(seeds="0-4").runs(echo=told.append)
    assert len(runs) == 5 and told == ["validating the configs of 5 runs (about 1 s)…"]


# ------------------------------------------------------------------------------------------------
# 5. Poor handling


def _leave_done(out: Path, spec, metrics_text: str) -> Path:
    folder = out / "runs" / spec.run_id
    folder.mkdir(parents=True)
    write_json_atomic(folder / "manifest.json", {"run_id": spec.run_id, "status": "done",
                      "config_sha256": config_hash(spec.pipeline_config())})  # fmt: skip
    (folder / "metrics.json").write_text(metrics_text)
    return folder


def test_a_truncated_or_foreign_metrics_file_is_not_a_finished_run(tmp_path):
    runs = build_space(seeds="0-4", no_figures=True).runs()
    whole = json.dumps(FINISHED_METRICS)
    texts = [whole, whole[: len(whole) // 2], "{}", json.dumps({**FINISHED_METRICS, "interrupted": True}),
             json.dumps({**FINISHED_METRICS, "frames": "6"})]  # fmt: skip
    for spec, text in zip(runs, texts, strict=True):
        _leave_done(tmp_path, spec, text)
    found = plan(runs, tmp_path)
    assert [s.run_id for s in found.done] == [runs[0].run_id]
    assert [s.run_id for s in found.todo] == [s.run_id for s in runs[1:]]


def test_a_folder_that_is_not_a_sweeps_is_refused_by_name(tmp_path, capsys, fake_ray):
    plain_run = tmp_path / "demo"
    plain_run.mkdir()
    (plain_run / ".hippo_nav_results").write_text("{}")
    (plain_run / "metrics.json").write_text("{}")
    other = tmp_path / "notes"
    other.mkdir()
    (other / "todo.txt").write_text("x")
    for folder, what in (
        (plain_run, "is the results folder of a `hippo-nav run`"),
        (other, "is not a sweep folder"),
    ):
        for extra in ([], ["--dry-run"]):
            assert main(["sweep", "--stop", "6", "--no-progress", "--out", str(folder), *extra]) == 2
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1 and f"{folder} {what}" in err
        assert not (folder / "sweep.json").exists() and not (folder / "runs").exists()
    assert not fake_ray.init_calls


def test_an_empty_axis_is_refused_naming_it(tmp_path):
    for text, axis in (('[set]\n"views.novelty_threshold" = []\n', "set views.novelty_threshold"),
                       ("seeds = []\n", "the seeds axis"), ("lesion = []\n", "the lesion axis"),
                       ('[[space]]\nodometry = []\n', "the odometry axis")):  # fmt: skip
        file = tmp_path / "s.toml"
        file.write_text(text)
        with pytest.raises(HippoNavError, match=f"{axis} has no values"):
            build_space(file)
    with pytest.raises(HippoNavError, match="sequence ''"):
        build_space(sequences="00,", dataset={"dataset": str(tmp_path)})


def test_two_spellings_of_one_value_make_one_run(tmp_path):
    (run,) = build_space(sets=["injection.decay_per_frame=1,1.0"]).runs()
    assert run.overrides == {"injection.decay_per_frame": 1.0}
    file = tmp_path / "s.yaml"
    file.write_text("space:\n  - set: {vo.window_keyframes: 8}\n  - set: {vo.window.max_keyframes: 8}\n")
    runs = build_space(file).runs()
    assert len(runs) == 1 and runs[0].pipeline_config().vo.window.max_keyframes == 8


def test_a_local_sweep_does_not_print_rays_token_notice(caplog):
    class Ray:
        def is_initialized(self):
            return False

        def init(self, **kwargs):
            logging.getLogger(scheduler_module._TOKEN_LOGGER).warning(
                "Token authentication is enabled for this Ray cluster. Set RAY_AUTH_MODE=disabled to opt out."
            )
            logging.getLogger(scheduler_module._TOKEN_LOGGER).warning("another warning")

    with caplog.at_level(logging.WARNING):
        assert scheduler_module._connect(Ray(), SweepOptions(workers=1))
    assert [r.getMessage() for r in caplog.records] == ["another warning"]


def test_out_of_range_numbers_are_refused_naming_the_option(tmp_path, fake_ray):
    space = build_space(dataset={"stop": 6})
    for options, option in ((SweepOptions(workers=10**30), "--workers"), (SweepOptions(cpus_per_run=5000), "--cpus-per-run"),
                            (SweepOptions(retries=10**9), "--retries")):  # fmt: skip
        with pytest.raises(HippoNavError, match=f"{option} .*: give an integer from"):
            run_sweep(space, tmp_path / "s", options)
    file = tmp_path / "s.toml"
    for text, key in (
        ("stop = 1_000_000_000_000\n", "stop"),
        ("stride = 0\n", "stride"),
        ("start = -4\n", "start"),
    ):
        file.write_text(text)
        with pytest.raises(HippoNavError, match=f"^{key} .*: give an integer frame number from"):
            build_space(file)
    assert not fake_ray.init_calls


def test_what_failed_is_said_in_words_naming_the_file(tmp_path, capsys, fake_ray):
    out = tmp_path / "sweep"
    (out / ".sweep.lock").mkdir(parents=True)  # a lock that cannot be opened
    assert main(["sweep", "--stop", "6", "--no-progress", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "[Errno" not in err and str(out / ".sweep.lock") in err and len(err.splitlines()) == 1
    file = tmp_path / "s.toml"
    file.write_text(f'dataset = "{tmp_path}/{"x" * 300}"\n')  # a name too long to look at
    assert main(["sweep", str(file), "--dry-run"]) == 2
    err = capsys.readouterr().err.strip()
    assert "[Errno" not in err and err.startswith("hippo-nav: error: dataset ") and "no such file" in err


@pytest.mark.parametrize(
    "text",
    ["seeds = " + "[" * 5000 + "]" * 5000 + "\n", "[set]\n'views.novelty_threshold' = " + "[" * 40 + "0.4" + "]" * 40,
     "out = 5\n", "config_file = 3\n", 'dataset_kind = ["kitti"]\n', "seeds = 1.5\n", "lesion = [{a = 1}]\n",
     "sequence = [[0]]\n", "odometry = [{file = 3}]\n", 'odometry = [{file = "x", format = []}]\n', "space = 3\n",
     'cameras = {a = 1}\n', 'config = {views = 3}\n', "x" * (2**20 + 10)],
)  # fmt: skip
def test_structurally_extreme_sweep_files_are_one_line_errors(text, tmp_path, capsys):
    file = tmp_path / "s.toml"
    file.write_text(text)
    assert main(["sweep", str(file), "--dry-run", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("hippo-nav: error: ")


def test_yaml_deeply_nested_or_multiplied_by_aliases_is_a_one_line_error(tmp_path):
    file = tmp_path / "s.yaml"
    file.write_text("seeds: " + "[" * 3000 + "]" * 3000 + "\n")
    with pytest.raises(HippoNavError, match="nested too deeply"):
        build_space(file)
    laughs = ["a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    laughs += [
        f"{chr(98 + i)}: &{chr(98 + i)} [" + ", ".join([f"*{chr(97 + i)}"] * 9) + "]" for i in range(8)
    ]
    file.write_text("\n".join(laughs) + "\nseeds: *i\n")  # 9**9 values by reference
    with pytest.raises(HippoNavError, match="holds more than"):
        build_space(file)


# ------------------------------------------------------------------------------------------------
# 6. Property-based: malformed sweep files, manifests and metrics are one-line errors or ignored, never tracebacks

SCALARS = st.one_of(
    st.booleans(), st.integers(min_value=-(2**70), max_value=2**70), st.floats(allow_nan=True),
    st.text(max_size=12), st.sampled_from(["vo", "drift", "none", "dorsal", "ventral+dorsal", "0-3", "00", ""]),
)  # fmt: skip
VALUES = st.recursive(
    st.one_of(st.none(), SCALARS),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.one_of(st.text(max_size=8), st.sampled_from(
            ["file", "format", "align", "views.novelty_threshold", "seeds", "lesion", "views"])), inner, max_size=4)
    ),
    max_leaves=12,
)  # fmt: skip
KEYS = st.sampled_from(
    ["set", "seeds", "lesion", "sequence", "odometry", "dataset", "dataset_kind", "start", "stop", "stride",
     "config", "config_file", "out", "space", "cameras", "unknown"]
)  # fmt: skip
SWEEP_FILES = st.dictionaries(KEYS, VALUES, max_size=5)
SETTINGS = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _load(path: Path) -> None:
    space = build_space(path)
    if space.size() <= 16:  # validation of larger spaces is the same code, slower
        space.runs()


@SETTINGS
@given(data=SWEEP_FILES, suffix=st.sampled_from([".yaml", ".toml"]))
def test_any_structure_in_a_sweep_file_is_read_or_refused_in_one_line(data, suffix):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"s{suffix}"
        if suffix == ".yaml":
            path.write_text(yaml.safe_dump(data))
        else:
            path.write_text("\n".join(f"{k} = {json.dumps(v)}" for k, v in data.items()) + "\n")
        try:
            _load(path)
        except HippoNavError as err:
            assert "\n" not in str(err) and "[Errno" not in str(err)


@SETTINGS
@given(text=st.text(max_size=300), suffix=st.sampled_from([".yaml", ".toml"]))
def test_any_text_as_a_sweep_file_is_read_or_refused_in_one_line_by_the_command(text, suffix, capsys):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"s{suffix}"
        path.write_text(text, encoding="utf-8", errors="replace")
        code = main(["sweep", str(path), "--dry-run", "--out", str(Path(folder) / "o")])
        err = capsys.readouterr().err
        assert code in (0, 2)
        if code == 2:
            assert len(err.strip().splitlines()) == 1 and err.startswith("hippo-nav: error: ")


RUNS = build_space(seeds="0-1", no_figures=True).runs()
JSON_TEXT = st.one_of(
    VALUES.map(lambda v: json.dumps(v, default=str)),
    st.dictionaries(st.sampled_from(["status", "config_sha256", "frames", "interrupted", "stopped_by_error",
                                     "dataset", "attempt", "sweep_session"]), VALUES).map(json.dumps),
    st.binary(max_size=64).map(lambda b: b.decode("latin-1")), st.just("[" * 100_000),
)  # fmt: skip


@SETTINGS
@given(manifest=JSON_TEXT, metrics=JSON_TEXT, done=st.booleans())
def test_resume_reads_any_manifest_and_metrics_without_raising(manifest, metrics, done):
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder)
        run_dir = out / "runs" / RUNS[0].run_id
        run_dir.mkdir(parents=True)
        if done:  # a manifest that would be kept but for what metrics.json holds
            manifest = json.dumps({"status": "done", "config_sha256": config_hash(RUNS[0].pipeline_config())})
        (run_dir / "manifest.json").write_text(manifest)
        (run_dir / "metrics.json").write_text(metrics)
        found = plan(RUNS, out)
        assert len(found.todo) + len(found.done) + len(found.failed) == len(RUNS)
        if found.done:
            parsed = json.loads(metrics)
            assert (
                parsed["interrupted"] is False and isinstance(parsed["frames"], int) and parsed["frames"] >= 1
            )
        assert scheduler_module.finished(run_dir, read_manifest(run_dir)) == bool(found.done)
