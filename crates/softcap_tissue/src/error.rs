//! The error type of `softcap_tissue`.

use std::path::PathBuf;

/// Everything that can go wrong in the tissue stage.
#[derive(Debug, thiserror::Error)]
pub enum TissueError {
    /// An input MCAP (capture.mcap, material.mcap) could not be read or is invalid (the MCAP
    /// error names the file).
    #[error("{source}")]
    ReadMcap {
        /// File.
        path: PathBuf,
        /// Cause (names the channel and field).
        source: Box<softcap_mcap::Error>,
    },
    /// The tet mesh could not be read or is invalid (the mesh error names the file; for a mesh
    /// that fails validation, `path` is added).
    #[error("{}", mesh_message(.path, .source))]
    ReadMesh {
        /// File.
        path: PathBuf,
        /// Cause (names the line).
        source: Box<softcap_mesh::MeshError>,
    },
    /// An input is readable but unusable (missing field, markers outside the mesh, no probe
    /// examples …).
    #[error("{path}: {field}: {problem}")]
    BadInput {
        /// File.
        path: PathBuf,
        /// Channel / field / argument at fault.
        field: String,
        /// What is wrong.
        problem: String,
    },
    /// A line of an input text file is unusable.
    #[error("{}:{line}: {problem}", path.display())]
    BadInputLine {
        /// File.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        problem: String,
    },
    /// Invalid settings or arguments.
    #[error("bad settings: {field}: {problem}")]
    BadSettings {
        /// Setting.
        field: String,
        /// What is wrong.
        problem: String,
    },
    /// The FEM layer failed (reported, never a panic).
    #[error("FEM: {0}")]
    Fem(#[from] Box<softcap_fem::FemError>),
    /// A simulation did not converge (reported, nothing written).
    #[error("{what} did not converge: {status}")]
    NotConverged {
        /// What was being solved.
        what: String,
        /// Solver status.
        status: String,
    },
    /// Writing an output failed (nothing half-written is left behind).
    #[error("writing {path}: {reason}")]
    Output {
        /// File.
        path: PathBuf,
        /// Cause.
        reason: String,
    },
}

/// A reader error already names its file; a validation error (no file in it) gets the path.
fn mesh_message(path: &std::path::Path, e: &softcap_mesh::MeshError) -> String {
    use softcap_mesh::MeshError as M;
    match e {
        M::Io { .. } | M::Parse { .. } | M::Format { .. } => e.to_string(),
        _ => format!("{}: {e}", path.display()),
    }
}

impl TissueError {
    /// True for errors caused by the user's input (exit code 2), false for failures while
    /// running (exit code 1).
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            Self::ReadMcap { .. }
                | Self::ReadMesh { .. }
                | Self::BadInput { .. }
                | Self::BadInputLine { .. }
                | Self::BadSettings { .. }
        )
    }

    pub(crate) fn bad_input(
        path: impl Into<PathBuf>,
        field: impl Into<String>,
        problem: impl Into<String>,
    ) -> Self {
        Self::BadInput {
            path: path.into(),
            field: field.into(),
            problem: problem.into(),
        }
    }
}

impl softcap_app::Classify for TissueError {
    fn class(&self) -> softcap_app::ErrorClass {
        if self.is_bad_input() {
            softcap_app::ErrorClass::BadInput
        } else {
            softcap_app::ErrorClass::Failure
        }
    }
}

impl From<softcap_fem::FemError> for TissueError {
    fn from(e: softcap_fem::FemError) -> Self {
        Self::Fem(Box::new(e))
    }
}

/// Result alias.
pub type Result<T, E = TissueError> = std::result::Result<T, E>;
