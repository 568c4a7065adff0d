"""The release profile's choices (codegen units, LTO) judged by build time and frame rate together
(docs/testing.md, "Build profile").

Each profile is built from scratch into its own target folder (the crates already downloaded, so the time is
the compile a fresh clone pays after its downloads), then, round by round and interleaved so that every
profile sees the same machine load, its engine replaces the installed one (`python/hippo_nav/_core.abi3.so`,
put back at the end) and a fresh interpreter times the network step alone and the whole pipeline on a
KITTI sequence (figures and the saved map off). Needs `make develop` first.

    python tests/benchmarks/build_profiles.py --kitti KITTI_ROOT [--sequence 06] [--rounds 3] [--out runs/build_profiles]

Not a test (no assertions; pytest does not collect it): a reproducible measurement.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ENGINE = ROOT / "python" / "hippo_nav" / "_core.abi3.so"
# name: (codegen units, LTO) as Cargo's `[profile.release]` would say them.
PROFILES = {
    "cu16": ("16", "false"),
    "cu4": ("4", "false"),
    "thin-lto cu4": ("4", "thin"),
    "fat-lto cu1": ("1", "fat"),
}

ONE_ROUND = r"""
import json, sys, time
from hippo_nav.datasets import KittiOdometry
from hippo_nav.engine import SpatialMemory
from hippo_nav.pipeline import Pipeline, config_from_dict
memory = SpatialMemory()
for _ in range(20):
    memory.step(0.2, 12.0, 0.1)
clock = time.perf_counter()
for _ in range(300):
    memory.step(0.2, 12.0, 0.1)
step_ms = (time.perf_counter() - clock) / 300 * 1e3
data = KittiOdometry(sys.argv[1], sys.argv[2])
config = config_from_dict({"output": {"figures": False, "save_map": False}})
timing = Pipeline(data, config).run(None).metrics["timing"]
print(json.dumps({"step_ms": step_ms, "frames_per_s": timing["frames_per_s"]}))
"""


def build(target: Path, codegen_units: str, lto: str) -> float:
    shutil.rmtree(target, ignore_errors=True)
    env = dict(os.environ, CARGO_TARGET_DIR=str(target), PYO3_PYTHON=sys.executable)
    env |= {"CARGO_PROFILE_RELEASE_CODEGEN_UNITS": codegen_units, "CARGO_PROFILE_RELEASE_LTO": lto}
    clock = time.perf_counter()
    subprocess.run(
        ["cargo", "build", "--release", "-p", "hippo_py", "--features", "pyo3/extension-module", "--quiet"],
        cwd=ROOT,
        env=env,
        check=True,
    )
    return time.perf_counter() - clock


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kitti", type=Path, required=True, help="KITTI odometry root (sequences/NN/…)")
    parser.add_argument("--sequence", default="06")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("runs/build_profiles"))
    args = parser.parse_args()
    # Cargo runs in the project root and each round in the output folder: every path made absolute first.
    args.kitti, args.out = args.kitti.resolve(), args.out.resolve()
    args.out.mkdir(parents=True, exist_ok=True)
    built = {}
    for name, (units, lto) in PROFILES.items():
        target = args.out / f"target-{name.replace(' ', '-')}"
        seconds = build(target, units, lto)
        engine = target / "release" / "lib_core.so"
        built[name] = engine
        print(f"{name}: build {seconds:.0f} s, engine {engine.stat().st_size / 1e6:.1f} MB", flush=True)
    installed = args.out / "installed_core.so"
    shutil.copy(ENGINE, installed)
    rows: dict[str, list[dict]] = {name: [] for name in PROFILES}
    try:
        for _ in range(args.rounds):
            for name, engine in built.items():
                shutil.copy(engine, ENGINE)
                done = subprocess.run(
                    [sys.executable, "-c", ONE_ROUND, str(args.kitti), args.sequence],
                    capture_output=True,
                    text=True,
                    check=True,
                    cwd=args.out,
                )
                rows[name].append(json.loads(done.stdout.strip().splitlines()[-1]))
    finally:
        shutil.copy(installed, ENGINE)
    for name, runs in rows.items():
        rates = ", ".join(f"{run['frames_per_s']:.1f}" for run in runs)
        step = statistics.median(run["step_ms"] for run in runs)
        print(f"{name}: frames/s {rates}; network step median {step:.2f} ms")


if __name__ == "__main__":
    main()
