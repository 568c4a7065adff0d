"""Word view cells: local view cells that recognise real revisits (ORB words, geometric verification);
a `hippo_nav.view_cells.ViewDescriptor` (`parts.view_cells = "words"`, config section `view_words`).

A view is described by the ORB features of the left image (OpenCV; the image first shrunk by area
averaging to at most `max_width_px` columns). Its descriptors are quantised by a vocabulary of binary words
into a tf-idf bag of words (`hippo_views::words`, Rust), and the store's inverted index ranks the stored
cells by DBoW2's L1 similarity. A ranked cell is *verified* when enough of its descriptors match the view's
(mutual nearest neighbours that pass Lowe's ratio test) and fit one epipolar geometry (RANSAC on the
essential matrix when the camera matrix is known, otherwise the fundamental matrix): `min_inliers` or more
inliers make the view familiar. Unrelated places give a handful of chance inliers; a revisit in another
lane, under other light, gives tens.

A view cell stays the paper's unit (docs/spec.md §7): a familiar view names a cell, whose stored network
state the pipeline recalls; a novel view becomes a new cell. Two bars keep cells local while revisits are
still recognised through appearance and viewpoint change:

- a cell *stored before the current passage* (not among `recent`: the system passes the cells made within
  the last `view_search.passage_m` of travel) is recognised with `min_inliers` verified matches: the place
  is the same even if the light, the parked cars and the lane are not;
- a *recent* cell (the passage the agent is on) stays active only while it keeps `keep_inliers` matches
  (more): once the view has moved on that far, a new cell is made, so cells are spaced along the path
  instead of one cell covering a whole street.

Old cells are tried first: on a revisit, the cell of the earlier pass is recalled even though the cell
made a moment ago on this pass also looks like the view.

Relative heading: with a camera matrix, the median change of the verified features' bearings (see
`_heading`), counter-clockwise positive like the template cells' shift. Measurements: docs/views.md.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
from numpy.typing import ArrayLike
from pydantic import ConfigDict, Field

from hippo_nav import _core
from hippo_nav._core import HippoNavError, hamming_ratio_matches
from hippo_nav._defaults import ConfigSection
from hippo_nav.datasets.base import StereoCalibration, StereoFrame
from hippo_nav.io.errors import read_bytes
from hippo_nav.memory import split_ragged, stack_ragged

__all__ = [
    "Vocabulary",
    "WordObservation",
    "WordView",
    "WordViewCells",
    "WordViewConfig",
    "default_vocabulary",
    "train_vocabulary",
]


class WordViewConfig(ConfigSection):
    """Word view-cell parameters (the config's `view_words` section; measured choices: docs/views.md)."""

    model_config = ConfigDict(frozen=True)

    max_width_px: int = Field(
        640, ge=64, le=16384, description="images wider than this are shrunk first (area)"
    )
    orb_features: int = Field(500, ge=16, le=20000, description="ORB corners per view")
    orb_levels: int = Field(4, ge=1, le=12, description="ORB pyramid levels (scale factor 1.2)")
    min_features: int = Field(30, ge=8, le=20000, description="views with fewer features are uninformative")
    top_k: int = Field(
        5, ge=1, le=1000, description="best-ranked older cells verified (the bag of words only ranks)"
    )
    ratio_test: float = Field(0.8, gt=0.0, le=1.0, description="Lowe's ratio for descriptor matches")
    ransac_px: float = Field(2.0, gt=0.0, description="epipolar RANSAC threshold (shrunk-image pixels)")
    min_inliers: int = Field(
        40, ge=8, le=20000, description="verified matches that recognise a cell of an earlier pass"
    )
    keep_inliers: int = Field(
        60, ge=8, le=20000, description="verified matches that keep a recent cell active"
    )
    vocabulary: Path | None = Field(
        None, description="a vocabulary file (`hippo-nav vocabulary`); None: the one shipped with the package"
    )


@dataclass(frozen=True)
class WordView:
    """One view's features: keypoints (n, 2) float32 in the shrunk image's pixels, descriptors (n, 32)
    uint8, and the shrink factor (shrunk px per image px)."""

    keypoints_px: np.ndarray
    descriptors: np.ndarray
    scale: float

    def __len__(self) -> int:
        return len(self.keypoints_px)


@dataclass(frozen=True)
class WordObservation:
    """What one observation did (like `hippo_nav.views.ViewObservation`).

    `difference` is 1 − inliers / features of the view (1 when nothing verified), so that lower is more
    familiar as for templates; `inliers` and `score` (the bag-of-words similarity of the chosen cell) are
    the evidence itself. `recent` says the match is a cell of the current passage."""

    status: str
    cell_id: int | None
    difference: float
    inliers: int
    score: float
    relative_heading_rad: float
    recent: bool = False

    @property
    def is_new(self) -> bool:
        return self.status == "new"

    @property
    def shift_px(self) -> int:
        return 0


class Vocabulary:
    """A vocabulary of binary words (`hippo_views::words`): train it, save it, load it."""

    def __init__(self, native: Any) -> None:
        self._native = native

    @staticmethod
    def train(
        descriptor_sets: list[np.ndarray], branching: int = 10, levels: int = 4, seed: int = 0
    ) -> Vocabulary:
        """Train on the ORB descriptors of many images (a list of (n, 32) uint8 arrays)."""
        sets = [np.ascontiguousarray(d, dtype=np.uint8).reshape(-1, 32) for d in descriptor_sets]
        return Vocabulary(_core._Vocabulary.train(sets, branching, levels, seed))

    @staticmethod
    def load(path: str | Path) -> Vocabulary:
        """A vocabulary file (`save`, `hippo-nav vocabulary`); a missing, unreadable or damaged file
        (truncated, bit-flipped: its checksum fails; another format; empty; over `MAX_DATA_FILE_BYTES`; a
        folder) is one `HippoNavError` naming the file and what is wrong."""
        path = Path(path)
        if path.exists() and not path.is_file():
            # A folder, or a pipe or device (whose read could block for ever): refused before opening it.
            raise HippoNavError(
                f"{path}: not a vocabulary file (a folder or a device); give the file that "
                "`hippo-nav vocabulary --out FILE` wrote"
            )
        try:
            data = read_bytes(path, "vocabulary")
        except OSError as err:
            raise HippoNavError(f"{path}: cannot read the vocabulary ({err.strerror or err})") from None
        try:
            return Vocabulary(_core._Vocabulary.from_bytes(data))
        except HippoNavError as err:
            raise HippoNavError(f"{path}: {err}") from None

    def save(self, path: str | Path) -> None:
        """Write the vocabulary atomically (`hippo_nav.io.atomic`)."""
        from hippo_nav.io.atomic import write_bytes

        write_bytes(path, self._native.to_bytes())

    def __len__(self) -> int:
        return len(self._native)

    @property
    def branching(self) -> int:
        return int(self._native.branching)

    @property
    def levels(self) -> int:
        return int(self._native.levels)

    @property
    def sha256(self) -> str:
        """The checksum of the saved vocabulary (what a saved memory's word cells depend on)."""
        import hashlib

        return hashlib.sha256(bytes(self._native.to_bytes())).hexdigest()


_DEFAULT_VOCABULARY = Path(__file__).with_name("orb_words.voc")


def default_vocabulary() -> Vocabulary:
    """The vocabulary shipped with the package (see docs/views.md for how it was made)."""
    return Vocabulary.load(_DEFAULT_VOCABULARY)


class WordViewCells:
    """Word view cells, a `hippo_nav.view_cells.ViewDescriptor`: `describe` a frame (or
    `describe_image` a gray image), then `observe` the view (see the module doc)."""

    describe_on_worker: ClassVar[bool] = True
    """ORB features cost a few milliseconds a frame and need the image alone: made on the front end's loader thread."""

    def __init__(
        self,
        config: WordViewConfig | None = None,
        vocabulary: Vocabulary | None = None,
        camera_matrix: ArrayLike | None = None,
    ) -> None:
        self.config = config or WordViewConfig()
        self.vocabulary = vocabulary if vocabulary is not None else default_vocabulary()
        self._cells = _core._WordCells(self.vocabulary._native)
        self._camera_matrix = None if camera_matrix is None else np.asarray(camera_matrix, np.float64)
        self._orb: dict[int, Any] = {}  # by descriptor patch size (see `_detector`)

    def _detector(self, height_px: int) -> Any:
        """ORB with its descriptor patch and border fitted to the image: 31 px from 186 rows up, smaller on
        small renders so that most rows stay usable (a 96-row image would keep only 34 rows at 31 px)."""
        patch = int(np.clip(height_px // 6, 15, 31)) | 1
        if patch not in self._orb:
            cfg = self.config
            self._orb[patch] = cv2.ORB.create(
                nfeatures=cfg.orb_features,
                scaleFactor=1.2,
                nlevels=cfg.orb_levels,
                edgeThreshold=patch,
                patchSize=patch,
                fastThreshold=10,
            )
        return self._orb[patch]

    @classmethod
    def for_camera(cls, config: WordViewConfig, calibration: StereoCalibration) -> WordViewCells:
        """Word view cells for one camera (its matrix gives the relative heading)."""
        vocabulary = None if config.vocabulary is None else Vocabulary.load(config.vocabulary)
        return cls(config, vocabulary, camera_matrix=calibration.K)

    def __len__(self) -> int:
        return len(self._cells)

    def image_rows(self, height_px: int) -> None:
        """Features are taken from the whole image (nothing to outline)."""
        return

    def describe(self, frame: StereoFrame) -> WordView:
        """The ORB features of the frame's left image."""
        return self.describe_image(frame.left)

    def describe_image(self, gray: np.ndarray) -> WordView:
        """The ORB features of a gray image (uint8, any layout)."""
        image = np.asarray(gray)
        if image.ndim != 2:
            raise HippoNavError(f"expected a gray image of shape (H, W), got shape {image.shape}")
        if image.dtype != np.uint8:
            raise HippoNavError(f"expected a uint8 gray image, got dtype {image.dtype}")
        scale = min(1.0, self.config.max_width_px / image.shape[1])
        if scale < 1.0:
            size = (round(image.shape[1] * scale), round(image.shape[0] * scale))
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        keypoints, descriptors = self._detector(image.shape[0]).detectAndCompute(
            np.ascontiguousarray(image), None
        )
        if descriptors is None or not keypoints:
            return WordView(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8), scale)
        points = np.array([k.pt for k in keypoints], np.float32)
        return WordView(points, descriptors, scale)

    def add(self, view: WordView) -> int:
        """Store a view as a new cell without matching; returns its id."""
        return int(self._cells.add(_pixels(view), view.descriptors))

    # Persistent (docs/memory.md): every cell's features; they depend on the detector and the vocabulary.
    def depends_on(self) -> dict[str, object]:
        cfg = self.config
        return {
            "max_width_px": cfg.max_width_px,
            "orb_features": cfg.orb_features,
            "orb_levels": cfg.orb_levels,
            "vocabulary_sha256": self.vocabulary.sha256,
        }

    def export_state(self) -> dict[str, np.ndarray]:
        """Every cell's features, for a memory folder: `count` (cells,), `keypoints_px` (Σ count, 2) float32,
        `descriptors` (Σ count, 32) uint8, in cell order. A cell's bag of words is made again from them."""
        features = [self._cells.features(c) for c in range(len(self._cells))]
        return {
            "count": np.array([len(k) for k, _ in features], np.int64),
            "keypoints_px": stack_ragged([k for k, _ in features], 2, np.float32),
            "descriptors": stack_ragged([d for _, d in features], 32, np.uint8),
        }

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        """Store the cells of `export_state` (into an empty set of cells), with the same ids."""
        if len(self._cells):
            raise HippoNavError("saved view cells are restored into empty view cells only")
        for keypoints, descriptors in split_ragged(
            saved["count"], saved["keypoints_px"], saved["descriptors"]
        ):
            self._cells.add(np.asarray(keypoints, np.float64), np.ascontiguousarray(descriptors, np.uint8))

    def observe(
        self,
        view: WordView,
        candidates: ArrayLike | None = None,
        recent: ArrayLike | None = None,
    ) -> WordObservation:
        """Recognise a view among `candidates` (None: every cell); `recent` are the cells of the current
        passage (kept active with `keep_inliers`, tried after the older ones). A novel informative view
        becomes a new cell."""
        cfg = self.config
        if len(view) < cfg.min_features:
            return WordObservation("uninformative", None, 1.0, 0, 0.0, 0.0)
        bag = self._cells.bag(_pixels(view), view.descriptors)
        recent_ids = set() if recent is None else {int(c) for c in np.asarray(recent).reshape(-1)}
        n = len(self._cells)
        pool = (
            range(n) if candidates is None else sorted({int(c) for c in np.asarray(candidates).reshape(-1)})
        )
        old = [c for c in pool if c not in recent_ids]
        new = [c for c in pool if c in recent_ids]
        # Old cells first (a revisit), then the best recent one (the passage goes on).
        for ids, bar, top_k, is_recent in (
            (old, cfg.min_inliers, cfg.top_k, False),
            (new, cfg.keep_inliers, 1, True),
        ):
            if not ids:
                continue
            ranked = self._cells.query(bag, np.asarray(ids, np.int64), top_k)
            best: tuple[int, int, float, Any] | None = None
            for cell, score in ranked:
                inliers, geometry = self._verify(view, int(cell), bar)
                if inliers >= bar and (best is None or inliers > best[1]):
                    best = (int(cell), inliers, float(score), geometry)
            if best is not None:
                cell, inliers, score, geometry = best
                heading = self._heading(view, geometry)
                return WordObservation(
                    "familiar", cell, 1.0 - inliers / len(view), inliers, score, heading, is_recent
                )
        cell = int(self._cells.add(_pixels(view), view.descriptors, bag))
        return WordObservation("new", cell, 1.0, 0, 0.0, 0.0)

    def rank(
        self, view: WordView, candidates: ArrayLike | None = None, top_k: int | None = None
    ) -> list[tuple[int, float, int]]:
        """[(cell_id, bag-of-words score, verified inliers)] of the best-ranked cells among `candidates`
        (None: every cell), best score first, without storing anything: the evidence `observe` weighs."""
        if len(view) < self.config.min_features or len(self._cells) == 0:
            return []
        bag = self._cells.bag(_pixels(view), view.descriptors)
        ids = None if candidates is None else np.asarray(candidates, np.int64).reshape(-1)
        ranked = self._cells.query(bag, ids, self.config.top_k if top_k is None else top_k)
        return [(int(c), float(s), self._verify(view, int(c), 8)[0]) for c, s in ranked]

    def verify(self, view: WordView, cell_id: int) -> tuple[int, float]:
        """(inliers, relative heading in rad) of the view against a stored cell."""
        inliers, geometry = self._verify(view, int(cell_id), 8)
        return inliers, self._heading(view, geometry)

    def _verify(self, view: WordView, cell: int, bar: int) -> tuple[int, Any]:
        """Verified matches of the view with a stored cell, and what the heading needs (the fundamental
        matrix and the inlier points; None when not verified). Gives up as soon as `bar` is out of reach."""
        cfg = self.config
        stored_px, stored_desc = self._cells.features(cell)
        if len(stored_desc) < bar:
            return 0, None
        # OpenCV's knnMatch and the ratio test, in Rust: the same matches without a Python object per
        # candidate (those were most of the verification's time).
        query, train = hamming_ratio_matches(view.descriptors, stored_desc, cfg.ratio_test)
        if len(query) < max(bar, 8):
            return 0, None  # fewer matches than the bar: no geometry can verify it
        now = view.keypoints_px[query]
        then = stored_px[train]
        # USAC's 8-point RANSAC (PROSAC sampling, local optimisation) stops early on clear geometries; the
        # classic RANSAC ran its full budget on the many match sets that are mostly chance.
        try:
            F, mask = cv2.findFundamentalMat(then, now, cv2.USAC_FM_8PTS, cfg.ransac_px, 0.999, 1000)
        except cv2.error:  # a degenerate match set (e.g. every point on one line): no geometry
            return 0, None
        if F is None or mask is None or F.shape != (3, 3):
            return 0, None
        keep = mask.ravel() > 0
        return int(np.count_nonzero(keep)), (F, then[keep], now[keep])

    def _heading(self, view: WordView, geometry: Any) -> float:
        """Camera yaw now minus its yaw when the cell was stored (rad, counter-clockwise positive): the
        median change of the verified features' horizontal bearing, `atan((u_now − cx)/fx) −
        atan((u_then − cx)/fx)` (a left turn moves the scene right); 0 without a camera matrix.

        Like the template cells' shift, this takes the features to be far away: a sideways step of the
        camera adds parallax (near features move more). The epipolar geometry cannot do better here: a
        turn and a sideways step both move features along the image rows, so from one monocular pair the
        rotation is undetermined when the camera also stepped sideways (an essential matrix fitted to a
        rendered 8° turn with a 0.5 m step found no rotation at all). The closure measurement (stereo)
        gives the map its exact relative pose; this heading only turns the recalled head-direction code."""
        if self._camera_matrix is None or geometry is None:
            return 0.0
        _, then, now = geometry
        fx, cx = self._camera_matrix[0, 0] * view.scale, self._camera_matrix[0, 2] * view.scale
        bearing_now = np.arctan((now[:, 0].astype(np.float64) - cx) / fx)
        bearing_then = np.arctan((then[:, 0].astype(np.float64) - cx) / fx)
        return float(np.median(bearing_now - bearing_then))


def train_vocabulary(
    images: Iterable[np.ndarray],
    config: WordViewConfig | None = None,
    branching: int = 10,
    levels: int = 4,
    seed: int = 0,
) -> Vocabulary:
    """A vocabulary of `branching ** levels` words at most, trained on the ORB features of gray images
    described as `WordViewCells` would (same shrinking, same detector). Deterministic for the same images,
    settings and seed. `hippo-nav vocabulary` trains one on a folder of images, or remakes the shipped one."""
    # `describe_image` needs no vocabulary: a one-word stand-in avoids loading one.
    describer = WordViewCells(config, Vocabulary.train([np.zeros((1, 32), np.uint8)], 2, 1))
    sets = [describer.describe_image(image).descriptors for image in images]
    if not any(len(s) for s in sets):
        raise HippoNavError("no ORB features in the training images: give textured camera images")
    return Vocabulary.train(sets, branching, levels, seed)


def _pixels(view: WordView) -> np.ndarray:
    return np.asarray(view.keypoints_px, dtype=np.float64)
