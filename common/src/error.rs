//! The kinds of refusal in the farm protocol, shared by the coordinator, which refuses, and the
//! worker, which acts on the kind (joins again, drops a lost lease, retries later).
//!
//! Each kind's HTTP status is written once, in [`HTTP_STATUSES`], for the two HTTP ends: the
//! coordinator's service and the worker's HTTP link. The in-process link passes kinds as they
//! are, and the farm itself never sees a status code.

use std::fmt;

/// What kind of refusal an answer is. The message that comes with it names the problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// The request can be read but asks for something impossible: bad settings, a scene that
    /// does not load, a result that does not answer its task.
    Invalid,
    /// The request cannot be read: a body cut short, an undecodable result, a missing header,
    /// an unknown query parameter.
    Malformed,
    /// No such scene, job, frame, worker or endpoint.
    NotFound,
    /// The request came too late or twice: a lease that is not live (expired, answered, its
    /// job ended), a job that already ended.
    Conflict,
    /// The lease belongs to another worker.
    Forbidden,
    /// A missing or wrong token.
    Unauthorized,
    /// The body is over the size limit.
    TooLarge,
    /// The body's Content-Type is not one this request takes, or does not match the body.
    UnsupportedMediaType,
    /// The endpoint exists but not with this method.
    MethodNotAllowed,
    /// The coordinator failed (a database write, a file read): not the request's fault, so
    /// asking again later may work.
    Internal,
    /// The coordinator is at a limit it sets itself (uploads being received at once): asking
    /// again later will work.
    Busy,
}

/// Every kind with its HTTP status: the one table both HTTP ends read.
pub const HTTP_STATUSES: [(ErrorKind, u16); 11] = [
    (ErrorKind::Malformed, 400),
    (ErrorKind::Unauthorized, 401),
    (ErrorKind::Forbidden, 403),
    (ErrorKind::NotFound, 404),
    (ErrorKind::MethodNotAllowed, 405),
    (ErrorKind::Conflict, 409),
    (ErrorKind::TooLarge, 413),
    (ErrorKind::UnsupportedMediaType, 415),
    (ErrorKind::Invalid, 422),
    (ErrorKind::Internal, 500),
    (ErrorKind::Busy, 503),
];

impl ErrorKind {
    /// A short name for messages and logs.
    pub fn name(self) -> &'static str {
        match self {
            ErrorKind::Invalid => "invalid",
            ErrorKind::Malformed => "malformed",
            ErrorKind::NotFound => "not found",
            ErrorKind::Conflict => "conflict",
            ErrorKind::Forbidden => "forbidden",
            ErrorKind::Unauthorized => "unauthorized",
            ErrorKind::TooLarge => "too large",
            ErrorKind::UnsupportedMediaType => "unsupported media type",
            ErrorKind::MethodNotAllowed => "method not allowed",
            ErrorKind::Internal => "internal error",
            ErrorKind::Busy => "busy",
        }
    }

    /// The HTTP status that carries this kind.
    pub fn http_status(self) -> u16 {
        HTTP_STATUSES.iter().find(|(k, _)| *k == self).map_or(500, |&(_, s)| s)
    }

    /// The kind an HTTP error status carries. A 4xx status of no kind (a proxy's 408 or 429,
    /// say) is a [`ErrorKind::Malformed`] request; anything else is [`ErrorKind::Internal`], so
    /// that a proxy's 502 or 504 reads as the coordinator's trouble, not the request's.
    pub fn from_http_status(status: u16) -> ErrorKind {
        match HTTP_STATUSES.iter().find(|&&(_, s)| s == status) {
            Some(&(kind, _)) => kind,
            None if (400..500).contains(&status) => ErrorKind::Malformed,
            None => ErrorKind::Internal,
        }
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_has_one_status_and_reads_back_from_it() {
        for (kind, status) in HTTP_STATUSES {
            assert_eq!(kind.http_status(), status);
            assert_eq!(ErrorKind::from_http_status(status), kind);
        }
        let mut statuses: Vec<u16> = HTTP_STATUSES.iter().map(|&(_, s)| s).collect();
        statuses.sort_unstable();
        statuses.dedup();
        assert_eq!(statuses.len(), HTTP_STATUSES.len(), "two kinds share a status");
    }

    #[test]
    fn statuses_of_no_kind_keep_their_class() {
        assert_eq!(ErrorKind::from_http_status(429), ErrorKind::Malformed);
        assert_eq!(ErrorKind::from_http_status(408), ErrorKind::Malformed);
        assert_eq!(ErrorKind::from_http_status(502), ErrorKind::Internal);
        assert_eq!(ErrorKind::from_http_status(504), ErrorKind::Internal);
    }
}
