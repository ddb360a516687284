//! `shoal query`: a read-only SPARQL query against a running station (SPARQL 1.1 Protocol,
//! `POST /api/sparql` with an `application/sparql-query` body), and the one HTTP client
//! every CLI call to the station's API goes through. With logins on (the default) each
//! call sends `Authorization: Bearer <token>`: `--token`, else the `SHOAL_TOKEN`
//! environment variable.

use std::io::Read;
use std::net::SocketAddr;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// The environment variable CLI calls take their API token from.
pub const TOKEN_VAR: &str = "SHOAL_TOKEN";

/// The token in `SHOAL_TOKEN`, when set and not blank.
fn env_token() -> Option<String> {
    std::env::var(TOKEN_VAR)
        .ok()
        .filter(|t| !t.trim().is_empty())
}

/// Sends the query (with `token` as its bearer credential, if any), prints the results,
/// fails with the station's message on an error.
pub async fn run(
    sparql: &str,
    format: &str,
    station: SocketAddr,
    token: Option<&str>,
) -> Result<()> {
    let query = if sparql == "-" {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .context("cannot read standard input")?;
        s
    } else {
        sparql.to_string()
    };
    let (status, body) = tokio::time::timeout(
        Duration::from_secs(30),
        post_with(station, token, format, &query),
    )
    .await
    .context("the station did not answer within 30 s")??;
    if status == 200 {
        print!("{body}");
        return Ok(());
    }
    // Errors come as {"error": "..."}; show the message alone.
    let message = serde_json::from_str::<serde_json::Value>(&body)
        .ok()
        .and_then(|v| v.get("error").and_then(|e| e.as_str()).map(str::to_string))
        .unwrap_or(body);
    if status == 401 {
        let hint = if token.is_some() {
            "the token was refused: is it revoked, or for another station?"
        } else {
            "the station requires a login: pass an API token with --token or SHOAL_TOKEN"
        };
        bail!("the station answered 401: {message} ({hint})");
    }
    bail!("the station answered {status}: {message}")
}

/// POSTs `query` to the station's SPARQL endpoint with the token of `SHOAL_TOKEN`, if
/// set; the status code and the body.
pub(crate) async fn post(station: SocketAddr, format: &str, query: &str) -> Result<(u16, String)> {
    post_with(station, env_token().as_deref(), format, query).await
}

/// [`post`] with `token` as the bearer credential.
pub(crate) async fn post_with(
    station: SocketAddr,
    token: Option<&str>,
    format: &str,
    query: &str,
) -> Result<(u16, String)> {
    request_with(
        station,
        token,
        "POST",
        &format!("/api/sparql?format={format}"),
        Some(("application/sparql-query", query)),
    )
    .await
}

/// One HTTP/1.1 request to the station's API with the token of `SHOAL_TOKEN`, if set
/// (`Connection: close`); the status code and the body (de-chunked).
pub(crate) async fn request(
    station: SocketAddr,
    method: &str,
    path: &str,
    body: Option<(&str, &str)>,
) -> Result<(u16, String)> {
    request_with(station, env_token().as_deref(), method, path, body).await
}

/// The `Authorization` header line for `token`; a token that would break the header (a
/// space, a line break, a control character) is refused rather than sent.
fn authorization(token: Option<&str>) -> Result<String> {
    let Some(token) = token.map(str::trim) else {
        return Ok(String::new());
    };
    if token.is_empty() || !token.bytes().all(|b| b.is_ascii_graphic()) {
        bail!("the API token must be printable ASCII without spaces");
    }
    Ok(format!("Authorization: Bearer {token}\r\n"))
}

/// [`request`] with `token` as the bearer credential.
pub(crate) async fn request_with(
    station: SocketAddr,
    token: Option<&str>,
    method: &str,
    path: &str,
    body: Option<(&str, &str)>,
) -> Result<(u16, String)> {
    let auth = authorization(token)?;
    let mut s = tokio::net::TcpStream::connect(station)
        .await
        .with_context(|| {
            format!("no station API at {station} (is `shoal station` or `shoal up` running?)")
        })?;
    let (content_type, content) = body.unwrap_or(("text/plain", ""));
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {station}\r\n{auth}Content-Type: {content_type}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{content}",
        content.len()
    );
    s.write_all(request.as_bytes()).await?;
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).await?;
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .context("malformed HTTP response")?;
    let (head, body) = (
        String::from_utf8_lossy(&raw[..split]).into_owned(),
        &raw[split + 4..],
    );
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse::<u16>().ok())
        .context("malformed HTTP status line")?;
    let chunked = head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked");
    let body = if chunked {
        dechunk(body)?
    } else {
        body.to_vec()
    };
    Ok((status, String::from_utf8_lossy(&body).into_owned()))
}

/// Decodes an HTTP/1.1 chunked body (hex size line, data, CRLF; a zero size ends it),
/// on bytes, since a chunk may end inside a UTF-8 character.
fn dechunk(mut body: &[u8]) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    loop {
        let eol = body
            .windows(2)
            .position(|w| w == b"\r\n")
            .context("malformed chunk")?;
        let line = std::str::from_utf8(&body[..eol]).context("bad chunk size")?;
        let size = usize::from_str_radix(line.split(';').next().unwrap_or("").trim(), 16)
            .context("bad chunk size")?;
        if size == 0 {
            return Ok(out);
        }
        let rest = &body[eol + 2..];
        out.extend_from_slice(rest.get(..size).context("truncated chunk")?);
        body = rest
            .get(size..)
            .and_then(|r| r.strip_prefix(b"\r\n"))
            .context("malformed chunk end")?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunked_bodies_are_reassembled() {
        assert_eq!(
            dechunk(b"4\r\nv,b\n\r\n3\r\nx,1\r\n0\r\n\r\n").unwrap(),
            b"v,b\nx,1"
        );
        // A chunk boundary inside a UTF-8 character (é = c3 a9).
        assert_eq!(
            dechunk(b"1\r\n\xc3\r\n1\r\n\xa9\r\n0\r\n\r\n").unwrap(),
            "é".as_bytes()
        );
        assert!(dechunk(b"zz\r\n").is_err());
    }

    #[test]
    fn the_token_becomes_a_bearer_header_and_cannot_inject_others() {
        assert_eq!(authorization(None).unwrap(), "");
        assert_eq!(
            authorization(Some(" shoal_ab12 ")).unwrap(),
            "Authorization: Bearer shoal_ab12\r\n"
        );
        for bad in ["", "a b", "x\r\nX-Evil: 1", "tök"] {
            assert!(authorization(Some(bad)).is_err(), "{bad:?}");
        }
    }

    /// A one-shot server on 127.0.0.1 that answers 200 and hands back what it was sent.
    async fn echo_server() -> (SocketAddr, tokio::task::JoinHandle<String>) {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let task = tokio::spawn(async move {
            let (mut s, _) = listener.accept().await.unwrap();
            let mut got = Vec::new();
            let mut buf = [0u8; 4096];
            while !got.windows(4).any(|w| w == b"\r\n\r\n") {
                let n = s.read(&mut buf).await.unwrap();
                if n == 0 {
                    break;
                }
                got.extend_from_slice(&buf[..n]);
            }
            s.write_all(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\nok")
                .await
                .unwrap();
            String::from_utf8_lossy(&got).into_owned()
        });
        (addr, task)
    }

    #[tokio::test]
    async fn a_given_token_is_sent_as_a_bearer_credential() {
        let (addr, seen) = echo_server().await;
        let (status, body) = request_with(addr, Some("shoal_t0k"), "GET", "/api/fleet", None)
            .await
            .unwrap();
        assert_eq!((status, body.as_str()), (200, "ok"));
        let seen = seen.await.unwrap();
        assert!(
            seen.contains("\r\nAuthorization: Bearer shoal_t0k\r\n"),
            "{seen}"
        );
        let (addr, seen) = echo_server().await;
        request_with(addr, None, "GET", "/api/fleet", None)
            .await
            .unwrap();
        assert!(!seen.await.unwrap().contains("Authorization"));
    }
}
