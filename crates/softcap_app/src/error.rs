//! One error type for every softcap command: a cause chain plus who is at fault.
//!
//! A stage's library keeps its own `thiserror` enum with structured fields and says, once, which
//! of its variants are the user's fault ([`Classify`]). The class is decided where the error's
//! type is still known — when `?` converts it into an [`Error`] — and context added on the way
//! up ([`Context`]) keeps it, so the binary never re-derives it from strings or downcasts.
//!
//! ```
//! use softcap_app::{Classify, Context, Error, ErrorClass};
//!
//! #[derive(Debug, thiserror::Error)]
//! enum StageError {
//!     #[error("{path}: line {line}: {what}")]
//!     Parse { path: String, line: usize, what: String },
//!     #[error("solver diverged")]
//!     Diverged,
//! }
//! impl Classify for StageError {
//!     fn class(&self) -> ErrorClass {
//!         match self {
//!             StageError::Parse { .. } => ErrorClass::BadInput,
//!             StageError::Diverged => ErrorClass::Failure,
//!         }
//!     }
//! }
//!
//! fn load() -> Result<(), StageError> {
//!     Err(StageError::Parse { path: "a.csv".into(), line: 3, what: "x: not a number".into() })
//! }
//! let e: Error = load().context("loading the take").unwrap_err();
//! assert_eq!(e.class(), ErrorClass::BadInput);
//! assert_eq!(e.exit_code(), 2);
//! assert_eq!(e.message(), "loading the take: a.csv: line 3: x: not a number");
//! ```

use std::fmt::{self, Debug, Display};

/// Who is at fault: decides the exit code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorClass {
    /// The user's input (a missing or malformed file, a bad argument): exit code 2.
    BadInput,
    /// A failure while running on valid input (a write that failed, a solver that broke): exit code 1.
    Failure,
}

/// Implemented by each stage's error enum: which variants are the user's fault.
pub trait Classify {
    /// The class of this error.
    fn class(&self) -> ErrorClass;
}

/// An error with its causes and its [`ErrorClass`].
pub struct Error {
    class: ErrorClass,
    inner: anyhow::Error,
}

/// Result alias of softcap commands.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// A bad-input error with this message (say which file, line or field, and what is wrong).
    pub fn bad_input(message: impl Display + Debug + Send + Sync + 'static) -> Self {
        Self {
            class: ErrorClass::BadInput,
            inner: anyhow::Error::msg(message),
        }
    }

    /// A failure-while-running error with this message.
    pub fn failure(message: impl Display + Debug + Send + Sync + 'static) -> Self {
        Self {
            class: ErrorClass::Failure,
            inner: anyhow::Error::msg(message),
        }
    }

    /// Wraps any error with an explicit class.
    pub fn new(class: ErrorClass, error: impl std::error::Error + Send + Sync + 'static) -> Self {
        Self {
            class,
            inner: anyhow::Error::new(error),
        }
    }

    /// Who is at fault.
    pub fn class(&self) -> ErrorClass {
        self.class
    }

    /// 2 for bad input, 1 for a failure while running.
    pub fn exit_code(&self) -> u8 {
        match self.class {
            ErrorClass::BadInput => crate::EXIT_BAD_INPUT,
            ErrorClass::Failure => crate::EXIT_FAILURE,
        }
    }

    /// Adds a layer of context (what was being done), keeping the class.
    pub fn context(self, context: impl Display + Send + Sync + 'static) -> Self {
        Self {
            class: self.class,
            inner: self.inner.context(context),
        }
    }

    /// The chain of causes, outermost first.
    pub fn chain(&self) -> anyhow::Chain<'_> {
        self.inner.chain()
    }

    /// The outermost error, for `downcast_ref` in tests.
    pub fn as_anyhow(&self) -> &anyhow::Error {
        &self.inner
    }

    /// The message a user sees: each cause once, outermost first, joined by `": "`.
    ///
    /// Many error types print their source inside their own message (`"{path}: {source}"`) and
    /// also return it from `source()`; a cause whose text the message already contains is
    /// therefore skipped, so a path or an OS error is never printed twice.
    pub fn message(&self) -> String {
        let mut message = String::new();
        for cause in self.inner.chain() {
            let text = cause.to_string();
            if text.is_empty() || message.contains(&text) {
                continue;
            }
            if !message.is_empty() {
                message.push_str(": ");
            }
            message.push_str(&text);
        }
        message
    }
}

impl Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if f.alternate() {
            f.write_str(&self.message())
        } else {
            Display::fmt(&self.inner, f)
        }
    }
}

impl Debug for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?} error: {:?}", self.class, self.inner)
    }
}

impl<E> From<E> for Error
where
    E: std::error::Error + Classify + Send + Sync + 'static,
{
    fn from(e: E) -> Self {
        Self {
            class: e.class(),
            inner: anyhow::Error::new(e),
        }
    }
}

/// An `anyhow` error from a library that does not classify: a failure while running.
impl From<anyhow::Error> for Error {
    fn from(inner: anyhow::Error) -> Self {
        Self {
            class: ErrorClass::Failure,
            inner,
        }
    }
}

/// An OS error the user can cause (a missing or unreadable file, a folder where a file belongs,
/// bad data) is bad input; the rest (disk full, interrupted) is a failure. Add the path with
/// [`Context`].
impl Classify for std::io::Error {
    fn class(&self) -> ErrorClass {
        use std::io::ErrorKind as K;
        match self.kind() {
            K::NotFound
            | K::PermissionDenied
            | K::AlreadyExists
            | K::InvalidInput
            | K::InvalidData
            | K::UnexpectedEof
            | K::IsADirectory
            | K::NotADirectory
            | K::DirectoryNotEmpty => ErrorClass::BadInput,
            _ => ErrorClass::Failure,
        }
    }
}

/// An argument clap rejected while the command ran (e.g. a value checked after parsing).
impl Classify for clap::Error {
    fn class(&self) -> ErrorClass {
        ErrorClass::BadInput
    }
}

/// Context on results whose error already has a class ([`Classify`] types, [`Error`]).
pub trait Context<T> {
    /// Wraps the error with `context`, keeping its class.
    fn context(self, context: impl Display + Send + Sync + 'static) -> Result<T>;
    /// Wraps the error with the context `f` makes, keeping its class.
    fn with_context<C: Display + Send + Sync + 'static>(self, f: impl FnOnce() -> C) -> Result<T>;
}

impl<T, E: Into<Error>> Context<T> for std::result::Result<T, E> {
    fn context(self, context: impl Display + Send + Sync + 'static) -> Result<T> {
        self.map_err(|e| e.into().context(context))
    }

    fn with_context<C: Display + Send + Sync + 'static>(self, f: impl FnOnce() -> C) -> Result<T> {
        self.map_err(|e| e.into().context(f()))
    }
}

/// Classifies results of libraries that do not ([`toml`, `serde_json`, `csv`, …]) at the call site.
pub trait IntoError<T> {
    /// The input named by `f` is at fault (exit code 2), e.g. `.bad_input_with(|| path.display().to_string())`.
    fn bad_input_with<C: Display + Send + Sync + 'static>(self, f: impl FnOnce() -> C)
    -> Result<T>;
    /// A failure while doing what `f` names (exit code 1).
    fn failure_with<C: Display + Send + Sync + 'static>(self, f: impl FnOnce() -> C) -> Result<T>;
}

impl<T, E: std::error::Error + Send + Sync + 'static> IntoError<T> for std::result::Result<T, E> {
    fn bad_input_with<C: Display + Send + Sync + 'static>(
        self,
        f: impl FnOnce() -> C,
    ) -> Result<T> {
        self.map_err(|e| Error::new(ErrorClass::BadInput, e).context(f()))
    }

    fn failure_with<C: Display + Send + Sync + 'static>(self, f: impl FnOnce() -> C) -> Result<T> {
        self.map_err(|e| Error::new(ErrorClass::Failure, e).context(f()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("{path}: {source}")]
    struct Wrapped {
        path: String,
        #[source]
        source: std::io::Error,
    }

    impl Classify for Wrapped {
        fn class(&self) -> ErrorClass {
            self.source.class()
        }
    }

    #[test]
    fn a_source_printed_inside_its_wrapper_appears_once() {
        let os = std::io::Error::from(std::io::ErrorKind::NotFound);
        let os_text = os.to_string();
        let e: Error = Error::from(Wrapped {
            path: "take.csv".into(),
            source: os,
        })
        .context("reading the take");
        let m = e.message();
        assert_eq!(m, format!("reading the take: take.csv: {os_text}"));
        assert_eq!(m.matches("take.csv").count(), 1);
        assert_eq!(e.exit_code(), 2);
    }

    #[test]
    fn classes_survive_context_and_foreign_errors_are_classified_at_the_call_site() {
        let r: std::result::Result<(), std::io::Error> =
            Err(std::io::Error::from(std::io::ErrorKind::StorageFull));
        assert_eq!(
            r.context("writing out.mcap").unwrap_err().class(),
            ErrorClass::Failure
        );
        let r: std::result::Result<u32, std::num::ParseIntError> = "x".parse::<u32>();
        let e = r.bad_input_with(|| "settings.toml: `seed`").unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert_eq!(
            e.message(),
            "settings.toml: `seed`: invalid digit found in string"
        );
        let e = Error::from(anyhow::anyhow!("solver broke"));
        assert_eq!(
            (e.exit_code(), format!("{e:#}")),
            (1, "solver broke".into())
        );
    }
}
