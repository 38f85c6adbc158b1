//! The one error type of `softcap_synth`.

use std::path::PathBuf;
use thiserror::Error;

/// Everything that can stop the virtual rig from writing a session.
#[derive(Debug, Error)]
pub enum SynthError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The scenario file is malformed or a value is out of range.
    #[error("{path}: {message}")]
    Scenario {
        /// The scenario file.
        path: PathBuf,
        /// What is wrong (names the field).
        message: String,
    },
    /// A setting combination the rig cannot produce (e.g. an effect whose FEM support is absent).
    #[error("scenario {scenario}: {message}")]
    Unsupported {
        /// Scenario name.
        scenario: String,
        /// What cannot be done.
        message: String,
    },
    /// The ground-truth simulation failed.
    #[error("ground truth, frame {frame}: {message}")]
    Simulation {
        /// Frame whose solve failed.
        frame: usize,
        /// Solver status / reason.
        message: String,
    },
    /// softcap_fem refused the model.
    #[error(transparent)]
    Fem(#[from] softcap_fem::FemError),
    /// softcap_mesh refused a mesh or failed to write it.
    #[error(transparent)]
    Mesh(#[from] softcap_mesh::MeshError),
    /// softcap_core refused a camera.
    #[error(transparent)]
    Core(#[from] softcap_core::CoreError),
    /// PNG encoding failed.
    #[error("{path}: {message}")]
    Image {
        /// The image file.
        path: PathBuf,
        /// Encoder message.
        message: String,
    },
    /// The output directory exists and is not empty.
    #[error("{path}: output directory exists and is not empty (nothing was written)")]
    OutputExists {
        /// The directory.
        path: PathBuf,
    },
}

/// A scenario that is malformed or asks for what the rig cannot do, an output folder in the way,
/// or an input/output path the OS refuses is the user's input at fault; a failed simulation is a
/// failure while running.
impl softcap_app::Classify for SynthError {
    fn class(&self) -> softcap_app::ErrorClass {
        use softcap_app::ErrorClass::{BadInput, Failure};
        match self {
            SynthError::Scenario { .. }
            | SynthError::Unsupported { .. }
            | SynthError::OutputExists { .. } => BadInput,
            SynthError::Io { source, .. } => softcap_app::Classify::class(source),
            SynthError::Mesh(e) => softcap_app::Classify::class(e),
            SynthError::Simulation { .. }
            | SynthError::Fem(_)
            | SynthError::Core(_)
            | SynthError::Image { .. } => Failure,
        }
    }
}

/// Result alias.
pub type Result<T, E = SynthError> = std::result::Result<T, E>;

pub(crate) fn io_err(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> SynthError {
    let path = path.into();
    move |source| SynthError::Io { path, source }
}
