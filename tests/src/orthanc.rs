//! A real PACS for tests: Orthanc (Debian's `orthanc` with the
//! `orthanc-dicomweb` plugin) on a free loopback port, storing into a
//! temporary folder, refusing remote clients and with its DICOM port off;
//! stopped when dropped. Loaded through its REST API.
//!
//! [`Orthanc::start_or_skip`] skips a test (printing why) where Orthanc is
//! not installed, unless `VOXSERVE_REQUIRE_PACS=1` (set by `.ci/run`, whose
//! prerequisites install it), which makes that a failure.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::gpu::report_skip;

/// Where Debian puts Orthanc's DICOMweb plugin.
const DICOMWEB_PLUGIN: &str = "/usr/share/orthanc/plugins/libOrthancDicomWeb.so";

/// A running Orthanc; see the module docs.
#[derive(Debug)]
pub struct Orthanc {
    child: Child,
    /// Its REST API's root, e.g. `http://127.0.0.1:40123`.
    pub url: String,
    _dir: tempfile::TempDir,
}

impl Drop for Orthanc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `program` on the `PATH`, or in `/usr/sbin` (Debian's daemons).
pub(crate) fn find(program: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain([PathBuf::from("/usr/sbin")])
        .map(|dir| dir.join(program))
        .find(|p| p.is_file())
}

impl Orthanc {
    /// Starts Orthanc, or says why it cannot (not installed).
    ///
    /// # Panics
    /// When it is installed but does not answer within 30 s, or exits at
    /// start three times.
    pub fn start() -> Result<Orthanc, String> {
        Orthanc::start_with(&serde_json::json!({}))
    }

    /// [`Orthanc::start`] with `servers` as the DICOMweb servers it may
    /// send studies to (`{"NAME": ["URL"]}`; `POST
    /// /dicom-web/servers/NAME/stow` then pushes with STOW-RS).
    ///
    /// # Panics
    /// As [`Orthanc::start`].
    pub fn start_with(servers: &serde_json::Value) -> Result<Orthanc, String> {
        let binary = find("Orthanc").ok_or("Orthanc is not installed (Debian: orthanc)")?;
        if !Path::new(DICOMWEB_PLUGIN).is_file() {
            return Err(format!(
                "{DICOMWEB_PLUGIN} is missing (Debian: orthanc-dicomweb)"
            ));
        }
        // The port is free when chosen, but another test's listener may
        // take it before Orthanc binds it: Orthanc then exits, and starts
        // again on another port.
        let mut exits = Vec::new();
        for _ in 0..3 {
            match Orthanc::launch(&binary, servers)? {
                Ok(orthanc) => return Ok(orthanc),
                Err(exit) => exits.push(exit),
            }
        }
        panic!("Orthanc exited at start three times: {}", exits.join("; "));
    }

    /// Orthanc on a port free when chosen: `Ok(Err(why))` where it exits
    /// before it answers (with the end of its log).
    ///
    /// # Panics
    /// When it runs but does not answer within 30 s.
    fn launch(
        binary: &Path,
        servers: &serde_json::Value,
    ) -> Result<Result<Orthanc, String>, String> {
        let dir = tempfile::tempdir().map_err(|e| format!("no temporary folder: {e}"))?;
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(|e| format!("no free port: {e}"))?
            .port();
        let storage = dir.path().join("storage");
        let config = serde_json::json!({
            "Name": "voxserve-test",
            "StorageDirectory": storage,
            "IndexDirectory": storage,
            "HttpPort": port,
            "RemoteAccessAllowed": false,
            "AuthenticationEnabled": false,
            "DicomServerEnabled": false,
            "HttpCompressionEnabled": false,
            "Plugins": [DICOMWEB_PLUGIN],
            "DicomWeb": {"Enable": true, "Root": "/dicom-web/", "Servers": servers},
        });
        let config_file = dir.path().join("orthanc.json");
        std::fs::write(&config_file, config.to_string()).map_err(|e| e.to_string())?;
        let log =
            std::fs::File::create(dir.path().join("orthanc.log")).map_err(|e| e.to_string())?;
        let child = Command::new(binary)
            .arg(&config_file)
            .current_dir(dir.path())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|e| format!("cannot start Orthanc: {e}"))?;
        let mut orthanc = Orthanc {
            child,
            url: format!("http://127.0.0.1:{port}"),
            _dir: dir,
        };
        let start = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            if let Ok(Some(status)) = orthanc.child.try_wait() {
                let log = std::fs::read_to_string(orthanc._dir.path().join("orthanc.log"))
                    .unwrap_or_default();
                let tail: String = log.lines().rev().take(3).collect::<Vec<_>>().join(" | ");
                return Ok(Err(format!("port {port}: {status}: {tail}")));
            }
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "Orthanc did not answer on port {port} within 30 s"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        Ok(Ok(orthanc))
    }

    /// [`Orthanc::start`], or `None` after saying why `test` is skipped.
    ///
    /// # Panics
    /// When Orthanc is missing and `VOXSERVE_REQUIRE_PACS=1`.
    pub fn start_or_skip(test: &str) -> Option<Orthanc> {
        Orthanc::start_with_or_skip(test, &serde_json::json!({}))
    }

    /// [`Orthanc::start_with`], or `None` after saying why `test` is skipped.
    ///
    /// # Panics
    /// When Orthanc is missing and `VOXSERVE_REQUIRE_PACS=1`.
    pub fn start_with_or_skip(test: &str, servers: &serde_json::Value) -> Option<Orthanc> {
        match Orthanc::start_with(servers) {
            Ok(o) => Some(o),
            Err(why) => {
                if std::env::var("VOXSERVE_REQUIRE_PACS").is_ok_and(|v| v == "1") {
                    panic!("{test}: VOXSERVE_REQUIRE_PACS=1 but {why}");
                }
                report_skip(test, &why);
                None
            }
        }
    }

    /// Its DICOMweb root.
    pub fn dicomweb(&self) -> String {
        format!("{}/dicom-web", self.url)
    }

    /// Stores `file` (POST /instances); returns Orthanc's id of the instance.
    ///
    /// # Panics
    /// When Orthanc refuses it.
    pub async fn upload(&self, client: &reqwest::Client, file: &Path) -> String {
        self.upload_answer(client, file).await["ID"]
            .as_str()
            .expect("an instance id")
            .to_owned()
    }

    /// Stores `file` (POST /instances); returns Orthanc's answer (`ID`,
    /// `ParentStudy`, `ParentSeries`, …).
    ///
    /// # Panics
    /// When Orthanc refuses it.
    pub async fn upload_answer(&self, client: &reqwest::Client, file: &Path) -> serde_json::Value {
        let bytes = std::fs::read(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let body = client
            .post(format!("{}/instances", self.url))
            .body(bytes)
            .send()
            .await
            .and_then(reqwest::Response::error_for_status)
            .unwrap_or_else(|e| panic!("uploading {}: {e}", file.display()))
            .bytes()
            .await
            .expect("Orthanc's answer");
        serde_json::from_slice(&body).expect("JSON")
    }

    /// `POST path` with the JSON `body`; the answer, which must be a success.
    ///
    /// # Panics
    /// When Orthanc refuses.
    pub async fn post_json(
        &self,
        client: &reqwest::Client,
        path: &str,
        body: &serde_json::Value,
    ) -> String {
        let answer = client
            .post(format!("{}{path}", self.url))
            .body(body.to_string())
            .send()
            .await
            .unwrap_or_else(|e| panic!("POST {path}: {e}"));
        let status = answer.status();
        let text = answer.text().await.unwrap_or_default();
        assert!(status.is_success(), "POST {path}: HTTP {status}: {text}");
        text
    }

    /// Removes an instance by Orthanc's id.
    ///
    /// # Panics
    /// When Orthanc refuses.
    pub async fn delete_instance(&self, client: &reqwest::Client, id: &str) {
        client
            .delete(format!("{}/instances/{id}", self.url))
            .send()
            .await
            .and_then(reqwest::Response::error_for_status)
            .unwrap_or_else(|e| panic!("deleting {id}: {e}"));
    }
}
