//! Who is asking, and what they may see: [`Auth`].
//!
//! - **Authentication**: a request carries a bearer token, in
//!   `Authorization: Bearer TOKEN`, or, for a WebSocket upgrade from a
//!   browser (which cannot set headers there), as the subprotocol
//!   `bearer.TOKEN` beside `voxserve` in `Sec-WebSocket-Protocol`. A token is
//!   either an OpenID Connect access token (a JWT checked against the
//!   issuer's keys: [`oidc`]) or a static API token for scripts (`vxs_…`,
//!   stored hashed: [`tokens`]). Without either configured, the server is
//!   anonymous: everyone is [`Principal::anonymous`] and sees everything
//!   (`serve` allows that only on loopback).
//! - **Authorization**: per dataset, from the principal's roles, through a
//!   policy file ([`policy`]).
//!
//! A token never lands in a log or an error: errors say why it was refused,
//! not what it held.

pub mod oidc;
pub mod policy;
pub mod tokens;

use std::time::SystemTime;

use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::AppState;
use crate::audit::Outcome;

pub use oidc::{Oidc, OidcConfig};
pub use policy::Policy;
pub use tokens::ApiTokens;

/// The longest token read from a request, bytes.
pub const MAX_TOKEN_BYTES: usize = 16 * 1024;
/// The WebSocket subprotocol of view sessions; a token rides beside it as
/// `bearer.TOKEN`.
pub const SUBPROTOCOL: &str = "voxserve";
/// The prefix of a token in `Sec-WebSocket-Protocol`.
const SUBPROTOCOL_BEARER: &str = "bearer.";

/// How a principal proved who it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Proof {
    /// Nothing: the server has no authentication configured.
    Anonymous,
    /// A static API token.
    ApiToken,
    /// An OpenID Connect access token.
    Oidc,
}

/// Who is asking.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Principal {
    /// The user (`preferred_username`, else the subject), the API token's
    /// name, or `anonymous`.
    pub user: String,
    /// How it was proved.
    pub proof: Proof,
    /// Roles and groups from the token.
    pub roles: Vec<String>,
    /// When the token stops being valid; view sessions end then.
    pub expires: Option<SystemTime>,
}

impl Principal {
    /// Everyone, on a server without authentication.
    pub fn anonymous() -> Principal {
        Principal {
            user: "anonymous".into(),
            proof: Proof::Anonymous,
            roles: Vec::new(),
            expires: None,
        }
    }
}

/// Why a request's credentials were refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AuthError {
    /// No token: 401.
    #[error(
        "authentication required: send an access token (Authorization: Bearer TOKEN; for a WebSocket, the subprotocol bearer.TOKEN)"
    )]
    Missing,
    /// A token that is malformed, expired, from another issuer or audience,
    /// or whose signature does not verify: 401. The reason never quotes the
    /// token.
    #[error("access token refused: {0}")]
    Refused(String),
    /// The issuer's keys cannot be read: 503.
    #[error("access tokens cannot be checked now: {0}")]
    Unavailable(String),
}

impl AuthError {
    /// The error code of RFC 6750 for `WWW-Authenticate`.
    fn code(&self) -> Option<&'static str> {
        match self {
            AuthError::Missing | AuthError::Unavailable(_) => None,
            AuthError::Refused(_) => Some("invalid_token"),
        }
    }
}

impl IntoResponse for AuthError {
    fn into_response(self) -> Response {
        let status = match self {
            AuthError::Missing | AuthError::Refused(_) => StatusCode::UNAUTHORIZED,
            AuthError::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
        };
        let challenge = match self.code() {
            Some(code) => format!(r#"Bearer realm="voxserve", error="{code}""#),
            None => r#"Bearer realm="voxserve""#.to_owned(),
        };
        let body = axum::Json(serde_json::json!({ "error": self.to_string() }));
        let mut response = (status, body).into_response();
        if status == StatusCode::UNAUTHORIZED
            && let Ok(value) = HeaderValue::from_str(&challenge)
        {
            response
                .headers_mut()
                .insert(header::WWW_AUTHENTICATE, value);
        }
        response
    }
}

/// How the server authenticates and authorizes; see the module docs.
#[derive(Debug, Default)]
pub struct Auth {
    /// The OpenID Connect issuer whose access tokens are accepted.
    pub oidc: Option<Oidc>,
    /// The static API tokens accepted.
    pub tokens: Option<ApiTokens>,
    /// Who may see which dataset; without one, every authenticated
    /// principal sees every dataset.
    pub policy: Option<Policy>,
}

impl Auth {
    /// Whether requests must carry a token.
    pub fn required(&self) -> bool {
        self.oidc.is_some() || self.tokens.is_some()
    }

    /// Who sent a request with `headers`.
    ///
    /// # Errors
    /// [`AuthError`]: no token, a refused one, or keys that cannot be read.
    pub async fn authenticate(&self, headers: &HeaderMap) -> Result<Principal, AuthError> {
        if !self.required() {
            return Ok(Principal::anonymous());
        }
        let token = bearer_token(headers)?;
        if token.starts_with(tokens::PREFIX) {
            return match &self.tokens {
                Some(tokens) => tokens.verify(&token),
                None => Err(AuthError::Refused(
                    "API tokens are not accepted by this server".into(),
                )),
            };
        }
        match &self.oidc {
            Some(oidc) => oidc.verify(&token).await,
            None => Err(AuthError::Refused(
                "expected an API token (vxs_…); this server accepts no OpenID Connect tokens"
                    .into(),
            )),
        }
    }

    /// Whether `principal` may see the dataset `id`.
    pub fn may_see(&self, principal: &Principal, id: &str) -> bool {
        match (&self.policy, principal.proof) {
            (_, Proof::Anonymous) | (None, _) => true,
            (Some(policy), _) => policy.allows(&principal.roles, id),
        }
    }

    /// Whether a denied dataset answers 404, as if it did not exist.
    pub fn hides_denied(&self) -> bool {
        self.policy.as_ref().is_some_and(|p| p.hide_denied)
    }

    /// Whether `principal` may read `/metrics`.
    pub fn may_read_metrics(&self, principal: &Principal) -> bool {
        has_role(principal, &policy::metrics_roles(self.policy.as_ref()))
    }

    /// Whether `principal` may store studies (STOW-RS).
    pub fn may_store(&self, principal: &Principal) -> bool {
        has_role(principal, &policy::store_roles(self.policy.as_ref()))
    }

    /// Whether `principal` may search and open studies from the PACS.
    pub fn may_use_pacs(&self, principal: &Principal) -> bool {
        has_role(principal, &policy::pacs_roles(self.policy.as_ref()))
    }

    /// What the web client needs to log in, for `GET /api/auth`.
    pub fn describe(&self) -> serde_json::Value {
        serde_json::json!({
            "required": self.required(),
            "oidc": self.oidc.as_ref().map(Oidc::describe),
            "api_tokens": self.tokens.is_some(),
        })
    }
}

/// A file `serve` reads (API tokens, policy) that cannot be used: the flag
/// naming it, the file, and what is wrong, down to the entry and field.
#[derive(Debug, thiserror::Error)]
#[error("{flag} {path}: {message}")]
pub struct FileError {
    flag: &'static str,
    path: String,
    message: String,
}

/// `parse` of the text of the file at `path` (which `flag` names), read
/// only if it is at most `limit` bytes.
fn load_file<T>(
    flag: &'static str,
    path: &std::path::Path,
    limit: u64,
    parse: impl FnOnce(&str) -> Result<T, String>,
) -> Result<T, FileError> {
    read_bounded(path, limit)
        .and_then(|text| parse(&text))
        .map_err(|message| FileError {
            flag,
            path: path.display().to_string(),
            message,
        })
}

/// The text of the file at `path`, if it is at most `limit` bytes of UTF-8.
fn read_bounded(path: &std::path::Path, limit: u64) -> Result<String, String> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| format!("cannot open: {e}"))?;
    let mut text = String::new();
    file.take(limit + 1)
        .read_to_string(&mut text)
        .map_err(|e| format!("cannot read as UTF-8 text: {e}"))?;
    if text.len() as u64 > limit {
        return Err(format!("larger than {limit} bytes"));
    }
    Ok(text)
}

/// The token a request carries: `Authorization: Bearer`, else a
/// `bearer.TOKEN` subprotocol.
fn bearer_token(headers: &HeaderMap) -> Result<String, AuthError> {
    if let Some(value) = headers.get(header::AUTHORIZATION) {
        let text = value
            .to_str()
            .map_err(|_| AuthError::Refused("the Authorization header is not ASCII text".into()))?;
        let (scheme, token) = text.split_once(' ').unwrap_or((text, ""));
        if !scheme.eq_ignore_ascii_case("bearer") {
            return Err(AuthError::Refused(
                "the Authorization header's scheme: expected Bearer".into(),
            ));
        }
        return checked_token(token.trim());
    }
    for value in headers.get_all(header::SEC_WEBSOCKET_PROTOCOL) {
        let Ok(text) = value.to_str() else { continue };
        for protocol in text.split(',').map(str::trim) {
            if let Some(token) = protocol.strip_prefix(SUBPROTOCOL_BEARER) {
                return checked_token(token);
            }
        }
    }
    Err(AuthError::Missing)
}

/// `token` if it is of a length and alphabet a token can have.
fn checked_token(token: &str) -> Result<String, AuthError> {
    if token.is_empty() {
        return Err(AuthError::Refused("the token is empty".into()));
    }
    if token.len() > MAX_TOKEN_BYTES {
        return Err(AuthError::Refused(format!(
            "the token is longer than {MAX_TOKEN_BYTES} bytes"
        )));
    }
    let allowed = |c: char| c.is_ascii_alphanumeric() || "-_.~+/=".contains(c);
    if !token.chars().all(allowed) {
        return Err(AuthError::Refused(
            "the token holds characters no token has (expected base64url and dots)".into(),
        ));
    }
    Ok(token.to_owned())
}

/// Middleware: authenticates every request it wraps, puts the
/// [`Principal`] in the request's extensions, or answers 401 (503 when the
/// issuer's keys cannot be read) and records the refusal in the audit log.
pub async fn require(State(state): State<AppState>, mut request: Request, next: Next) -> Response {
    match state.auth.authenticate(request.headers()).await {
        Ok(principal) => {
            request.extensions_mut().insert(principal);
            next.run(request).await
        }
        Err(error) => {
            let client = request
                .extensions()
                .get::<axum::extract::ConnectInfo<std::net::SocketAddr>>()
                .map(|c| c.0.ip());
            state.audit.record(
                &crate::audit::Event::new("authenticate", None, client, Outcome::Denied)
                    .resource(request.uri().path())
                    .detail(error.to_string()),
            );
            error.into_response()
        }
    }
}

/// Whether `principal` has one of `allowed` (anonymous access, where the
/// server needs no authentication, has them all).
fn has_role(principal: &Principal, allowed: &[String]) -> bool {
    match principal.proof {
        Proof::Anonymous => true,
        _ => principal.roles.iter().any(|r| allowed.contains(r)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(&'static str, &str)]) -> HeaderMap {
        let mut map = HeaderMap::new();
        for (name, value) in pairs {
            map.append(*name, HeaderValue::from_str(value).expect("header value"));
        }
        map
    }

    #[test]
    fn the_token_comes_from_the_authorization_header_or_the_subprotocol() {
        let h = headers(&[("authorization", "Bearer abc.def.ghi")]);
        assert_eq!(bearer_token(&h), Ok("abc.def.ghi".into()));
        let h = headers(&[("authorization", "bearer  vxs_0123")]);
        assert_eq!(bearer_token(&h), Ok("vxs_0123".into()));
        let h = headers(&[("sec-websocket-protocol", "voxserve, bearer.abc.def.ghi")]);
        assert_eq!(bearer_token(&h), Ok("abc.def.ghi".into()));
        assert_eq!(bearer_token(&HeaderMap::new()), Err(AuthError::Missing));
        let h = headers(&[("sec-websocket-protocol", "voxserve")]);
        assert_eq!(bearer_token(&h), Err(AuthError::Missing));
    }

    #[test]
    fn malformed_credentials_are_refused_without_quoting_them() {
        for (value, expected) in [
            ("Basic dXNlcjpwYXNz", "scheme"),
            ("Bearer ", "empty"),
            ("Bearer a\"b", "characters"),
        ] {
            let error = bearer_token(&headers(&[("authorization", value)])).expect_err(value);
            let text = error.to_string();
            assert!(text.contains(expected), "{value}: {text}");
            assert!(
                !text.contains("dXNlcjpwYXNz") && !text.contains("a\"b"),
                "{text}"
            );
        }
        let long = format!("Bearer {}", "a".repeat(MAX_TOKEN_BYTES + 1));
        let error = bearer_token(&headers(&[("authorization", &long)])).expect_err("long");
        assert!(error.to_string().contains("longer than"), "{error}");
    }

    #[test]
    fn without_authentication_everyone_is_anonymous_and_sees_everything() {
        let auth = Auth::default();
        assert!(!auth.required());
        let principal = futures_util::FutureExt::now_or_never(auth.authenticate(&HeaderMap::new()))
            .expect("no await")
            .expect("anonymous");
        assert_eq!(principal, Principal::anonymous());
        assert!(auth.may_see(&principal, "anything"));
        assert!(auth.may_read_metrics(&principal));
    }
}
