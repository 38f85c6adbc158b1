//! The one error type of `softcap_psd`.

use std::path::PathBuf;

/// Errors of the pose-space detail stage.
#[derive(Debug, thiserror::Error)]
pub enum PsdError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// the file
        path: PathBuf,
        /// the OS error
        source: std::io::Error,
    },
    /// A pose file is malformed.
    #[error("{path}: byte {offset}: {reason}")]
    BadPoseFile {
        /// the file
        path: PathBuf,
        /// byte offset of the problem
        offset: usize,
        /// what is wrong
        reason: String,
    },
    /// A marker-trajectory file is malformed.
    #[error("{path}: line {line}: field `{field}`: {reason}")]
    BadMarkerFile {
        /// the file
        path: PathBuf,
        /// 1-based line
        line: usize,
        /// the column
        field: String,
        /// what is wrong
        reason: String,
    },
    /// An input MCAP recording cannot be opened (missing, truncated, corrupt).
    #[error("{path}: {reason}")]
    BadRecording {
        /// the file
        path: PathBuf,
        /// what is wrong
        reason: String,
    },
    /// A message of an input MCAP recording is missing or malformed.
    #[error("{path}: topic `{topic}`, frame {frame}, field `{field}`: {reason}")]
    BadMessage {
        /// the file
        path: PathBuf,
        /// the channel
        topic: String,
        /// the frame (`-` when not tied to one)
        frame: String,
        /// the message field
        field: String,
        /// what is wrong
        reason: String,
    },
    /// Writing an output recording failed.
    #[error("{path}: writing: {reason}")]
    Output {
        /// the output
        path: PathBuf,
        /// why
        reason: String,
    },
    /// Array sizes disagree.
    #[error("{what}: expected {expected}, got {got}")]
    SizeMismatch {
        /// what was being checked
        what: &'static str,
        /// expected length
        expected: usize,
        /// actual length
        got: usize,
    },
    /// A setting is out of range.
    #[error("setting `{field}`: {reason}")]
    InvalidSetting {
        /// the field
        field: &'static str,
        /// why
        reason: String,
    },
    /// The mesh could not be read.
    #[error(transparent)]
    Mesh(#[from] softcap_mesh::MeshError),
    /// The linear shell could not be built.
    #[error(transparent)]
    Shell(#[from] softcap_mesh::ShellError),
    /// An RBF fit failed.
    #[error(transparent)]
    Rbf(#[from] softcap_core::CoreError),
    /// Writing an image or plot failed.
    #[error("{path}: {reason}")]
    Render {
        /// the output
        path: PathBuf,
        /// why
        reason: String,
    },
}

/// Malformed pose, marker and recording files are the user's input at fault; an OS error is
/// classified by its kind; fits, renders and outputs that fail are failures while running.
impl softcap_app::Classify for PsdError {
    fn class(&self) -> softcap_app::ErrorClass {
        use softcap_app::ErrorClass::{BadInput, Failure};
        match self {
            PsdError::BadPoseFile { .. }
            | PsdError::BadMarkerFile { .. }
            | PsdError::BadRecording { .. }
            | PsdError::BadMessage { .. } => BadInput,
            PsdError::Io { source, .. } => softcap_app::Classify::class(source),
            PsdError::Mesh(e) => softcap_app::Classify::class(e),
            PsdError::Output { .. }
            | PsdError::SizeMismatch { .. }
            | PsdError::InvalidSetting { .. }
            | PsdError::Shell(_)
            | PsdError::Rbf(_)
            | PsdError::Render { .. } => Failure,
        }
    }
}

/// Result with [`PsdError`].
pub type Result<T, E = PsdError> = std::result::Result<T, E>;
