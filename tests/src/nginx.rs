//! nginx (Debian's package) as the load balancer in front of render nodes,
//! on a loopback port, with the configuration the README documents
//! (`tests/nginx/two-nodes.conf`). Tests skip where nginx is not installed,
//! unless `VOXSERVE_REQUIRE_NGINX=1` (set by `.ci/run`, whose prerequisites
//! install it), which makes that a failure.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::gpu::report_skip;
use crate::orthanc::find;

/// The configuration, with `@NAME@` placeholders.
const TEMPLATE: &str = include_str!("../nginx/two-nodes.conf");

/// An nginx process balancing over some nodes; stopped when dropped.
#[derive(Debug)]
pub struct Nginx {
    child: Child,
    /// `http://127.0.0.1:PORT`.
    pub url: String,
    dir: tempfile::TempDir,
}

impl Nginx {
    /// nginx in front of `nodes` (each `host:port`), or `None` after saying
    /// why `test` is skipped.
    ///
    /// # Panics
    /// When nginx is missing and `VOXSERVE_REQUIRE_NGINX=1`, or it does not
    /// answer within 10 s.
    pub fn start_or_skip(test: &str, nodes: &[&str]) -> Option<Nginx> {
        let Some(binary) = find("nginx") else {
            let why = "nginx is not installed (Debian: nginx)";
            if std::env::var("VOXSERVE_REQUIRE_NGINX").is_ok_and(|v| v == "1") {
                panic!("{test}: VOXSERVE_REQUIRE_NGINX=1 but {why}");
            }
            report_skip(test, why);
            return None;
        };
        // The port is free when chosen; another test may take it first:
        // nginx then exits, and starts again on another.
        let mut exits = Vec::new();
        for _ in 0..3 {
            match Nginx::launch(&binary, nodes) {
                Ok(nginx) => return Some(nginx),
                Err(exit) => exits.push(exit),
            }
        }
        panic!("nginx exited at start three times: {}", exits.join("; "));
    }

    fn launch(binary: &Path, nodes: &[&str]) -> Result<Nginx, String> {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free port")
            .port();
        let upstreams: Vec<String> = nodes
            .iter()
            .map(|node| format!("        server {node} max_fails=1 fail_timeout=10s;"))
            .collect();
        let config = TEMPLATE
            .replace("@PREFIX@", dir.path().to_str().expect("utf-8"))
            .replace("@LISTEN@", &format!("127.0.0.1:{port}"))
            .replace("@UPSTREAMS@", &upstreams.join("\n"));
        let file = dir.path().join("nginx.conf");
        std::fs::write(&file, config).expect("writing nginx.conf");
        let log = std::fs::File::create(dir.path().join("nginx.log")).expect("nginx.log");
        let child = Command::new(binary)
            .arg("-p")
            .arg(dir.path())
            .arg("-c")
            .arg(&file)
            // The compiled-in error log (/var/log/nginx) is not opened.
            .args(["-e", "stderr"])
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("starting nginx");
        let mut nginx = Nginx {
            child,
            url: format!("http://127.0.0.1:{port}"),
            dir,
        };
        let start = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            if let Ok(Some(status)) = nginx.child.try_wait() {
                return Err(format!("port {port}: {status}: {}", nginx.log()));
            }
            assert!(
                start.elapsed() < Duration::from_secs(10),
                "nginx did not listen on port {port} within 10 s: {}",
                nginx.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(nginx)
    }

    /// What nginx wrote to its error log so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("nginx.log")).unwrap_or_default()
    }
}

impl Drop for Nginx {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
