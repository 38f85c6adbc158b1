//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong writing or reading a softcap recording.
///
/// Every variant names the file it concerns, so a binary can print `{e:#}` and the user knows
/// which file to look at and what is wrong with it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The operating system refused a read, write, fsync or rename.
    #[error("{path}: {action}: {source}")]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// The file is not a valid MCAP file (bad magic, bad CRC, malformed record, ...).
    #[error("{path}: corrupt MCAP file: {problem}")]
    Corrupt { path: PathBuf, problem: String },
    /// The file ends before the MCAP footer/end magic: the writer did not finish.
    #[error("{path}: truncated MCAP file ({len} bytes): {problem}")]
    Truncated {
        path: PathBuf,
        len: u64,
        problem: String,
    },
    /// The MCAP library reported an error while writing.
    #[error("{path}: writing MCAP failed: {source}")]
    Write {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    /// A channel the caller asked for is absent.
    #[error("{path}: no channel `{topic}`")]
    MissingChannel { path: PathBuf, topic: String },
    /// A static channel (logged once at time 0) has no message or several.
    #[error("{path}: channel `{topic}` has {count} messages, expected exactly one")]
    NotStatic {
        path: PathBuf,
        topic: String,
        count: usize,
    },
    /// A channel exists but carries another message type than the caller asked for.
    #[error("{path}: channel `{topic}` has schema `{found}` ({encoding}), expected `{expected}`")]
    WrongSchema {
        path: PathBuf,
        topic: String,
        expected: String,
        found: String,
        encoding: String,
    },
    /// A message's bytes do not decode as the channel's protobuf type.
    #[error(
        "{path}: channel `{topic}` message at log_time {log_time_ns} ns does not decode: {source}"
    )]
    Decode {
        path: PathBuf,
        topic: String,
        log_time_ns: u64,
        #[source]
        source: prost::DecodeError,
    },
    /// An embedded schema is not a valid protobuf `FileDescriptorSet`, or lacks its message.
    #[error("{path}: schema `{schema}` is unusable: {problem}")]
    BadSchema {
        path: PathBuf,
        schema: String,
        problem: String,
    },
    /// The `softcap.provenance` metadata record is missing a field or a field is malformed.
    #[error("{path}: metadata `softcap.provenance` field `{field}`: {problem}")]
    Provenance {
        path: PathBuf,
        field: String,
        problem: String,
    },
    /// A message decoded but a field's value is unusable (non-finite, out of range, inconsistent).
    #[error("{path}: channel `{topic}` field `{field}`: {problem}")]
    Invalid {
        path: PathBuf,
        topic: String,
        field: String,
        problem: String,
    },
    /// The output path has no file name (e.g. `/` or `..`).
    #[error("{path}: output path has no file name")]
    BadOutputPath { path: PathBuf },
    /// A message could not be encoded (foxglove encoders report buffer errors).
    #[error("{path}: channel `{topic}`: encoding failed: {problem}")]
    Encode {
        path: PathBuf,
        topic: String,
        problem: String,
    },
}

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// A file that is not a softcap recording, lacks a channel or holds bad values is the user's
/// input at fault; an OS error is classified by its kind; a failed encode or MCAP write is a
/// failure while running.
impl softcap_app::Classify for Error {
    fn class(&self) -> softcap_app::ErrorClass {
        use softcap_app::ErrorClass::{BadInput, Failure};
        match self {
            Error::Io { source, .. } => softcap_app::Classify::class(source),
            Error::Write { .. } | Error::Encode { .. } => Failure,
            Error::Corrupt { .. }
            | Error::Truncated { .. }
            | Error::MissingChannel { .. }
            | Error::NotStatic { .. }
            | Error::WrongSchema { .. }
            | Error::Decode { .. }
            | Error::BadSchema { .. }
            | Error::Provenance { .. }
            | Error::Invalid { .. }
            | Error::BadOutputPath { .. } => BadInput,
        }
    }
}
