//! Errors of the windowed refinement. Every message says what is wrong and what to do.
use thiserror::Error;

/// Everything that can go wrong giving the window a camera, a keyframe or its parameters.
#[derive(Debug, Error)]
pub enum VoError {
    /// A parameter outside its range (the shape every core crate uses for parameter errors).
    #[error("invalid parameter `{name}` = {value}: {why}")]
    BadParameter {
        /// The parameter, as the config names it.
        name: &'static str,
        /// Its value as given.
        value: String,
        /// What it must be.
        why: String,
    },
    /// A non-finite pose or pixel.
    #[error("{what} must be finite, got {value}; check the tracker's output")]
    NonFinite {
        /// What was not finite.
        what: &'static str,
        /// Its value.
        value: f64,
    },
    /// A pose whose rotation is not a rotation.
    #[error("the keyframe pose's rotation is not orthonormal (|RᵀR − I| = {deviation:.2e}); pass a rigid transform")]
    NotRigid {
        /// Largest entry of RᵀR − I.
        deviation: f64,
    },
    /// One landmark observed twice in one keyframe.
    #[error(
        "landmark {landmark} is observed twice in one keyframe; give each tracked point one id"
    )]
    DuplicateLandmark {
        /// The landmark id.
        landmark: u64,
    },
}

/// Result of the windowed refinement.
pub type Result<T> = std::result::Result<T, VoError>;
