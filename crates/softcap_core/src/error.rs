//! The one error type of `softcap_core`.
//!
//! Errors are for input that cannot be worked on (mismatched dimensions, too few samples,
//! a singular interpolation system). An optimizer that runs but does not converge is *not*
//! an error: it returns a report whose `status` says why it stopped.

use thiserror::Error;

/// Everything that can go wrong in `softcap_core` before or while setting up a computation.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CoreError {
    /// A slice or matrix had the wrong length / shape.
    #[error("{what}: expected {expected} values, got {got}")]
    DimensionMismatch {
        /// Which argument was wrong.
        what: &'static str,
        /// Length implied by the other arguments.
        expected: usize,
        /// Length passed in.
        got: usize,
    },
    /// Not enough data for the requested model.
    #[error("{what}: need at least {needed}, got {got}")]
    TooFewSamples {
        /// Which quantity was too small.
        what: &'static str,
        /// Minimum required.
        needed: usize,
        /// What was supplied.
        got: usize,
    },
    /// A non-finite (NaN or infinite) value in the input.
    #[error("{what}: non-finite value at index {index}")]
    NonFiniteInput {
        /// Which argument.
        what: &'static str,
        /// Flat index of the first offending value.
        index: usize,
    },
    /// A box bound with `lower > upper` (or a NaN bound).
    #[error("bound {index}: lower {lower} > upper {upper}")]
    InvalidBounds {
        /// Parameter index.
        index: usize,
        /// Lower bound.
        lower: f64,
        /// Upper bound.
        upper: f64,
    },
    /// A settings field outside its valid range.
    #[error("invalid setting {field}: {reason}")]
    InvalidSetting {
        /// Field name in the settings struct.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A linear system that should be uniquely solvable was singular or the solve produced
    /// non-finite numbers (e.g. duplicate RBF centres, or centres not unisolvent for the
    /// polynomial tail).
    #[error("singular {what} system (size {size}): {detail}")]
    SingularSystem {
        /// Which system.
        what: &'static str,
        /// Its dimension.
        size: usize,
        /// Extra information (residual, pivot).
        detail: String,
    },
    /// A camera that cannot project: singular intrinsics, non-finite values, improper rotation.
    #[error("{reason}")]
    InvalidCamera {
        /// What is wrong with it.
        reason: String,
    },
    /// An index out of range (e.g. an RBF centre index ≥ number of samples).
    #[error("{what}: index {index} out of range 0..{len}")]
    IndexOutOfRange {
        /// Which argument.
        what: &'static str,
        /// Offending index.
        index: usize,
        /// Valid length.
        len: usize,
    },
}

/// Result alias for `softcap_core`.
pub type Result<T, E = CoreError> = std::result::Result<T, E>;

pub(crate) fn check_len(what: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(CoreError::DimensionMismatch {
            what,
            expected,
            got,
        })
    }
}

pub(crate) fn check_finite(what: &'static str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(index) => Err(CoreError::NonFiniteInput { what, index }),
    }
}
