//! The neural engine of hippo_nav: continuous attractor networks of the entorhinal–hippocampal model of
//! Zeng, Li & Si ("Bayesian Integration of Multi-resolutional Grid Codes for Spatial Cognition"), as fixed
//! by `SPEC.md`.
//!
//! - [`fusion`]: Bayesian (precision-weighted) fusion of the grid modules' bumps (SPEC §4).
pub mod circular;
pub mod error;
pub mod fusion;

pub use error::{AttractorError, Result};
pub use fusion::{fuse_bumps, fuse_homocentric, Bump2, FusedEstimate};
