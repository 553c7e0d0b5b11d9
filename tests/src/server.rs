//! A real voxserve server on an ephemeral port, stopped when dropped.

use server::stream::StreamSettings;
use server::{AppState, Dataset, RenderService};
use shaders::{Backend, GpuContext};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

/// A running server.
#[derive(Debug)]
pub struct TestServer {
    /// `http://127.0.0.1:PORT` (`https://` over TLS).
    pub base_url: String,
    stop: Option<oneshot::Sender<()>>,
    /// The task running [`server::run`].
    running: Option<JoinHandle<std::io::Result<()>>>,
}

impl TestServer {
    /// Serves the phantom at `phantom_size`³ on `gpu`, on 127.0.0.1 port 0.
    ///
    /// # Panics
    /// When the server cannot start.
    pub async fn start(gpu: &GpuContext, phantom_size: u32) -> TestServer {
        TestServer::start_with(gpu, phantom_size, StreamSettings::default()).await
    }

    /// [`TestServer::start`] with view sessions set up as `stream`.
    ///
    /// # Panics
    /// When the server cannot start.
    pub async fn start_with(
        gpu: &GpuContext,
        phantom_size: u32,
        stream: StreamSettings,
    ) -> TestServer {
        let dataset = Dataset::phantom(phantom_size, 256 << 20).expect("phantom");
        TestServer::with_datasets(gpu, vec![dataset], 2, stream).await
    }

    /// A server offering `datasets` (the first is the default), keeping the
    /// blocks of at most `resident` of them on the GPU.
    ///
    /// # Panics
    /// When the server cannot start.
    pub async fn with_datasets(
        gpu: &GpuContext,
        datasets: Vec<Dataset>,
        resident: usize,
        stream: StreamSettings,
    ) -> TestServer {
        TestServer::with_backend(Backend::Gpu(gpu.clone()), datasets, resident, stream).await
    }

    /// A server rendering with `backend` (the GPU or the CPU renderer),
    /// offering `datasets` (the first is the default), keeping the blocks of
    /// at most `resident` of them in the renderer's atlas.
    ///
    /// # Panics
    /// When the server cannot start.
    pub async fn with_backend(
        backend: Backend,
        datasets: Vec<Dataset>,
        resident: usize,
        stream: StreamSettings,
    ) -> TestServer {
        let renderer = RenderService::start(backend, 512 << 20, resident).expect("render worker");
        TestServer::serving(AppState::new(datasets, renderer, stream)).await
    }

    /// A server of `state` (its access, authentication, TLS).
    ///
    /// # Panics
    /// When the server cannot start.
    pub async fn serving(state: AppState) -> TestServer {
        TestServer::serving_at(state, "127.0.0.1:0").await
    }

    /// A server of `state` on `address` (e.g. the one a stopped server
    /// used, to restart it as a client sees a restart).
    ///
    /// # Panics
    /// When the server cannot start.
    pub async fn serving_at(state: AppState, address: &str) -> TestServer {
        let listener = TcpListener::bind(address)
            .await
            .unwrap_or_else(|e| panic!("bind {address}: {e}"));
        let addr = listener.local_addr().expect("local address");
        let (stop, stopped) = oneshot::channel::<()>();
        let shutdown = async {
            // A dropped sender stops the server as well.
            let _ = stopped.await;
        };
        let scheme = if state.tls.is_some() { "https" } else { "http" };
        let running = tokio::spawn(server::run(listener, state, shutdown));
        TestServer {
            base_url: format!("{scheme}://{addr}"),
            stop: Some(stop),
            running: Some(running),
        }
    }

    /// Shuts the server down as Ctrl-C does `voxserve serve`, and waits for
    /// [`server::run`] to return (which it does once every view session has
    /// ended); what it returned.
    ///
    /// # Panics
    /// When the server's task panicked.
    pub async fn shut_down(mut self) -> std::io::Result<()> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        match self.running.take() {
            Some(running) => running
                .await
                .expect("the server's task ends without panicking"),
            None => Ok(()),
        }
    }

    /// The WebSocket URL of `path` (which starts with `/`).
    pub fn ws_url(&self, path: &str) -> String {
        format!("{}{path}", self.base_url.replacen("http://", "ws://", 1))
    }

    /// The absolute URL of `path` (which starts with `/`).
    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base_url)
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}

/// `voxserve serve` run as a process, killed when dropped: its URL (from
/// the line it prints) and, once it has ended, what it wrote to stderr.
#[derive(Debug)]
pub struct Spawned {
    /// The URL it printed, without the trailing `/`.
    pub url: String,
    /// The first line it printed.
    pub line: String,
    child: std::process::Child,
    stderr: Option<std::thread::JoinHandle<String>>,
}

impl Spawned {
    /// Runs `binary` with `args` (`serve …`) and waits up to a minute for
    /// the line naming its URL.
    ///
    /// # Errors
    /// What it wrote to stderr when it exited without printing a URL.
    ///
    /// # Panics
    /// When it cannot be started, prints nothing within a minute, or prints
    /// a line without a URL.
    pub async fn start(binary: &str, args: &[&str]) -> Result<Spawned, String> {
        Spawned::start_with_env(binary, args, &[]).await
    }

    /// [`Spawned::start`] with `env` added to the server's environment.
    ///
    /// # Errors
    /// As [`Spawned::start`].
    ///
    /// # Panics
    /// As [`Spawned::start`].
    pub async fn start_with_env(
        binary: &str,
        args: &[&str],
        env: &[(String, String)],
    ) -> Result<Spawned, String> {
        use std::io::{BufRead, BufReader, Read};
        let mut child = std::process::Command::new(binary)
            .args(args)
            .envs(env.iter().map(|(k, v)| (k, v)))
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("start voxserve serve");
        let stdout = child.stdout.take().expect("stdout");
        let mut err = child.stderr.take().expect("stderr");
        // Drained so the server never blocks on a full pipe.
        let stderr = std::thread::spawn(move || {
            let mut text = String::new();
            let _ = err.read_to_string(&mut text);
            text
        });
        let line = tokio::task::spawn_blocking(move || {
            let mut line = String::new();
            BufReader::new(stdout).read_line(&mut line).map(|_| line)
        });
        let mut spawned = Spawned {
            url: String::new(),
            line: String::new(),
            child,
            stderr: Some(stderr),
        };
        let line = tokio::time::timeout(std::time::Duration::from_secs(60), line)
            .await
            .expect("the server printed nothing within 60 s")
            .expect("reader task")
            .expect("reading stdout");
        if line.is_empty() {
            // stdout closed without a URL: the server exited.
            let _ = spawned.child.wait();
            return Err(spawned.stderr_text());
        }
        let url = line
            .split_whitespace()
            .find(|w| w.starts_with("http://") || w.starts_with("https://"))
            .unwrap_or_else(|| panic!("no URL in {line:?}"));
        spawned.url = url.trim_end_matches('/').to_owned();
        spawned.line = line;
        Ok(spawned)
    }

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Asks the server to drain and exit (SIGTERM), as an orchestrator does.
    ///
    /// # Panics
    /// When `kill` cannot be run or fails.
    pub fn terminate(&self) {
        let sent = std::process::Command::new("kill")
            .args(["-TERM", &self.pid().to_string()])
            .status()
            .expect("running kill");
        assert!(sent.success(), "kill -TERM {}: {sent}", self.pid());
    }

    /// Waits up to `patience` for the server to exit: its exit status and
    /// what it wrote to stderr, or `Err(self)` while it still runs.
    ///
    /// # Errors
    /// The server itself, when it is still running after `patience`.
    pub fn wait_exit(
        mut self,
        patience: std::time::Duration,
    ) -> Result<(std::process::ExitStatus, String), Spawned> {
        let start = std::time::Instant::now();
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Ok((status, self.stderr_text()));
            }
            if start.elapsed() > patience {
                return Err(self);
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// Stops the server and returns what it wrote to stderr.
    pub fn stop(mut self) -> String {
        let _ = self.child.kill();
        let _ = self.child.wait();
        self.stderr_text()
    }

    fn stderr_text(&mut self) -> String {
        self.stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default()
    }
}

impl Drop for Spawned {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The view sessions open on the node at `base_url` (`http://host:port`), as
/// its `/metrics` counts them.
pub async fn sessions_open(base_url: &str) -> Result<u32, String> {
    let url = format!("{base_url}/metrics");
    let text = reqwest::get(&url)
        .await
        .and_then(reqwest::Response::error_for_status)
        .map_err(|e| format!("GET {url}: {e}"))?
        .text()
        .await
        .map_err(|e| format!("{url}: {e}"))?;
    text.lines()
        .find_map(|line| line.strip_prefix("voxserve_sessions_open "))
        .and_then(|n| n.trim().parse().ok())
        .ok_or_else(|| format!("no voxserve_sessions_open in {url}: {text}"))
}
