//! Errors of the experience map and its correctors. Every message says what is wrong and what to do.
use thiserror::Error;

/// Everything that can go wrong building, correcting, saving or reading a map or pose graph.
#[derive(Debug, Error)]
pub enum MapError {
    /// A link or edge to a vertex that is not there.
    #[error("vertex {vertex} does not exist (the map holds {len} vertices); add it before linking to it")]
    UnknownVertex {
        /// The missing vertex.
        vertex: usize,
        /// How many vertices there are.
        len: usize,
    },
    /// A link from a vertex to itself.
    #[error("a link must join two different vertices, got {vertex} -> {vertex}; drop self-links")]
    SelfLink {
        /// The vertex.
        vertex: usize,
    },
    /// A non-finite pose, code or measurement.
    #[error("{what} must be finite, got {value}; check the upstream odometry or codes")]
    NonFinite {
        /// What was not finite.
        what: &'static str,
        /// Its value.
        value: f64,
    },
    /// A finite pose whose position lies beyond any map ([`crate::graph::MAX_COORDINATE_M`]).
    #[error("{what} lies {value:e} m away, beyond any map (at most {limit:e} m); check the units and the upstream odometry")]
    TooFar {
        /// What was too far.
        what: &'static str,
        /// The coordinate.
        value: f64,
        /// The bound.
        limit: f64,
    },
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
    /// An information matrix that is not symmetric positive definite.
    #[error("information matrix of edge {edge} is not symmetric positive definite; check the file or the noise model")]
    BadInformation {
        /// The edge (or link) it belongs to.
        edge: usize,
    },
    /// A graph without vertices.
    #[error("the pose graph is empty; add at least one vertex")]
    EmptyGraph,
    /// A correction asked for while a session's part of the map is not joined to the rest.
    #[error("vertices {first} and later belong to a session that has not yet recognised a place of the map it started in; nothing joins them to the earlier vertices, so the map cannot be corrected as a whole until a closure joins them")]
    Unjoined {
        /// The session's first vertex.
        first: usize,
    },
    /// A vertex no chain of edges joins to the fixed one.
    #[error("vertex {vertex} is not connected to the fixed vertex by any chain of edges; every vertex needs a path to it (add odometry links)")]
    Disconnected {
        /// The first such vertex.
        vertex: usize,
    },
    /// The sparse Cholesky factorisation failed.
    #[error("sparse Cholesky failed ({detail}); the system is singular: the graph probably has a vertex constrained in too few directions")]
    Factorization {
        /// faer's message.
        detail: String,
    },
    /// A sparse factorisation that would not fit in memory (checked before it is allocated).
    #[error(
        "correcting this pose graph would need {needed_bytes} bytes ({}) for its sparse Cholesky factors, \
         more than {limit}: {limit_bytes} bytes ({}). Loop closures between far-apart vertices fill the \
         factor in: use fewer (or more local) loop closures, correct with relaxation instead \
         (PoseGraph.relax, or correct with method=\"relaxation\"), or run with more memory \
         (max_factor_bytes sets the limit)",
        gib(*.needed_bytes),
        gib(*.limit_bytes)
    )]
    FactorTooLarge {
        /// Bytes the factor(s) and their workspace would take.
        needed_bytes: u64,
        /// Bytes allowed.
        limit_bytes: u64,
        /// Where the limit comes from.
        limit: &'static str,
    },
    /// A g2o line that cannot be read.
    #[error("g2o line {line}: {message}")]
    G2oParse {
        /// The line number (from 1).
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    /// A file that cannot be read or written.
    #[error("cannot read or write {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// A map file that is not one, or is damaged.
    #[error("not a hippo_nav map file: {0}")]
    Format(String),
}

/// The result of everything that can fail in this crate.
pub type Result<T> = std::result::Result<T, MapError>;

/// Bytes in GiB with one decimal, for messages.
fn gib(bytes: u64) -> String {
    format!("{:.1} GiB", bytes as f64 / f64::from(1u32 << 30))
}
