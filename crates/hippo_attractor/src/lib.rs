//! The neural engine of hippo_nav: continuous attractor networks of the entorhinal–hippocampal
//! model of Zeng, Li & Si ("Bayesian Integration of Multi-resolutional Grid Codes for Spatial
//! Cognition"), as stated, with its departures from the paper, in `docs/spec.md`.
//!
//! - [`HdRing`]: head-direction-by-velocity ring (docs/spec.md §2), exact rank-2 recurrent input.
//! - [`GridModule`]: grid-by-velocity tori with k = 1, 2, 4 bumps per axis (docs/spec.md §3),
//!   per-slice FFTs.
//! - [`PlaceNetwork`]: CA3 place torus (docs/spec.md §5).
//! - [`find_bumps`], [`fuse_homocentric`]: bump decoding and Bayesian fusion (docs/spec.md §4).
//! - [`SpatialMemory`]: the whole network stepped per camera frame, with lesions and view injection.
//! - [`tau_effective`]: the integrator's effective time constant (implicit global inhibition, exact leak).
//! - [`reference`]: dense-weight reference implementations, for tests and benchmarks only.
//!
//! The modules behind these are private; everything a caller needs is re-exported here.
#![warn(missing_docs)]
mod check;
mod circular;
mod decode;
mod dynamics;
mod error;
mod fft2;
mod fusion;
mod grid;
mod hd;
mod lanes;
mod place;
mod real;
pub mod reference;
mod spatial_memory;

pub use circular::wrap as wrap_angle;
pub use decode::find_bumps;
pub use dynamics::tau_effective;
pub use error::{AttractorError, Result};
pub use fusion::{fuse_bumps, fuse_homocentric, Bump2, FusedEstimate};
pub use grid::{GridModule, GridParams};
pub use hd::{HdParams, HdReadout, HdRing};
pub use place::{PlaceNetwork, PlaceParams};
pub use real::Real;
pub use spatial_memory::{
    AuxState, ModuleReadout, SpatialMemory, SpatialMemoryParams, SpatialReadout, ViewInjection,
    WarmStarts, N_MODULES,
};
