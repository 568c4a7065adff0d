//! Local view cells (docs/spec.md §7): template comparison with a horizontal shift search.
//!
//! A template is a small, patch-normalised, row-major `height × width` image (made by the Python side with
//! OpenCV). [`ViewCells::observe`] compares it with every stored template using the normalised mean
//! absolute difference of [`compare`](crate::compare) (0 identical … ≈0.71 unrelated … 1), minimised over
//! horizontal shifts `±max_shift_px`. Below `novelty_threshold` the view is familiar and the match gives the
//! cell id, the difference and the relative heading `shift · field_of_view / width` (counter-clockwise
//! positive, i.e. positive when the camera has turned left since the cell was stored); otherwise a new cell
//! stores the template. Templates with almost no texture are reported as uninformative and never stored.
//!
//! The search is exact but pruned: a cheap whole-column key picks the likely matches to compare first, then
//! every other template is skipped when its coarse lower bound exceeds the best difference found (shared
//! between threads) and otherwise compared exactly with early exit; a novel query, which prunes nothing,
//! costs about the same as the plain search.
//! [`ViewCells::best_match_brute_force`] is the plain reference it is tested against.
//! [`ViewCells::observe_among`] and [`ViewCells::best_match_among`] run the same search over a given subset
//! of cells (e.g. those stored near the current place estimate), so that a long run's per-frame cost is set
//! by the subset, not by the store.
#![warn(missing_docs)]
mod cells;
pub mod compare;
mod error;
mod params;
pub mod words;

pub use cells::{ViewCells, ViewMatch, ViewObservation, ViewStatus};
pub use error::ViewError;
pub use params::{ViewCellParams, MAX_TEMPLATE_VALUES};
