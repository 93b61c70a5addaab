//! The crate's one error type. Every variant names the file (or argument) and what is wrong with it,
//! so a user with their own data can fix the input without reading our code.

use std::path::PathBuf;

/// Result alias used throughout the crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong on bad input. Broken internal invariants panic instead.
#[derive(Debug)]
#[non_exhaustive]
pub enum Error {
    /// A file could not be opened, read or written.
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A line of a text file is malformed.
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
    BadFile {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// A folder is not a sequence in any format we read, or is one with no usable frames.
    BadSequence {
        /// The sequence folder.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// A backend cannot run an op, a shape or a tensor it was given (SPEC.md §15): never a silent
    /// fallback to another backend.
    Unsupported {
        /// The backend's name (`--backend`).
        backend: String,
        /// What it cannot do, and what to use instead.
        what: String,
    },
    /// A command-line or API argument is out of range.
    InvalidArgument {
        /// The argument's name (as on the command line where there is one).
        name: String,
        /// What is wrong with it.
        what: String,
    },
}

// Display and source by hand rather than through `thiserror`: its proc-macro (and the `syn` it
// needs) sat on the critical path of every clean build for six format strings (issue 33).
impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Error::Parse { path, line, what } => write!(f, "{}:{line}: {what}", path.display()),
            Error::BadFile { path, what } | Error::BadSequence { path, what } => {
                write!(f, "{}: {what}", path.display())
            }
            Error::Unsupported { backend, what } => write!(f, "backend {backend}: unsupported: {what}"),
            Error::InvalidArgument { name, what } => write!(f, "invalid {name}: {what}"),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Io { source, .. } => Some(source),
            _ => None,
        }
    }
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
