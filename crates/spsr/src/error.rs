//! Errors reported by the library. Every failure a user can cause (bad files, bad parameters,
//! unusable point clouds) is a variant here; the library never panics on user input.

use std::path::PathBuf;

/// Everything that can go wrong in spsr, one variant per stage or validation failure.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The operating system refused a read or write.
    #[error("{}: {source}", path.display())]
    Io {
        /// File concerned.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The file's content is malformed (bad header, truncated body, unparsable number, ...).
    #[error("{}: {message}", path.display())]
    Parse {
        /// File concerned.
        path: PathBuf,
        /// What is wrong, with the line or element where known.
        message: String,
    },
    /// The point file has positions but no normals.
    #[error("{}: the points have no normals (nx, ny, nz); spsr needs oriented points", path.display())]
    MissingNormals {
        /// File concerned.
        path: PathBuf,
    },
    /// A parameter is out of its allowed range.
    #[error("invalid parameter {name}: {message}")]
    InvalidParameter {
        /// Parameter name as the command line spells it (e.g. `--depth`).
        name: &'static str,
        /// What is wrong and what is allowed.
        message: String,
    },
    /// Positions and normals (or other per-point arrays) differ in length.
    #[error("length mismatch: {positions} positions but {normals} normals")]
    LengthMismatch {
        /// Number of positions.
        positions: usize,
        /// Number of normals.
        normals: usize,
    },
    /// Not enough usable points to reconstruct anything.
    #[error("too few usable points: {usable} usable, {dropped} dropped (non-finite values or zero-length normals); at least {required} are needed")]
    TooFewPoints {
        /// Points that passed the validity filter.
        usable: usize,
        /// Points that were dropped.
        dropped: usize,
        /// Minimum number of points required.
        required: usize,
    },
    /// The usable points span no volume along any axis (all identical).
    #[error("degenerate input: {0}")]
    Degenerate(String),
    /// The run would need more memory than allowed (`Params::max_memory`, or the memory the
    /// machine has available). Nothing large has been allocated yet.
    #[error("{message}")]
    ResourceLimit {
        /// Estimated peak memory of the run, in bytes.
        estimate: u64,
        /// The limit, in bytes.
        limit: u64,
        /// The deepest `--depth` expected to fit.
        suggested_depth: u32,
        /// The full explanation, with what to do.
        message: String,
    },
    /// A mesh given to a mesh operation (such as [`crate::trim::trim`]) cannot be used: it
    /// lacks the per-vertex data the operation needs, holds non-finite values, refers to
    /// vertices that do not exist, or has no triangles.
    #[error("{0}")]
    InvalidMesh(String),
    /// The output path cannot be used.
    #[error("{}: {message}", path.display())]
    Output {
        /// File concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

impl Error {
    /// The same error with the file `from` called `to` (a temporary copy named after its
    /// source).
    pub(crate) fn with_path(mut self, from: &std::path::Path, to: &std::path::Path) -> Self {
        match &mut self {
            Error::Io { path, .. }
            | Error::Parse { path, .. }
            | Error::MissingNormals { path }
            | Error::Output { path, .. }
                if path == from =>
            {
                *path = to.to_path_buf();
            }
            _ => {}
        }
        self
    }
}

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;
