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
    /// An output (figure, print file) could not be produced.
    #[error("{path}: {reason}")]
    Output {
        /// the output
        path: PathBuf,
        /// what failed
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

/// Malformed input files, bad arguments and paths the OS refuses are the user's input at fault;
/// FEM, numerics, non-convergence and failed outputs are failures while running.
impl softcap_app::Classify for DesignError {
    fn class(&self) -> softcap_app::ErrorClass {
        use softcap_app::ErrorClass::{BadInput, Failure};
        match self {
            DesignError::File { .. } | DesignError::Invalid { .. } => BadInput,
            DesignError::Io { source, .. } => softcap_app::Classify::class(source),
            DesignError::Fem(_)
            | DesignError::Core(_)
            | DesignError::NotConverged { .. }
            | DesignError::Output { .. } => Failure,
        }
    }
}

/// Result alias.
pub type Result<T, E = DesignError> = std::result::Result<T, E>;
