use thiserror::Error;

/// Everything that can go wrong when building or driving the networks. Messages say what to fix.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum AttractorError {
    /// A parameter outside its range (the shape every core crate uses for parameter errors).
    #[error("invalid parameter `{name}` = {value}: {why}")]
    BadParameter {
        /// The parameter, as the config names it (`hd.n_theta`, `grid[2].k`).
        name: String,
        /// Its value as given.
        value: String,
        /// What it must be.
        why: String,
    },
    /// An array of the wrong length for the network it belongs to.
    #[error("array `{name}` has {got} elements, expected {expected} ({shape})")]
    BadShape {
        /// The array.
        name: &'static str,
        /// Its length.
        got: usize,
        /// The length the network needs.
        expected: usize,
        /// The network's shape, for the message.
        shape: String,
    },
    /// A non-finite per-frame input (a velocity, a time step).
    #[error("input `{name}` is not finite ({value}); check the odometry feeding the network")]
    NonFinite {
        /// The input.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// A per-frame input the network cannot represent (beyond its velocity axes, a negative time).
    #[error("input `{name}` = {value} is outside the range the network can represent ({why})")]
    OutOfRange {
        /// The input.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The range it must lie in.
        why: String,
    },
    /// An array holding a NaN or an infinity.
    #[error("array `{name}` contains a NaN or infinite value at index {index}")]
    NonFiniteArray {
        /// The array.
        name: &'static str,
        /// The first bad element.
        index: usize,
    },
    /// Bayesian fusion without any bump to fuse.
    #[error("no bump to fuse: every grid module is lesioned or silent")]
    NothingToFuse,
    /// A bump given to the fusion that is not one (a non-positive width, a non-finite centre).
    #[error("bad bump: {0}")]
    BadBump(String),
    /// The integration blew up.
    #[error(
        "the network state diverged (non-finite activity); reduce `max_substep_s` or the gains"
    )]
    Diverged,
}

impl AttractorError {
    /// The error of grid module `index`'s own check, naming the module: `grid.k` becomes `grid[2].k`.
    pub fn in_module(self, index: usize) -> Self {
        match self {
            AttractorError::BadParameter { name, value, why } => AttractorError::BadParameter {
                name: match name.strip_prefix("grid.") {
                    Some(field) => format!("grid[{index}].{field}"),
                    None => name,
                },
                value,
                why,
            },
            other => other,
        }
    }
}

/// The result of everything that can fail in this crate.
pub type Result<T> = std::result::Result<T, AttractorError>;
