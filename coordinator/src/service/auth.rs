//! Bearer tokens: workers present the shared join token on every request of the worker protocol,
//! users the API token on the user API, each when one is configured. `/`, `/healthz`, `/metrics`
//! and the OpenAPI document stay open (probes and scrapers; the dashboard asks for the token).
//!
//! `DELETE /api/v1/workers/{id}` takes either: with the API token an operator removes any worker
//! (the request is marked [`Operator`]); otherwise it is a worker leaving, which passes with the
//! join token and may remove only itself (`workers.rs` checks the `x-worker-id` header).

use axum::{
    extract::{Request, State},
    http::{header, HeaderValue, Method},
    middleware::Next,
    response::{IntoResponse, Response},
};

use super::AppState;
use crate::farm::{ErrorKind, FarmError};

/// Which token a route needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Realm {
    Open,
    Worker,
    User,
    /// Scene downloads: workers fetch scenes, users may too.
    Either,
    /// Removing a worker: the worker itself (join token) or an operator (API token).
    Leave,
}

/// Marks a request that presented the configured API token on a [`Realm::Leave`] route: an
/// operator, who may remove any worker.
#[derive(Clone, Copy, Debug)]
pub(super) struct Operator;

fn realm(method: &Method, path: &str) -> Realm {
    match path {
        "/" | "/healthz" | "/metrics" | "/api/v1/openapi.json" => return Realm::Open,
        "/api/v1/workers" if method == Method::POST => return Realm::Worker,
        _ => {}
    }
    let one_worker =
        path.strip_prefix("/api/v1/workers/").is_some_and(|id| !id.is_empty() && !id.contains('/'));
    if one_worker && method == Method::DELETE {
        return Realm::Leave;
    }
    if path.starts_with("/api/v1/leases/") || path.starts_with("/api/v1/workers/") {
        Realm::Worker
    } else if path.starts_with("/api/v1/scenes/") && method == Method::GET {
        Realm::Either
    } else if path.starts_with("/api/v1/") {
        Realm::User
    } else {
        Realm::Open
    }
}

/// Equality that takes the same time wherever the strings differ.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn presented(req: &Request) -> Option<&[u8]> {
    let value = req.headers().get(header::AUTHORIZATION)?.as_bytes();
    value.strip_prefix(b"Bearer ").or_else(|| value.strip_prefix(b"bearer "))
}

pub(super) async fn check(State(state): State<AppState>, mut req: Request, next: Next) -> Response {
    match refusal(&state, &req) {
        None => {
            if realm(req.method(), req.uri().path()) == Realm::Leave && is_operator(&state, &req) {
                req.extensions_mut().insert(Operator);
            }
            next.run(req).await
        }
        Some(message) => {
            let mut resp = FarmError::new(ErrorKind::Unauthorized, message).into_response();
            resp.headers_mut().insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
            resp
        }
    }
}

/// Whether `req` presents the API token, and the coordinator has one.
fn is_operator(state: &AppState, req: &Request) -> bool {
    let api = &state.config.api_token;
    api.as_ref().is_some_and(|t| presented(req).is_some_and(|p| same(p, t.as_bytes())))
}

/// Why `req` may not pass, if it may not.
fn refusal(state: &AppState, req: &Request) -> Option<&'static str> {
    let (join, api) = (&state.config.join_token, &state.config.api_token);
    let given = presented(req);
    let ok = |token: &Option<String>| match token {
        None => true,
        Some(t) => given.is_some_and(|p| same(p, t.as_bytes())),
    };
    match realm(req.method(), req.uri().path()) {
        Realm::Open => None,
        Realm::Worker if !ok(join) => Some(if given.is_some() {
            "join token refused: the worker's --token (RENDERFARM_TOKEN) does not match the coordinator's"
        } else {
            "this coordinator needs a join token: start the worker with --token (or RENDERFARM_TOKEN)"
        }),
        Realm::User if !ok(api) => {
            Some("missing or wrong API token: send Authorization: Bearer <the coordinator's --api-token>")
        }
        Realm::Either if !ok(join) && !ok(api) => {
            Some("missing or wrong token: send Authorization: Bearer <join or API token>")
        }
        Realm::Leave if !is_operator(state, req) && !ok(join) => Some(if given.is_some() {
            "token refused: a worker leaves with the join token, an operator removes a worker with the API token"
        } else {
            "this coordinator needs a token: a worker leaves with the join token (--token), an operator removes a worker with the API token"
        }),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn routes_are_sorted_into_realms() {
        let (get, post, delete) = (Method::GET, Method::POST, Method::DELETE);
        assert_eq!(realm(&get, "/healthz"), Realm::Open);
        assert_eq!(realm(&get, "/metrics"), Realm::Open);
        assert_eq!(realm(&post, "/api/v1/workers"), Realm::Worker);
        assert_eq!(realm(&get, "/api/v1/workers"), Realm::User);
        assert_eq!(realm(&post, "/api/v1/workers/abc/lease"), Realm::Worker);
        assert_eq!(realm(&delete, "/api/v1/workers/abc"), Realm::Leave);
        assert_eq!(realm(&delete, "/api/v1/workers/abc/lease"), Realm::Worker);
        assert_eq!(realm(&delete, "/api/v1/workers/"), Realm::Worker);
        assert_eq!(realm(&post, "/api/v1/leases/l/result"), Realm::Worker);
        assert_eq!(realm(&get, "/api/v1/scenes/abc"), Realm::Either);
        assert_eq!(realm(&post, "/api/v1/scenes"), Realm::User);
        assert_eq!(realm(&delete, "/api/v1/jobs/j"), Realm::User);
        assert_eq!(realm(&get, "/api/v1/jobs/j/frames/0.exr"), Realm::User);
        assert!(same(b"secret", b"secret") && !same(b"secret", b"secreT") && !same(b"a", b"ab"));
    }
}
