//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong when writing frames to disk.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// Creating, writing or flushing a file failed.
    #[error("I/O error on {}: {source}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The PNG encoder failed (this includes I/O errors raised while encoding).
    #[error("PNG encoding of {} failed: {source}", path.display())]
    Png {
        /// The file being written.
        path: PathBuf,
        /// The underlying error.
        source: png::EncodingError,
    },
    /// The GIF encoder failed (this includes I/O errors raised while encoding).
    #[error("GIF encoding of {} failed: {source}", path.display())]
    Gif {
        /// The file being written.
        path: PathBuf,
        /// The underlying error.
        source: gif::EncodingError,
    },
    /// A [`Frame`](crate::Frame) is inconsistent (buffer length is not
    /// `width * height * 3`) or does not fit the output (e.g. a GIF of another size).
    #[error("invalid frame: {0}")]
    InvalidFrame(String),
    /// A parameter is out of range (e.g. a non-positive frame rate, or a size the
    /// format cannot store).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}
