//! [`FaceError`], the crate's one error type.

use std::path::PathBuf;

/// Errors of the face stage. Non-convergence of an optimizer is a reported status, not an error.
#[derive(Debug, thiserror::Error)]
pub enum FaceError {
    /// A file could not be opened or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A face take's file or directory is missing or malformed (`softcap face track`).
    #[error("{path}: {reason}")]
    Take {
        /// The file or directory.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A CSV record is malformed.
    #[error("{path}:{line}: field `{field}`: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The offending field.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// Input data is inconsistent (wrong sizes, missing markers, degenerate geometry).
    #[error("invalid input `{what}`: {reason}")]
    InvalidInput {
        /// What was checked.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A setting is out of range.
    #[error("invalid setting `{field}`: {reason}")]
    InvalidSetting {
        /// The settings field.
        field: &'static str,
        /// Why it is invalid.
        reason: String,
    },
    /// A sparse factorization failed (matrix not positive definite).
    #[error("factorization of {what} failed: {reason}")]
    Factorization {
        /// Which system.
        what: &'static str,
        /// The solver's message.
        reason: String,
    },
    /// The pixel classifier failed to train or predict.
    #[error("pixel classifier: {0}")]
    Classifier(String),
    /// An error from a softcap_core solver or interpolator (message kept).
    #[error("softcap_core: {0}")]
    Core(String),
    /// The MCAP output could not be written.
    #[error("MCAP output: {0}")]
    Output(String),
    /// An image could not be written.
    #[error("{path}: {reason}")]
    Image {
        /// The file.
        path: PathBuf,
        /// The cause.
        reason: String,
    },
}

/// Malformed or inconsistent input files are the user's fault; an OS error is classified by
/// its kind; solver, classifier and output failures are failures while running.
impl softcap_app::Classify for FaceError {
    fn class(&self) -> softcap_app::ErrorClass {
        use softcap_app::ErrorClass::{BadInput, Failure};
        match self {
            FaceError::Parse { .. } | FaceError::InvalidInput { .. } | FaceError::Take { .. } => {
                BadInput
            }
            FaceError::Io { source, .. } => softcap_app::Classify::class(source),
            FaceError::InvalidSetting { .. }
            | FaceError::Factorization { .. }
            | FaceError::Classifier(_)
            | FaceError::Core(_)
            | FaceError::Output(_)
            | FaceError::Image { .. } => Failure,
        }
    }
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, FaceError>;
