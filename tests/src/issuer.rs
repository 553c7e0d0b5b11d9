//! An OpenID Connect issuer on a loopback port for tests: [`Issuer`] signs
//! access tokens with real keys (RSA for RS256, P-256 for ES256, made by
//! `openssl genpkey`), publishes them as a JWKS, and logs a browser in with
//! the authorization-code flow and PKCE (S256), approving at once as the
//! user it is told to.
//!
//! | route | answer |
//! |---|---|
//! | `GET /.well-known/openid-configuration` | the discovery document |
//! | `GET /jwks` | the public keys, each with its `kid` |
//! | `GET /authorize?…` | a redirect to `redirect_uri` with `code` and `state` |
//! | `POST /token` | the code exchanged, its PKCE verifier checked, for an access token |

use std::collections::HashMap;
use std::process::Command;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{SystemTime, UNIX_EPOCH};

use axum::extract::{Form, Query, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use base64::Engine as _;
use base64::engine::general_purpose::URL_SAFE_NO_PAD;
use jsonwebtoken::jwk::{Jwk, JwkSet};
use jsonwebtoken::{Algorithm, EncodingKey, Header};
use sha2::{Digest, Sha256};
use tokio::net::TcpListener;
use tokio::sync::oneshot;

/// The audience the issuer's tokens name unless told otherwise.
pub const AUDIENCE: &str = "voxserve";
/// The web client's client id at the issuer.
pub const CLIENT_ID: &str = "voxserve-web";

/// One signing key.
struct Key {
    kid: String,
    alg: Algorithm,
    encoding: EncodingKey,
    jwk: Jwk,
}

/// A code handed out by `/authorize`, waiting for `/token`.
struct Grant {
    challenge: String,
    redirect_uri: String,
}

/// What the routes share.
#[derive(Default)]
struct Shared {
    keys: Vec<Key>,
    grants: HashMap<String, Grant>,
    /// Who `/authorize` logs in, with which roles.
    login: (String, Vec<String>),
    issued: u64,
    jwks_reads: u64,
}

/// An issuer on a loopback port, stopped when dropped; see the module docs.
pub struct Issuer {
    /// The issuer's URL (`iss`), `http://127.0.0.1:PORT`.
    pub url: String,
    shared: Arc<Mutex<Shared>>,
    _stop: oneshot::Sender<()>,
}

impl std::fmt::Debug for Issuer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Issuer").field("url", &self.url).finish()
    }
}

/// A private key made by `openssl genpkey` with `args`, as PEM.
fn generate_pem(args: &[&str]) -> Vec<u8> {
    let out = Command::new("openssl")
        .arg("genpkey")
        .args(args)
        .output()
        .expect("openssl genpkey runs (the test issuer's keys; .ci/prereqs installs openssl)");
    assert!(
        out.status.success(),
        "openssl genpkey {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// A new key for `alg` (RS256 or ES256) named `kid`.
fn new_key(alg: Algorithm, kid: &str) -> Key {
    let encoding = match alg {
        Algorithm::RS256 => {
            let pem = generate_pem(&["-algorithm", "RSA", "-pkeyopt", "rsa_keygen_bits:2048"]);
            EncodingKey::from_rsa_pem(&pem).expect("an RSA key")
        }
        Algorithm::ES256 => {
            let pem = generate_pem(&["-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256"]);
            EncodingKey::from_ec_pem(&pem).expect("a P-256 key")
        }
        other => panic!("the test issuer signs RS256 and ES256, not {other:?}"),
    };
    let mut jwk = Jwk::from_encoding_key(&encoding, alg).expect("the key's JWK");
    jwk.common.key_id = Some(kid.to_owned());
    Key {
        kid: kid.to_owned(),
        alg,
        encoding,
        jwk,
    }
}

/// Seconds since the epoch.
pub fn now_s() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

impl Issuer {
    /// Starts an issuer with an RS256 and an ES256 key.
    pub async fn start() -> Issuer {
        Issuer::start_on(TcpListener::bind("127.0.0.1:0").await.expect("bind")).await
    }

    /// [`Issuer::start`] serving on `listener`.
    pub async fn start_on(listener: TcpListener) -> Issuer {
        let url = format!("http://{}", listener.local_addr().expect("address"));
        let shared = Arc::new(Mutex::new(Shared {
            keys: vec![
                new_key(Algorithm::RS256, "rsa-1"),
                new_key(Algorithm::ES256, "ec-1"),
            ],
            login: ("dr.test".into(), vec!["radiology".into()]),
            ..Shared::default()
        }));
        let routes = Router::new()
            .route("/.well-known/openid-configuration", get(discovery))
            .route("/jwks", get(jwks))
            .route("/authorize", get(authorize))
            .route("/token", post(token).options(preflight))
            .with_state((url.clone(), shared.clone()));
        let (stop, stopped) = oneshot::channel::<()>();
        tokio::spawn(async move {
            let _ = axum::serve(listener, routes)
                .with_graceful_shutdown(async {
                    let _ = stopped.await;
                })
                .await;
        });
        Issuer {
            url,
            shared,
            _stop: stop,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Claims of a token for `user` with `roles`: this issuer, the
    /// [`AUDIENCE`], valid for an hour.
    pub fn claims(&self, user: &str, roles: &[&str]) -> serde_json::Value {
        let now = now_s();
        serde_json::json!({
            "iss": self.url,
            "aud": AUDIENCE,
            "sub": format!("sub-{user}"),
            "preferred_username": user,
            "roles": roles,
            "iat": now,
            "exp": now + 3600,
        })
    }

    /// `claims` signed with the issuer's current key for `alg`.
    pub fn sign(&self, alg: Algorithm, claims: &serde_json::Value) -> String {
        let shared = self.lock();
        let key = shared
            .keys
            .iter()
            .rev()
            .find(|k| k.alg == alg)
            .expect("a key for the algorithm");
        let mut header = Header::new(alg);
        header.kid = Some(key.kid.clone());
        jsonwebtoken::encode(&header, claims, &key.encoding).expect("signed")
    }

    /// Replaces the RS256 key with a new one named `kid` (the old one leaves
    /// the JWKS).
    pub fn rotate(&self, kid: &str) {
        let key = new_key(Algorithm::RS256, kid);
        let mut shared = self.lock();
        shared.keys.retain(|k| k.alg != Algorithm::RS256);
        shared.keys.push(key);
    }

    /// A token signed by a key the issuer never published, named as its
    /// current RS256 key: a forgery.
    pub fn forge(&self, claims: &serde_json::Value) -> String {
        let kid = {
            let shared = self.lock();
            let key = shared.keys.iter().find(|k| k.alg == Algorithm::RS256);
            key.expect("an RSA key").kid.clone()
        };
        let stranger = new_key(Algorithm::RS256, &kid);
        let mut header = Header::new(Algorithm::RS256);
        header.kid = Some(kid);
        jsonwebtoken::encode(&header, claims, &stranger.encoding).expect("signed")
    }

    /// How a server checks this issuer's tokens: keys from its discovery
    /// document, the [`AUDIENCE`], the web client as [`CLIENT_ID`].
    pub fn config(&self) -> server::auth::OidcConfig {
        server::auth::OidcConfig {
            issuer: self.url.clone(),
            audience: AUDIENCE.into(),
            jwks: server::auth::oidc::JwksSource::Discovery,
            client_id: Some(CLIENT_ID.into()),
            scopes: "openid profile".into(),
        }
    }

    /// Who `/authorize` logs in from now on.
    pub fn log_in_as(&self, user: &str, roles: &[&str]) {
        self.lock().login = (
            user.to_owned(),
            roles.iter().map(|&r| r.to_owned()).collect(),
        );
    }

    /// How many access tokens `/token` has issued.
    pub fn issued(&self) -> u64 {
        self.lock().issued
    }

    /// How many times the JWKS was read.
    pub fn jwks_reads(&self) -> u64 {
        self.lock().jwks_reads
    }
}

type Ctx = State<(String, Arc<Mutex<Shared>>)>;

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(PoisonError::into_inner)
}

async fn discovery(State((url, _)): Ctx) -> Json<serde_json::Value> {
    Json(serde_json::json!({
        "issuer": url,
        "jwks_uri": format!("{url}/jwks"),
        "authorization_endpoint": format!("{url}/authorize"),
        "token_endpoint": format!("{url}/token"),
        "response_types_supported": ["code"],
        "code_challenge_methods_supported": ["S256"],
        "id_token_signing_alg_values_supported": ["RS256", "ES256"],
    }))
}

async fn jwks(State((_, shared)): Ctx) -> Json<JwkSet> {
    let mut shared = lock(&shared);
    shared.jwks_reads += 1;
    Json(JwkSet {
        keys: shared.keys.iter().map(|k| k.jwk.clone()).collect(),
    })
}

fn bad(message: &str) -> Response {
    (
        StatusCode::BAD_REQUEST,
        Json(serde_json::json!({"error": message})),
    )
        .into_response()
}

async fn authorize(
    State((_, shared)): Ctx,
    Query(query): Query<HashMap<String, String>>,
) -> Response {
    let get = |name: &str| query.get(name).cloned().unwrap_or_default();
    if get("response_type") != "code" || get("client_id") != CLIENT_ID {
        return bad("expected response_type=code and the web client's client_id");
    }
    if get("code_challenge_method") != "S256" || get("code_challenge").len() != 43 {
        return bad("expected a PKCE S256 code_challenge");
    }
    let redirect_uri = get("redirect_uri");
    let code = format!("code-{}", lock(&shared).grants.len() + 1);
    lock(&shared).grants.insert(
        code.clone(),
        Grant {
            challenge: get("code_challenge"),
            redirect_uri: redirect_uri.clone(),
        },
    );
    let sep = if redirect_uri.contains('?') { '&' } else { '?' };
    let state = get("state");
    Redirect::to(&format!("{redirect_uri}{sep}code={code}&state={state}")).into_response()
}

const CORS: [(header::HeaderName, &str); 2] = [
    (header::ACCESS_CONTROL_ALLOW_ORIGIN, "*"),
    (header::ACCESS_CONTROL_ALLOW_HEADERS, "content-type"),
];

async fn preflight() -> Response {
    (StatusCode::NO_CONTENT, CORS).into_response()
}

async fn token(State((url, shared)): Ctx, Form(form): Form<HashMap<String, String>>) -> Response {
    let get = |name: &str| form.get(name).cloned().unwrap_or_default();
    let grant = lock(&shared).grants.remove(&get("code"));
    let Some(grant) = grant else {
        return (CORS, bad("unknown or used code")).into_response();
    };
    let challenge = URL_SAFE_NO_PAD.encode(Sha256::digest(get("code_verifier").as_bytes()));
    if challenge != grant.challenge || get("redirect_uri") != grant.redirect_uri {
        return (
            CORS,
            bad("the PKCE verifier or redirect_uri does not match"),
        )
            .into_response();
    }
    let (user, roles) = lock(&shared).login.clone();
    let now = now_s();
    let claims = serde_json::json!({
        "iss": url, "aud": AUDIENCE, "sub": format!("sub-{user}"),
        "preferred_username": user, "roles": roles, "iat": now, "exp": now + 3600,
    });
    let signed = {
        let mut shared = lock(&shared);
        shared.issued += 1;
        let key = shared.keys.iter().find(|k| k.alg == Algorithm::ES256);
        let key = key.expect("an EC key");
        let mut header = Header::new(key.alg);
        header.kid = Some(key.kid.clone());
        jsonwebtoken::encode(&header, &claims, &key.encoding)
    };
    match signed {
        Ok(access_token) => (
            CORS,
            Json(serde_json::json!({
                "access_token": access_token, "token_type": "Bearer", "expires_in": 3600,
            })),
        )
            .into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, CORS, e.to_string()).into_response(),
    }
}
