//! `shoal query`: a read-only SPARQL query against a running station (SPARQL 1.1 Protocol,
//! `POST /api/sparql` with an `application/sparql-query` body), and the one HTTP client
//! every CLI call to the station's API goes through ([`ApiClient`], on `reqwest` with
//! rustls). With logins on (the default) each call sends `Authorization: Bearer <token>`:
//! `--token`, else the `SHOAL_TOKEN` environment variable. When the console serves HTTPS
//! (`[console.tls]`) calls go over TLS and trust the console's own certificate, or the one
//! `--ca` names.

use std::io::Read;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use reqwest::header::{AUTHORIZATION, CONTENT_TYPE, HeaderValue};

/// The environment variable CLI calls take their API token from.
pub const TOKEN_VAR: &str = "SHOAL_TOKEN";

/// The longest a CLI call waits for the station's answer.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(30);

/// The token in `SHOAL_TOKEN`, when set and not blank.
fn env_token() -> Option<String> {
    std::env::var(TOKEN_VAR)
        .ok()
        .filter(|t| !t.trim().is_empty())
}

/// Where a CLI call finds the station's API and what it trusts there.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Target {
    /// `http://host:port` or `https://host:port`, no path.
    pub base: String,
    /// PEM certificates to trust for HTTPS (the console's own, or its CA).
    pub ca: Option<PathBuf>,
}

impl Target {
    /// The API from `--station` (an address or an `http(s)://` URL) and `--ca`, or else
    /// from the console's configuration: HTTPS trusting its certificate when
    /// `[console.tls]` is on, plain HTTP otherwise. A listen address of 0.0.0.0 or [::]
    /// is reached on loopback.
    pub fn new(
        station: Option<&str>,
        ca: Option<&Path>,
        listen: SocketAddr,
        tls_cert: Option<&Path>,
    ) -> Result<Self> {
        let tls = tls_cert.is_some();
        let base = match station.map(str::trim) {
            Some(s) if s.starts_with("http://") || s.starts_with("https://") => {
                let url = reqwest::Url::parse(s).with_context(|| format!("--station {s}"))?;
                if url.path() != "/" || url.query().is_some() || url.host().is_none() {
                    bail!("--station {s}: give the scheme, host and port only");
                }
                s.trim_end_matches('/').to_string()
            }
            Some(s) => {
                let addr: SocketAddr = s.parse().with_context(|| {
                    format!("--station {s}: not host:port or an http(s):// URL")
                })?;
                format!("{}://{}", if tls { "https" } else { "http" }, addr)
            }
            None => {
                let mut addr = listen;
                if addr.ip().is_unspecified() {
                    addr.set_ip(if addr.is_ipv4() {
                        std::net::Ipv4Addr::LOCALHOST.into()
                    } else {
                        std::net::Ipv6Addr::LOCALHOST.into()
                    });
                }
                format!("{}://{}", if tls { "https" } else { "http" }, addr)
            }
        };
        let ca = ca.or(tls_cert).map(Path::to_path_buf);
        Ok(Self { base, ca })
    }

    /// Plain HTTP to `addr` (the benchmarks' own loopback stations).
    pub fn plain(addr: SocketAddr) -> Self {
        Self {
            base: format!("http://{addr}"),
            ca: None,
        }
    }
}

/// An HTTP client for the station's API: one connection pool, the target's trust, and
/// the bearer token.
#[derive(Debug, Clone)]
pub struct ApiClient {
    base: String,
    http: reqwest::Client,
    auth: Option<HeaderValue>,
}

impl ApiClient {
    /// A client for `target`, sending `token` (or else `SHOAL_TOKEN`'s) as its bearer
    /// credential. Fails on a token that cannot be a header value or an unreadable CA.
    pub fn new(target: &Target, token: Option<&str>) -> Result<Self> {
        let token = token.map(str::to_owned).or_else(env_token);
        let auth = authorization(token.as_deref())?;
        let mut builder = reqwest::Client::builder()
            .timeout(ANSWER_TIMEOUT)
            .connect_timeout(Duration::from_secs(5))
            .redirect(reqwest::redirect::Policy::none())
            .no_proxy()
            .tls_built_in_root_certs(false);
        if target.base.starts_with("https://") {
            let Some(path) = &target.ca else {
                bail!(
                    "{} is HTTPS: name the certificate to trust with --ca (the console's [console.tls] cert, or its CA)",
                    target.base
                );
            };
            let pem = std::fs::read(path)
                .with_context(|| format!("cannot read the certificate {}", path.display()))?;
            let certs = reqwest::Certificate::from_pem_bundle(&pem)
                .with_context(|| format!("{} holds no PEM certificate", path.display()))?;
            if certs.is_empty() {
                bail!("{} holds no PEM certificate", path.display());
            }
            for c in certs {
                builder = builder.add_root_certificate(c);
            }
        }
        let http = builder.build().context("cannot set up the HTTP client")?;
        Ok(Self {
            base: target.base.clone(),
            http,
            auth,
        })
    }

    /// One request to `path` (with a `(content type, body)`), the status code and the
    /// body as text.
    pub async fn request(
        &self,
        method: reqwest::Method,
        path: &str,
        body: Option<(&str, String)>,
    ) -> Result<(u16, String)> {
        let url = format!("{}{path}", self.base);
        let mut req = self.http.request(method, &url);
        if let Some(auth) = &self.auth {
            req = req.header(AUTHORIZATION, auth.clone());
        }
        if let Some((content_type, content)) = body {
            req = req.header(CONTENT_TYPE, content_type).body(content);
        }
        let response = req.send().await.map_err(|e| {
            let hint = if e.is_connect() {
                " (is `shoal station` or `shoal up` running, and does the --ca certificate match the console's?)"
            } else {
                ""
            };
            anyhow::Error::new(e).context(format!("no answer from the station API at {}{hint}", self.base))
        })?;
        let status = response.status().as_u16();
        let text = response
            .text()
            .await
            .with_context(|| format!("the answer from {url} broke off"))?;
        Ok((status, text))
    }

    /// POSTs `query` to the SPARQL endpoint, results in `format`.
    pub async fn sparql(&self, format: &str, query: &str) -> Result<(u16, String)> {
        self.request(
            reqwest::Method::POST,
            &format!("/api/sparql?format={format}"),
            Some(("application/sparql-query", query.to_owned())),
        )
        .await
    }
}

/// Sends the query, prints the results, fails with the station's message on an error.
pub async fn run(sparql: &str, format: &str, client: &ApiClient) -> Result<()> {
    let query = if sparql == "-" {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .context("cannot read standard input")?;
        s
    } else {
        sparql.to_string()
    };
    let (status, body) = client.sparql(format, &query).await?;
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
        let hint = if client.auth.is_some() {
            "the token was refused: is it revoked, or for another station?"
        } else {
            "the station requires a login: pass an API token with --token or SHOAL_TOKEN"
        };
        bail!("the station answered 401: {message} ({hint})");
    }
    bail!("the station answered {status}: {message}")
}

/// The `Authorization` header for `token`; a token that would break the header (a space,
/// a line break, a control character) is refused rather than sent.
fn authorization(token: Option<&str>) -> Result<Option<HeaderValue>> {
    let Some(token) = token.map(str::trim) else {
        return Ok(None);
    };
    if token.is_empty() || !token.bytes().all(|b| b.is_ascii_graphic()) {
        bail!("the API token must be printable ASCII without spaces");
    }
    let mut value = HeaderValue::from_str(&format!("Bearer {token}"))
        .context("the API token cannot be sent in a header")?;
    value.set_sensitive(true);
    Ok(Some(value))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[test]
    fn the_token_becomes_a_bearer_header_and_cannot_inject_others() {
        assert_eq!(authorization(None).unwrap(), None);
        assert_eq!(
            authorization(Some(" shoal_ab12 ")).unwrap().unwrap(),
            "Bearer shoal_ab12"
        );
        for bad in ["", "a b", "x\r\nX-Evil: 1", "tök"] {
            assert!(authorization(Some(bad)).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn the_target_follows_the_flags_then_the_console_configuration() {
        let listen: SocketAddr = "0.0.0.0:8640".parse().unwrap();
        let cert = Path::new("/keys/console.crt");
        let t = |station, ca, tls| Target::new(station, ca, listen, tls).unwrap();
        assert_eq!(t(None, None, None).base, "http://127.0.0.1:8640");
        let https = t(None, None, Some(cert));
        assert_eq!(https.base, "https://127.0.0.1:8640");
        assert_eq!(https.ca.as_deref(), Some(cert));
        assert_eq!(
            t(Some("10.0.0.5:9000"), None, Some(cert)).base,
            "https://10.0.0.5:9000"
        );
        let named = t(
            Some("https://station.local:8443/"),
            Some(Path::new("ca.pem")),
            None,
        );
        assert_eq!(named.base, "https://station.local:8443");
        assert_eq!(named.ca.as_deref(), Some(Path::new("ca.pem")));
        for bad in ["station", "http://h:1/api", "ftp//x"] {
            assert!(Target::new(Some(bad), None, listen, None).is_err(), "{bad}");
        }
        // HTTPS without a certificate to trust is refused before any connection.
        let err = ApiClient::new(&t(Some("https://127.0.0.1:1"), None, None), None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("--ca"), "{err}");
        // A CA file that is missing, or holds no certificate, is named.
        let dir = std::env::temp_dir().join(format!("shoal-query-ca-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let junk = dir.join("junk.pem");
        std::fs::write(&junk, "not a certificate\n").unwrap();
        for (ca, says) in [
            (dir.join("missing.pem"), "cannot read the certificate"),
            (junk, "holds no PEM certificate"),
        ] {
            let target = Target::new(Some("https://127.0.0.1:1"), Some(&ca), listen, None).unwrap();
            let err = format!("{:#}", ApiClient::new(&target, None).unwrap_err());
            assert!(
                err.contains(says) && err.contains(&*ca.to_string_lossy()),
                "{err}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
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
            s.write_all(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\nConnection: close\r\n\r\nok")
                .await
                .unwrap();
            String::from_utf8_lossy(&got).into_owned()
        });
        (addr, task)
    }

    #[tokio::test]
    async fn a_given_token_is_sent_as_a_bearer_credential() {
        let (addr, seen) = echo_server().await;
        let client = ApiClient::new(&Target::plain(addr), Some("shoal_t0k")).unwrap();
        let (status, body) = client
            .request(reqwest::Method::GET, "/api/fleet", None)
            .await
            .unwrap();
        assert_eq!((status, body.as_str()), (200, "ok"));
        let seen = seen.await.unwrap().to_ascii_lowercase();
        assert!(
            seen.contains("\r\nauthorization: bearer shoal_t0k\r\n"),
            "{seen}"
        );
        let (addr, seen) = echo_server().await;
        let client = ApiClient {
            auth: None,
            ..ApiClient::new(&Target::plain(addr), None).unwrap()
        };
        client
            .request(reqwest::Method::GET, "/api/fleet", None)
            .await
            .unwrap();
        assert!(
            !seen
                .await
                .unwrap()
                .to_ascii_lowercase()
                .contains("authorization")
        );
    }
}
