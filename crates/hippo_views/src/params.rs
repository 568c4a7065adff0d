//! View-cell parameters: the single source of defaults (Python reads them as JSON).
use crate::error::ViewError;
use serde::{Deserialize, Serialize};

/// How templates are made and compared.
///
/// The crop and patch fields are applied by the Python template extractor (OpenCV); they live here so that
/// one struct holds every default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewCellParams {
    /// Template width after downsampling (columns).
    pub width_px: usize,
    /// Template height after downsampling (rows).
    pub height_px: usize,
    /// Image rows kept before downsampling, as fractions of the height (top, bottom): drops sky and bonnet.
    pub crop_rows_frac: (f64, f64),
    /// Side of the square neighbourhood (template pixels, odd) used by patch normalisation.
    pub patch_size_px: usize,
    /// Horizontal shift search range ±max_shift_px (template columns).
    pub max_shift_px: usize,
    /// Normalised difference (0 identical, ~0.7 unrelated, ≤ 1) below which a view is familiar.
    pub novelty_threshold: f32,
    /// Horizontal field of view covered by the template (radians); converts shift to heading.
    pub field_of_view_rad: f64,
    /// Mean |value| below which a patch-normalised template carries no texture and is not matched. Real
    /// views score 0.3–0.7 (a KITTI frame at 1/12 of its brightness 0.27); a dark frame of sensor noise
    /// (σ = 2 grey levels) about 0.08 with the Python templates' 5-grey-level noise floor.
    pub min_texture: f32,
    /// Rows pooled per block in the coarse lower-bound prefilter (1 = exact full comparison as bound).
    pub coarse_rows: usize,
}

/// Values of a template at most (`width_px · height_px`): every view cell stores one, 256 kB at this size.
pub const MAX_TEMPLATE_VALUES: usize = 1 << 16;

impl Default for ViewCellParams {
    fn default() -> Self {
        Self {
            width_px: 64,
            height_px: 24,
            crop_rows_frac: (0.1, 0.7),
            patch_size_px: 5,
            max_shift_px: 8,
            novelty_threshold: 0.45,
            // KITTI's left camera: 2·atan(620.5 / 718.856).
            field_of_view_rad: 1.4275,
            min_texture: 0.1,
            coarse_rows: 4,
        }
    }
}

fn bad(name: &'static str, value: impl std::fmt::Display, why: &str) -> ViewError {
    ViewError::BadParameter {
        name,
        value: value.to_string(),
        why: why.to_string(),
    }
}

impl ViewCellParams {
    /// Check every field; called by `ViewCells::new`.
    pub fn validate(&self) -> Result<(), ViewError> {
        if !(4..=4096).contains(&self.width_px) {
            return Err(bad(
                "width_px",
                self.width_px,
                "use 4 to 4096 columns (e.g. 64)",
            ));
        }
        if !(1..=4096).contains(&self.height_px) {
            return Err(bad(
                "height_px",
                self.height_px,
                "use 1 to 4096 rows (e.g. 24)",
            ));
        }
        if self.template_len() > MAX_TEMPLATE_VALUES {
            return Err(bad(
                "width_px",
                format!("{} (× height_px {})", self.width_px, self.height_px),
                &format!(
                    "a template (stored for every view cell) may have {MAX_TEMPLATE_VALUES} values at most"
                ),
            ));
        }
        if 2 * self.max_shift_px >= self.width_px {
            return Err(bad(
                "max_shift_px",
                self.max_shift_px,
                "must be under half the template width so shifted templates still overlap",
            ));
        }
        let (top, bottom) = self.crop_rows_frac;
        if !((0.0..1.0).contains(&top) && top < bottom && bottom <= 1.0) {
            return Err(bad(
                "crop_rows_frac",
                format!("({top}, {bottom})"),
                "need 0 ≤ top < bottom ≤ 1 (fractions of the image height)",
            ));
        }
        if self.patch_size_px.is_multiple_of(2) || !(3..=255).contains(&self.patch_size_px) {
            return Err(bad(
                "patch_size_px",
                self.patch_size_px,
                "must be odd and from 3 to 255",
            ));
        }
        if !(self.novelty_threshold > 0.0 && self.novelty_threshold < 1.0) {
            return Err(bad(
                "novelty_threshold",
                self.novelty_threshold,
                "the normalised difference lies in [0, 1]; pick a threshold inside (0, 1)",
            ));
        }
        if !(self.field_of_view_rad > 0.0 && self.field_of_view_rad < std::f64::consts::TAU) {
            return Err(bad(
                "field_of_view_rad",
                self.field_of_view_rad,
                "must lie in (0, 2π)",
            ));
        }
        if !(self.min_texture >= 0.0 && self.min_texture.is_finite()) {
            return Err(bad(
                "min_texture",
                self.min_texture,
                "must be finite and ≥ 0",
            ));
        }
        if !(1..=4096).contains(&self.coarse_rows) {
            return Err(bad("coarse_rows", self.coarse_rows, "use 1 to 4096 rows"));
        }
        Ok(())
    }

    /// Values per template.
    pub fn template_len(&self) -> usize {
        self.width_px * self.height_px
    }

    /// Heading change per template column (radians); positive shift = camera turned counter-clockwise.
    pub fn heading_rad_per_px(&self) -> f64 {
        self.field_of_view_rad / self.width_px as f64
    }
}
