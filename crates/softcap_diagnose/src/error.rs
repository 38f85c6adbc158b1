//! The error type of `softcap_diagnose`.

use std::path::PathBuf;

/// Everything that can go wrong while diagnosing a recording.
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    /// The recording is unusable (empty, inconsistent marker counts, non-finite values …).
    #[error("bad recording: {what}")]
    BadRecording {
        /// what is wrong
        what: String,
    },
    /// A frame carries a non-finite value.
    #[error("frame {frame}: non-finite {field}")]
    NonFinite {
        /// frame index
        frame: u64,
        /// which field
        field: &'static str,
    },
    /// The model simulation failed (reported, never a panic).
    #[error("simulation failed at frame {frame}: {reason}")]
    Simulation {
        /// frame index (or `u64::MAX` for the unloaded state)
        frame: u64,
        /// solver status / reason
        reason: String,
    },
    /// The FEM layer reported an error.
    #[error(transparent)]
    Fem(#[from] Box<softcap_fem::FemError>),
    /// The mesh layer reported an error (a refinement target it cannot meet).
    #[error(transparent)]
    Mesh(#[from] Box<softcap_mesh::MeshError>),
    /// Reading or writing an MCAP file failed (the MCAP error names the file).
    #[error("{source}")]
    Mcap {
        /// file
        path: PathBuf,
        /// cause
        source: Box<softcap_mcap::Error>,
    },
    /// A required channel or field is missing in an input file.
    #[error("{path}: {what}")]
    BadInput {
        /// file
        path: PathBuf,
        /// what is missing or wrong
        what: String,
    },
    /// Writing the JSON or the report failed.
    #[error("{path}: {reason}")]
    Output {
        /// file
        path: PathBuf,
        /// cause
        reason: String,
    },
}

/// A recording, material or mesh that is unusable is the user's input at fault; a failed
/// simulation or output is a failure while running.
impl softcap_app::Classify for DiagnoseError {
    fn class(&self) -> softcap_app::ErrorClass {
        use softcap_app::ErrorClass::{BadInput, Failure};
        match self {
            DiagnoseError::BadInput { .. }
            | DiagnoseError::BadRecording { .. }
            | DiagnoseError::NonFinite { .. }
            | DiagnoseError::Mesh(_) => BadInput,
            DiagnoseError::Mcap { source, .. } => softcap_app::Classify::class(source.as_ref()),
            DiagnoseError::Simulation { .. }
            | DiagnoseError::Fem(_)
            | DiagnoseError::Output { .. } => Failure,
        }
    }
}

/// Result alias.
pub type Result<T, E = DiagnoseError> = std::result::Result<T, E>;
