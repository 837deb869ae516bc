//! Library errors. Each names the file it concerns, so the CLI can print one clear line.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input is unreadable or invalid (missing, not glTF, truncated, out-of-range data...).
    #[error("{path}: {message}")]
    Input { path: PathBuf, message: String },
    /// Writing the output failed.
    #[error("{path}: {message}")]
    Output { path: PathBuf, message: String },
    /// The options do not make sense.
    #[error("invalid option: {0}")]
    Options(String),
}

impl Error {
    pub fn input(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            message: message.into(),
        }
    }
    pub fn output(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> Self {
        Error::Output {
            path: path.into(),
            message: message.to_string(),
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
