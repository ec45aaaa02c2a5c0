//! The error type of the I/O crate.

use std::path::PathBuf;
use thiserror::Error;

/// What reading or writing a file can go wrong with. Each variant names the file.
#[derive(Debug, Error)]
pub enum IoError {
    /// The file could not be read.
    #[error("{path}: cannot read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// The file or folder could not be written.
    #[error("{path}: cannot write: {source} (check that the folder exists and is writable)")]
    Write {
        /// The file or folder.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// A text file is malformed at a line.
    #[error("{path}:{line}:{column}: {message}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What is wrong there.
        message: String,
    },
    /// An encoder file (one conveyor position per frame) is malformed.
    #[error("{path}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Encoder {
        /// The file.
        path: PathBuf,
        /// 1-based line, when one is at fault.
        line: Option<usize>,
        /// What is wrong and what to write.
        message: String,
    },
    /// A field holds a value that is well-formed but impossible.
    #[error("{path}{}: {field}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// 1-based line of the field, when it could be found.
        line: Option<usize>,
        /// Dotted field name.
        field: String,
        /// What is wrong and what would be right.
        message: String,
    },
    /// A knowledge base is contradictory, incomplete or malformed.
    #[error("knowledge base {dir}: {message}")]
    Knowledge {
        /// Its folder.
        dir: PathBuf,
        /// File, entry and what is wrong.
        message: String,
    },
    /// The inspection history database cannot be used.
    #[error("{path}: {message}")]
    Database {
        /// The database file.
        path: PathBuf,
        /// What is wrong and what to do.
        message: String,
    },
    /// An image file is not a usable image.
    #[error("{path}: {message}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// Runs a third-party image decoder on the file at `path`, turning a panic inside it into [`IoError::Image`]: a
/// damaged file must be refused, never crash the program. The `tiff` crate (0.10) indexes an empty SampleFormat
/// tag while it reads an image's header, and no check before the decoder can see the tag; the image crate's TIFF
/// frames go through it too.
pub(crate) fn decode_guarded<T>(
    path: &std::path::Path,
    decode: impl FnOnce() -> Result<T, IoError>,
) -> Result<T, IoError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(decode)).unwrap_or_else(|_| {
        Err(IoError::Image {
            path: path.to_path_buf(),
            message: "damaged: the decoder failed on its header or data (rewrite the file)"
                .to_string(),
        })
    })
}
