//! Who may reach the server: [`Access`], the names it answers to (the `Host`
//! a request names) and the web origins whose pages may open view sessions.
//!
//! - **Host** (every request): an IP address, `localhost`, or one of
//!   [`Access::host_names`]. Anything else is answered 421 (misdirected): a
//!   page on another site whose name an attacker points at this server's
//!   address (DNS rebinding) names its own site in `Host`, so it cannot
//!   read from the server.
//! - **Origin** (WebSocket upgrades): browsers send `Origin` with every
//!   WebSocket handshake and the same-origin policy does not apply to
//!   WebSockets, so without this check any page the user visits could open a
//!   view session. A handshake is let in when it has no `Origin` (not from a
//!   browser: scripts, the benchmarks), when its `Origin` names the host the
//!   request went to (the server's own pages), or when it is one of
//!   [`Access::allowed_origins`]; else 403.
//! - **Client address**: the connection's peer, or, where the peer is one of
//!   [`Access::trusted_proxies`] (a load balancer), the address its
//!   `X-Forwarded-For` names ([`crate::listen::forwarded_client`]): what
//!   the audit trail records and per-client limits count.
//! - **Response headers** (every response, [`security_headers`]): a
//!   Content-Security-Policy that lets the web client load only its own
//!   scripts, styles and images and talk only to this server and the
//!   OpenID issuer, with `frame-ancestors` from
//!   [`Access::frame_ancestors`] (`'none'` unless configured, for
//!   embedding in a record system); `X-Content-Type-Options: nosniff`;
//!   `Referrer-Policy: no-referrer` (a launch URL's token never leaves in a
//!   `Referer`); and over TLS, `Strict-Transport-Security`.

use std::net::IpAddr;

use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, Uri, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::AppState;
use crate::listen::ConnectionLimits;

/// Who may reach the server; see the module docs.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Access {
    /// Host names the server answers to besides IP addresses and
    /// `localhost`, lower-case, without port.
    pub host_names: Vec<String>,
    /// Web origins (`https://viewer.example.org`) whose pages may open view
    /// sessions besides the server's own, lower-case, without a trailing `/`.
    pub allowed_origins: Vec<String>,
    /// How many connections the server keeps, and for how long.
    pub connections: ConnectionLimits,
    /// Sources that may embed the web client in a frame
    /// (`https://emr.example.org`); none: it may not be framed.
    pub frame_ancestors: Vec<String>,
    /// How often one client may call the API.
    pub requests: crate::client::RequestRate,
    /// Load balancers and reverse proxies whose `X-Forwarded-For` names
    /// the client ([`crate::listen::forwarded_client`]); their own
    /// connections are not capped per client: addresses and networks.
    pub trusted_proxies: Vec<ipnet::IpNet>,
}

/// Why a request was not let in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refused {
    /// The `Host` is not a name of this server: 421.
    #[error("{0}")]
    Host(String),
    /// The `Origin` may not open view sessions: 403.
    #[error("{0}")]
    Origin(String),
}

impl IntoResponse for Refused {
    fn into_response(self) -> Response {
        let status = match self {
            Refused::Host(_) => StatusCode::MISDIRECTED_REQUEST,
            Refused::Origin(_) => StatusCode::FORBIDDEN,
        };
        let body = axum::Json(serde_json::json!({ "error": self.to_string() }));
        (status, body).into_response()
    }
}

/// The host part of an authority (`name`, `name:port`, `[v6]:port`),
/// lower-case.
fn host_of(authority: &str) -> String {
    let host = match authority.strip_prefix('[') {
        Some(rest) => rest.split(']').next().unwrap_or(rest),
        None => authority
            .rsplit_once(':')
            .map_or(authority, |(host, _)| host),
    };
    host.to_ascii_lowercase()
}

/// `text` as quoted in a refusal: at most 80 characters.
fn quoted(text: &str) -> String {
    let cut: String = text.chars().take(80).collect();
    format!("{cut:?}")
}

impl Access {
    /// The authority (`host[:port]`) a request with `uri` and `headers`
    /// went to: HTTP/2's `:authority`, else the `Host` header.
    pub fn authority<'a>(uri: &'a Uri, headers: &'a HeaderMap) -> Option<&'a str> {
        uri.authority()
            .map(axum::http::uri::Authority::as_str)
            .or_else(|| headers.get(header::HOST)?.to_str().ok())
    }

    /// Whether `request` names a host of this server.
    ///
    /// # Errors
    /// [`Refused::Host`], naming the host and what was expected.
    pub fn check_host(&self, request: &Request) -> Result<(), Refused> {
        let Some(authority) = Access::authority(request.uri(), request.headers()) else {
            return Err(Refused::Host(
                "the request names no host (Host header): expected this server's name".into(),
            ));
        };
        let host = host_of(authority);
        if host == "localhost" || host.parse::<IpAddr>().is_ok() || self.host_names.contains(&host)
        {
            return Ok(());
        }
        let mut names = vec!["an IP address".to_owned(), "localhost".to_owned()];
        names.extend(self.host_names.iter().cloned());
        Err(Refused::Host(format!(
            "Host {}: not a name of this server; expected {} (serve --host-name adds names)",
            quoted(authority),
            names.join(", ")
        )))
    }

    /// Whether a WebSocket handshake with `uri` and `headers` may open a
    /// view session.
    ///
    /// # Errors
    /// [`Refused::Origin`], naming the origin and what was expected.
    pub fn check_origin(&self, uri: &Uri, headers: &HeaderMap) -> Result<(), Refused> {
        let Some(origin) = headers.get(header::ORIGIN) else {
            return Ok(());
        };
        let origin = origin.to_str().unwrap_or("").trim_end_matches('/');
        let lower = origin.to_ascii_lowercase();
        let authority = Access::authority(uri, headers).map(str::to_ascii_lowercase);
        let own = lower
            .split_once("://")
            .map(|(_, rest)| rest)
            .is_some_and(|rest| Some(rest) == authority.as_deref());
        if own || self.allowed_origins.contains(&lower) {
            return Ok(());
        }
        Err(Refused::Origin(format!(
            "Origin {}: pages of that site may not open view sessions; expected this server's own \
             pages{} (serve --allow-origin adds origins)",
            quoted(origin),
            if self.allowed_origins.is_empty() {
                String::new()
            } else {
                format!(" or {}", self.allowed_origins.join(", "))
            }
        )))
    }
}

impl Access {
    /// The Content-Security-Policy of every response, the web client
    /// talking to the OpenID issuer at `issuer_origins`.
    pub fn content_security_policy(&self, issuer_origins: &[String]) -> String {
        let issuer = issuer_origins
            .iter()
            .map(|o| format!(" {o}"))
            .collect::<String>();
        let ancestors = if self.frame_ancestors.is_empty() {
            "'none'".to_owned()
        } else {
            self.frame_ancestors.join(" ")
        };
        format!(
            "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; \
             connect-src 'self'{issuer}; form-action 'self'{issuer}; base-uri 'none'; \
             frame-ancestors {ancestors}"
        )
    }
}

/// How long browsers keep to TLS once told (`Strict-Transport-Security`).
const HSTS: &str = "max-age=31536000";

/// Middleware: the security headers of the module docs on every response.
pub async fn security_headers(
    State(state): State<AppState>,
    request: Request,
    next: Next,
) -> Response {
    let mut response = next.run(request).await;
    let headers = response.headers_mut();
    let issuer = state
        .auth
        .oidc
        .as_ref()
        .map(crate::auth::Oidc::endpoint_origins)
        .unwrap_or_default();
    if let Ok(csp) = HeaderValue::from_str(&state.access.content_security_policy(&issuer)) {
        headers.insert(header::CONTENT_SECURITY_POLICY, csp);
    }
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    if state.tls.is_some() {
        headers.insert(
            header::STRICT_TRANSPORT_SECURITY,
            HeaderValue::from_static(HSTS),
        );
    }
    response
}

/// Middleware: refuses requests whose `Host` is not a name of this server.
pub async fn host_guard(State(state): State<AppState>, request: Request, next: Next) -> Response {
    match state.access.check_host(&request) {
        Ok(()) => next.run(request).await,
        Err(refused) => refused.into_response(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(host: &str) -> Request {
        Request::builder()
            .uri("/healthz")
            .header(header::HOST, host)
            .body(axum::body::Body::empty())
            .expect("a request")
    }

    #[test]
    fn hosts_are_addresses_localhost_or_configured_names() {
        let access = Access {
            host_names: vec!["viewer.example.org".into()],
            ..Access::default()
        };
        for host in [
            "127.0.0.1:8080",
            "localhost",
            "LOCALHOST:1",
            "[::1]:8080",
            "10.1.2.3",
            "Viewer.Example.org:443",
        ] {
            assert_eq!(access.check_host(&request(host)), Ok(()), "{host}");
        }
        for host in [
            "evil.example",
            "evil.example:8080",
            "viewer.example.org.evil",
        ] {
            let refused = access.check_host(&request(host)).expect_err(host);
            assert!(
                refused.to_string().contains("not a name of this server"),
                "{refused}"
            );
        }
    }

    #[test]
    fn origins_are_the_server_s_own_or_allowed() {
        let access = Access {
            allowed_origins: vec!["https://pacs.example.org".into()],
            ..Access::default()
        };
        let headers = |origin: Option<&str>| {
            let mut headers = HeaderMap::new();
            headers.insert(header::HOST, HeaderValue::from_static("127.0.0.1:8080"));
            if let Some(origin) = origin {
                headers.insert(
                    header::ORIGIN,
                    HeaderValue::from_str(origin).expect("a header"),
                );
            }
            headers
        };
        for origin in [
            None,
            Some("http://127.0.0.1:8080"),
            Some("https://pacs.example.org"),
            Some("HTTPS://PACS.example.org/"),
        ] {
            let uri = Uri::from_static("/api/stream");
            assert_eq!(
                access.check_origin(&uri, &headers(origin)),
                Ok(()),
                "{origin:?}"
            );
        }
        for origin in [
            "https://evil.example",
            "http://127.0.0.1:9090",
            "null",
            "https://pacs.example.org.evil",
        ] {
            let uri = Uri::from_static("/api/stream");
            let refused = access
                .check_origin(&uri, &headers(Some(origin)))
                .expect_err(origin);
            assert!(refused.to_string().contains("may not open"), "{refused}");
        }
    }
}
