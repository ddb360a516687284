//! `shoal query`: a read-only SPARQL query against a running station (SPARQL 1.1 Protocol,
//! `POST /api/sparql` with an `application/sparql-query` body).

use std::io::Read;
use std::net::SocketAddr;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Sends the query, prints the results, fails with the station's message on an error.
pub async fn run(sparql: &str, format: &str, station: SocketAddr) -> Result<()> {
    let query = if sparql == "-" {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .context("cannot read standard input")?;
        s
    } else {
        sparql.to_string()
    };
    let (status, body) =
        tokio::time::timeout(Duration::from_secs(30), post(station, format, &query))
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
    bail!("the station answered {status}: {message}")
}

/// POSTs `query` to the station's SPARQL endpoint; the status code and the body.
pub(crate) async fn post(station: SocketAddr, format: &str, query: &str) -> Result<(u16, String)> {
    request(
        station,
        "POST",
        &format!("/api/sparql?format={format}"),
        Some(("application/sparql-query", query)),
    )
    .await
}

/// One HTTP/1.1 request to the station's API (`Connection: close`); the status code and
/// the body (de-chunked).
pub(crate) async fn request(
    station: SocketAddr,
    method: &str,
    path: &str,
    body: Option<(&str, &str)>,
) -> Result<(u16, String)> {
    let mut s = tokio::net::TcpStream::connect(station)
        .await
        .with_context(|| {
            format!("no station API at {station} (is `shoal station` or `shoal up` running?)")
        })?;
    let (content_type, content) = body.unwrap_or(("text/plain", ""));
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {station}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{content}",
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
}
