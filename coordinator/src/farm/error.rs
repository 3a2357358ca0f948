//! The farm's refusals: a kind and a message naming the problem. Free of HTTP: the service
//! turns kinds into status codes, the in-process link hands them to its workers as they are.

use std::fmt;

pub use common::error::ErrorKind;

/// Why the farm refused a request.
#[derive(Clone, Debug, PartialEq)]
pub struct FarmError {
    /// What kind of refusal, which the caller acts on.
    pub kind: ErrorKind,
    /// What is wrong, for a person.
    pub message: String,
}

impl FarmError {
    /// A refusal of `kind`.
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        FarmError { kind, message: message.into() }
    }

    /// The request asks for something impossible.
    pub fn invalid(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Invalid, message)
    }

    /// The request cannot be read.
    pub fn malformed(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Malformed, message)
    }

    /// No such thing.
    pub fn not_found(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::NotFound, message)
    }

    /// Too late or twice.
    pub fn conflict(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Conflict, message)
    }

    /// Someone else's.
    pub fn forbidden(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Forbidden, message)
    }

    /// The farm failed, not the request.
    pub fn internal(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Internal, message)
    }
}

impl From<anyhow::Error> for FarmError {
    fn from(e: anyhow::Error) -> Self {
        FarmError::internal(format!("internal error: {e:#}"))
    }
}

impl fmt::Display for FarmError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for FarmError {}

/// A farm answer or its refusal.
pub type FarmResult<T> = Result<T, FarmError>;
