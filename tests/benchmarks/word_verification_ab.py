"""What matching the word cells' verification in Rust (`_core.hamming_ratio_matches`) changed: the pipeline with
every default on, its verification as before (OpenCV's `knnMatch(k=2)` and the ratio test in Python: one
`DMatch` object per candidate) against as now, interleaved round by round on the same frames so both see the
same machine load (docs/results.md, "Cost"). Each round checks that both make the same view cells, frame by
frame (the matches are identical, `tests/view_cells/test_word_matching.py`).

    python tests/benchmarks/word_verification_ab.py --dataset runs/renders --sequence 05 --stop 800 [--rounds 3]

Prints per round and implementation: frames/s, CPU ms a frame (every thread), the views stage's ms a frame; then
the ratios now / before. Not a test (no assertions on time; pytest does not collect it).
"""

from __future__ import annotations

import argparse
import statistics
from typing import Any

import cv2
import numpy as np
from hippo_nav.pipeline import Pipeline, config_from_dict, open_input
from hippo_nav.view_cells import words

_MATCHER = cv2.BFMatcher(cv2.NORM_HAMMING)  # one, as the code before kept one per WordViewCells
_NOW = words.WordViewCells._verify


def _verify_before(self: words.WordViewCells, view: Any, cell: int, bar: int) -> tuple[int, Any]:
    """`WordViewCells._verify` as it was before (2026-12-02): the matches from OpenCV's knnMatch."""
    cfg = self.config
    stored_px, stored_desc = self._cells.features(cell)
    if len(stored_desc) < bar:
        return 0, None
    pairs = _MATCHER.knnMatch(view.descriptors, stored_desc, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < cfg.ratio_test * p[1].distance]
    if len(good) < max(bar, 8):
        return 0, None
    now = view.keypoints_px[[m.queryIdx for m in good]]
    then = stored_px[[m.trainIdx for m in good]]
    try:
        F, mask = cv2.findFundamentalMat(then, now, cv2.USAC_FM_8PTS, cfg.ransac_px, 0.999, 1000)
    except cv2.error:
        return 0, None
    if F is None or mask is None or F.shape != (3, 3):
        return 0, None
    keep = mask.ravel() > 0
    return int(np.count_nonzero(keep)), (F, then[keep], now[keep])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, help="a KITTI root (or a render folder)")
    parser.add_argument("--sequence", default="05")
    parser.add_argument("--stop", type=int, default=800, help="frames of the sequence from its first")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    measured: dict[str, list[tuple[float, float, float]]] = {"before": [], "now": []}
    for round_ in range(args.rounds):
        cells = {}
        for name, verify in (("before", _verify_before), ("now", _NOW)):
            words.WordViewCells._verify = verify  # type: ignore[method-assign]
            data = open_input(args.dataset, sequence=args.sequence, stop=args.stop)
            result = Pipeline(data, config_from_dict({"output": {"figures": False}})).run(None)
            timing = result.metrics["timing"]
            row = (timing["frames_per_s"], timing["cpu_ms_per_frame"], timing["per_frame_ms"]["views"])
            measured[name].append(row)
            cells[name] = result.record.column("view_cell")
            print(
                f"round {round_} {name:6s} {row[0]:6.1f} frames/s  {row[1]:6.1f} ms CPU  views {row[2]:5.1f} ms"
            )
        if cells["before"] != cells["now"]:
            raise SystemExit("the two made different view cells: the matches are not the same")
    for i, what in enumerate(("frames/s", "CPU a frame", "views a frame")):
        ratios = [n[i] / b[i] for n, b in zip(measured["now"], measured["before"])]
        print(
            f"{what}: now / before {min(ratios):.2f}–{max(ratios):.2f}× (median {statistics.median(ratios):.2f}×)"
        )
    words.WordViewCells._verify = _NOW  # type: ignore[method-assign]


if __name__ == "__main__":
    main()
