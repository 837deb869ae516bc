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
    /// The simplifier refused a mesh (e.g. of a tile's content), with its reason as the source.
    #[error("{path}: simplification failed")]
    Simplify { path: PathBuf, source: Source },
    /// A tile could not be encoded (Draco, an image, the glTF JSON), with its reason as the source.
    #[error("{path}: encoding failed")]
    Encode { path: PathBuf, source: Source },
}

/// The cause of an error from a stage (its own error type), kept whole so the CLI prints the
/// chain; boxed, so this base module names no stage.
pub type Source = Box<dyn std::error::Error + Send + Sync>;

impl Error {
    pub fn input(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            message: message.into(),
        }
    }
    pub fn simplify(path: impl Into<PathBuf>, source: impl Into<Source>) -> Self {
        Error::Simplify {
            path: path.into(),
            source: source.into(),
        }
    }
    pub fn encode(path: impl Into<PathBuf>, source: impl Into<Source>) -> Self {
        Error::Encode {
            path: path.into(),
            source: source.into(),
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
