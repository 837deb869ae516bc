//! Library errors. Each names the file it concerns, so the CLI can print one clear line: the
//! error, then its chain of sources (`path: message: cause: cause...`).

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input is unreadable or invalid (missing, not glTF, truncated, out-of-range data...),
    /// with the reader's error or the I/O error as the source when there is one.
    #[error("{}", located(path, message))]
    Input {
        path: PathBuf,
        message: String,
        #[source]
        source: Option<Source>,
    },
    /// Writing the output failed, with the I/O (or serialization) error as the source when there
    /// is one.
    #[error("{}", located(path, message))]
    Output {
        path: PathBuf,
        message: String,
        #[source]
        source: Option<Source>,
    },
    /// The options do not make sense.
    #[error("invalid option: {0}")]
    Options(String),
    /// The simplifier refused a mesh (e.g. of a tile's content), with its reason as the source.
    #[error("{path}: simplification failed")]
    Simplify { path: PathBuf, source: Source },
    /// A tile could not be encoded (Draco, an image, the glTF JSON), with its reason as the source.
    #[error("{path}: encoding failed")]
    Encode { path: PathBuf, source: Source },
    /// bimtiles itself went wrong on this input (a defect, caught before anything was written),
    /// e.g. a tile box that came out not finite.
    #[error("{}: internal error (a bimtiles defect; nothing was written): {message}", path.display())]
    Internal { path: PathBuf, message: String },
}

/// The cause of an error from a stage (its own error type), kept whole so the CLI prints the
/// chain; boxed, so this base module names no stage.
pub type Source = Box<dyn std::error::Error + Send + Sync>;

/// "path: message", or only the path when the message is empty (the source then says it all,
/// and the CLI prints it right after).
fn located(path: &Path, message: &str) -> String {
    match message.is_empty() {
        true => path.display().to_string(),
        false => format!("{}: {message}", path.display()),
    }
}

impl Error {
    /// The same error, its path moved from under `from` to under `to` (a build's temporary folder
    /// to the output the user named).
    pub fn relocated(mut self, from: &Path, to: &Path) -> Self {
        let path = match &mut self {
            Error::Input { path, .. }
            | Error::Output { path, .. }
            | Error::Simplify { path, .. }
            | Error::Encode { path, .. }
            | Error::Internal { path, .. } => path,
            Error::Options(_) => return self,
        };
        if let Ok(rest) = path.strip_prefix(from) {
            *path = to.join(rest);
        }
        self
    }
    /// Bad input described by a message alone.
    pub fn input(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            message: message.into(),
            source: None,
        }
    }
    /// Bad input with its cause; `message` says what was being done (may be empty when the
    /// source's own text names the problem, e.g. a reader's error type).
    pub fn input_from(
        path: impl Into<PathBuf>,
        message: impl Into<String>,
        source: impl Into<Source>,
    ) -> Self {
        Error::Input {
            path: path.into(),
            message: message.into(),
            source: Some(source.into()),
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
    /// A failed write described by a message alone.
    pub fn output(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> Self {
        Error::Output {
            path: path.into(),
            message: message.to_string(),
            source: None,
        }
    }
    /// A failed write with its cause (the I/O or serialization error); `message` says what was
    /// being done.
    pub fn output_from(
        path: impl Into<PathBuf>,
        message: impl Into<String>,
        source: impl Into<Source>,
    ) -> Self {
        Error::Output {
            path: path.into(),
            message: message.into(),
            source: Some(source.into()),
        }
    }
}

/// The error and its sources as one line, `error: cause: cause...`, as the CLI prints them (for
/// callers that show an error without the CLI, and for tests).
pub fn chain_text(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        text.push_str(": ");
        text.push_str(&c.to_string());
        cause = c.source();
    }
    text
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// The message a panic carried (a `&str` or `String` payload), for a caught panic turned into an
/// error or the binary's one line.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn input_keeps_its_source_and_prints_one_line() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "gone");
        let e = Error::input_from("a.glb", "cannot read", io);
        assert_eq!(e.to_string(), "a.glb: cannot read");
        let source = std::error::Error::source(&e).expect("the I/O error is the source");
        assert_eq!(source.to_string(), "gone");
        assert_eq!(chain_text(&e), "a.glb: cannot read: gone");
        // An empty message leaves the source to name the problem.
        let e = Error::input_from("a.ifc", "", std::io::Error::other("empty file"));
        assert_eq!(chain_text(&e), "a.ifc: empty file");
        let e = Error::output("out", "output path exists and is not a folder");
        assert!(std::error::Error::source(&e).is_none());
        assert_eq!(
            chain_text(&e),
            "out: output path exists and is not a folder"
        );
    }
}
