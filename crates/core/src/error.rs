//! The one error type shared by every kinetree crate.

use std::path::PathBuf;

/// Everything that can go wrong in kinetree, typed so that callers can match on it.
///
/// Errors raised while reading a file are wrapped in [`Error::File`], so the message names the
/// file as well as the position inside it.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An error raised while reading or writing `path`.
    #[error("{path}: {source}")]
    File {
        /// The file concerned.
        path: PathBuf,
        /// What went wrong inside it.
        #[source]
        source: Box<Error>,
    },
    /// An operating-system I/O failure.
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// A file whose content does not follow its format; `position` says where (line, byte, field).
    #[error("malformed file at {position}: {message}")]
    Malformed {
        /// Where in the file, e.g. `line 12` or `header`.
        position: String,
        /// What is wrong.
        message: String,
    },
    /// An array of the wrong element type.
    #[error("wrong data type: expected {expected}, found {found}")]
    DType {
        /// The expected type.
        expected: String,
        /// The type found.
        found: String,
    },
    /// An array of the wrong shape.
    #[error("wrong shape: expected {expected}, found {found}")]
    Shape {
        /// The expected shape.
        expected: String,
        /// The shape found.
        found: String,
    },
    /// Some but not all of a point's three coordinates are NaN.
    #[error(
        "frame {frame}, point {point}: partly NaN coordinates (all three must be NaN for an occluded point)"
    )]
    PartialNan {
        /// Frame index (0-based).
        frame: usize,
        /// Point index (0-based).
        point: usize,
    },
    /// An infinite coordinate.
    #[error("frame {frame}, point {point}: infinite coordinate")]
    NonFinite {
        /// Frame index (0-based).
        frame: usize,
        /// Point index (0-based).
        point: usize,
    },
    /// A coordinate so large that squared distances would overflow (no recording in metres
    /// holds one).
    #[error(
        "frame {frame}, point {point}: coordinate {value:e} is beyond +-1e100 (squared distances would overflow); are the tracks in metres?"
    )]
    CoordinateOverflow {
        /// Frame index (0-based).
        frame: usize,
        /// Point index (0-based).
        point: usize,
        /// The coordinate.
        value: f64,
    },
    /// Fewer frames than the method needs.
    #[error("too few frames: {found} (at least {min} needed)")]
    TooFewFrames {
        /// Frames found.
        found: usize,
        /// Frames needed.
        min: usize,
    },
    /// Fewer points than the method needs.
    #[error("too few points: {found} (at least {min} needed)")]
    TooFewPoints {
        /// Points found.
        found: usize,
        /// Points needed.
        min: usize,
    },
    /// Not a single point is visible in any frame.
    #[error("no visible data: every coordinate is NaN")]
    NoVisibleData,
    /// A parameter outside its valid range.
    #[error("invalid parameter `{name}`: {message}")]
    InvalidParameter {
        /// Parameter name, with its unit where it has one.
        name: String,
        /// Why it is invalid.
        message: String,
    },
    /// A model (read from JSON or built by hand) that breaks the schema's rules; `field` is
    /// its path in the JSON, e.g. `joints[2].axis`.
    #[error("invalid model: `{field}` {message}")]
    InvalidModel {
        /// The field's path in the model JSON.
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// Work or memory beyond a limit, refused before anything is allocated.
    #[error("{what}: needs about {estimate}, above the limit of {limit}; {hint}")]
    TooLarge {
        /// What was asked for.
        what: String,
        /// The estimate, with its unit.
        estimate: String,
        /// The limit, with its unit.
        limit: String,
        /// How to raise the limit.
        hint: String,
    },
    /// An experiment or pipeline configuration that cannot be used.
    #[error("configuration error: {0}")]
    Config(String),
    /// Input that is well-formed but from which the method cannot proceed.
    #[error("cannot proceed: {0}")]
    Degenerate(String),
    /// A numerical routine failed (non-convergence, NaN where none may be).
    #[error("numerical failure: {0}")]
    Numerical(String),
}

impl Error {
    /// Wraps `self` with the file it came from.
    pub fn in_file(self, path: impl Into<PathBuf>) -> Error {
        Error::File {
            path: path.into(),
            source: Box::new(self),
        }
    }

    /// The innermost error, looking through [`Error::File`] wrappers.
    pub fn root(&self) -> &Error {
        match self {
            Error::File { source, .. } => source.root(),
            other => other,
        }
    }
}

/// Result with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
