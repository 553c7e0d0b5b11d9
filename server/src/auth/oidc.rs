//! OpenID Connect access tokens: [`Oidc`] checks a JWT's signature against
//! the issuer's published keys (JWKS), and its issuer, audience, expiry and
//! not-before.
//!
//! - **Keys** come from the issuer's discovery document
//!   (`ISSUER/.well-known/openid-configuration`, its `jwks_uri`), or from a
//!   JWKS URL or file given instead. They are kept [`KEYS_FRESH`] and read
//!   again when a token names a key id (`kid`) they lack, at most once per
//!   [`REFRESH_GAP`]: an issuer that rotates its keys is followed without a
//!   restart, and tokens naming made-up key ids cannot make the server
//!   hammer the issuer. A failed refresh keeps the keys there were.
//! - **Algorithms**: the key's own (RS256/384/512, PS256/384/512,
//!   ES256/384, EdDSA); `none` and the HMAC ones (a public key used as a
//!   shared secret) are refused.
//! - **Roles**: the claims `roles`, `groups` and Keycloak's
//!   `realm_access.roles`.

use std::path::PathBuf;
use std::time::{Duration, Instant, UNIX_EPOCH};

use jsonwebtoken::errors::ErrorKind;
use jsonwebtoken::jwk::{Jwk, JwkSet};
use jsonwebtoken::{Algorithm, DecodingKey, Validation};
use tokio::sync::{Mutex, RwLock};

use super::{AuthError, Principal, Proof};

/// How long keys are used before they are read again.
pub const KEYS_FRESH: Duration = Duration::from_secs(600);
/// The shortest time between two reads of the keys.
pub const REFRESH_GAP: Duration = Duration::from_secs(1);
/// Clock difference allowed between issuer and server.
const LEEWAY_S: u64 = 30;
/// The largest discovery document or key set read, bytes.
const MAX_DOCUMENT_BYTES: usize = 1 << 20;
/// How long a request to the issuer may take.
const ISSUER_TIMEOUT: Duration = Duration::from_secs(10);
/// The most roles taken from a token, and the longest.
const MAX_ROLES: usize = 256;
const MAX_ROLE_LEN: usize = 256;

/// Where the issuer's keys come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum JwksSource {
    /// The discovery document's `jwks_uri`.
    Discovery,
    /// A JWKS URL.
    Url(String),
    /// A JWKS file, read again as keys are refreshed.
    File(PathBuf),
}

/// How tokens of one issuer are checked, and how the web client logs in.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OidcConfig {
    /// The issuer (`iss`), an `https://` URL (`http://` on loopback).
    pub issuer: String,
    /// The audience tokens must name (`aud`).
    pub audience: String,
    /// Where the keys come from.
    pub jwks: JwksSource,
    /// The web client's OAuth client id (a public client: authorization
    /// code with PKCE); without it the web client cannot log in itself and
    /// needs a launch URL with `access_token=`.
    pub client_id: Option<String>,
    /// The scopes the web client asks for.
    pub scopes: String,
}

/// The issuer's endpoints from its discovery document.
#[derive(Debug, Clone, Default, serde::Deserialize)]
struct Discovery {
    issuer: String,
    jwks_uri: Option<String>,
    authorization_endpoint: Option<String>,
    token_endpoint: Option<String>,
}

/// The keys and when they were read.
#[derive(Debug)]
struct Keys {
    set: JwkSet,
    read: Instant,
}

/// Checks one issuer's access tokens; see the module docs.
#[derive(Debug)]
pub struct Oidc {
    config: OidcConfig,
    discovery: Discovery,
    keys: RwLock<Keys>,
    /// Held while the keys are read: one read at a time.
    refreshing: Mutex<Instant>,
    client: reqwest::Client,
}

/// The issuer could not be reached, or answered that it cannot serve now
/// (5xx, 429): worth trying again, unlike a wrong answer.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Unreachable(String);

impl Oidc {
    /// [`Oidc::connect`], trying again (after ¼ s, doubling to 5 s) while
    /// the issuer cannot be reached, for up to `patience`: a server may
    /// start before its identity provider. A wrong answer fails at once.
    ///
    /// # Errors
    /// As [`Oidc::connect`]; the last one when the issuer stayed unreachable.
    pub async fn connect_waiting(config: OidcConfig, patience: Duration) -> anyhow::Result<Oidc> {
        let deadline = Instant::now() + patience;
        let mut pause = Duration::from_millis(250);
        loop {
            match Oidc::connect(config.clone()).await {
                Err(e) if e.is::<Unreachable>() && Instant::now() + pause < deadline => {
                    tracing::warn!(
                        "the OpenID Connect issuer cannot be reached yet ({e:#}): trying again in \
                         {pause:?}"
                    );
                    tokio::time::sleep(pause).await;
                    pause = (pause * 2).min(Duration::from_secs(5));
                }
                other => return other,
            }
        }
    }

    /// Reads the issuer's discovery document (unless the keys come from a
    /// file and the web client does not log in) and its keys.
    ///
    /// # Errors
    /// Naming the URL or file and what was wrong with it.
    pub async fn connect(config: OidcConfig) -> anyhow::Result<Oidc> {
        let issuer = config.issuer.trim_end_matches('/');
        let client = reqwest::Client::builder()
            .timeout(ISSUER_TIMEOUT)
            .redirect(reqwest::redirect::Policy::none())
            .build()
            .map_err(|e| anyhow::anyhow!("cannot make an HTTP client for the issuer: {e}"))?;
        let needs_discovery = config.jwks == JwksSource::Discovery || config.client_id.is_some();
        let discovery = if needs_discovery {
            let url = format!("{issuer}/.well-known/openid-configuration");
            let bytes = fetch(&client, &url).await?;
            let discovery: Discovery = serde_json::from_slice(&bytes).map_err(|e| {
                anyhow::anyhow!("{url}: {e}; expected an OpenID Connect discovery document")
            })?;
            if discovery.issuer != config.issuer {
                anyhow::bail!(
                    "{url}: issuer {:?}, expected {:?} (--oidc-issuer must be the issuer exactly as its tokens name it)",
                    discovery.issuer,
                    config.issuer
                );
            }
            discovery
        } else {
            Discovery::default()
        };
        let oidc = Oidc {
            config,
            discovery,
            keys: RwLock::new(Keys {
                set: JwkSet { keys: Vec::new() },
                read: Instant::now(),
            }),
            refreshing: Mutex::new(Instant::now()),
            client,
        };
        let set = oidc.read_keys().await?;
        *oidc.keys.write().await = Keys {
            set,
            read: Instant::now(),
        };
        Ok(oidc)
    }

    /// What the web client needs to log in.
    pub fn describe(&self) -> serde_json::Value {
        serde_json::json!({
            "issuer": self.config.issuer,
            "client_id": self.config.client_id,
            "scopes": self.config.scopes,
            "authorization_endpoint": self.discovery.authorization_endpoint,
            "token_endpoint": self.discovery.token_endpoint,
        })
    }

    /// The origins of the issuer's endpoints the web client talks to (for
    /// the Content-Security-Policy).
    pub fn endpoint_origins(&self) -> Vec<String> {
        [
            &self.discovery.authorization_endpoint,
            &self.discovery.token_endpoint,
        ]
        .into_iter()
        .flatten()
        .filter_map(|url| origin_of(url))
        .collect()
    }

    /// The principal an access token stands for.
    ///
    /// # Errors
    /// [`AuthError::Refused`] with the reason (never the token's content);
    /// [`AuthError::Unavailable`] when the keys cannot be read.
    pub async fn verify(&self, token: &str) -> Result<Principal, AuthError> {
        let header = jsonwebtoken::decode_header(token).map_err(|e| {
            AuthError::Refused(match e.kind() {
                ErrorKind::InvalidToken | ErrorKind::Base64(_) | ErrorKind::Utf8(_) => {
                    "the token is not a well-formed JWT".into()
                }
                _ => "the token's header is malformed or names an algorithm voxserve does not accept (none and unknown ones are refused)".into(),
            })
        })?;
        if !ACCEPTED.contains(&header.alg) {
            return Err(AuthError::Refused(format!(
                "the token's algorithm {:?} is not accepted: expected a public-key signature (RS*, PS*, ES*, EdDSA)",
                header.alg
            )));
        }
        let jwk = self.key(header.kid.as_deref()).await?;
        if let Some(alg) = jwk.common.key_algorithm
            && alg.to_string() != format!("{:?}", header.alg)
        {
            return Err(AuthError::Refused(
                "the token's algorithm is not its key's".into(),
            ));
        }
        let key = DecodingKey::from_jwk(&jwk)
            .map_err(|_| AuthError::Refused("the issuer's key cannot be used".into()))?;
        let mut validation = Validation::new(header.alg);
        validation.leeway = LEEWAY_S;
        validation.validate_nbf = true;
        validation.set_issuer(&[&self.config.issuer]);
        validation.set_audience(&[&self.config.audience]);
        validation.set_required_spec_claims(&["exp", "iss", "aud", "sub"]);
        let data = jsonwebtoken::decode::<serde_json::Value>(token, &key, &validation)
            .map_err(|e| AuthError::Refused(reason(e.kind())))?;
        principal(&data.claims)
    }

    /// The key `kid` names (the only key when the token names none),
    /// reading the keys again when they are stale or lack it.
    async fn key(&self, kid: Option<&str>) -> Result<Jwk, AuthError> {
        {
            let keys = self.keys.read().await;
            if keys.read.elapsed() < KEYS_FRESH
                && let Some(jwk) = pick(&keys.set, kid)?
            {
                return Ok(jwk);
            }
        }
        self.refresh().await;
        let keys = self.keys.read().await;
        pick(&keys.set, kid)?.ok_or_else(|| {
            AuthError::Refused("the token's key id is not one of the issuer's keys".into())
        })
    }

    /// Reads the keys again unless they were read less than
    /// [`REFRESH_GAP`] ago; keeps the old ones if that fails.
    async fn refresh(&self) {
        let mut last = self.refreshing.lock().await;
        if last.elapsed() < REFRESH_GAP {
            return;
        }
        *last = Instant::now();
        match self.read_keys().await {
            Ok(set) => {
                *self.keys.write().await = Keys {
                    set,
                    read: Instant::now(),
                };
            }
            Err(e) => tracing::warn!("keeping the issuer's keys read before: {e:#}"),
        }
    }

    /// The key set from where the configuration says.
    async fn read_keys(&self) -> anyhow::Result<JwkSet> {
        let (bytes, from) = match &self.config.jwks {
            JwksSource::File(path) => {
                let text = super::read_bounded(path, MAX_DOCUMENT_BYTES as u64)
                    .map_err(|e| anyhow::anyhow!("JWKS file {}: {e}", path.display()))?;
                (text.into_bytes(), path.display().to_string())
            }
            JwksSource::Url(url) => (fetch(&self.client, url).await?, url.clone()),
            JwksSource::Discovery => {
                let url = self.discovery.jwks_uri.clone().ok_or_else(|| {
                    anyhow::anyhow!("the issuer's discovery document has no jwks_uri")
                })?;
                (fetch(&self.client, &url).await?, url)
            }
        };
        let set: JwkSet = serde_json::from_slice(&bytes)
            .map_err(|e| anyhow::anyhow!("{from}: {e}; expected a JSON Web Key Set"))?;
        if set.keys.is_empty() {
            anyhow::bail!("{from}: the key set holds no key");
        }
        Ok(set)
    }
}

/// The algorithms accepted: public-key signatures only.
const ACCEPTED: [Algorithm; 9] = [
    Algorithm::RS256,
    Algorithm::RS384,
    Algorithm::RS512,
    Algorithm::PS256,
    Algorithm::PS384,
    Algorithm::PS512,
    Algorithm::ES256,
    Algorithm::ES384,
    Algorithm::EdDSA,
];

/// The key of `set` that `kid` names; with no `kid`, the only key.
fn pick(set: &JwkSet, kid: Option<&str>) -> Result<Option<Jwk>, AuthError> {
    match kid {
        Some(kid) => Ok(set.find(kid).cloned()),
        None if set.keys.len() == 1 => Ok(set.keys.first().cloned()),
        None => Err(AuthError::Refused(
            "the token names no key id (kid) and the issuer has several keys".into(),
        )),
    }
}

/// Why jsonwebtoken refused a token, in words that quote nothing of it.
fn reason(kind: &ErrorKind) -> String {
    match kind {
        ErrorKind::ExpiredSignature => "the token has expired".into(),
        ErrorKind::ImmatureSignature => "the token is not valid yet (nbf)".into(),
        ErrorKind::InvalidIssuer => "the token is from another issuer".into(),
        ErrorKind::InvalidAudience => "the token is for another audience".into(),
        ErrorKind::InvalidSignature => "the token's signature does not verify".into(),
        ErrorKind::InvalidAlgorithm => "the token's algorithm is not its key's".into(),
        ErrorKind::MissingRequiredClaim(claim) => {
            format!("the token lacks the claim {claim:?}")
        }
        _ => "the token is not a well-formed JWT".into(),
    }
}

/// The principal of verified `claims`.
fn principal(claims: &serde_json::Value) -> Result<Principal, AuthError> {
    let text = |name: &str| claims.get(name).and_then(serde_json::Value::as_str);
    let subject =
        text("sub").ok_or_else(|| AuthError::Refused("the token's sub is not a string".into()))?;
    let user = text("preferred_username").unwrap_or(subject);
    let mut roles = Vec::new();
    let lists = [
        claims.get("roles"),
        claims.get("groups"),
        claims.pointer("/realm_access/roles"),
    ];
    for list in lists.into_iter().flatten() {
        let items: Vec<&serde_json::Value> = match list {
            serde_json::Value::Array(items) => items.iter().collect(),
            one @ serde_json::Value::String(_) => vec![one],
            _ => continue,
        };
        for item in items {
            if let Some(role) = item.as_str()
                && role.len() <= MAX_ROLE_LEN
                && roles.len() < MAX_ROLES
                && !roles.iter().any(|r| r == role)
            {
                roles.push(role.to_owned());
            }
        }
    }
    let expires = claims
        .get("exp")
        .and_then(serde_json::Value::as_u64)
        .map(|s| UNIX_EPOCH + Duration::from_secs(s));
    Ok(Principal {
        user: user.chars().take(MAX_ROLE_LEN).collect(),
        proof: Proof::Oidc,
        roles,
        expires,
    })
}

/// `scheme://host[:port]` of `url`.
pub fn origin_of(url: &str) -> Option<String> {
    let (scheme, rest) = url.split_once("://")?;
    let authority = rest.split(['/', '?', '#']).next()?;
    (!authority.is_empty()).then(|| format!("{scheme}://{authority}"))
}

/// The body at `url`, at most [`MAX_DOCUMENT_BYTES`].
async fn fetch(client: &reqwest::Client, url: &str) -> anyhow::Result<Vec<u8>> {
    let mut response = client
        .get(url)
        .header("accept", "application/json")
        .send()
        .await
        .map_err(|e| Unreachable(format!("{url}: {e}")))?;
    let status = response.status();
    if status.is_server_error() || status == reqwest::StatusCode::TOO_MANY_REQUESTS {
        return Err(Unreachable(format!("{url}: HTTP {status}")).into());
    }
    if !status.is_success() {
        anyhow::bail!("{url}: HTTP {status}");
    }
    let mut body = Vec::new();
    while let Some(chunk) = response
        .chunk()
        .await
        .map_err(|e| anyhow::anyhow!("{url}: {e}"))?
    {
        if body.len() + chunk.len() > MAX_DOCUMENT_BYTES {
            anyhow::bail!("{url}: larger than {MAX_DOCUMENT_BYTES} bytes");
        }
        body.extend_from_slice(&chunk);
    }
    Ok(body)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roles_come_from_roles_groups_and_realm_access() {
        let claims = serde_json::json!({
            "sub": "u1", "preferred_username": "dr.who",
            "roles": ["a", "b"], "groups": "c",
            "realm_access": {"roles": ["a", "d", 5]},
            "exp": 4_000_000_000u64,
        });
        let p = principal(&claims).expect("principal");
        assert_eq!(p.user, "dr.who");
        assert_eq!(p.roles, ["a", "b", "c", "d"]);
        assert_eq!(p.proof, Proof::Oidc);
        assert!(p.expires.is_some());
        let p = principal(&serde_json::json!({"sub": "u2"})).expect("principal");
        assert_eq!((p.user.as_str(), p.roles.len()), ("u2", 0));
    }

    #[test]
    fn origins_of_urls() {
        assert_eq!(
            origin_of("https://id.example.org:8443/realms/x/auth?y=1").as_deref(),
            Some("https://id.example.org:8443")
        );
        assert_eq!(origin_of("nonsense"), None);
    }
}
