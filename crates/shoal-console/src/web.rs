//! The web console's files, built by `build.rs` (Vite) and embedded in the binary.

use axum::http::{HeaderValue, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};

use crate::ApiError;

include!(concat!(env!("OUT_DIR"), "/web_assets.rs"));

/// The browser may load only what the station serves (and inline images it draws): the
/// console works without the internet, and this makes the browser enforce it.
const CSP: &str = "default-src 'self'; img-src 'self' data: blob:; style-src 'self' 'unsafe-inline'; \
                   connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'; \
                   form-action 'self'";

/// The embedded file at `path` (`/` is `/index.html`): (media type, contents).
pub fn asset(path: &str) -> Option<(&'static str, &'static [u8])> {
    let path = if path == "/" { "/index.html" } else { path };
    ASSETS
        .iter()
        .find(|(p, _, _)| *p == path)
        .map(|(_, mime, bytes)| (*mime, *bytes))
}

/// Every embedded path, for tests and diagnostics.
pub fn asset_paths() -> impl Iterator<Item = &'static str> {
    ASSETS.iter().map(|(p, _, _)| *p)
}

/// Serves the console's files; anything else under `/api/` is a JSON 404.
pub(crate) async fn serve(uri: Uri) -> Response {
    let path = uri.path();
    if path.starts_with("/api/") || path == "/api" {
        return ApiError::NotFound(format!("no API endpoint {path}")).into_response();
    }
    let Some((mime, bytes)) = asset(path) else {
        return (
            StatusCode::NOT_FOUND,
            [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
            format!(
                "{path} is not part of the console: open / (or /status.html without JavaScript)\n"
            ),
        )
            .into_response();
    };
    let mut res = (StatusCode::OK, bytes).into_response();
    let h = res.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(mime));
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    // Vite puts a content hash in every asset name, so they never change; the page must be
    // fetched again to pick up a new build.
    let cache = if path.starts_with("/assets/") {
        "public, max-age=31536000, immutable"
    } else {
        "no-cache"
    };
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static(cache));
    if mime.starts_with("text/html") {
        h.insert(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static(CSP),
        );
        h.insert(
            header::REFERRER_POLICY,
            HeaderValue::from_static("no-referrer"),
        );
    }
    res
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_bundle_has_a_page_that_loads_only_its_own_files() {
        let (mime, page) = asset("/").unwrap();
        assert!(mime.starts_with("text/html"));
        let page = std::str::from_utf8(page).unwrap();
        // Every script and stylesheet the page names is embedded, under /assets/.
        let refs: Vec<&str> = page
            .split(['"', '\''])
            .filter(|s| s.starts_with("/assets/"))
            .collect();
        assert!(refs.iter().any(|r| r.ends_with(".js")), "{page}");
        for r in &refs {
            assert!(
                asset(r).is_some(),
                "{r} is named by index.html but not embedded"
            );
        }
        assert!(!page.contains("http://") && !page.contains("https://"));
        assert!(asset_paths().all(|p| p == "/index.html" || p.starts_with("/assets/")));
    }

    #[test]
    fn the_scripts_fetch_nothing_from_other_hosts() {
        for path in asset_paths().filter(|p| p.ends_with(".js") || p.ends_with(".css")) {
            let text = String::from_utf8_lossy(asset(path).unwrap().1);
            // Namespace and CRS identifiers are URIs but are never fetched.
            for (i, _) in text.match_indices("://") {
                let start = text[..i].rfind(['"', '\'', '`', '(']).map_or(0, |s| s + 1);
                let url = &text[start..(i + 60).min(text.len())];
                let known = [
                    "http://www.w3.org/",
                    "http://www.opengis.net/",
                    "https://example.invalid/",
                ];
                let dynamic = url.starts_with("${") || url.contains("//${");
                assert!(
                    known.iter().any(|k| url.starts_with(k)) || dynamic,
                    "{path} names an outside URL: {url}"
                );
            }
        }
    }
}
