//! The listener: accepts TCP connections under [`ConnectionLimits`] and serves
//! each with hyper (HTTP/1.1 with upgrades to WebSocket, or HTTP/2).
//!
//! - **Caps**: at most [`ConnectionLimits::max_connections`] open, and at most
//!   [`ConnectionLimits::per_client`] from one client address. A connection
//!   beyond a cap does not wait and is not refused: the one of the same client
//!   (per-client cap) or of all (overall cap) that has been quiet the longest
//!   is closed to make room. Idle connections thus never lock anyone out, and
//!   a client that opens many only closes its own.
//! - **Timeouts**: a request's headers must arrive within
//!   [`ConnectionLimits::header_timeout`] (slow-header connections end), and a
//!   connection on which nothing was read or written for
//!   [`ConnectionLimits::idle_timeout`] is closed unless a request on it is
//!   being answered (a large frame may render for minutes on a CPU; what it
//!   may cost is bounded by the render worker, not by the connection).
//! - **Descriptors**: when `accept` fails for want of file descriptors, the
//!   quietest connection is closed and accepting resumes shortly.
//!
//! - **TLS** ([`crate::tls`]): when configured, the handshake must end
//!   within the header timeout.
//!
//! Each request carries the client's address as axum's `ConnectInfo`. An
//! upgraded connection (a view session) leaves these counts once upgraded:
//! view sessions have caps and timeouts of their own ([`crate::stream`]).

use std::collections::HashMap;
use std::future::Future;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::{Pin, pin};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::ConnectInfo;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;
use tower::ServiceExt;

/// How many connections the server keeps, and for how long.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct ConnectionLimits {
    /// Connections open at once, at most.
    pub max_connections: usize,
    /// Connections open at once from one client address, at most.
    pub per_client: usize,
    /// The longest a request's headers may take to arrive.
    pub header_timeout: Duration,
    /// A connection on which nothing was read or written this long, and no
    /// request is being answered, is closed.
    pub idle_timeout: Duration,
}

impl ConnectionLimits {
    /// The defaults, also `serve`'s flags' defaults: below the usual limit of
    /// 1 024 open files, with room for the stores' files.
    pub const DEFAULT: ConnectionLimits = ConnectionLimits {
        max_connections: 512,
        per_client: 64,
        header_timeout: Duration::from_secs(10),
        idle_timeout: Duration::from_secs(120),
    };
}

impl Default for ConnectionLimits {
    fn default() -> ConnectionLimits {
        ConnectionLimits::DEFAULT
    }
}

/// How long accepting pauses after it failed (out of file descriptors).
const ACCEPT_BACKOFF: Duration = Duration::from_millis(20);
/// HTTP/2 streams at once on one connection.
const MAX_STREAMS: u32 = 32;

/// An open connection: its client and when it was last active.
#[derive(Debug)]
struct Open {
    client: IpAddr,
    activity: Arc<Activity>,
    close: CancellationToken,
}

/// When a connection last read or wrote (milliseconds since the registry's
/// epoch), and how many of its requests are being answered.
#[derive(Debug)]
struct Activity {
    epoch: Instant,
    last_ms: AtomicU64,
    answering: AtomicUsize,
}

/// A request being answered on a connection: counted in its
/// [`Activity`] until dropped.
#[derive(Debug)]
struct Answering(Arc<Activity>);

impl Drop for Answering {
    fn drop(&mut self) {
        self.0.touch();
        self.0.answering.fetch_sub(1, Ordering::Relaxed);
    }
}

impl Activity {
    fn new(epoch: Instant) -> Activity {
        let activity = Activity {
            epoch,
            last_ms: AtomicU64::new(0),
            answering: AtomicUsize::new(0),
        };
        activity.touch();
        activity
    }

    /// Counts a request as being answered until the guard is dropped.
    fn answering(self: &Arc<Self>) -> Answering {
        self.answering.fetch_add(1, Ordering::Relaxed);
        Answering(self.clone())
    }

    /// Whether a request is being answered.
    fn busy(&self) -> bool {
        self.answering.load(Ordering::Relaxed) > 0
    }

    /// When the connection was last active, for choosing the quietest: a
    /// connection answering a request is not quiet.
    fn quiet_since_ms(&self) -> u64 {
        if self.busy() {
            u64::MAX
        } else {
            self.last_ms.load(Ordering::Relaxed)
        }
    }

    fn touch(&self) {
        let ms = u64::try_from(self.epoch.elapsed().as_millis()).unwrap_or(u64::MAX);
        self.last_ms.store(ms, Ordering::Relaxed);
    }

    /// The instant of the last read or write.
    fn last(&self) -> Instant {
        self.epoch + Duration::from_millis(self.last_ms.load(Ordering::Relaxed))
    }
}

/// The open connections.
#[derive(Debug)]
struct Registry {
    epoch: Instant,
    next_id: u64,
    open: HashMap<u64, Open>,
}

impl Registry {
    /// Registers a connection of `client`, first closing the quietest one of
    /// the same client, or of all, when a cap of `limits` is reached.
    fn admit(
        &mut self,
        client: IpAddr,
        limits: &ConnectionLimits,
    ) -> (u64, Arc<Activity>, CancellationToken) {
        let same = self.open.values().filter(|o| o.client == client).count();
        if same >= limits.per_client {
            self.close_quietest(|o| o.client == client);
        } else if self.open.len() >= limits.max_connections {
            self.close_quietest(|_| true);
        }
        let id = self.next_id;
        self.next_id += 1;
        let activity = Arc::new(Activity::new(self.epoch));
        let close = CancellationToken::new();
        let open = Open {
            client,
            activity: activity.clone(),
            close: close.clone(),
        };
        self.open.insert(id, open);
        (id, activity, close)
    }

    /// Closes the connection among those `which` selects that was active
    /// least recently; whether there was one.
    fn close_quietest(&mut self, which: impl Fn(&Open) -> bool) -> bool {
        let quietest = self
            .open
            .iter()
            .filter(|(_, o)| which(o))
            .min_by_key(|(_, o)| o.activity.quiet_since_ms())
            .map(|(id, _)| *id);
        let Some(open) = quietest.and_then(|id| self.open.remove(&id)) else {
            return false;
        };
        tracing::debug!("closing the quietest connection, of {}", open.client);
        open.close.cancel();
        true
    }
}

/// A shared [`Registry`].
#[derive(Debug, Clone)]
struct Connections(Arc<Mutex<Registry>>);

impl Connections {
    fn new() -> Connections {
        Connections(Arc::new(Mutex::new(Registry {
            epoch: Instant::now(),
            next_id: 0,
            open: HashMap::new(),
        })))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Registry> {
        // The registry holds no invariant a panic could break halfway.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// A TCP stream that notes when it last read or wrote.
#[derive(Debug)]
struct Tracked {
    stream: TcpStream,
    activity: Arc<Activity>,
}

impl AsyncRead for Tracked {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.stream).poll_read(cx, buf);
        if buf.filled().len() > before {
            self.activity.touch();
        }
        polled
    }
}

impl AsyncWrite for Tracked {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.stream).poll_write(cx, data);
        if matches!(polled, Poll::Ready(Ok(n)) if n > 0) {
            self.activity.touch();
        }
        polled
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.stream).poll_write_vectored(cx, data);
        if matches!(polled, Poll::Ready(Ok(n)) if n > 0) {
            self.activity.touch();
        }
        polled
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

/// A `--trusted-proxy` value: an IP address, or a network in CIDR notation
/// (host bits are dropped: `10.1.2.3/8` is `10.0.0.0/8`).
pub fn parse_trusted_proxy(value: &str) -> Result<ipnet::IpNet, String> {
    if let Ok(address) = value.parse::<IpAddr>() {
        return Ok(ipnet::IpNet::from(address.to_canonical()));
    }
    value
        .parse::<ipnet::IpNet>()
        .map(|n| n.trunc())
        .map_err(|_| {
            format!(
                "'{value}' is neither an IP address (10.0.0.1, fd00::1) nor a network in CIDR \
             notation (10.0.0.0/8, fd00::/8)"
            )
        })
}

/// Whether `address` is one of `trusted` or in one of their networks (an
/// IPv4 address mapped into IPv6, as a dual-stack socket reports it, as the
/// IPv4 address it is).
pub fn is_trusted(trusted: &[ipnet::IpNet], address: IpAddr) -> bool {
    let address = address.to_canonical();
    trusted.iter().any(|network| network.contains(&address))
}

/// The client a trusted proxy forwarded a request for: the rightmost
/// address of `X-Forwarded-For` that is not itself trusted ([`is_trusted`];
/// those left of it are whatever the client sent, and prove nothing).
/// `None` when there is no such header, every address in it is trusted, or
/// an entry is not an IP address (then the proxy itself counts as the client).
pub fn forwarded_client(
    headers: &axum::http::HeaderMap,
    trusted: &[ipnet::IpNet],
) -> Option<IpAddr> {
    let mut entries = Vec::new();
    for value in headers.get_all("x-forwarded-for") {
        entries.extend(value.to_str().ok()?.split(',').map(str::trim));
    }
    for entry in entries.iter().rev() {
        let address: IpAddr = entry.parse().ok()?;
        if !is_trusted(trusted, address) {
            return Some(address);
        }
    }
    None
}

/// Serves `router` on `listener` under `limits` until `stop` is cancelled,
/// then lets every connection finish its requests in flight and returns when
/// they have (upgraded connections are not waited for), or when `deadline`
/// is cancelled (the drain's deadline), closing those still answering. A request from one
/// of `trusted` counts as from the client it forwards
/// ([`forwarded_client`]); their connections are not capped per client.
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: ConnectionLimits,
    trusted: Arc<[ipnet::IpNet]>,
    tls: Option<Arc<crate::tls::Tls>>,
    stop: CancellationToken,
    deadline: CancellationToken,
) -> io::Result<()> {
    let connections = Connections::new();
    let tasks = TaskTracker::new();
    let mut builder = Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout);
    builder
        .http2()
        .timer(TokioTimer::new())
        .max_concurrent_streams(MAX_STREAMS)
        .enable_connect_protocol();
    let builder = Arc::new(builder);
    loop {
        let accepted = tokio::select! {
            () = stop.cancelled() => break,
            accepted = listener.accept() => accepted,
        };
        let (stream, client) = match accepted {
            Ok(accepted) => accepted,
            Err(e) => {
                accept_failed(&e, &connections).await;
                continue;
            }
        };
        // Frames go out at once: a slice view's placement and its frame are
        // two writes, and Nagle's algorithm would hold the second until the
        // peer's (delayed) acknowledgement of the first, tens of ms.
        if let Err(e) = stream.set_nodelay(true) {
            tracing::debug!("TCP_NODELAY on a connection from {client}: {e}");
        }
        let proxy = is_trusted(&trusted, client.ip());
        let capped = if proxy {
            ConnectionLimits {
                per_client: usize::MAX,
                ..limits
            }
        } else {
            limits
        };
        let (id, activity, close) = connections.lock().admit(client.ip(), &capped);
        let trusted = trusted.clone();
        let tracked = Tracked {
            stream,
            activity: activity.clone(),
        };
        let answering = activity.clone();
        let service = TowerToHyperService::new(
            router
                .clone()
                .map_request(
                    move |mut request: axum::extract::Request<hyper::body::Incoming>| {
                        let from = if proxy {
                            forwarded_client(request.headers(), &trusted)
                                .map_or(client, |ip| SocketAddr::new(ip, client.port()))
                        } else {
                            client
                        };
                        request.extensions_mut().insert(ConnectInfo(from));
                        request
                    },
                )
                .map_future(move |response| {
                    let answering = answering.answering();
                    async move {
                        let response = response.await;
                        drop(answering);
                        response
                    }
                }),
        );
        let builder = builder.clone();
        let connections = connections.clone();
        let ends = Ends {
            close,
            stop: stop.clone(),
            deadline: deadline.clone(),
        };
        let acceptor = tls.as_ref().map(|tls| tls.acceptor());
        tasks.spawn(async move {
            let ended = match acceptor {
                None => {
                    let connection = pin!(
                        builder.serve_connection_with_upgrades(TokioIo::new(tracked), service)
                    );
                    watch(connection, &activity, limits.idle_timeout, &ends).await
                }
                // The handshake counts as the headers: it must be done in time.
                Some(acceptor) => {
                    match tokio::time::timeout(limits.header_timeout, acceptor.accept(tracked))
                        .await
                    {
                        Ok(Ok(stream)) => {
                            let io = TokioIo::new(stream);
                            let connection =
                                pin!(builder.serve_connection_with_upgrades(io, service));
                            watch(connection, &activity, limits.idle_timeout, &ends).await
                        }
                        Ok(Err(e)) => Err(format!("TLS handshake failed: {e}").into()),
                        Err(_) => Err("TLS handshake not done within the header timeout".into()),
                    }
                }
            };
            if let Err(e) = ended {
                tracing::debug!("connection of {client}: {e}");
            }
            connections.lock().open.remove(&id);
        });
    }
    // Closed now, not when the connections are done: a connection attempt
    // meanwhile is refused at once (a load balancer tries another node)
    // rather than left waiting in the backlog.
    drop(listener);
    tasks.close();
    tokio::select! {
        () = tasks.wait() => {}
        () = deadline.cancelled() => {
            tracing::warn!(
                "{} connections still answering requests at the drain's deadline: closing them",
                tasks.len()
            );
            tasks.wait().await;
        }
    }
    Ok(())
}

/// A connection being served: it resolves when it ends, and can be told to
/// finish its requests in flight and end.
trait Serving: Future<Output = Result<(), Box<dyn std::error::Error + Send + Sync>>> {
    fn finish(self: Pin<&mut Self>);
}

impl<I, S, E, B> Serving for hyper_util::server::conn::auto::UpgradeableConnection<'_, I, S, E>
where
    Self: Future<Output = Result<(), Box<dyn std::error::Error + Send + Sync>>>,
    S: hyper::service::HttpService<hyper::body::Incoming, ResBody = B>,
    S::Error: Into<Box<dyn std::error::Error + Send + Sync>>,
    I: hyper::rt::Read + hyper::rt::Write + Unpin,
    B: hyper::body::Body + 'static,
    B::Error: Into<Box<dyn std::error::Error + Send + Sync>>,
    E: hyper_util::server::conn::auto::HttpServerConnExec<S::Future, B>,
{
    fn finish(self: Pin<&mut Self>) {
        self.graceful_shutdown();
    }
}

/// What ends a connection [`watch`]es: its own close (a cap made room),
/// the drain's start (it finishes its requests in flight, then ends) and
/// the drain's deadline (it ends at once).
struct Ends {
    close: CancellationToken,
    stop: CancellationToken,
    deadline: CancellationToken,
}

/// Runs `connection` until it ends, it was closed (to make room), nothing
/// was read or written for `idle_timeout` while no request was being
/// answered, after the drain's start it has finished its requests in
/// flight, or the drain's deadline came ([`Ends`]).
async fn watch(
    mut connection: Pin<&mut impl Serving>,
    activity: &Activity,
    idle_timeout: Duration,
    ends: &Ends,
) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let mut stopping = false;
    loop {
        let idle_at = activity.last() + idle_timeout;
        tokio::select! {
            served = connection.as_mut() => return served,
            () = ends.close.cancelled() => return Ok(()),
            () = ends.deadline.cancelled() => {
                return Err("closed at the drain's deadline with a request in flight".into());
            }
            () = ends.stop.cancelled(), if !stopping => {
                stopping = true;
                connection.as_mut().finish();
            }
            () = tokio::time::sleep_until(idle_at.into()) => {
                if !activity.busy() && activity.last() + idle_timeout <= Instant::now() {
                    return Ok(());
                }
            }
        }
    }
}

/// After `accept` failed: when for want of file descriptors, closes the
/// quietest connection; pauses briefly either way (the error may repeat at
/// once).
async fn accept_failed(error: &io::Error, connections: &Connections) {
    // ENFILE and EMFILE (Linux): no kind of std's names them.
    let out_of_files = matches!(error.raw_os_error(), Some(23 | 24));
    if out_of_files {
        let closed = connections.lock().close_quietest(|_| true);
        tracing::warn!(
            "cannot accept a connection: {error}; {} the quietest connection",
            if closed { "closed" } else { "found no" }
        );
    } else {
        tracing::debug!("cannot accept a connection: {error}");
    }
    tokio::time::sleep(ACCEPT_BACKOFF).await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trusted_proxy_s_client_is_the_rightmost_untrusted_forwarded_address() {
        let proxy: IpAddr = [10, 0, 0, 1].into();
        let inner: IpAddr = [10, 0, 0, 2].into();
        let with = |values: &[&str]| {
            let mut headers = axum::http::HeaderMap::new();
            for value in values {
                headers.append("x-forwarded-for", value.parse().expect("a header value"));
            }
            forwarded_client(&headers, &[proxy.into(), inner.into()])
        };
        // What the client wrote itself (left) proves nothing.
        assert_eq!(with(&["6.6.6.6, 192.0.2.7"]), Some([192, 0, 2, 7].into()));
        // Proxies in a chain are skipped, over several header lines too.
        assert_eq!(
            with(&["192.0.2.7, 10.0.0.2", "10.0.0.1"]),
            Some([192, 0, 2, 7].into())
        );
        assert_eq!(
            with(&["2001:db8::5"]),
            Some("2001:db8::5".parse().expect("v6"))
        );
        // None: the proxy itself is the client.
        assert_eq!(with(&[]), None);
        assert_eq!(with(&["10.0.0.1"]), None);
        assert_eq!(with(&["192.0.2.7, not-an-address"]), None);
        assert_eq!(with(&["192.0.2.7:4711"]), None);
    }

    #[test]
    fn trusted_proxies_are_addresses_or_networks() {
        let parse = |v: &str| parse_trusted_proxy(v).expect(v);
        let trusted = [
            parse("10.0.0.0/8"),
            parse("192.0.2.7"),
            parse("fd00::/8"),
            parse("172.16.9.9/12"),
        ];
        assert_eq!(trusted[3].to_string(), "172.16.0.0/12", "host bits dropped");
        let is = |a: &str| is_trusted(&trusted, a.parse().expect(a));
        assert!(is("10.200.3.4") && is("192.0.2.7") && is("fd12::1") && is("172.31.0.1"));
        assert!(!is("11.0.0.1") && !is("192.0.2.8") && !is("fe80::1") && !is("172.32.0.1"));
        // As a dual-stack socket reports an IPv4 client.
        assert!(is("::ffff:10.1.1.1") && !is("::ffff:11.1.1.1"));
        // The nearest untrusted hop behind a chain of proxies in the networks.
        let mut headers = axum::http::HeaderMap::new();
        headers.append(
            "x-forwarded-for",
            "6.6.6.6, 198.51.100.3, 10.9.9.9, fd00::2"
                .parse()
                .expect("a header value"),
        );
        assert_eq!(
            forwarded_client(&headers, &trusted),
            Some([198, 51, 100, 3].into())
        );
        for bad in [
            "10.0.0.0/33",
            "proxy.example.org",
            "10.0.0",
            "",
            "fd00::/129",
        ] {
            let message = parse_trusted_proxy(bad).expect_err(bad);
            assert!(
                message.contains("CIDR") && message.contains(bad),
                "{message}"
            );
        }
    }

    fn limits(max_connections: usize, per_client: usize) -> ConnectionLimits {
        ConnectionLimits {
            max_connections,
            per_client,
            ..ConnectionLimits::DEFAULT
        }
    }

    #[test]
    fn a_cap_closes_the_quietest_connection_of_the_client_or_of_all() {
        let registry = Connections::new();
        let mut registry = registry.lock();
        let a: IpAddr = [127, 0, 0, 2].into();
        let b: IpAddr = [127, 0, 0, 3].into();
        let limits = limits(3, 2);
        let (_, first_a, close_first_a) = registry.admit(a, &limits);
        let (_, second_a, close_second_a) = registry.admit(a, &limits);
        // The first is the quieter one (earlier activity).
        first_a.last_ms.store(1, Ordering::Relaxed);
        second_a.last_ms.store(5, Ordering::Relaxed);
        let (_, third_a, close_third_a) = registry.admit(a, &limits);
        third_a.last_ms.store(9, Ordering::Relaxed);
        assert!(close_first_a.is_cancelled(), "a's quietest made room");
        assert!(!close_second_a.is_cancelled() && !close_third_a.is_cancelled());
        assert_eq!(registry.open.len(), 2);
        // Another client fills the overall cap, then the quietest of all goes.
        let (_, first_b, close_first_b) = registry.admit(b, &limits);
        first_b.last_ms.store(7, Ordering::Relaxed);
        assert_eq!(registry.open.len(), 3);
        let (_, _, close_second_b) = registry.admit(b, &limits);
        assert!(
            close_second_a.is_cancelled(),
            "the quietest of all made room"
        );
        assert!(!close_first_b.is_cancelled() && !close_second_b.is_cancelled());
        assert_eq!(registry.open.len(), 3);
        // A connection answering a request is not the quietest, however
        // long ago it last read or wrote.
        first_b.last_ms.store(0, Ordering::Relaxed);
        let answering = first_b.answering();
        let (_, _, close_third_b) = registry.admit(b, &limits);
        assert!(!close_first_b.is_cancelled(), "busy connections stay");
        assert!(close_second_b.is_cancelled() || close_third_a.is_cancelled());
        drop(answering);
        assert!(!first_b.busy());
        drop(close_third_b);
    }

    #[tokio::test]
    async fn a_request_answered_slower_than_the_idle_timeout_is_answered() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let router = Router::new().route(
            "/slow",
            axum::routing::get(|| async {
                tokio::time::sleep(Duration::from_millis(1500)).await;
                "done"
            }),
        );
        let limits = ConnectionLimits {
            idle_timeout: Duration::from_millis(300),
            ..ConnectionLimits::DEFAULT
        };
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("address");
        let stop = CancellationToken::new();
        tokio::spawn(serve(
            listener,
            router,
            limits,
            Arc::from([]),
            None,
            stop.clone(),
            CancellationToken::new(),
        ));
        let mut stream = TcpStream::connect(addr).await.expect("connect");
        stream
            .write_all(b"GET /slow HTTP/1.1\r\nHost: localhost\r\n\r\n")
            .await
            .expect("send");
        let mut answer = vec![0u8; 1024];
        let n = tokio::time::timeout(Duration::from_secs(10), stream.read(&mut answer))
            .await
            .expect("an answer")
            .expect("read");
        let text = String::from_utf8_lossy(&answer[..n]);
        assert!(
            text.starts_with("HTTP/1.1 200") && text.ends_with("done"),
            "{text}"
        );
        // Then, quiet, the connection is closed after the idle timeout.
        let started = Instant::now();
        let end = tokio::time::timeout(Duration::from_secs(10), stream.read(&mut answer))
            .await
            .expect("closed");
        assert!(matches!(end, Ok(0) | Err(_)), "{end:?}");
        assert!(started.elapsed() < Duration::from_secs(5));
        stop.cancel();
    }

    #[tokio::test]
    async fn a_drain_answers_requests_in_flight_until_its_deadline_then_closes_them() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let router = Router::new().route(
            "/wait/{ms}",
            axum::routing::get(
                |axum::extract::Path(ms): axum::extract::Path<u64>| async move {
                    tokio::time::sleep(Duration::from_millis(ms)).await;
                    "done"
                },
            ),
        );
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("address");
        let (stop, deadline) = (CancellationToken::new(), CancellationToken::new());
        let served = tokio::spawn(serve(
            listener,
            router,
            ConnectionLimits::DEFAULT,
            Arc::from([]),
            None,
            stop.clone(),
            deadline.clone(),
        ));
        let ask = |ms: u64| async move {
            let mut stream = TcpStream::connect(addr).await.expect("connect");
            let request = format!("GET /wait/{ms} HTTP/1.1\r\nHost: localhost\r\n\r\n");
            stream.write_all(request.as_bytes()).await.expect("send");
            stream
        };
        let (mut quick, mut slow) = (ask(500).await, ask(60_000).await);
        tokio::time::sleep(Duration::from_millis(100)).await;
        stop.cancel();
        let started = Instant::now();
        let mut answer = vec![0u8; 1024];
        let n = tokio::time::timeout(Duration::from_secs(10), quick.read(&mut answer))
            .await
            .expect("an answer")
            .expect("read");
        let text = String::from_utf8_lossy(&answer[..n]);
        assert!(
            text.starts_with("HTTP/1.1 200"),
            "answered while draining: {text}"
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert!(!served.is_finished(), "a request is still in flight");
        deadline.cancel();
        let end = tokio::time::timeout(Duration::from_secs(10), slow.read(&mut answer))
            .await
            .expect("closed at the deadline");
        assert!(matches!(end, Ok(0) | Err(_)), "{end:?}");
        tokio::time::timeout(Duration::from_secs(10), served)
            .await
            .expect("serve returned at the deadline")
            .expect("joined")
            .expect("served");
        assert!(started.elapsed() < Duration::from_secs(10));
    }
}
