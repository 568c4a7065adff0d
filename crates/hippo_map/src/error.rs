//! Errors of the experience map and its correctors. Every message says what is wrong and what to do.
use thiserror::Error;

#[derive(Debug, Error)]
pub enum MapError {
    #[error("vertex {vertex} does not exist (the map holds {len} vertices); add it before linking to it")]
    UnknownVertex { vertex: usize, len: usize },
    #[error("a link must join two different vertices, got {vertex} -> {vertex}; drop self-links")]
    SelfLink { vertex: usize },
    #[error("{what} must be finite, got {value}; check the upstream odometry or codes")]
    NonFinite { what: &'static str, value: f64 },
    #[error("{what} must be {requirement}, got {value}")]
    InvalidParameter {
        what: &'static str,
        requirement: &'static str,
        value: f64,
    },
    #[error("information matrix of edge {edge} is not symmetric positive definite; check the file or the noise model")]
    BadInformation { edge: usize },
    #[error("the pose graph is empty; add at least one vertex")]
    EmptyGraph,
    #[error("vertex {vertex} is not connected to the fixed vertex by any chain of edges; every vertex needs a path to it (add odometry links)")]
    Disconnected { vertex: usize },
    #[error("sparse Cholesky failed ({detail}); the system is singular: the graph probably has a vertex constrained in too few directions")]
    Factorization { detail: String },
    #[error("g2o line {line}: {message}")]
    G2oParse { line: usize, message: String },
    #[error("cannot read or write {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("not a hippo_nav map file: {0}")]
    Format(String),
}

pub type Result<T> = std::result::Result<T, MapError>;
