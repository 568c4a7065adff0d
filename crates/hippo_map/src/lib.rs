//! Experience map (docs/spec.md §8): vertices, odometric links, loop closure and map correction.
//!
//! - [`se2`]: planar rigid transforms and angle wrapping.
//! - [`graph`]: the pose graph, its g2o `EdgeSE2` cost `χ² = Σ eᵀΩe`, dead reckoning and ATE.
//! - [`g2o`]: reader and writer of g2o 2-D pose graphs.
//! - [`init`]: chordal initialisation (linear rotations, then linear translations).
//! - [`solve`]: exact correction, sparse Gauss–Newton with a Levenberg–Marquardt fallback on faer's
//!   Cholesky (ordering, symbolic factorisation and buffers set up once per solve), robust loss on loops.
//! - [`relax`]: the paper's correction, RatSLAM-style iterative relaxation.
//! - [`experience`]: the experience map driven per camera frame (creation rule, loop closure, ambiguity).
//! - [`persist`]: versioned, checksummed map files.
// Small fixed-size matrix code reads best with explicit row/column indices.
#![allow(clippy::needless_range_loop)]
pub mod error;
pub mod experience;
pub mod g2o;
pub mod graph;
pub mod init;
pub mod persist;
pub mod relax;
pub mod se2;
pub mod solve;
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
pub use relax::{relax, RelaxationParams, RelaxationReport};
pub use se2::{wrap_angle, Pose2};
pub use solve::{optimize, Initialization, RobustLoss, SolveReport, SolverParams, Termination};
