"""View-cell matching speed (`make bench`; skipped by the default test run).

One round = one query template matched against every stored cell without storing it
(`TemplateViewCells.best_match`, the pruned exact search), against 1 000 and 10 000 stored random patch-normalised
templates. The baseline is the plain exhaustive search of the same store (`best_match_brute_force`, every
cell at every shift); compare within one group (`views_1000`, `views_10000`) for the speed-up. Two queries:
`revisit` (a noisy copy of one stored template, the loop-closure case: the match is found early and prunes
the rest) and `novel` (an unrelated view, the worst case for pruning). Both searches return the same answer
(checked before timing).

`test_restricted_match`: the same pruned search over every cell (`full`) against a 200-cell subset
(`candidates=`, e.g. the cells stored near the current place estimate, the target among them for a
revisit), with 1 000 and 5 000 stored cells; each group (`views_among_<n>_<query>`) shows the ratio. The
subset's cost does not grow with the store, which is what keeps a long run's per-frame cost flat.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hippo_nav import _core
from hippo_nav.view_cells import TemplateViewCells as ViewCells

SIZES = (1_000, 10_000)
RESTRICTED_SIZES = (1_000, 5_000)
SUBSET = 200


def _random_templates(cells: ViewCells, n: int, rng: np.random.Generator) -> np.ndarray:
    """`n` templates made by `template_from_image` from smooth random images (street-like mid frequencies)."""
    cfg = cells.config
    shape = (4 * cfg.height_px, 4 * cfg.width_px)  # crop keeps 60 % of the rows: still ≥ height_px
    out = np.empty((n, cfg.height_px, cfg.width_px), np.float32)
    for k in range(n):
        noise = cv2.GaussianBlur(rng.normal(size=shape).astype(np.float32), (0, 0), 3.0)
        image = np.clip(128 + 40 * noise / noise.std(), 0, 255).astype(np.uint8)
        out[k] = cells.template_from_image(image)
    return out


@pytest.fixture(scope="module")
def stores() -> dict[int, tuple[ViewCells, dict[str, np.ndarray]]]:
    rng = np.random.default_rng(0)
    result = {}
    for n in SIZES:
        cells = ViewCells()
        templates = _random_templates(cells, n, rng)
        for t in templates:
            cells.add(t)
        revisit = templates[n // 3] + rng.normal(scale=0.3, size=templates[0].shape).astype(np.float32)
        novel = _random_templates(cells, 1, rng)[0]
        result[n] = (cells, {"revisit": revisit, "novel": novel})
    return result


@pytest.mark.parametrize("query", ["revisit", "novel"])
@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("search", ["pruned", "brute_force"])
def test_best_match(benchmark, stores, n: int, query: str, search: str) -> None:
    benchmark.group = f"views_{n}"
    cells, queries = stores[n]
    q = queries[query]
    core: _core._ViewCells = cells._cells
    fast, brute = core.best_match(q), core.best_match_brute_force(q)
    assert fast is not None and brute is not None
    assert fast[0] == brute[0] and fast[2] == brute[2] and fast[1] == pytest.approx(brute[1], abs=1e-6)
    if query == "revisit":
        assert fast[0] == n // 3
    benchmark.extra_info.update(stored=n, query=query, cell_id=fast[0], difference=float(fast[1]))
    fn = cells.best_match if search == "pruned" else core.best_match_brute_force
    benchmark(fn, q)


@pytest.fixture(scope="module")
def restricted_stores() -> dict[int, tuple[ViewCells, dict[str, np.ndarray], np.ndarray]]:
    rng = np.random.default_rng(1)
    result = {}
    for n in RESTRICTED_SIZES:
        cells = ViewCells()
        templates = _random_templates(cells, n, rng)
        for t in templates:
            cells.add(t)
        target = n // 3
        revisit = templates[target] + rng.normal(scale=0.3, size=templates[0].shape).astype(np.float32)
        novel = _random_templates(cells, 1, rng)[0]
        others = rng.choice(np.delete(np.arange(n), target), size=SUBSET - 1, replace=False)
        subset = np.sort(np.r_[others, target]).astype(np.int64)
        result[n] = (cells, {"revisit": revisit, "novel": novel}, subset)
    return result


@pytest.mark.parametrize("query", ["revisit", "novel"])
@pytest.mark.parametrize("n", RESTRICTED_SIZES)
@pytest.mark.parametrize("search", ["full", f"subset{SUBSET}"])
def test_restricted_match(benchmark, restricted_stores, n: int, query: str, search: str) -> None:
    benchmark.group = f"views_among_{n}_{query}"
    cells, queries, subset = restricted_stores[n]
    q = queries[query]
    d = cells.differences(q)[0]
    got = cells.best_match(q, subset)
    assert got is not None and got[1] == pytest.approx(float(d[subset].min()), abs=1e-6)
    if query == "revisit":
        assert got[0] == n // 3 == cells.best_match(q)[0]  # type: ignore[index]
    candidates = None if search == "full" else subset
    benchmark.extra_info.update(
        stored=n, query=query, candidates=len(subset) if candidates is not None else n
    )
    benchmark(cells.best_match, q, candidates)


@pytest.fixture(scope="module")
def word_descriptors() -> tuple[np.ndarray, np.ndarray]:
    """ORB descriptors (500 each, the word cells' default) of a textured image and of the same image shifted
    8 px with noise: a revisit's verification."""
    rng = np.random.default_rng(3)
    noise = cv2.GaussianBlur(rng.normal(size=(400, 1200)).astype(np.float32), (0, 0), 2.0)
    image = np.clip(128 + 50 * noise / noise.std(), 0, 255).astype(np.uint8)
    shifted = np.clip(np.roll(image, 8, axis=1) + rng.normal(scale=4, size=image.shape), 0, 255).astype(
        np.uint8
    )
    orb = cv2.ORB_create(500)
    return orb.detectAndCompute(image, None)[1], orb.detectAndCompute(shifted, None)[1]


def _opencv_ratio_matches(query: np.ndarray, stored: np.ndarray, ratio: float) -> tuple[list[int], list[int]]:
    """What the word cells' verification did before: OpenCV's knnMatch, the ratio test in Python."""
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(query, stored, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    return [m.queryIdx for m in good], [m.trainIdx for m in good]


@pytest.mark.parametrize("how", ["opencv_knn", "rust"])
def test_word_ratio_matches(benchmark, word_descriptors, how: str) -> None:
    """Group `word_matches`: the word cells' verification matching (500 × 500 descriptors, ratio 0.8), OpenCV's
    knnMatch with the ratio test in Python against `hamming_ratio_matches`; both give the same matches
    (checked before timing)."""
    query, stored = word_descriptors
    expected = _opencv_ratio_matches(query, stored, 0.8)
    got = _core.hamming_ratio_matches(query, stored, 0.8)
    assert (got[0].tolist(), got[1].tolist()) == expected and len(expected[0]) > 100
    benchmark.group = "word_matches"
    if how == "rust":
        benchmark(_core.hamming_ratio_matches, query, stored, 0.8)
    else:
        benchmark(_opencv_ratio_matches, query, stored, 0.8)
