//! [`AppError`]: what an HTTP handler can fail with, and the response each becomes.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};

/// A handler's failure.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// The request is malformed or out of range; the message says which field and
    /// what was expected. Answered with 400 and not logged.
    #[error("{0}")]
    BadRequest(String),
    /// The caller may not see the named thing. Answered with 403.
    #[error("{0}")]
    Forbidden(String),
    /// The named thing does not exist. Answered with 404.
    #[error("{0}")]
    NotFound(String),
    /// A PACS the server asked failed or answered what it should not; the
    /// message names the PACS and the request. Answered with 502.
    #[error("{0}")]
    BadGateway(String),
    /// The server is at capacity; the client may retry. Answered with 503.
    #[error("{0}")]
    Busy(String),
    /// The client holds as much as one client may; it may retry once it has
    /// let some go. Answered with 429.
    #[error("{0}")]
    TooMany(String),
    /// The volume data the view needs cannot be read: a file of the store is
    /// missing or damaged. Logged; answered with 500 and the reason, naming the
    /// file, so the client shows it (never an image with the data left out).
    #[error("the volume data of this view cannot be read: {0}")]
    DataUnreadable(String),
    /// Something broke inside the server. Logged once here; the client sees a
    /// generic 500.
    #[error("internal error: {0}")]
    Internal(String),
}

impl AppError {
    /// Logs the error if it is one the server's operator must see (data that
    /// cannot be read, internal failures); returns it.
    pub fn logged(self) -> AppError {
        match &self {
            AppError::DataUnreadable(_) | AppError::Internal(_) => tracing::error!("{self}"),
            _ => {}
        }
        self
    }
}

/// Seconds a client refused for want of capacity (503, 429) is asked to wait
/// before it tries again (`Retry-After`); the web client doubles it on each
/// refusal in a row.
pub const RETRY_AFTER_S: u32 = 2;

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let retry = matches!(self, AppError::Busy(_) | AppError::TooMany(_));
        let (status, message) = match self {
            AppError::BadRequest(m) => (StatusCode::BAD_REQUEST, m),
            AppError::Forbidden(m) => (StatusCode::FORBIDDEN, m),
            AppError::NotFound(m) => (StatusCode::NOT_FOUND, m),
            AppError::BadGateway(m) => (StatusCode::BAD_GATEWAY, m),
            AppError::Busy(m) => (StatusCode::SERVICE_UNAVAILABLE, m),
            AppError::TooMany(m) => (StatusCode::TOO_MANY_REQUESTS, m),
            e @ AppError::DataUnreadable(_) => {
                let message = e.logged().to_string();
                (StatusCode::INTERNAL_SERVER_ERROR, message)
            }
            AppError::Internal(m) => {
                tracing::error!("{m}");
                (
                    StatusCode::INTERNAL_SERVER_ERROR,
                    "internal server error (logged on the server)".to_owned(),
                )
            }
        };
        let mut response = (status, Json(serde_json::json!({ "error": message }))).into_response();
        if retry {
            response.headers_mut().insert(
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from(RETRY_AFTER_S),
            );
        }
        response
    }
}
