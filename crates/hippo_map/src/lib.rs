//! Experience map (docs/spec.md §8): vertices, odometric links, loop closure and map correction.
//!
//! - [`Pose2`]: planar rigid transforms and angle wrapping (`se2`).
//! - [`PoseGraph`]: the pose graph, its g2o `EdgeSE2` cost `χ² = Σ eᵀΩe`, dead reckoning and ATE (`graph`).
//! - [`read_g2o`], [`write_g2o`]: reader and writer of g2o 2-D pose graphs (`g2o`).
//! - [`initialize_chordal`]: chordal initialisation (linear rotations, then linear translations) (`init`).
//! - [`optimize`]: exact correction, sparse Gauss–Newton with a Levenberg–Marquardt fallback on faer's
//!   Cholesky (ordering, symbolic factorisation and buffers set up once per solve), robust loss on loops
//!   (`solve`).
//! - [`relax`]: the paper's correction, RatSLAM-style iterative relaxation (`relax`).
//! - [`ExperienceMap`]: the experience map driven per camera frame (creation rule, loop closure,
//!   ambiguity) (`experience`); its loop gate grows with the shortest path through the links (`paths`).
//! - [`to_bytes`], [`from_bytes`], `ExperienceMap::save`/`load`: versioned, checksummed map files
//!   (`persist`), written whole or not at all and never through a link (`files`).
//! - Long solves take a stop hook ([`optimize_with_stop`], [`relax_with_stop`],
//!   [`ExperienceMap::correct_with_stop`]), and a graph whose factorisation would not fit in memory is
//!   refused before it is allocated ([`SolverParams::max_factor_bytes`], `memory`).
//!
//! The modules behind these are private; everything a caller needs is re-exported here.
#![warn(missing_docs)]
// Small fixed-size matrix code reads best with explicit row/column indices.
#![allow(clippy::needless_range_loop)]
mod error;
mod experience;
mod files;
mod g2o;
mod graph;
mod init;
mod memory;
mod paths;
mod persist;
mod relax;
mod se2;
mod solve;
mod sparse;

pub use error::{MapError, Result};
pub use experience::{
    AmbiguityPolicy, ClosureMode, ClosureRejection, CorrectionReport, Corrector, ExperienceMap,
    FrameInput, FrameOutcome, Link, LoopCandidate, LoopMeasurement, MapParams, OnlineCorrection,
    Vertex,
};
pub use g2o::{format_g2o, parse_g2o, read_g2o, write_g2o};
pub use graph::{ate_rmse_m, isotropic_information, Edge, EdgeKind, PoseGraph};
pub use init::initialize_chordal;
pub use persist::{from_bytes, to_bytes, FORMAT_VERSION, MAGIC};
pub use relax::{relax, relax_with_stop, RelaxationParams, RelaxationReport};
pub use se2::{wrap_angle, Pose2};
pub use solve::{
    optimize, optimize_with_stop, Initialization, RobustLoss, SolveReport, SolverParams,
    Termination,
};
