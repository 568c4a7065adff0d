"""The paper's view descriptor (docs/spec.md §7): whole-image templates (OpenCV), matching in Rust (`hippo_views`).

A template is the left image cropped to the rows `crop_rows_frac` (dropping sky and bonnet), shrunk to
`height_px × width_px` with area averaging (`cv2.INTER_AREA`), then patch-normalised: each pixel minus the
mean of its `patch_size_px` square neighbourhood, divided by that neighbourhood's standard deviation (plus a
noise floor of 5 grey levels so flat or dark regions stay near zero instead of amplifying sensor noise:
a dark frame of pure noise at σ = 2 grey levels then scores a texture of 0.08, under `min_texture`, while a
KITTI frame scores ≈ 0.6 and the same frame at 1/12 of its brightness 0.27). This
removes exposure and large-scale illumination changes. Matching uses the normalised difference of
`hippo_views::compare` (0 identical, ≈0.7 unrelated, ≤ 1), so one `novelty_threshold` serves every dataset.

`observe` and `best_match` take `candidates`, a set of cell ids to match against instead of every cell (e.g.
the cells stored near the current place estimate): the answer is exactly the exhaustive one over that
subset, at a cost that does not grow with the store.

Relative heading: a positive `shift_px` (scene moved right) means the camera has turned counter-clockwise
since the cell was stored, by `shift_px · field_of_view_rad / width_px`.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import cv2
import numpy as np
from numpy.typing import ArrayLike
from pydantic import ConfigDict, Field, model_validator

from hippo_nav import _core
from hippo_nav._core import HippoNavError, ViewObservation
from hippo_nav._defaults import ConfigSection, rust_default
from hippo_nav.datasets.base import StereoCalibration, StereoFrame

__all__ = ["TemplateViewCells", "TemplateViewConfig", "field_of_view_rad"]


def _default(name: str) -> Any:
    # The Rust defaults are the single source; this model only names and types them.
    return rust_default("views", name)


# Noise floor of the patch standard deviation, in 8-bit grey levels.
_NOISE_FLOOR_GREY = 5.0

MAX_TEMPLATE_VALUES = 1 << 16
"""Values of a template at most (`width_px · height_px`; every view cell stores one), as in the Rust cells
(`hippo_views::MAX_TEMPLATE_VALUES`): 256 kB a cell."""


class TemplateViewConfig(ConfigSection):
    """View-cell parameters (see `crates/hippo_views/src/params.rs` for their meaning; the same checks are
    made there)."""

    model_config = ConfigDict(frozen=True)

    width_px: int = Field(_default("width_px"), ge=4, le=4096, description="template columns")
    height_px: int = Field(_default("height_px"), ge=1, le=4096, description="template rows")
    crop_rows_frac: tuple[float, float] = Field(
        (_default("crop_rows_frac")[0], _default("crop_rows_frac")[1]),
        description="image rows kept (top, bottom), fractions of the height: 0 ≤ top < bottom ≤ 1",
    )
    patch_size_px: int = Field(
        _default("patch_size_px"), ge=3, le=255, description="patch-normalisation side (odd)"
    )
    max_shift_px: int = Field(
        _default("max_shift_px"), ge=0, le=2048, description="shift search ±columns (under half the width)"
    )
    novelty_threshold: float = Field(
        _default("novelty_threshold"), gt=0.0, lt=1.0, description="difference below which a view is familiar"
    )
    field_of_view_rad: float = Field(_default("field_of_view_rad"), gt=0.0, lt=2 * math.pi)
    min_texture: float = Field(_default("min_texture"), ge=0.0)
    coarse_rows: int = Field(_default("coarse_rows"), ge=1, le=4096)

    @model_validator(mode="after")
    def _consistent(self) -> TemplateViewConfig:
        if self.width_px * self.height_px > MAX_TEMPLATE_VALUES:
            raise ValueError(
                f"width_px · height_px = {self.width_px} · {self.height_px}: a template (stored for every "
                f"view cell) may have {MAX_TEMPLATE_VALUES} values at most"
            )
        if 2 * self.max_shift_px >= self.width_px:
            raise ValueError(
                f"max_shift_px = {self.max_shift_px} must be under half the template width ({self.width_px}) "
                "so shifted templates still overlap"
            )
        top, bottom = self.crop_rows_frac
        if not (0.0 <= top < bottom <= 1.0):
            raise ValueError(
                f"crop_rows_frac = ({top}, {bottom}): need 0 ≤ top < bottom ≤ 1 (fractions of the image height)"
            )
        if self.patch_size_px % 2 == 0:
            raise ValueError(f"patch_size_px = {self.patch_size_px} must be odd")
        return self


def field_of_view_rad(fx_px: float, image_width_px: int) -> float:
    """Horizontal field of view of a pinhole camera, for `TemplateViewConfig.field_of_view_rad`."""
    if not (fx_px > 0 and image_width_px > 0):
        raise HippoNavError(f"need fx_px > 0 and image_width_px > 0, got {fx_px} and {image_width_px}")
    return 2.0 * math.atan(image_width_px / (2.0 * fx_px))


class TemplateViewCells:
    """Local view cells of whole-image templates, a `hippo_nav.view_cells.ViewDescriptor`:
    `template_from_image` (or `describe`) then `observe` each frame."""

    describe_on_worker: ClassVar[bool] = False
    """The template (≈ 0.1 ms a frame) is made on the back end, beside the match."""

    def __init__(self, config: TemplateViewConfig | None = None) -> None:
        self.config = config or TemplateViewConfig()
        self._cells = _core._ViewCells(self.config.model_dump_json())

    @classmethod
    def for_camera(cls, config: TemplateViewConfig, calibration: StereoCalibration) -> TemplateViewCells:
        """View cells for one camera: unless `config` sets `field_of_view_rad`, it is the camera's (from
        `calibration`), so that template shifts convert to the right relative heading on any camera."""
        if "field_of_view_rad" not in config.model_fields_set:
            fov = field_of_view_rad(calibration.fx, calibration.image_size_px[0])
            config = config.model_copy(update={"field_of_view_rad": fov})
        return cls(config)

    def __len__(self) -> int:
        return len(self._cells)

    def describe(self, frame: StereoFrame) -> np.ndarray:
        """The template of the frame's left image."""
        return self.template_from_image(frame.left)

    def image_rows(self, height_px: int) -> tuple[int, int]:
        """The rows the template is cut from (`crop_rows_frac` of an image `height_px` high)."""
        top, bottom = (round(float(f) * height_px) for f in self.config.crop_rows_frac)
        return top, bottom

    def template_from_image(self, gray: np.ndarray) -> np.ndarray:
        """(height_px, width_px) float32 template of a gray image (any layout, uint8 or float in 0–255)."""
        image = np.asarray(gray)
        if image.ndim != 2:
            raise HippoNavError(
                f"expected a gray image of shape (H, W), got shape {image.shape}; convert colour images "
                "with cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)"
            )
        if not (np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)):
            raise HippoNavError(f"image dtype {image.dtype} is not numeric")
        if np.issubdtype(image.dtype, np.floating) and image.size and 0 < np.nanmax(image) <= 1.0:
            raise HippoNavError(
                "float image with values in [0, 1]: templates expect grey levels 0–255; multiply by 255"
            )
        cfg = self.config
        top = round(cfg.crop_rows_frac[0] * image.shape[0])
        bottom = round(cfg.crop_rows_frac[1] * image.shape[0])
        if bottom - top < cfg.height_px or image.shape[1] < cfg.width_px:
            raise HippoNavError(
                f"image of shape {image.shape} is too small for a {cfg.height_px}×{cfg.width_px} template "
                f"after cropping rows {cfg.crop_rows_frac}"
            )
        crop = np.ascontiguousarray(image[top:bottom], dtype=np.float32)
        if not np.isfinite(crop).all():
            raise HippoNavError("image contains NaN or infinite values")
        small = cv2.resize(crop, (cfg.width_px, cfg.height_px), interpolation=cv2.INTER_AREA)
        k = (cfg.patch_size_px, cfg.patch_size_px)
        mean = cv2.blur(small, k, borderType=cv2.BORDER_REFLECT)
        mean_sq = cv2.blur(small * small, k, borderType=cv2.BORDER_REFLECT)
        std = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0) + _NOISE_FLOOR_GREY**2)
        return ((small - mean) / std).astype(np.float32)

    def observe(
        self,
        template: np.ndarray,
        candidates: ArrayLike | None = None,
        recent: ArrayLike | None = None,
    ) -> ViewObservation:
        """Match a template; a novel one becomes a new cell (status 'new'), a blank one is 'uninformative'.

        `candidates` restricts the match to those cell ids (e.g. the cells stored near the current place
        estimate): the view is familiar only if one of them is below the novelty threshold, otherwise it
        becomes a new cell. None matches against every cell. Duplicates are fine; an unknown id raises.
        `recent` is accepted for the protocol and unused: the paper's template cells treat every cell alike.
        """
        return self._cells.observe(_as_float(template), _as_ids(candidates))

    def best_match(
        self, template: np.ndarray, candidates: ArrayLike | None = None
    ) -> tuple[int, float, int] | None:
        """(cell_id, difference, shift_px) of the closest stored cell (among `candidates` if given: None =
        every cell), without storing anything; None when there is nothing to match."""
        return self._cells.best_match(_as_float(template), _as_ids(candidates))

    def differences(self, template: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Difference and best shift against every cell, in id order."""
        return self._cells.differences(_as_float(template))

    def add(self, template: np.ndarray) -> int:
        """Store a template as a new cell without matching (e.g. to restore saved cells)."""
        return self._cells.add(_as_float(template))

    def templates(self) -> np.ndarray:
        """Every stored template, shape (len, height_px, width_px)."""
        return self._cells.templates()

    # Persistent (docs/memory.md): the templates, and the settings that shape them.
    def depends_on(self) -> dict[str, object]:
        cfg = self.config
        return {
            "width_px": cfg.width_px,
            "height_px": cfg.height_px,
            "crop_rows_frac": list(cfg.crop_rows_frac),
            "patch_size_px": cfg.patch_size_px,
        }

    def export_state(self) -> dict[str, np.ndarray]:
        """Every cell's template, for a memory folder."""
        return {"templates": np.asarray(self.templates(), np.float32)}

    def restore_state(self, saved: dict[str, np.ndarray]) -> None:
        """Store the templates of `export_state` (into an empty set of cells), with the same ids."""
        if len(self._cells):
            raise HippoNavError("saved view cells are restored into empty view cells only")
        for template in np.asarray(saved["templates"], np.float32):
            self.add(template)


def _as_ids(candidates: ArrayLike | None) -> np.ndarray | None:
    """Candidate cell ids as a 1-D int64 array (any integer sequence or array; None passes through)."""
    if candidates is None:
        return None
    ids = np.asarray(candidates)
    if ids.ndim != 1:
        raise HippoNavError(f"candidates must be a 1-D sequence of cell ids, got shape {ids.shape}")
    if ids.size == 0:
        return np.empty(0, np.int64)
    if not np.issubdtype(ids.dtype, np.integer):
        raise HippoNavError(f"candidate cell ids must be integers, got dtype {ids.dtype}")
    if ids.dtype == np.uint64 and ids.max() > np.iinfo(np.int64).max:
        raise HippoNavError(f"candidate cell id {int(ids.max())} does not exist")
    return ids.astype(np.int64, copy=False)


def _as_float(template: np.ndarray) -> np.ndarray:
    t = np.asarray(template)
    if t.dtype not in (np.float32, np.float64):
        if not np.issubdtype(t.dtype, np.number):
            raise HippoNavError(f"template dtype {t.dtype} is not numeric")
        t = t.astype(np.float32)
    return t
