//! [`Endpoint`]: a PACS's DICOMweb service as `--pacs NAME=URL` names it,
//! with the authorization `--pacs-auth NAME=FILE` gives it.

use std::path::Path;

use reqwest::Url;
use reqwest::header::{AUTHORIZATION, HeaderName, HeaderValue};

/// Most bytes of a `--pacs-auth` file.
const MAX_AUTH_FILE_BYTES: u64 = 16 * 1024;

/// One PACS's DICOMweb service.
#[derive(Clone)]
pub struct Endpoint {
    /// The name the flags and the API use for it.
    pub name: String,
    /// The service's root (QIDO-RS, WADO-RS), without a trailing slash.
    pub base: Url,
    /// A header sent with every request (its value is a secret: never logged).
    pub auth: Option<(HeaderName, HeaderValue)>,
}

impl std::fmt::Debug for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Endpoint")
            .field("name", &self.name)
            .field("base", &self.base.as_str())
            .field("auth", &self.auth.as_ref().map(|(name, _)| name))
            .finish()
    }
}

/// `--pacs NAME=URL`: a name of 1 to 32 letters, digits, `-` and `_`, and
/// an `http` or `https` URL of the DICOMweb root.
pub fn parse_pacs(text: &str) -> Result<Endpoint, String> {
    let (name, url) = text.split_once('=').ok_or_else(|| {
        format!("{text:?}: expected NAME=URL, e.g. main=http://pacs:8042/dicom-web")
    })?;
    let name = parse_name(name)?;
    let base = Url::parse(url.trim_end_matches('/'))
        .map_err(|e| format!("{url:?}: {e}; expected the URL of a DICOMweb service"))?;
    if !matches!(base.scheme(), "http" | "https") || base.host_str().is_none() {
        return Err(format!(
            "{url:?}: expected an http:// or https:// URL with a host"
        ));
    }
    if base.query().is_some() || base.fragment().is_some() || !base.username().is_empty() {
        return Err(format!(
            "{url:?}: expected a URL without a query, fragment or user (give credentials with --pacs-auth)"
        ));
    }
    Ok(Endpoint {
        name,
        base,
        auth: None,
    })
}

/// `--pacs-auth NAME=FILE`, checked for its form only (the file is read
/// once the flags are parsed: [`Endpoints::new`]).
pub fn parse_auth(text: &str) -> Result<(String, std::path::PathBuf), String> {
    let (name, file) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?}: expected NAME=FILE"))?;
    Ok((parse_name(name)?, file.into()))
}

/// A PACS's name.
fn parse_name(name: &str) -> Result<String, String> {
    if name.is_empty()
        || name.len() > 32
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        return Err(format!(
            "PACS name {name:?}: expected 1 to 32 letters, digits, '-' or '_'"
        ));
    }
    Ok(name.to_owned())
}

/// The authorization in `file`: a line `Header-Name: value`, or a bare
/// token sent as `Authorization: Bearer TOKEN`.
fn read_auth(file: &Path) -> anyhow::Result<(HeaderName, HeaderValue)> {
    let size = std::fs::metadata(file)
        .map_err(|e| anyhow::anyhow!("--pacs-auth {}: {e}", file.display()))?
        .len();
    if size > MAX_AUTH_FILE_BYTES {
        anyhow::bail!(
            "--pacs-auth {}: {size} bytes; expected a header line or a token of at most {MAX_AUTH_FILE_BYTES} bytes",
            file.display()
        );
    }
    let text = std::fs::read_to_string(file)
        .map_err(|e| anyhow::anyhow!("--pacs-auth {}: {e}", file.display()))?;
    let line = text.trim();
    let bad = |what: &str| {
        anyhow::anyhow!(
            "--pacs-auth {}: {what}; expected one line `Header-Name: value` or a bare token",
            file.display()
        )
    };
    if line.is_empty() || line.contains('\n') {
        return Err(bad("not one line"));
    }
    let (name, value) = match line.split_once(':') {
        Some((name, value)) if !name.contains(char::is_whitespace) => {
            let name = HeaderName::from_bytes(name.as_bytes())
                .map_err(|_| bad("not a header name before the colon"))?;
            (name, value.trim().to_owned())
        }
        _ => (AUTHORIZATION, format!("Bearer {line}")),
    };
    let mut value =
        HeaderValue::from_str(&value).map_err(|_| bad("a character a header cannot hold"))?;
    value.set_sensitive(true);
    Ok((name, value))
}

/// The configured PACS endpoints, by name.
#[derive(Debug, Clone, Default)]
pub struct Endpoints(Vec<Endpoint>);

impl Endpoints {
    /// `endpoints` with the authorization files of `auth` read; every name
    /// must be unique, and every `--pacs-auth` must name a `--pacs`.
    pub fn new(
        endpoints: Vec<Endpoint>,
        auth: &[(String, std::path::PathBuf)],
    ) -> anyhow::Result<Endpoints> {
        let mut endpoints = endpoints;
        for (i, e) in endpoints.iter().enumerate() {
            if endpoints[..i].iter().any(|o| o.name == e.name) {
                anyhow::bail!("--pacs {}: the name is given twice", e.name);
            }
        }
        for (name, file) in auth {
            let endpoint = endpoints
                .iter_mut()
                .find(|e| &e.name == name)
                .ok_or_else(|| {
                    anyhow::anyhow!("--pacs-auth {name}: no --pacs {name}=URL names that PACS")
                })?;
            endpoint.auth = Some(read_auth(file)?);
        }
        Ok(Endpoints(endpoints))
    }

    /// Every endpoint.
    pub fn all(&self) -> &[Endpoint] {
        &self.0
    }

    /// The endpoint called `name`, or the only one when `name` is `None`.
    pub fn pick(&self, name: Option<&str>) -> anyhow::Result<&Endpoint> {
        let names = || {
            self.0
                .iter()
                .map(|e| e.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        };
        match name {
            Some(name) => self.0.iter().find(|e| e.name == name).ok_or_else(|| {
                anyhow::anyhow!(
                    "PACS {name:?}: not configured; expected one of: {}",
                    names()
                )
            }),
            None => match self.0.as_slice() {
                [only] => Ok(only),
                [] => anyhow::bail!("no PACS configured: give --pacs NAME=URL"),
                _ => anyhow::bail!(
                    "several PACS configured ({}): say which with --from NAME",
                    names()
                ),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pacs_flags_name_the_part_that_is_wrong() {
        let e = parse_pacs("main=http://127.0.0.1:8042/dicom-web/").expect("valid");
        assert_eq!(e.base.as_str(), "http://127.0.0.1:8042/dicom-web");
        for (flag, words) in [
            ("http://x", "expected NAME=URL"),
            ("=http://x", "PACS name"),
            ("a b=http://x", "PACS name"),
            ("main=ftp://x/", "http:// or https://"),
            ("main=not a url", "expected the URL"),
            ("main=http://u:p@x/", "--pacs-auth"),
        ] {
            let err = parse_pacs(flag).expect_err(flag);
            assert!(err.contains(words), "{flag}: {err}");
        }
    }

    #[test]
    fn an_auth_file_holds_a_header_or_a_token() {
        let dir = tempfile::tempdir().expect("tempdir");
        let header = dir.path().join("header");
        std::fs::write(&header, "X-Api-Key: s3cret\n").expect("write");
        let token = dir.path().join("token");
        std::fs::write(&token, "abc.def.ghi\n").expect("write");
        let two = dir.path().join("two");
        std::fs::write(&two, "a\nb\n").expect("write");
        let endpoints = |file: &Path| {
            Endpoints::new(
                vec![parse_pacs("main=http://127.0.0.1:1").expect("valid")],
                &[("main".to_owned(), file.to_owned())],
            )
        };
        let e = endpoints(&header).expect("header");
        let (name, value) = e.all()[0].auth.clone().expect("auth");
        assert_eq!(
            (name.as_str(), value.to_str().ok()),
            ("x-api-key", Some("s3cret"))
        );
        assert!(
            !format!("{:?}", e.all()[0]).contains("s3cret"),
            "the secret is not printed"
        );
        let e = endpoints(&token).expect("token");
        let (name, value) = e.all()[0].auth.clone().expect("auth");
        assert_eq!(name, AUTHORIZATION);
        assert_eq!(value.to_str().ok(), Some("Bearer abc.def.ghi"));
        let err = endpoints(&two).expect_err("two lines").to_string();
        assert!(err.contains("not one line"), "{err}");
        let err = Endpoints::new(Vec::new(), &[("x".into(), header.clone())])
            .expect_err("no such PACS")
            .to_string();
        assert!(err.contains("no --pacs x=URL"), "{err}");
    }
}
