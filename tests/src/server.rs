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
    /// `http://127.0.0.1:PORT`.
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
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind port 0");
        let addr = listener.local_addr().expect("local address");
        let (stop, stopped) = oneshot::channel::<()>();
        let shutdown = async {
            // A dropped sender stops the server as well.
            let _ = stopped.await;
        };
        let state = AppState::new(datasets, renderer, stream);
        let running = tokio::spawn(server::run(listener, state, shutdown));
        TestServer {
            base_url: format!("http://{addr}"),
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
