//! Library errors: every variant names the file (and where it can, the field) so a
//! bad scene produces one readable line instead of a panic.
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{}: {cause}", path.display())]
    Io {
        path: PathBuf,
        cause: std::io::Error,
    },
    /// A value in a scene or asset file is present but wrong.
    #[error("{}: {field}: {msg}", path.display())]
    Field {
        path: PathBuf,
        field: String,
        msg: String,
    },
    /// A file that could not be parsed at all (syntax, truncated, wrong format).
    #[error("{}: {msg}", path.display())]
    Format { path: PathBuf, msg: String },
    /// No adapter, a device that could not be opened or was lost, a GPU buffer too large.
    #[error("GPU: {0}")]
    Gpu(String),
    #[error("{0}")]
    Other(String),
}

impl Error {
    pub fn io(path: &Path, cause: std::io::Error) -> Self {
        Error::Io {
            path: path.to_path_buf(),
            cause,
        }
    }
    pub fn field(path: &Path, field: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Field {
            path: path.to_path_buf(),
            field: field.into(),
            msg: msg.into(),
        }
    }
    pub fn format(path: &Path, msg: impl Into<String>) -> Self {
        Error::Format {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, Error>;
