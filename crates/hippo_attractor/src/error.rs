use thiserror::Error;

/// Everything that can go wrong when building or driving the networks. Messages say what to fix.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum AttractorError {
    #[error("invalid parameter `{name}` = {value}: {why}")]
    BadParameter {
        name: &'static str,
        value: String,
        why: String,
    },
    #[error("array `{name}` has {got} elements, expected {expected} ({shape})")]
    BadShape {
        name: &'static str,
        got: usize,
        expected: usize,
        shape: String,
    },
    #[error("input `{name}` is not finite ({value}); check the odometry feeding the network")]
    NonFinite { name: &'static str, value: f64 },
    #[error("input `{name}` = {value} is outside the range the network can represent ({why})")]
    OutOfRange {
        name: &'static str,
        value: f64,
        why: String,
    },
    #[error("array `{name}` contains a NaN or infinite value at index {index}")]
    NonFiniteArray { name: &'static str, index: usize },
    #[error("no bump to fuse: every grid module is lesioned or silent")]
    NothingToFuse,
    #[error("bad bump: {0}")]
    BadBump(String),
    #[error(
        "the network state diverged (non-finite activity); reduce `max_substep_s` or the gains"
    )]
    Diverged,
}

pub type Result<T> = std::result::Result<T, AttractorError>;
