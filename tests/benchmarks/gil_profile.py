"""How long the frame loop holds the interpreter lock, and where (docs/results.md, "Cost"): py-spy's `--gil`
mode samples only the thread that holds it, so its samples over the loop's wall time are the share of the
time no other thread could run Python.

    python tests/benchmarks/gil_profile.py --kitti KITTI_ROOT [--sequence 06] [--stop 51] [--rounds 3]

Each round runs `hippo-nav run` under `py-spy record --gil` (py-spy comes with the test extras) and counts
the samples whose stack is in the frame loop or on the pipeline's threads; the loop's wall time is the frames
over `metrics.json` `timing.frames_per_s`. The profiler slows the run (its frame rate is printed), so read
the share, not the milliseconds. Not a test (no assertions; pytest does not collect it).
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

RATE_HZ = 400
_THREAD = re.compile(r"thread \((\d+)\)(?:: ([^;]+))?")


def gil_samples(raw: Path) -> tuple[collections.Counter[str], collections.Counter[tuple[str, str]]]:
    """Samples in the frame loop by thread, and by (thread, innermost hippo_nav function)."""
    lines = [line.rstrip("\n").rsplit(" ", 1) for line in raw.read_text().splitlines() if line.strip()]
    names: dict[str, str] = {}
    for stack, _ in lines:
        match = _THREAD.match(stack)
        if match and match.group(2):
            names[match.group(1)] = re.sub(r"_\d+$", "", match.group(2))
    threads: collections.Counter[str] = collections.Counter()
    holders: collections.Counter[tuple[str, str]] = collections.Counter()
    for stack, count in lines:
        match = _THREAD.match(stack)
        name = names.get(match.group(1), "?") if match else "?"
        if name in ("MainThread", "?") and "_run_frames" not in stack:
            continue  # start-up, imports, writing the results
        frames = stack.split(";")
        ours = [f.split(" (")[0] for f in frames[1:] if "hippo_nav/" in f]
        threads[name] += int(count)
        holders[(name, ours[-1] if ours else frames[-1].split(" (")[0])] += int(count)
    return threads, holders


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kitti", required=True, help="KITTI odometry root (sequences/, poses/)")
    parser.add_argument("--sequence", default="06")
    parser.add_argument("--stop", type=int, default=51)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    bin_dir = Path(sys.executable).parent
    total_threads: collections.Counter[str] = collections.Counter()
    total_holders: collections.Counter[tuple[str, str]] = collections.Counter()
    loop_s = frames = 0.0
    for round_ in range(args.rounds):
        with tempfile.TemporaryDirectory() as tmp:
            raw, out = Path(tmp) / "gil.txt", Path(tmp) / "run"
            command = [
                str(bin_dir / "py-spy"),
                "record",
                "--gil",
                "--threads",
                "-r",
                str(RATE_HZ),
                "-f",
                "raw",
            ]
            command += ["-o", str(raw), "--", str(bin_dir / "hippo-nav"), "run", "--dataset", args.kitti]
            command += ["--sequence", args.sequence, "--stop", str(args.stop), "--out", str(out)]
            run = command + ["--no-figures", "--no-progress"]
            done = subprocess.run(run, check=False, capture_output=True, text=True)
            if done.returncode != 0 or not (out / "metrics.json").is_file():
                # py-spy refused (no ptrace here) or the run failed (py-spy exits 0 then): say which.
                sys.exit(f"gil_profile: the profiled run failed:\n{done.stderr.strip()[-2000:]}")
            metrics = json.loads((out / "metrics.json").read_text())
            threads, holders = gil_samples(raw)
        n, fps = metrics["frames"], metrics["timing"]["frames_per_s"]
        frames, loop_s = frames + n, loop_s + n / fps
        total_threads += threads
        total_holders += holders
        held = sum(threads.values()) / (RATE_HZ * n / fps)
        print(
            f"round {round_ + 1}: {fps:.1f} frames/s under the profiler, the lock held {held:.0%} of the loop"
        )
    samples = sum(total_threads.values())
    print(
        f"\nthe lock held {samples / (RATE_HZ * loop_s):.0%} of the frame loop's wall time ({args.rounds} rounds)"
    )
    print("| thread | share of the loop | ms a frame (profiled) |\n|---|---|---|")
    for name, count in total_threads.most_common():
        print(f"| {name} | {count / (RATE_HZ * loop_s):.1%} | {1e3 * count / RATE_HZ / frames:.2f} |")
    print("\n| thread | innermost hippo_nav function | share of the held time |\n|---|---|---|")
    for (name, function), count in total_holders.most_common(12):
        print(f"| {name} | `{function}` | {count / samples:.1%} |")


if __name__ == "__main__":
    main()
