//! The capture stage's error type: every variant names the file (and line/field or marker) at fault.

use std::path::PathBuf;

/// Everything that can go wrong while reading or processing a session.
///
/// [`CaptureError::is_bad_input`] separates bad input (exit code 2) from failures while running.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A file could not be opened or read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A TOML file is not valid TOML or does not match the expected structure.
    #[error("{path}:{line}: {message}")]
    Toml {
        /// The file.
        path: PathBuf,
        /// 1-based line of the error (0 when unknown).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A required field is missing or has a bad value.
    #[error("{path}:{line}: field `{field}`: {message}")]
    Field {
        /// The file.
        path: PathBuf,
        /// 1-based line (0 when the field is not tied to a line).
        line: usize,
        /// The field (column or key).
        field: String,
        /// What is wrong.
        message: String,
    },
    /// A camera is unusable (singular intrinsics, improper rotation, ...).
    #[error("{path}: camera `{camera}`: {message}")]
    Camera {
        /// The cameras file.
        path: PathBuf,
        /// Camera id.
        camera: String,
        /// What is wrong.
        message: String,
    },
    /// A marker could never be reconstructed because it is seen in fewer than two views in every frame.
    #[error(
        "marker `{marker}`: seen in fewer than two views in every frame ({max_views} at most); cannot triangulate it"
    )]
    TooFewViews {
        /// Marker id.
        marker: String,
        /// Largest number of views it had in any frame.
        max_views: usize,
    },
    /// An image could not be decoded or has the wrong size.
    #[error("{path}: {message}")]
    Image {
        /// The image file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A C3D, NPZ or URDF file could not be parsed.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Calibration input that cannot determine a rig (a camera no point sees, cameras that share
    /// no points, points on a line, a zero-length scale baseline).
    #[error("{path}: degenerate calibration input: {message}")]
    Degenerate {
        /// The input (points file, session or calibration).
        path: PathBuf,
        /// What is wrong, naming the camera.
        message: String,
    },
    /// The output could not be written.
    #[error("{path}: cannot write output: {message}")]
    Output {
        /// The output file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

impl CaptureError {
    /// True for errors caused by the user's input (exit code 2), false for failures while running.
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, CaptureError::Output { .. })
    }

    pub(crate) fn field(
        path: &std::path::Path,
        line: usize,
        field: &str,
        message: impl Into<String>,
    ) -> Self {
        CaptureError::Field {
            path: path.to_path_buf(),
            line,
            field: field.to_string(),
            message: message.into(),
        }
    }
}

impl softcap_app::Classify for CaptureError {
    fn class(&self) -> softcap_app::ErrorClass {
        if self.is_bad_input() {
            softcap_app::ErrorClass::BadInput
        } else {
            softcap_app::ErrorClass::Failure
        }
    }
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, CaptureError>;
