//! The crate's one error type. Every variant names the file (or argument) and what is wrong with it,
//! so a user with their own data can fix the input without reading our code.

use std::path::PathBuf;

/// Result alias used throughout the crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong on bad input. Broken internal invariants panic instead.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// A line of a text file is malformed.
    #[error("{}:{line}: {what}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the line.
        what: String,
    },
    /// A file exists but its content is unusable (undecodable or truncated image, wrong bit depth,
    /// wrong size, non-finite values, ...).
    #[error("{}: {what}", path.display())]
    BadFile {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// A folder is not a sequence in any format we read, or is one with no usable frames.
    #[error("{}: {what}", path.display())]
    BadSequence {
        /// The sequence folder.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// A backend cannot run an op, a shape or a tensor it was given (SPEC.md §15): never a silent
    /// fallback to another backend.
    #[error("backend {backend}: unsupported: {what}")]
    Unsupported {
        /// The backend's name (`--backend`).
        backend: String,
        /// What it cannot do, and what to use instead.
        what: String,
    },
    /// A command-line or API argument is out of range.
    #[error("invalid {name}: {what}")]
    InvalidArgument {
        /// The argument's name (as on the command line where there is one).
        name: String,
        /// What is wrong with it.
        what: String,
    },
}

impl Error {
    /// Shorthand for [`Error::Parse`].
    pub fn parse(path: impl Into<PathBuf>, line: usize, what: impl Into<String>) -> Self {
        Error::Parse { path: path.into(), line, what: what.into() }
    }
    /// Shorthand for [`Error::BadFile`].
    pub fn bad_file(path: impl Into<PathBuf>, what: impl Into<String>) -> Self {
        Error::BadFile { path: path.into(), what: what.into() }
    }
    /// Shorthand for [`Error::BadSequence`].
    pub fn bad_sequence(path: impl Into<PathBuf>, what: impl Into<String>) -> Self {
        Error::BadSequence { path: path.into(), what: what.into() }
    }
    /// Shorthand for [`Error::InvalidArgument`].
    pub fn invalid_argument(name: impl Into<String>, what: impl Into<String>) -> Self {
        Error::InvalidArgument { name: name.into(), what: what.into() }
    }
    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }
}
