//! Authentication, authorization, audit, security headers and TLS against a
//! real issuer ([`voxserve_tests::issuer`]: real RS256 and ES256 keys, a
//! JWKS, key rotation) and real TLS (a certificate made here, verified by
//! the client).
//!
//! The servers render on the CPU (no GPU needed).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use base64::Engine as _;
use base64::engine::general_purpose::URL_SAFE_NO_PAD;
use futures_util::StreamExt;
use jsonwebtoken::Algorithm;
use server::audit::Audit;
use server::auth::{ApiTokens, Auth, Oidc, Policy};
use server::stream::StreamSettings;
use server::{AppState, Dataset, RenderService};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::{self, Message};
use voxserve_tests::issuer::{CLIENT_ID, Issuer, now_s};
use voxserve_tests::server::TestServer;

/// The policy of these tests: anyone authenticated sees the phantom,
/// radiology also `ct-secret`, monitoring reads `/metrics`.
const POLICY: &str = r#"{
    "rules": [
        {"roles": ["*"], "datasets": ["phantom"]},
        {"roles": ["radiology"], "datasets": ["ct-*"]}
    ],
    "metrics_roles": ["monitoring"]
}"#;

/// A server on a loopback port, stopped when dropped.
struct Secured {
    base: String,
    audit: PathBuf,
    _dir: tempfile::TempDir,
    _server: TestServer,
}

/// Two datasets: `phantom` and `ct-secret` (the same volume).
fn datasets() -> Vec<Dataset> {
    let phantom = Dataset::phantom(32, 16 << 20).expect("phantom");
    let mut secret = phantom.clone();
    secret.id = "ct-secret".into();
    vec![phantom, secret]
}

/// An issuer, and a server accepting its tokens under `policy`.
async fn with_issuer(policy: Option<&str>) -> (Issuer, Secured) {
    let issuer = Issuer::start().await;
    let oidc = Oidc::connect(issuer.config())
        .await
        .expect("the issuer's discovery document and keys");
    let auth = Auth {
        oidc: Some(oidc),
        policy: policy.map(|text| Policy::parse(text).expect("policy")),
        ..Auth::default()
    };
    let server = start(auth, None).await;
    (issuer, server)
}

/// Starts a server with `auth`, auditing to a file, over `tls` if given.
async fn start(auth: Auth, tls: Option<Arc<server::tls::Tls>>) -> Secured {
    let dir = tempfile::tempdir().expect("temp dir");
    let audit = dir.path().join("audit.jsonl");
    let renderer = RenderService::start(shaders::Backend::Cpu, 64 << 20, 1).expect("renderer");
    let mut state = AppState::new(datasets(), renderer, StreamSettings::default())
        .with_auth(auth, Audit::open(&audit).expect("audit log"));
    if let Some(tls) = tls {
        state = state.with_tls(tls);
    }
    let server = TestServer::serving(state).await;
    Secured {
        base: server.base_url.clone(),
        audit,
        _dir: dir,
        _server: server,
    }
}

/// A GET of `path` with `token` as a bearer token: status, body.
async fn get(base: &str, path: &str, token: Option<&str>) -> (u16, String) {
    let client = reqwest::Client::new();
    let mut request = client.get(format!("{base}{path}"));
    if let Some(token) = token {
        request = request.header("authorization", format!("Bearer {token}"));
    }
    let response = request.send().await.expect("an answer");
    let status = response.status().as_u16();
    if status == 401 {
        let challenge = response.headers().get("www-authenticate");
        assert!(
            challenge.is_some_and(|v| v.to_str().is_ok_and(|v| v.starts_with("Bearer"))),
            "a 401 names the Bearer scheme: {:?}",
            response.headers()
        );
    }
    (status, response.text().await.expect("a body"))
}

/// The ids of the datasets `/api/datasets` lists for `token`.
async fn listed(base: &str, token: &str) -> Vec<String> {
    let (status, body) = get(base, "/api/datasets", Some(token)).await;
    assert_eq!(status, 200, "{body}");
    let list: Vec<serde_json::Value> = serde_json::from_str(&body).expect("JSON");
    list.iter()
        .map(|d| d["id"].as_str().expect("an id").to_owned())
        .collect()
}

/// An unsigned token (`alg: none`) with `claims`.
fn unsigned(claims: &serde_json::Value) -> String {
    let header = URL_SAFE_NO_PAD.encode(br#"{"alg":"none","typ":"JWT"}"#);
    let body = URL_SAFE_NO_PAD.encode(claims.to_string());
    format!("{header}.{body}.")
}

/// The audit log's lines.
fn audit_lines(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path)
        .expect("the audit log")
        .lines()
        .map(|line| serde_json::from_str(line).expect("a JSON line"))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_are_checked_and_datasets_shown_by_role() {
    let (issuer, server) = with_issuer(Some(POLICY)).await;
    let base = &server.base;
    let good = issuer.claims("dr.house", &["radiology"]);
    let with = |changes: serde_json::Value| {
        let mut claims = good.clone();
        for (k, v) in changes.as_object().expect("an object") {
            claims[k] = v.clone();
        }
        claims
    };
    let refused = [
        ("no token", None, "authentication required"),
        (
            "expired",
            Some(issuer.sign(
                Algorithm::RS256,
                &with(serde_json::json!({"exp": now_s() - 3600})),
            )),
            "expired",
        ),
        (
            "wrong issuer",
            Some(issuer.sign(
                Algorithm::RS256,
                &with(serde_json::json!({"iss": "https://evil.example"})),
            )),
            "another issuer",
        ),
        (
            "wrong audience",
            Some(issuer.sign(
                Algorithm::ES256,
                &with(serde_json::json!({"aud": "someone-else"})),
            )),
            "another audience",
        ),
        ("bad signature", Some(issuer.forge(&good)), "signature"),
        ("alg none", Some(unsigned(&good)), "algorithm"),
        (
            "HS256 with a guessed secret",
            Some(
                jsonwebtoken::encode(
                    &jsonwebtoken::Header::new(Algorithm::HS256),
                    &good,
                    &jsonwebtoken::EncodingKey::from_secret(b"secret"),
                )
                .expect("signed"),
            ),
            "not accepted",
        ),
        ("garbage", Some("abc.def.ghi".to_owned()), "malformed"),
        ("not a JWT", Some("abc".to_owned()), "well-formed"),
        (
            "unknown API token",
            Some(format!("vxs_{}", "0".repeat(64))),
            "API tokens",
        ),
    ];
    for (what, token, reason) in &refused {
        for path in [
            "/api/datasets",
            "/api/render?w=16&h=16",
            "/api/settings",
            "/metrics",
        ] {
            let (status, body) = get(base, path, token.as_deref()).await;
            assert_eq!(status, 401, "{what} {path}: {body}");
            assert!(body.contains(reason), "{what}: {body}");
            assert!(
                !body.contains("phantom") && !body.contains("ct-secret"),
                "{body}"
            );
            if let Some(token) = token {
                let signature = token.rsplit('.').next().unwrap_or_default();
                assert!(
                    signature.len() < 8 || !body.contains(signature),
                    "{what}: the answer quotes the token: {body}"
                );
            }
        }
    }

    // The web client's files, /healthz and /api/auth need no token.
    for path in ["/", "/app.js", "/healthz", "/api/auth"] {
        let (status, body) = get(base, path, None).await;
        assert_eq!(status, 200, "{path}: {body}");
    }
    let (_, body) = get(base, "/api/auth", None).await;
    let described: serde_json::Value = serde_json::from_str(&body).expect("JSON");
    assert_eq!(described["required"], true);
    assert_eq!(described["oidc"]["client_id"], CLIENT_ID);
    assert_eq!(
        described["oidc"]["authorization_endpoint"],
        format!("{}/authorize", issuer.url)
    );
    let (_, body) = get(base, "/healthz", None).await;
    assert!(
        !body.contains("adapter"),
        "/healthz tells strangers nothing: {body}"
    );

    // Valid, both algorithms; without the role the secret dataset is out.
    let radiologist = issuer.sign(Algorithm::RS256, &good);
    let nurse = issuer.sign(Algorithm::ES256, &issuer.claims("nurse", &["ward"]));
    assert_eq!(listed(base, &radiologist).await, ["phantom", "ct-secret"]);
    assert_eq!(listed(base, &nurse).await, ["phantom"]);
    for path in [
        "/api/datasets/ct-secret",
        "/api/datasets/ct-secret/render?w=16&h=16",
        "/api/render?dataset=ct-secret&w=16&h=16",
    ] {
        let (status, body) = get(base, path, Some(&nurse)).await;
        assert_eq!(status, 403, "{path}: {body}");
        let (status, body) = get(base, path, Some(&radiologist)).await;
        assert_eq!(status, 200, "{path}: {body}");
    }
    let (status, body) = get(base, "/api/settings", Some(&nurse)).await;
    assert_eq!(status, 200);
    assert!(
        !body.contains("ct-secret"),
        "settings list only what the caller sees"
    );
    let (status, _) = get(base, "/api/render?w=16&h=16", Some(&nurse)).await;
    assert_eq!(
        status, 200,
        "the default dataset is the first the caller may see"
    );
    let (status, body) = get(base, "/metrics", Some(&radiologist)).await;
    assert_eq!(status, 403, "{body}");

    // The audit log: one line per event, with the user.
    let lines = audit_lines(&server.audit);
    let count = |event: &str, user: Option<&str>, outcome: &str| {
        lines
            .iter()
            .filter(|l| {
                l["event"] == event
                    && l["user"].as_str() == user
                    && l["outcome"] == outcome
                    && l["client"] == "127.0.0.1"
            })
            .count()
    };
    assert_eq!(count("authenticate", None, "denied"), refused.len() * 4);
    assert_eq!(count("list", Some("dr.house"), "success"), 1);
    assert_eq!(count("list", Some("nurse"), "success"), 1);
    assert_eq!(count("describe", Some("nurse"), "denied"), 1);
    assert_eq!(count("render", Some("nurse"), "denied"), 2);
    assert_eq!(count("render", Some("nurse"), "success"), 1);
    assert_eq!(count("render", Some("dr.house"), "success"), 2);
    assert_eq!(count("metrics", Some("dr.house"), "denied"), 1);
    for line in &lines {
        let text = line.to_string();
        assert!(
            !text.contains(&radiologist) && !text.contains("w=16"),
            "{text}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rotated_key_is_picked_up_and_the_old_one_dropped() {
    let (issuer, server) = with_issuer(None).await;
    let claims = issuer.claims("dr.rota", &[]);
    let old = issuer.sign(Algorithm::RS256, &claims);
    assert_eq!(get(&server.base, "/api/datasets", Some(&old)).await.0, 200);
    let reads = issuer.jwks_reads();
    issuer.rotate("rsa-2");
    let new = issuer.sign(Algorithm::RS256, &claims);
    // Keys are read again at most once a second: ask until then.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let (status, body) = get(&server.base, "/api/datasets", Some(&new)).await;
        if status == 200 {
            break;
        }
        assert!(body.contains("key id"), "{body}");
        assert!(
            Instant::now() < deadline,
            "the new key was not picked up: {body}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert!(issuer.jwks_reads() > reads);
    let (status, body) = get(&server.base, "/api/datasets", Some(&old)).await;
    assert_eq!(status, 401, "a token of the withdrawn key: {body}");
    // Made-up key ids do not make the server read the keys each time.
    let forged = issuer.forge(&claims);
    let rest: Vec<&str> = forged.split('.').skip(1).collect();
    let reads = issuer.jwks_reads();
    for i in 0..20 {
        let header = URL_SAFE_NO_PAD.encode(format!(r#"{{"alg":"RS256","kid":"made-up-{i}"}}"#));
        let token = format!("{header}.{}", rest.join("."));
        assert_eq!(
            get(&server.base, "/api/datasets", Some(&token)).await.0,
            401
        );
    }
    assert!(
        issuer.jwks_reads() <= reads + 2,
        "20 made-up key ids read the keys {} times",
        issuer.jwks_reads() - reads
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_tokens_work_and_metrics_need_their_role() {
    let (script, script_entry) =
        server::auth::tokens::generate("nightly-export", vec!["radiology".into()]).expect("random");
    let (monitor, monitor_entry) =
        server::auth::tokens::generate("prometheus", vec!["monitoring".into()]).expect("random");
    let auth = Auth {
        tokens: Some(ApiTokens::new(vec![script_entry, monitor_entry]).expect("tokens")),
        policy: Some(Policy::parse(POLICY).expect("policy")),
        ..Auth::default()
    };
    let server = start(auth, None).await;
    let base = &server.base;
    assert_eq!(listed(base, &script).await, ["phantom", "ct-secret"]);
    assert_eq!(listed(base, &monitor).await, ["phantom"]);
    let (status, body) = get(base, "/metrics", Some(&monitor)).await;
    assert_eq!(status, 200, "{body}");
    assert!(body.contains("voxserve_"), "{body}");
    assert_eq!(get(base, "/metrics", Some(&script)).await.0, 403);
    assert_eq!(get(base, "/metrics", None).await.0, 401);
    let (status, body) = get(base, "/api/datasets", Some("eyJhbGciOiJSUzI1NiJ9.e30.c2ln")).await;
    assert_eq!(status, 401);
    assert!(body.contains("no OpenID Connect"), "{body}");
    let lines = audit_lines(&server.audit);
    assert!(
        lines.iter().any(|l| l["event"] == "metrics"
            && l["user"] == "prometheus"
            && l["proof"] == "api_token"),
        "{lines:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn storing_studies_needs_the_store_role() {
    let (viewer, viewer_entry) =
        server::auth::tokens::generate("viewer", vec!["radiology".into()]).expect("random");
    let (modality, modality_entry) =
        server::auth::tokens::generate("ct-scanner", vec!["store".into()]).expect("random");
    let auth = Auth {
        tokens: Some(ApiTokens::new(vec![viewer_entry, modality_entry]).expect("tokens")),
        policy: Some(Policy::parse(POLICY).expect("policy")),
        ..Auth::default()
    };
    let server = start(auth, None).await;
    let stow = |token: Option<&str>| {
        let mut request = reqwest::Client::new()
            .post(format!("{}/dicom-web/studies", server.base))
            .header(
                "content-type",
                "multipart/related; type=\"application/dicom\"; boundary=XX",
            )
            .body("--XX--\r\n");
        if let Some(token) = token {
            request = request.header("authorization", format!("Bearer {token}"));
        }
        request.send()
    };
    assert_eq!(stow(None).await.expect("answer").status().as_u16(), 401);
    let denied = stow(Some(&viewer)).await.expect("answer");
    assert_eq!(denied.status().as_u16(), 403);
    assert!(denied.text().await.expect("body").contains("store role"));
    // Allowed; this server receives nothing (no --receive): it says so.
    let allowed = stow(Some(&modality)).await.expect("answer");
    assert_eq!(allowed.status().as_u16(), 404);
    assert!(allowed.text().await.expect("body").contains("--receive"));
    let lines = audit_lines(&server.audit);
    assert!(
        lines
            .iter()
            .any(|l| l["event"] == "store" && l["user"] == "viewer" && l["outcome"] == "denied"),
        "{lines:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_denied_dataset_can_look_unknown() {
    let tokens = [server::auth::tokens::generate("a", vec!["ward".into()]).expect("random")];
    let policy = POLICY.replace(
        "\"metrics_roles\"",
        "\"hide_denied\": true, \"metrics_roles\"",
    );
    let auth = Auth {
        tokens: Some(ApiTokens::new(vec![tokens[0].1.clone()]).expect("tokens")),
        policy: Some(Policy::parse(&policy).expect("policy")),
        ..Auth::default()
    };
    let server = start(auth, None).await;
    let token = Some(tokens[0].0.as_str());
    let (denied, denied_body) = get(&server.base, "/api/datasets/ct-secret", token).await;
    let (unknown, unknown_body) = get(&server.base, "/api/datasets/ct-other", token).await;
    assert_eq!((denied, unknown), (404, 404));
    assert_eq!(
        denied_body.replace("ct-secret", "X"),
        unknown_body.replace("ct-other", "X"),
        "a denied dataset answers as an unknown one"
    );
}

/// A WebSocket handshake with `/api/stream` of `base` with `protocols`.
async fn open_session(
    base: &str,
    protocols: Option<&str>,
) -> Result<
    (
        tokio_tungstenite::WebSocketStream<
            tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
        >,
        tungstenite::handshake::client::Response,
    ),
    tungstenite::Error,
> {
    let url = format!("{}/api/stream", base.replacen("http", "ws", 1));
    let mut request = url.into_client_request().expect("a request");
    if let Some(protocols) = protocols {
        request.headers_mut().insert(
            "sec-websocket-protocol",
            protocols.parse().expect("a header value"),
        );
    }
    tokio_tungstenite::connect_async(request).await
}

/// The next text message as JSON, within 30 s.
async fn next_json(
    socket: &mut tokio_tungstenite::WebSocketStream<
        tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
    >,
) -> Result<serde_json::Value, Option<tungstenite::protocol::CloseFrame>> {
    loop {
        let message = tokio::time::timeout(Duration::from_secs(30), socket.next())
            .await
            .expect("a message in time")
            .expect("the socket is open")
            .expect("a message");
        match message {
            Message::Text(text) => return Ok(serde_json::from_str(&text).expect("JSON")),
            Message::Close(frame) => return Err(frame),
            _ => {}
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_view_session_is_authenticated_at_the_upgrade_and_ends_with_its_token() {
    let (issuer, server) = with_issuer(Some(POLICY)).await;
    match open_session(&server.base, Some("voxserve")).await {
        Err(tungstenite::Error::Http(response)) => assert_eq!(response.status(), 401),
        other => panic!("expected 401 without a token, got {other:?}"),
    }
    let nurse = issuer.sign(Algorithm::ES256, &issuer.claims("nurse", &["ward"]));
    let (mut socket, response) =
        open_session(&server.base, Some(&format!("voxserve, bearer.{nurse}")))
            .await
            .expect("a session");
    assert_eq!(
        response
            .headers()
            .get("sec-websocket-protocol")
            .and_then(|v| v.to_str().ok()),
        Some("voxserve"),
        "the server picks the voxserve subprotocol, never echoes the token"
    );
    let hello = next_json(&mut socket).await.expect("hello");
    let ids: Vec<&str> = hello["datasets"]
        .as_array()
        .expect("datasets")
        .iter()
        .filter_map(|d| d["id"].as_str())
        .collect();
    assert_eq!(ids, ["phantom"]);
    let view = serde_json::json!({"type": "view", "id": 1, "set": {"dataset": "ct-secret"}});
    futures_util::SinkExt::send(&mut socket, Message::Text(view.to_string().into()))
        .await
        .expect("send");
    let reply = next_json(&mut socket).await.expect("a reply");
    assert_eq!(reply["type"], "error", "{reply}");
    drop(socket);

    // A token that expires in two seconds: the session ends then.
    let mut claims = issuer.claims("dr.brief", &["radiology"]);
    claims["exp"] = serde_json::json!(now_s() + 2);
    let brief = issuer.sign(Algorithm::RS256, &claims);
    let (mut socket, _) = open_session(&server.base, Some(&format!("voxserve, bearer.{brief}")))
        .await
        .expect("a session");
    next_json(&mut socket).await.expect("hello");
    let view = serde_json::json!({"type": "view", "id": 1, "set": {"dataset": "ct-secret", "w": 16, "h": 16}});
    futures_util::SinkExt::send(&mut socket, Message::Text(view.to_string().into()))
        .await
        .expect("send");
    let closed = loop {
        match next_json(&mut socket).await {
            Ok(_) => {}
            Err(frame) => break frame,
        }
    };
    let frame = closed.expect("a close frame");
    assert_eq!(
        u16::from(frame.code),
        server::protocol::CLOSE_EXPIRED,
        "{frame:?}"
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    let lines = audit_lines(&server.audit);
    let events: Vec<(String, String)> = lines
        .iter()
        .filter(|l| l["user"] == "dr.brief")
        .map(|l| {
            (
                l["event"].as_str().unwrap_or("").to_owned(),
                l["dataset"].as_str().unwrap_or("").to_owned(),
            )
        })
        .collect();
    let expected = [
        ("session-open", ""),
        ("view", "ct-secret"),
        ("session-close", ""),
    ]
    .map(|(e, d)| (e.to_owned(), d.to_owned()));
    assert_eq!(events, expected);
    assert!(lines.iter().any(|l| l["event"] == "session-close"
        && l["detail"].as_str().is_some_and(|d| d.contains("expired"))));
}

/// A self-signed certificate for 127.0.0.1 and localhost, written as PEM
/// to `dir`: the paths of the certificate and the key, and the
/// certificate's PEM.
fn certificate(dir: &Path, name: &str) -> (PathBuf, PathBuf, String) {
    let names = vec!["localhost".to_owned(), "127.0.0.1".to_owned()];
    let certified = rcgen::generate_simple_self_signed(names).expect("a certificate");
    let cert_pem = certified.cert.pem();
    let cert = dir.join(format!("{name}.crt"));
    let key = dir.join(format!("{name}.key"));
    std::fs::write(&cert, &cert_pem).expect("write");
    std::fs::write(&key, certified.signing_key.serialize_pem()).expect("write");
    (cert, key, cert_pem)
}

/// A client that trusts only `pem`.
fn client_trusting(pem: &str) -> reqwest::Client {
    reqwest::Client::builder()
        .tls_certs_only([reqwest::Certificate::from_pem(pem.as_bytes()).expect("PEM")])
        .build()
        .expect("a client")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn served_over_tls_with_http2_hsts_and_a_certificate_reloaded() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (cert, key, first_pem) = certificate(dir.path(), "first");
    let tls = Arc::new(server::tls::Tls::load(&cert, &key).expect("TLS"));
    let server = start(Auth::default(), Some(tls.clone())).await;
    let response = client_trusting(&first_pem)
        .get(format!("{}/healthz", server.base))
        .send()
        .await
        .expect("a verified TLS connection");
    assert_eq!(response.status(), 200);
    assert_eq!(
        response.version(),
        reqwest::Version::HTTP_2,
        "ALPN picks HTTP/2"
    );
    let headers = response.headers();
    assert!(
        headers.contains_key("strict-transport-security"),
        "{headers:?}"
    );
    // A client that trusts another certificate refuses this one.
    let (_, _, stranger_pem) = certificate(dir.path(), "stranger");
    assert!(
        client_trusting(&stranger_pem)
            .get(format!("{}/healthz", server.base))
            .send()
            .await
            .is_err()
    );
    // Plain HTTP on the TLS port gets no answer.
    let plain = server.base.replacen("https", "http", 1);
    assert!(reqwest::get(format!("{plain}/healthz")).await.is_err());
    // A renewed certificate at the same paths is served after a reload.
    let (_, _, second_pem) = certificate(dir.path(), "second");
    std::fs::copy(dir.path().join("second.crt"), &cert).expect("copy");
    std::fs::copy(dir.path().join("second.key"), &key).expect("copy");
    tls.reload().expect("reload");
    let response = client_trusting(&second_pem)
        .get(format!("{}/healthz", server.base))
        .send()
        .await
        .expect("the renewed certificate");
    assert_eq!(response.status(), 200);
    // Garbage in place of the certificate: the reload fails and keeps it.
    std::fs::write(&cert, "not a certificate").expect("write");
    let error = tls.reload().expect_err("garbage");
    assert!(error.to_string().contains("--tls-cert"), "{error}");
    assert_eq!(
        client_trusting(&second_pem)
            .get(format!("{}/healthz", server.base))
            .send()
            .await
            .expect("still served")
            .status(),
        200
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_response_has_the_security_headers() {
    let server = start(Auth::default(), None).await;
    for path in ["/", "/app.js", "/api/datasets", "/nonexistent", "/healthz"] {
        let response = reqwest::get(format!("{}{path}", server.base))
            .await
            .expect("an answer");
        let headers = response.headers();
        let header = |name: &str| {
            headers
                .get(name)
                .and_then(|v| v.to_str().ok())
                .unwrap_or_default()
                .to_owned()
        };
        assert_eq!(header("x-content-type-options"), "nosniff", "{path}");
        assert_eq!(header("referrer-policy"), "no-referrer", "{path}");
        let csp = header("content-security-policy");
        for part in [
            "default-src 'none'",
            "script-src 'self'",
            "frame-ancestors 'none'",
        ] {
            assert!(csp.contains(part), "{path}: {csp}");
        }
        assert!(
            !headers.contains_key("strict-transport-security"),
            "not over TLS"
        );
    }
}

/// Behind a reverse proxy every viewer has one address: signed in, each
/// user's sessions count against a share of their own.
#[tokio::test]
async fn signed_in_users_have_session_shares_of_their_own_on_one_address() {
    let (issuer, server) = with_issuer(Some(POLICY)).await;
    let per_client = StreamSettings::default().sessions_per_client;
    let nurse = issuer.sign(Algorithm::ES256, &issuer.claims("nurse", &["ward"]));
    let mut open = Vec::new();
    for _ in 0..per_client {
        let (mut socket, _) =
            open_session(&server.base, Some(&format!("voxserve, bearer.{nurse}")))
                .await
                .expect("a session within the nurse's share");
        next_json(&mut socket).await.expect("hello");
        open.push(socket);
    }
    match open_session(&server.base, Some(&format!("voxserve, bearer.{nurse}"))).await {
        Err(tungstenite::Error::Http(response)) => assert_eq!(response.status(), 429),
        other => panic!("expected 429 beyond the nurse's share, got {other:?}"),
    }
    let doctor = issuer.sign(Algorithm::RS256, &issuer.claims("dr.who", &["radiology"]));
    let (mut socket, _) = open_session(&server.base, Some(&format!("voxserve, bearer.{doctor}")))
        .await
        .expect("another user from the same address gets in");
    next_json(&mut socket).await.expect("hello");
}

/// A server may start before its identity provider: it keeps trying while
/// the issuer cannot be reached, and fails at once on a wrong answer.
#[tokio::test]
async fn the_issuer_is_waited_for_at_start_and_a_wrong_one_fails_at_once() {
    // A port nobody listens on yet.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let mut config = {
        let issuer = Issuer::start().await;
        issuer.config()
    };
    config.issuer = format!("http://127.0.0.1:{port}");
    let waiting = tokio::spawn(Oidc::connect_waiting(
        config.clone(),
        Duration::from_secs(30),
    ));
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(!waiting.is_finished(), "still trying while nothing listens");
    let listener = tokio::net::TcpListener::bind(("127.0.0.1", port))
        .await
        .expect("the port");
    let issuer = Issuer::start_on(listener).await;
    let oidc = waiting
        .await
        .expect("the task")
        .expect("connected once the issuer is up");
    let token = issuer.sign(Algorithm::RS256, &issuer.claims("dr.late", &["radiology"]));
    assert_eq!(
        oidc.verify(&token).await.expect("a valid token").user,
        "dr.late"
    );
    // An issuer that answers with another name is a wrong configuration.
    let mut wrong = config;
    wrong.issuer = format!("{}/", issuer.url);
    let started = Instant::now();
    let error = Oidc::connect_waiting(wrong, Duration::from_secs(30))
        .await
        .expect_err("a different issuer name");
    assert!(started.elapsed() < Duration::from_secs(5), "failed at once");
    assert!(format!("{error:#}").contains("expected"), "{error:#}");
}
