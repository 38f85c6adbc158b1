//! The one error type of softcap_design.

use std::path::PathBuf;

/// Errors of the design stage: bad input (named by file / field) or a failed numerical step.
#[derive(Debug, thiserror::Error)]
pub enum DesignError {
    /// A FEM error (invalid mesh, parameters, factorization).
    #[error("FEM: {0}")]
    Fem(#[from] softcap_fem::FemError),
    /// A core numerical error (RBF, LM, k-means input).
    #[error("numerics: {0}")]
    Core(#[from] softcap_core::CoreError),
    /// A simulation did not converge (reported, never a panic).
    #[error("simulation of {what} did not converge: {status}")]
    NotConverged {
        /// what was simulated
        what: String,
        /// solver status
        status: String,
    },
    /// Invalid setting or argument.
    #[error("invalid {field}: {reason}")]
    Invalid {
        /// setting / field name
        field: &'static str,
        /// why
        reason: String,
    },
    /// A file could not be read or parsed.
    #[error("{path}: {reason}")]
    File {
        /// the file
        path: PathBuf,
        /// what is wrong (line / field when known)
        reason: String,
    },
    /// I/O error on a named file.
    #[error("{path}: {source}")]
    Io {
        /// the file
        path: PathBuf,
        /// cause
        source: std::io::Error,
    },
}

/// Result alias.
pub type Result<T, E = DesignError> = std::result::Result<T, E>;
