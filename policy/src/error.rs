//! The crate's error type.

/// Everything that can go wrong in `policy`: bad shapes, bad configs, bad weight files,
/// non-finite training values.
#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    /// A state buffer whose length does not match `batch × humans × 13`.
    #[error(
        "state batch holds {len} values, expected batch {batch} × humans {humans} × {} = {expected}",
        crate::FEATURE_DIM
    )]
    StateShape {
        /// Values given.
        len: usize,
        /// Declared batch size.
        batch: usize,
        /// Declared humans per sample.
        humans: usize,
        /// `batch × humans × 13`.
        expected: usize,
    },
    /// A batch with no samples or no humans.
    #[error("empty state batch (batch {batch}, humans {humans}); both must be at least 1")]
    EmptyBatch {
        /// Declared batch size.
        batch: usize,
        /// Declared humans per sample.
        humans: usize,
    },
    /// A side buffer (targets, rewards, output) whose length does not match the batch.
    #[error("{what}: expected {expected} values, got {got}")]
    Length {
        /// Which buffer.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Given length.
        got: usize,
    },
    /// A network description that cannot be built.
    #[error("invalid network config: {0}")]
    Config(String),
    /// A flat parameter vector of the wrong length for the network.
    #[error("parameter vector has {got} values, the {kind} network needs {expected}")]
    ParamCount {
        /// Network kind name.
        kind: &'static str,
        /// Parameters the network has.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// NaN or infinity caught at a chokepoint (loss, gradients, imported weights).
    #[error("non-finite value in {0}")]
    NonFinite(&'static str),
    /// A weight or optimiser file that cannot be decoded.
    #[error("cannot decode {what}: {reason}")]
    Decode {
        /// Which artifact.
        what: &'static str,
        /// Why.
        reason: String,
    },
    /// The dfdx device failed (allocation).
    #[error("dfdx device: {0}")]
    Device(String),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}
