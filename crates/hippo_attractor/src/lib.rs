//! The neural engine of hippo_nav: continuous attractor networks of the entorhinal–hippocampal
//! model of Zeng, Li & Si ("Bayesian Integration of Multi-resolutional Grid Codes for Spatial
//! Cognition"), as stated, with its departures from the paper, in `docs/spec.md`.
//!
//! - [`hd`]: head-direction-by-velocity ring (docs/spec.md §2), exact rank-2 recurrent input.
//! - [`grid`]: grid-by-velocity tori with k = 1, 2, 4 bumps per axis (docs/spec.md §3),
//!   per-slice FFTs.
//! - [`place`]: CA3 place torus (docs/spec.md §5).
//! - [`decode`], [`fusion`]: bump decoding and Bayesian fusion (docs/spec.md §4).
//! - [`spatial_memory`]: the whole network stepped per camera frame, with lesions and view injection.
//! - [`dynamics`]: the integrator (implicit global inhibition, exact leak).
//! - [`reference`]: dense-weight reference implementations, for tests and benchmarks only.
pub mod check;
pub mod circular;
pub mod decode;
pub mod dynamics;
pub mod error;
pub mod fft2;
pub mod fusion;
pub mod grid;
pub mod hd;
pub mod lanes;
pub mod place;
pub mod real;
pub mod reference;
pub mod spatial_memory;

pub use error::{AttractorError, Result};
pub use fusion::{fuse_bumps, fuse_homocentric, Bump2, FusedEstimate};
pub use grid::{GridModule, GridParams};
pub use hd::{HdParams, HdReadout, HdRing};
pub use place::{PlaceNetwork, PlaceParams};
pub use real::Real;
pub use spatial_memory::{
    AuxState, ModuleReadout, SpatialMemory, SpatialMemoryParams, SpatialReadout, ViewInjection,
    N_MODULES,
};
