//! [`Client`]: whom a request counts against in the server's fair shares
//! (view sessions, frames waiting for the render worker, requests a second):
//! the signed-in user when the server authenticates, else the address it
//! comes from. Behind a reverse proxy every viewer has the proxy's address,
//! so with authentication each user has a share of their own; one user on
//! several machines has one.
//!
//! [`RequestRates`]: at most [`RequestRate::per_second`] API requests a
//! second per client, with bursts of [`RequestRate::burst`] (the generic cell
//! rate algorithm of `governor`); beyond it 429 with `Retry-After`.

use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::num::NonZeroU32;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use axum::extract::{ConnectInfo, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use governor::clock::{Clock, DefaultClock};
use governor::{DefaultKeyedRateLimiter, Quota, RateLimiter};

use crate::AppState;
use crate::auth::{Principal, Proof};

/// Whom a request counts against; see the module docs.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Client {
    /// A signed-in user (or API token), by how it signed in and its name.
    User(Arc<str>),
    /// An anonymous client, by address.
    Address(IpAddr),
}

impl Client {
    /// The client `principal`, asking from `address`, counts as.
    pub fn of(principal: &Principal, address: IpAddr) -> Client {
        let kind = match principal.proof {
            Proof::Anonymous => return Client::Address(address),
            Proof::ApiToken => "token",
            Proof::Oidc => "user",
        };
        Client::User(format!("{kind} {}", principal.user).into())
    }
}

impl fmt::Display for Client {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Client::User(name) => f.write_str(name),
            Client::Address(address) => write!(f, "{address}"),
        }
    }
}

impl From<IpAddr> for Client {
    fn from(address: IpAddr) -> Client {
        Client::Address(address)
    }
}

/// How often one client may ask.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RequestRate {
    /// API requests a second, sustained.
    pub per_second: u32,
    /// Requests at once above that.
    pub burst: u32,
}

impl RequestRate {
    /// The defaults, also `serve`'s flags': far above what the web client
    /// asks (a handful of requests when it opens; views go over its
    /// WebSocket), far below what would keep the server from others.
    pub const DEFAULT: RequestRate = RequestRate {
        per_second: 20,
        burst: 100,
    };
}

impl Default for RequestRate {
    fn default() -> RequestRate {
        RequestRate::DEFAULT
    }
}

/// Checks after which clients quiet long enough to be back at a full burst
/// are forgotten, so the table holds only recent clients.
const FORGET_EVERY: u64 = 1024;

/// Every client's request rate; see the module docs.
#[derive(Debug)]
pub struct RequestRates {
    rate: RequestRate,
    limiter: DefaultKeyedRateLimiter<Client>,
    checks: AtomicU64,
}

impl RequestRates {
    /// Rates held to `rate` (values of 0 count as 1).
    pub fn new(rate: RequestRate) -> RequestRates {
        let one = NonZeroU32::MIN;
        let quota = Quota::per_second(NonZeroU32::new(rate.per_second).unwrap_or(one))
            .allow_burst(NonZeroU32::new(rate.burst).unwrap_or(one));
        RequestRates {
            rate,
            limiter: RateLimiter::keyed(quota),
            checks: AtomicU64::new(0),
        }
    }

    /// Counts a request of `client`: `Err` with how long to wait when it is
    /// over its rate.
    pub fn check(&self, client: &Client) -> Result<(), Duration> {
        if self.checks.fetch_add(1, Ordering::Relaxed) % FORGET_EVERY == FORGET_EVERY - 1 {
            self.limiter.retain_recent();
            self.limiter.shrink_to_fit();
        }
        self.limiter
            .check_key(client)
            .map_err(|not_until| not_until.wait_time_from(DefaultClock::default().now()))
    }

    /// Clients with a recent request.
    pub fn clients(&self) -> usize {
        self.limiter.len()
    }
}

/// Middleware (inside authentication): puts the request's [`Client`] in its
/// extensions, or answers 429 with `Retry-After` when the client is over its
/// rate.
pub async fn limit_rate(
    State(state): State<AppState>,
    mut request: Request,
    next: Next,
) -> Response {
    let address = request
        .extensions()
        .get::<ConnectInfo<SocketAddr>>()
        .map_or(IpAddr::from([0, 0, 0, 0]), |c| c.0.ip());
    let client = match request.extensions().get::<Principal>() {
        Some(principal) => Client::of(principal, address),
        None => Client::Address(address),
    };
    if let Err(wait) = state.rates.check(&client) {
        let seconds = wait.as_secs() + u64::from(wait.subsec_nanos() > 0);
        let rate = state.rates.rate;
        let message = format!(
            "{client} is over its rate of {} API requests a second (bursts of {}): retry in \
             {seconds} s",
            rate.per_second, rate.burst
        );
        tracing::debug!("{message}");
        let mut response = (
            StatusCode::TOO_MANY_REQUESTS,
            axum::Json(serde_json::json!({ "error": message })),
        )
            .into_response();
        response
            .headers_mut()
            .insert(header::RETRY_AFTER, HeaderValue::from(seconds.max(1)));
        return response;
    }
    request.extensions_mut().insert(client);
    next.run(request).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_client_over_its_rate_waits_and_others_do_not() {
        let rates = RequestRates::new(RequestRate {
            per_second: 1,
            burst: 3,
        });
        let (a, b) = (
            Client::from(IpAddr::from([10, 0, 0, 1])),
            Client::User("user a".into()),
        );
        for _ in 0..3 {
            assert_eq!(rates.check(&a), Ok(()));
        }
        let wait = rates.check(&a).expect_err("a fourth at once");
        assert!(
            wait > Duration::ZERO && wait <= Duration::from_secs(1),
            "{wait:?}"
        );
        assert_eq!(rates.check(&b), Ok(()), "another client's share is its own");
        assert_eq!(rates.clients(), 2);
    }

    #[test]
    fn users_count_by_name_and_anonymous_clients_by_address() {
        let address = IpAddr::from([10, 0, 0, 7]);
        let mut alice = Principal::anonymous();
        assert_eq!(Client::of(&alice, address), Client::Address(address));
        alice.user = "alice".into();
        alice.proof = Proof::Oidc;
        assert_eq!(Client::of(&alice, address).to_string(), "user alice");
        alice.proof = Proof::ApiToken;
        assert_eq!(Client::of(&alice, address).to_string(), "token alice");
    }
}
