//! Request bodies and the errors axum's own extractors make, in the API's one error form.
//!
//! - [`ApiJson`] takes a JSON object body: 415 when it is not sent as JSON, 413 when it
//!   is too large, 400 when it is not JSON, 422 when it is JSON of the wrong shape (an
//!   array where an object is wanted, a missing or unknown member). serde would read a
//!   struct from an array of its fields in order; the API documents objects only.
//! - [`json_errors`] rewrites any remaining plain-text error under `/api/` (a path that is
//!   not UTF-8, a method the path does not have) as `{"error": ...}`, keeping its status
//!   and headers, so every error a client sees has the documented form.

use axum::Json;
use axum::body::{Body, Bytes};
use axum::extract::rejection::{BytesRejection, JsonRejection};
use axum::extract::{FromRequest, Request};
use axum::http::{HeaderMap, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde::de::DeserializeOwned;

use crate::ApiError;

/// A JSON object request body, read as `T`.
#[derive(Debug)]
pub(crate) struct ApiJson<T>(pub(crate) T);

impl<S, T> FromRequest<S> for ApiJson<T>
where
    S: Send + Sync,
    T: DeserializeOwned,
{
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        let headers = req.headers().clone();
        if !is_json(&headers) {
            return Err(ApiError::UnsupportedMediaType(
                "send the body as application/json".into(),
            ));
        }
        let body = Bytes::from_request(req, state)
            .await
            .map_err(|e| bytes_rejection(&e))?;
        parse(&body).map(Self)
    }
}

/// True when the request says its body is JSON (`application/json` or `+json`).
pub(crate) fn is_json(headers: &HeaderMap) -> bool {
    let Some(ct) = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
    else {
        return false;
    };
    let essence = ct
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    essence == "application/json"
        || (essence.starts_with("application/") && essence.ends_with("+json"))
}

/// Reads a JSON object body as `T` (see the module's statuses).
pub(crate) fn parse<T: DeserializeOwned>(body: &[u8]) -> Result<T, ApiError> {
    let mut value: serde_json::Value = serde_json::from_slice(body)
        .map_err(|e| ApiError::BadRequest(format!("the body is not JSON: {e}")))?;
    if !value.is_object() {
        return Err(ApiError::Unprocessable(
            "the body must be a JSON object".into(),
        ));
    }
    // JSON has one number type: `155.0` is the integer 155 (JSON Schema says so too), but
    // serde refuses it for an integer field.
    if integral_floats_as_integers(&mut value) {
        let normalised =
            serde_json::to_vec(&value).map_err(|e| ApiError::Internal(e.to_string()))?;
        return Json::<T>::from_bytes(&normalised)
            .map(|Json(t)| t)
            .map_err(|e| json_rejection(&e));
    }
    // axum's reader names the member at fault (`tasks[0].task.kind: ...`).
    Json::<T>::from_bytes(body)
        .map(|Json(t)| t)
        .map_err(|e| json_rejection(&e))
}

/// Rewrites every float with no fractional part that fits an `i64` or `u64` as that
/// integer; true when it changed anything.
fn integral_floats_as_integers(v: &mut serde_json::Value) -> bool {
    use serde_json::Value;
    match v {
        Value::Number(n) if n.is_f64() => {
            let Some(f) = n.as_f64() else { return false };
            // The bounds are exact powers of two, so the comparisons are exact.
            #[allow(
                clippy::cast_possible_truncation,
                clippy::cast_sign_loss,
                clippy::cast_precision_loss
            )]
            let int = if f.fract() != 0.0 || !f.is_finite() {
                None
            } else if f >= -(2f64.powi(63)) && f < 2f64.powi(63) {
                Some(Value::from(f as i64))
            } else if f >= 0.0 && f < 2f64.powi(64) {
                Some(Value::from(f as u64))
            } else {
                None
            };
            int.map(|i| *v = i).is_some()
        }
        Value::Array(items) => items
            .iter_mut()
            .fold(false, |changed, i| integral_floats_as_integers(i) | changed),
        Value::Object(members) => members
            .values_mut()
            .fold(false, |changed, m| integral_floats_as_integers(m) | changed),
        _ => false,
    }
}

/// The API error for a JSON body axum could not read, with axum's status.
pub(crate) fn json_rejection(e: &JsonRejection) -> ApiError {
    match e.status() {
        StatusCode::UNPROCESSABLE_ENTITY => ApiError::Unprocessable(e.body_text()),
        StatusCode::UNSUPPORTED_MEDIA_TYPE => ApiError::UnsupportedMediaType(e.body_text()),
        StatusCode::PAYLOAD_TOO_LARGE => ApiError::PayloadTooLarge(e.body_text()),
        _ => ApiError::BadRequest(e.body_text()),
    }
}

/// The API error for a body that could not be read (too large, cut off).
pub(crate) fn bytes_rejection(e: &BytesRejection) -> ApiError {
    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::PayloadTooLarge(e.body_text())
    } else {
        ApiError::BadRequest(e.body_text())
    }
}

/// Longest plain-text error body [`json_errors`] reads to quote it.
const MAX_QUOTED: usize = 4096;

/// Middleware: plain-text errors under `/api/` become `{"error": ...}` (module doc).
pub(crate) async fn json_errors(req: Request, next: Next) -> Response {
    let api = req.uri().path().starts_with("/api/");
    let res = next.run(req).await;
    let status = res.status();
    if !api || !(status.is_client_error() || status.is_server_error()) {
        return res;
    }
    let is_json_already = res
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|ct| ct.starts_with("application/json"));
    if is_json_already {
        return res;
    }
    let (mut parts, body) = res.into_parts();
    let text = match axum::body::to_bytes(body, MAX_QUOTED).await {
        Ok(b) if !b.is_empty() => String::from_utf8_lossy(&b).into_owned(),
        _ => status
            .canonical_reason()
            .unwrap_or("error")
            .to_ascii_lowercase(),
    };
    let json = serde_json::json!({ "error": text }).to_string();
    parts.headers.remove(header::CONTENT_LENGTH);
    parts.headers.insert(
        header::CONTENT_TYPE,
        header::HeaderValue::from_static("application/json"),
    );
    Response::from_parts(parts, Body::from(json)).into_response()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Confirm {
        confirm: bool,
    }

    #[test]
    fn an_object_of_the_right_shape_is_read() {
        assert_eq!(
            parse::<Confirm>(br#"{"confirm": true}"#).unwrap(),
            Confirm { confirm: true }
        );
    }

    /// serde reads a struct from an array of its fields: `[true]` was accepted as
    /// `{"confirm": true}` (schemathesis found `[null, null]` creating a subscription).
    #[test]
    fn an_array_for_an_object_is_422() {
        assert!(matches!(
            parse::<Confirm>(b"[true]"),
            Err(ApiError::Unprocessable(_))
        ));
    }

    #[test]
    fn not_json_is_400_and_the_wrong_members_422() {
        assert!(matches!(
            parse::<Confirm>(b"\x00"),
            Err(ApiError::BadRequest(_))
        ));
        let Err(ApiError::Unprocessable(msg)) = parse::<Confirm>(br#"{"confirm": 1}"#) else {
            panic!("a number read as a bool");
        };
        assert!(msg.contains("confirm"), "{msg}");
        assert!(matches!(
            parse::<Confirm>(br#"{"confirm": true, "x": 1}"#),
            Err(ApiError::Unprocessable(_))
        ));
    }

    #[derive(Debug, Deserialize, PartialEq)]
    struct Times {
        at_ms: i64,
        seq: u64,
        speed: f64,
    }

    /// schemathesis sent `"expires_ms": 155.0`, a JSON Schema integer, and got 422.
    #[test]
    fn integral_floats_are_read_as_integers() {
        assert_eq!(
            parse::<Times>(br#"{"at_ms": 155.0, "seq": 1.8e19, "speed": 2.0}"#).unwrap(),
            Times {
                at_ms: 155,
                seq: 18_000_000_000_000_000_000,
                speed: 2.0
            }
        );
        // Found by schemathesis: a large integral float must be parsed exactly (the
        // default parser read this one as -3885740807046793.5, and the body got 422).
        assert_eq!(
            parse::<Times>(br#"{"at_ms": -3885740807046794.0, "seq": 1, "speed": 2}"#)
                .unwrap()
                .at_ms,
            -3_885_740_807_046_794
        );
        assert!(matches!(
            parse::<Times>(br#"{"at_ms": 155.5, "seq": 1, "speed": 2}"#),
            Err(ApiError::Unprocessable(_))
        ));
    }

    #[test]
    fn json_content_types_are_recognised() {
        let mut h = HeaderMap::new();
        assert!(!is_json(&h));
        for (ct, ok) in [
            ("application/json", true),
            ("Application/JSON; charset=utf-8", true),
            ("application/merge-patch+json", true),
            ("text/plain", false),
            ("application/jsonx", false),
        ] {
            h.insert(header::CONTENT_TYPE, ct.parse().unwrap());
            assert_eq!(is_json(&h), ok, "{ct}");
        }
    }
}
