//! The web client: the files of `web/`, compiled into the binary so `voxserve`
//! serves them from wherever it runs.

use axum::http::{HeaderValue, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};
use rust_embed::RustEmbed;

use crate::AppError;

/// The files of `web/`.
#[derive(RustEmbed)]
#[folder = "../web/"]
struct Assets;

/// Serves `path` from the embedded client; `/` is `index.html`.
pub fn asset(uri: &Uri) -> Result<Response, AppError> {
    let path = uri.path().trim_start_matches('/');
    let path = if path.is_empty() { "index.html" } else { path };
    let file =
        Assets::get(path).ok_or_else(|| AppError::NotFound(format!("no such file: /{path}")))?;
    let mime = mime_guess::from_path(path).first_or_octet_stream();
    let content_type = HeaderValue::from_str(mime.as_ref())
        .unwrap_or(HeaderValue::from_static("application/octet-stream"));
    Ok((
        StatusCode::OK,
        [
            (header::CONTENT_TYPE, content_type),
            // The client is small and changes with the binary: always revalidate.
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        file.data,
    )
        .into_response())
}
