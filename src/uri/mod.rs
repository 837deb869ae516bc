//! URIs as bimtiles meets them, in one place: the relative references and data URIs (RFC 2397) a
//! glTF or a tileset names its buffers, images and tiles with, the request paths `serve` answers
//! (RFC 3986), and the media types of the files they lead to.
//!
//! One verb a file: [`data`] decodes and encodes data URIs, [`percent`] undoes percent-encoding,
//! [`confine`] keeps a URI inside its root folder, [`mime`] names media types. Every problem is a
//! [`UriError`], so each caller words it the same way.

pub mod confine;
pub mod data;
pub mod mime;
pub mod percent;

use std::path::PathBuf;

/// Why a URI was refused or could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum UriError {
    /// A `%` not followed by two hex digits (where escapes must be well formed), or escapes that
    /// do not decode to UTF-8.
    #[error("URI '{uri}' is not valid percent-encoding")]
    BadPercentEncoding { uri: String },
    /// A NUL byte, plain or encoded: no file name holds one.
    #[error("URI '{uri}' holds a NUL byte (refused)")]
    Nul { uri: String },
    /// A leading `/` (or an empty segment of a request path), a scheme or drive (`:`), or a `\`.
    #[error("URI '{uri}' is absolute or has a scheme (refused)")]
    Absolute { uri: String },
    /// `..` (or a root) in the path; in a request path also `.` and an encoded separator.
    #[error("URI '{uri}' escapes {folder} (refused)")]
    Escapes { uri: String, folder: &'static str },
    /// A segment starting with `.` where the rules refuse them (`.git`, `.env`).
    #[error("URI '{uri}' names a hidden file (refused)")]
    Hidden { uri: String },
    /// The path stays inside the folder by its text, but a symlink leads out of it.
    #[error("URI '{uri}' leads outside {folder} (refused)")]
    LeadsOutside { uri: String, folder: &'static str },
    /// No such regular file (or a folder without its index file).
    #[error("URI '{uri}' names no file")]
    NotFound { uri: String },
    /// A data URI whose media type runs to the end: RFC 2397 puts a comma before the data.
    #[error("a data URI without a comma")]
    DataNoComma,
    /// A data URI in the plain (percent-encoded) form; only base64 content is read.
    #[error("data URI is not base64")]
    DataNotBase64,
    #[error("bad base64 in data URI")]
    BadBase64 { source: base64::DecodeError },
    /// The file a URI names, inside its folder, could not be read.
    #[error("cannot read '{}'", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
}
