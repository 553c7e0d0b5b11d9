//! The audit trail: one JSON line per access event — who, from where, what
//! action on which dataset, the outcome, when — written to the file
//! `serve --audit-log` names (opened again on `SIGHUP`, for log rotation),
//! else logged at `info` under the target `voxserve::audit`.
//!
//! | event | when |
//! |---|---|
//! | `authenticate` | a request's credentials were refused (outcome `denied`) |
//! | `list` | the datasets were listed (detail: how many were shown) |
//! | `describe` | a dataset was described |
//! | `render` | a frame was rendered over HTTP |
//! | `session-open`, `session-close` | a view session opened or ended (detail: why, frames sent) |
//! | `view` | a view session showed a dataset for the first time, or again after another |
//! | `metrics` | `/metrics` was read |
//! | `store` | instances were pushed: a STOW-RS request (the user) or a DICOM association (`AE TITLE`); detail: how many stored and refused |
//! | `pacs` | the PACS was searched or a series opened from it for the study browser or a launch (outcome `denied` without a PACS role) |
//! | `associate` | a DICOM association was rejected (outcome `denied`; detail: the AE title not recognised) |
//!
//! Lines hold no token and no query string: the dataset's id is the only
//! resource named.

use std::io::Write;
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, PoisonError};

use serde::Serialize;

use crate::auth::{Principal, Proof};

/// How an access ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Allowed and done.
    Success,
    /// Refused: not authenticated, or not allowed.
    Denied,
    /// Allowed but failed (bad request, unreadable data, busy).
    Failure,
}

/// One access event.
#[derive(Debug, Clone, Serialize)]
pub struct Event {
    /// When, RFC 3339 in UTC.
    pub time: String,
    /// What was done; see the module docs.
    pub event: &'static str,
    /// Who: the user, the API token's name, `anonymous`, or nothing when
    /// not authenticated.
    pub user: Option<String>,
    /// How the user proved who it is.
    pub proof: Option<Proof>,
    /// The client's address.
    pub client: Option<IpAddr>,
    /// The dataset, when the event concerns one.
    pub dataset: Option<String>,
    /// The resource (a path without its query) when no dataset is named.
    pub resource: Option<String>,
    /// How it ended.
    pub outcome: Outcome,
    /// More, in words (why it was refused, …).
    pub detail: Option<String>,
}

impl Event {
    /// An event of `principal` (none when not authenticated) from `client`.
    pub fn new(
        event: &'static str,
        principal: Option<&Principal>,
        client: Option<IpAddr>,
        outcome: Outcome,
    ) -> Event {
        Event {
            time: now_rfc3339(),
            event,
            user: principal.map(|p| p.user.clone()),
            proof: principal.map(|p| p.proof),
            client,
            dataset: None,
            resource: None,
            outcome,
            detail: None,
        }
    }

    /// This event about the dataset `id`.
    pub fn dataset(mut self, id: &str) -> Event {
        self.dataset = Some(id.to_owned());
        self
    }

    /// This event about the resource `path`.
    pub fn resource(mut self, path: &str) -> Event {
        self.resource = Some(path.chars().take(256).collect());
        self
    }

    /// This event with `detail`.
    pub fn detail(mut self, detail: impl Into<String>) -> Event {
        self.detail = Some(detail.into());
        self
    }
}

/// The current time as RFC 3339 in UTC, to the millisecond.
fn now_rfc3339() -> String {
    let now = time::OffsetDateTime::now_utc();
    let now = now
        .replace_nanosecond(u32::from(now.millisecond()) * 1_000_000)
        .unwrap_or(now);
    now.format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

/// Where events go; see the module docs.
#[derive(Debug, Default)]
pub struct Audit {
    file: Option<(PathBuf, Mutex<std::fs::File>)>,
}

impl Audit {
    /// An audit trail appended to the file at `path`.
    ///
    /// # Errors
    /// When the file cannot be opened for appending.
    pub fn open(path: &Path) -> std::io::Result<Audit> {
        let file = open_append(path)?;
        Ok(Audit {
            file: Some((path.to_owned(), Mutex::new(file))),
        })
    }

    /// Opens the file again (after it was moved away for rotation).
    ///
    /// # Errors
    /// When it cannot be opened; events keep going to the old file.
    pub fn reopen(&self) -> std::io::Result<()> {
        if let Some((path, file)) = &self.file {
            let fresh = open_append(path)?;
            *file.lock().unwrap_or_else(PoisonError::into_inner) = fresh;
        }
        Ok(())
    }

    /// Records `event`.
    pub fn record(&self, event: &Event) {
        let Ok(mut line) = serde_json::to_string(event) else {
            return;
        };
        match &self.file {
            None => tracing::info!(target: "voxserve::audit", "{line}"),
            Some((path, file)) => {
                line.push('\n');
                let mut file = file.lock().unwrap_or_else(PoisonError::into_inner);
                if let Err(e) = file.write_all(line.as_bytes()) {
                    tracing::error!(
                        "audit log {}: cannot write: {e}; the event: {line}",
                        path.display()
                    );
                }
            }
        }
    }
}

fn open_append(path: &Path) -> std::io::Result<std::fs::File> {
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_are_json_lines_appended_and_reopened_after_rotation() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("audit.jsonl");
        let audit = Audit::open(&path).expect("open");
        let who = Principal::anonymous();
        let client = Some(IpAddr::from([127, 0, 0, 1]));
        audit.record(&Event::new("describe", Some(&who), client, Outcome::Success).dataset("ct"));
        std::fs::rename(&path, dir.path().join("audit.1")).expect("rotate");
        audit.reopen().expect("reopen");
        audit.record(&Event::new("authenticate", None, client, Outcome::Denied).detail("no token"));
        let old = std::fs::read_to_string(dir.path().join("audit.1")).expect("old");
        let line: serde_json::Value = serde_json::from_str(old.trim()).expect("json");
        assert_eq!(line["event"], "describe");
        assert_eq!(line["user"], "anonymous");
        assert_eq!(line["dataset"], "ct");
        assert_eq!(line["client"], "127.0.0.1");
        assert_eq!(line["outcome"], "success");
        assert!(
            line["time"].as_str().is_some_and(|t| t.ends_with('Z')),
            "{line}"
        );
        let new = std::fs::read_to_string(&path).expect("new");
        let line: serde_json::Value = serde_json::from_str(new.trim()).expect("json");
        assert_eq!(
            (line["event"].as_str(), line["user"].is_null()),
            (Some("authenticate"), true)
        );
    }
}
