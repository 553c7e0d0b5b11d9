//! A real S3-compatible server for tests: `s3s-fs` (the `s3s` S3 protocol
//! over a folder) on a loopback port, signing required, on a runtime of its
//! own in this process; voxserve reaches it over HTTP as it would reach any
//! S3 endpoint. It can be stopped and started again on the same port (a
//! store that goes away mid-session), and made slow.
//!
//! Buckets are folders under [`S3Server::root`]; an object is the file at
//! `root/bucket/key`.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use hyper_util::rt::{TokioExecutor, TokioIo};
use s3s::auth::SimpleAuth;
use s3s::service::S3ServiceBuilder;

/// The access key the server accepts.
pub const ACCESS_KEY: &str = "voxserve-test";
/// Its secret.
pub const SECRET_KEY: &str = "voxserve-test-secret";

/// A running (or stopped) S3 server; see the module docs.
#[derive(Debug)]
pub struct S3Server {
    root: tempfile::TempDir,
    addr: SocketAddr,
    runtime: Option<tokio::runtime::Runtime>,
    /// Milliseconds each response is held back.
    delay_ms: Arc<AtomicU64>,
    /// Requests answered so far.
    requests: Arc<AtomicU64>,
}

impl S3Server {
    /// Starts a server with the buckets `buckets` (empty).
    ///
    /// # Panics
    /// When no loopback port or temporary folder is available.
    pub fn start(buckets: &[&str]) -> S3Server {
        let root = tempfile::tempdir().expect("a temporary folder for the S3 server");
        for bucket in buckets {
            std::fs::create_dir(root.path().join(bucket)).expect("a bucket folder");
        }
        let mut server = S3Server {
            root,
            addr: SocketAddr::from(([127, 0, 0, 1], 0)),
            runtime: None,
            delay_ms: Arc::new(AtomicU64::new(0)),
            requests: Arc::new(AtomicU64::new(0)),
        };
        server.resume();
        server
    }

    /// The endpoint URL (`http://127.0.0.1:PORT`).
    pub fn endpoint(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// The folder holding the buckets.
    pub fn root(&self) -> &Path {
        self.root.path()
    }

    /// The file holding `key` of `bucket`.
    pub fn object_file(&self, bucket: &str, key: &str) -> PathBuf {
        self.root.path().join(bucket).join(key)
    }

    /// The environment a client needs to reach the server with `secret`.
    pub fn env_with_secret(&self, secret: &str) -> Vec<(String, String)> {
        [
            ("AWS_ACCESS_KEY_ID", ACCESS_KEY),
            ("AWS_SECRET_ACCESS_KEY", secret),
            ("AWS_REGION", "us-east-1"),
            ("AWS_ENDPOINT_URL", &self.endpoint()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v.to_owned()))
        .collect()
    }

    /// The environment a client needs to reach the server.
    pub fn env(&self) -> Vec<(String, String)> {
        self.env_with_secret(SECRET_KEY)
    }

    /// The requests it has been sent so far.
    pub fn requests(&self) -> u64 {
        self.requests.load(Ordering::Relaxed)
    }

    /// Holds every later response back by `delay`.
    pub fn set_delay(&self, delay: Duration) {
        self.delay_ms
            .store(delay.as_millis() as u64, Ordering::Relaxed);
    }

    /// Stops serving: the port is closed and open connections are dropped.
    pub fn stop(&mut self) {
        if let Some(runtime) = self.runtime.take() {
            // Without waiting, so a test's async code may stop it too.
            runtime.shutdown_background();
        }
    }

    /// Serves again on the same port (after [`S3Server::stop`]).
    ///
    /// # Panics
    /// When the port cannot be bound again within 10 s.
    pub fn resume(&mut self) {
        assert!(self.runtime.is_none(), "the S3 server is running");
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("s3-test-server")
            .enable_all()
            .build()
            .expect("a runtime for the S3 server");
        let fs = s3s_fs::FileSystem::new(self.root.path()).expect("s3s-fs over the root folder");
        let mut builder = S3ServiceBuilder::new(fs);
        builder.set_auth(SimpleAuth::from_single(ACCESS_KEY, SECRET_KEY));
        let service = builder.build();
        // Bound here (a stopped server's port may take a moment to close),
        // without blocking on the runtime, so async tests may call this.
        let wanted = self.addr;
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        let listener = loop {
            match std::net::TcpListener::bind(wanted) {
                Ok(listener) => break listener,
                Err(e) if std::time::Instant::now() > deadline => {
                    panic!("S3 server: cannot bind {wanted}: {e}")
                }
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        listener
            .set_nonblocking(true)
            .expect("a non-blocking listener");
        self.addr = listener.local_addr().expect("the S3 server's address");
        let listener = {
            let _inside = runtime.enter();
            tokio::net::TcpListener::from_std(listener).expect("a tokio listener")
        };
        let (delay, requests) = (self.delay_ms.clone(), self.requests.clone());
        runtime.spawn(async move {
            loop {
                let Ok((socket, _)) = listener.accept().await else {
                    continue;
                };
                // Each response leaves at once, as from a real S3 endpoint.
                let _ = socket.set_nodelay(true);
                let service = service.clone();
                let (delay, requests) = (delay.clone(), requests.clone());
                tokio::spawn(async move {
                    let slow = hyper::service::service_fn(move |request| {
                        requests.fetch_add(1, Ordering::Relaxed);
                        let service = service.clone();
                        let delay = Duration::from_millis(delay.load(Ordering::Relaxed));
                        async move {
                            tokio::time::sleep(delay).await;
                            hyper::service::Service::call(&service, request).await
                        }
                    });
                    let _ = hyper_util::server::conn::auto::Builder::new(TokioExecutor::new())
                        .serve_connection(TokioIo::new(socket), slow)
                        .await;
                });
            }
        });
        self.runtime = Some(runtime);
    }
}

impl Drop for S3Server {
    fn drop(&mut self) {
        self.stop();
    }
}
