//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong reading, writing or validating a mesh.
///
/// Reader errors name the source (a path, or the name given to a `*_from_reader` function) and,
/// for text formats, the 1-based line number.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be opened, read or written.
    #[error("{}: {source}", file.display())]
    Io {
        /// The file (or stream name).
        file: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A text line could not be parsed.
    #[error("{}:{line}: {message}", file.display())]
    Parse {
        /// The file (or stream name).
        file: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the line.
        message: String,
    },
    /// The file is malformed in a way that has no single line (binary data, missing sections).
    #[error("{}: {message}", file.display())]
    Format {
        /// The file (or stream name).
        file: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("vertex {vertex} has non-finite coordinate {axis} = {value}")]
    NonFiniteVertex {
        /// Vertex index.
        vertex: usize,
        /// Axis (0 = x, 1 = y, 2 = z).
        axis: usize,
        /// The offending value.
        value: f64,
    },
    /// An element refers to a vertex that does not exist.
    #[error(
        "element {element} corner {corner} refers to vertex {index}, but there are only {num_vertices} vertices"
    )]
    IndexOutOfRange {
        /// Element (triangle or tet) index.
        element: usize,
        /// Corner within the element.
        corner: usize,
        /// The out-of-range vertex index.
        index: usize,
        /// Number of vertices in the mesh.
        num_vertices: usize,
    },
    /// An element uses the same vertex twice.
    #[error("element {element} uses vertex {index} more than once")]
    RepeatedVertex {
        /// Element index.
        element: usize,
        /// The repeated vertex index.
        index: usize,
    },
    /// An element has (near-)zero area or volume.
    #[error("element {element} is degenerate: measure {measure:e} is below {tolerance:e}")]
    DegenerateElement {
        /// Element index.
        element: usize,
        /// Area (triangles) or signed volume (tets).
        measure: f64,
        /// The threshold it fell below.
        tolerance: f64,
    },
    /// A tet has negative orientation `det[x1−x0, x2−x0, x3−x0] < 0`.
    #[error("tet {tet} is inverted: det[x1-x0, x2-x0, x3-x0] = {det:e}")]
    InvertedElement {
        /// Tet index.
        tet: usize,
        /// The (negative) determinant, 6 × signed volume.
        det: f64,
    },
    /// A vertex is used by no element.
    #[error("vertex {vertex} is not used by any element")]
    UnusedVertex {
        /// Vertex index.
        vertex: usize,
    },
    /// A mesh has no elements where some are required.
    #[error("mesh has no elements")]
    Empty,
    /// A refinement target that cannot be met: a target edge length that is not positive and
    /// finite, a ball that is not finite, or more tets than the caller's limit.
    #[error("local refinement: {message}")]
    Refinement {
        /// What is wrong.
        message: String,
    },
}

/// Result alias for this crate.
pub type Result<T, E = MeshError> = std::result::Result<T, E>;

impl MeshError {
    pub(crate) fn io(file: impl Into<PathBuf>, source: std::io::Error) -> Self {
        MeshError::Io {
            file: file.into(),
            source,
        }
    }

    pub(crate) fn parse(file: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        MeshError::Parse {
            file: file.into(),
            line,
            message: message.into(),
        }
    }

    pub(crate) fn format(file: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        MeshError::Format {
            file: file.into(),
            message: message.into(),
        }
    }

    /// The 1-based line number for text parse errors.
    pub fn line(&self) -> Option<usize> {
        match self {
            MeshError::Parse { line, .. } => Some(*line),
            _ => None,
        }
    }
}

/// A file that cannot be parsed or a mesh that fails validation is the user's input at fault; an
/// OS error is classified by its kind; a refinement target that cannot be met is a failure.
impl softcap_app::Classify for MeshError {
    fn class(&self) -> softcap_app::ErrorClass {
        match self {
            MeshError::Io { source, .. } => softcap_app::Classify::class(source),
            MeshError::Refinement { .. } => softcap_app::ErrorClass::Failure,
            _ => softcap_app::ErrorClass::BadInput,
        }
    }
}
