//! Which hosts and origins the console answers to, and the count of what it refused.
//!
//! - `Host`: every request must name this console (`[console] allowed_hosts`, plus the
//!   listen address, `localhost`, `127.0.0.1` and `[::1]` on the listen port), else 421.
//!   A `Host` without a port is judged by its name alone: browsers always send a
//!   non-default port, and HTTP/1.0 tools often send none.
//!   A DNS-rebinding page reaches the console under the attacker's own name, which is in
//!   no list; an IP literal cannot be rebound, so when the console listens on every
//!   interface any IP literal on its port is accepted too.
//! - `Origin`: a WebSocket handshake or a state-changing request (POST, PUT, PATCH,
//!   DELETE) that names an origin must name this console's own (`scheme://Host`) or one of
//!   `[console] allowed_origins`, else 403, logins on or off. Requests without `Origin` are
//!   judged by the guard in `lib.rs`: browsers send it on every such request, so its
//!   absence means a tool, allowed only with a bearer token or with logins off.

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicU64, Ordering};

use serde::Serialize;

/// A `Host` value split into its lower-cased name (IPv6 literals keep their brackets) and
/// port (`None` when absent).
fn split_host(host: &str) -> Option<(String, Option<u16>)> {
    let host = host.trim().to_ascii_lowercase();
    if host.is_empty() {
        return None;
    }
    if let Some(rest) = host.strip_prefix('[') {
        let (inside, after) = rest.split_once(']')?;
        let port = match after {
            "" => None,
            p => Some(p.strip_prefix(':')?.parse().ok()?),
        };
        return Some((format!("[{inside}]"), port));
    }
    match host.rsplit_once(':') {
        Some((name, port)) => Some((name.to_owned(), Some(port.parse().ok()?))),
        None => Some((host, None)),
    }
}

/// True when `name` (as [`split_host`] gives it) is an IP address literal.
fn is_ip_literal(name: &str) -> bool {
    let bare = name
        .strip_prefix('[')
        .and_then(|n| n.strip_suffix(']'))
        .unwrap_or(name);
    bare.parse::<IpAddr>().is_ok()
}

/// How often a request was refused for each reason since the console started.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct Refusals {
    /// `Host` not one this console answers to (421).
    pub host: u64,
    /// `Origin` not this console's, or missing on a cookie-authenticated change (403).
    pub origin: u64,
    /// Missing or wrong `X-CSRF-Token` on a cookie-authenticated change (403).
    pub csrf: u64,
    /// Logins refused for too many recent failures (429).
    pub login_throttled: u64,
    /// Logins refused because every password-hashing turn was taken (503).
    pub login_busy: u64,
    /// Logins with a wrong name or password (401).
    pub login_failed: u64,
}

impl Refusals {
    /// Each count with the name `/metrics` labels it with.
    pub fn labelled(&self) -> [(&'static str, u64); 6] {
        [
            ("host", self.host),
            ("origin", self.origin),
            ("csrf", self.csrf),
            ("login_throttled", self.login_throttled),
            ("login_busy", self.login_busy),
            ("login_failed", self.login_failed),
        ]
    }
}

/// A reason a request was refused, for [`Gate::count`].
#[derive(Debug, Clone, Copy)]
pub(crate) enum Refused {
    Host,
    Origin,
    Csrf,
    LoginThrottled,
    LoginBusy,
    LoginFailed,
}

/// The hosts and origins this console answers to.
#[derive(Debug)]
pub(crate) struct Gate {
    /// `http` or `https`.
    pub(crate) scheme: &'static str,
    /// The port the console listens on.
    port: u16,
    /// (name, port): a `None` port matches any.
    hosts: Vec<(String, Option<u16>)>,
    /// `allowed_hosts` has `*`: no `Host` check at all.
    any_host: bool,
    /// Listening on every interface: any IP literal on the listen port is this console.
    any_ip: bool,
    /// Extra origins, lower-cased, without a trailing slash.
    origins: Vec<String>,
    counts: [AtomicU64; 6],
}

impl Gate {
    /// The gate for a console on `listen` (the bound address), over TLS or not, with the
    /// configured extra hosts and origins.
    pub(crate) fn new(
        listen: SocketAddr,
        tls: bool,
        allowed_hosts: &[String],
        allowed_origins: &[String],
    ) -> Self {
        let port = listen.port();
        let mut hosts: Vec<(String, Option<u16>)> = ["localhost", "127.0.0.1", "[::1]"]
            .iter()
            .map(|h| ((*h).to_owned(), Some(port)))
            .collect();
        let any_ip = listen.ip().is_unspecified();
        if !any_ip {
            let name = match listen.ip() {
                IpAddr::V4(a) => a.to_string(),
                IpAddr::V6(a) => format!("[{a}]"),
            };
            hosts.push((name, Some(port)));
        }
        hosts.extend(allowed_hosts.iter().filter_map(|h| split_host(h)));
        Self {
            scheme: if tls { "https" } else { "http" },
            port,
            hosts,
            any_host: allowed_hosts.iter().any(|h| h.trim() == "*"),
            any_ip,
            origins: allowed_origins
                .iter()
                .map(|o| o.trim().trim_end_matches('/').to_ascii_lowercase())
                .collect(),
            counts: Default::default(),
        }
    }

    /// True when `host` (a `Host` header) names this console.
    pub(crate) fn host_ok(&self, host: &str) -> bool {
        if self.any_host {
            return true;
        }
        let Some((name, port)) = split_host(host) else {
            return false;
        };
        // The name is what DNS rebinding controls; the port only has to agree when given.
        let same_port = |p: Option<u16>| port.is_none() || p.is_none() || p == port;
        if self.any_ip && same_port(Some(self.port)) && is_ip_literal(&name) {
            return true;
        }
        self.hosts.iter().any(|(n, p)| *n == name && same_port(*p))
    }

    /// True when `origin` is this console's own (`scheme://host`, `host` the request's
    /// checked `Host`, or the listen address when it sent none) or an allowed one.
    pub(crate) fn origin_ok(&self, origin: &str, host: Option<&str>) -> bool {
        let origin = origin.trim().trim_end_matches('/').to_ascii_lowercase();
        if self.origins.contains(&origin) {
            return true;
        }
        let Some(rest) = origin
            .strip_prefix(self.scheme)
            .and_then(|r| r.strip_prefix("://"))
        else {
            return false;
        };
        match host {
            Some(h) => rest == h.trim().to_ascii_lowercase(),
            None => self.host_ok(rest),
        }
    }

    /// Counts one refusal.
    pub(crate) fn count(&self, why: Refused) {
        self.counts[why as usize].fetch_add(1, Ordering::Relaxed);
    }

    /// The counts now.
    pub(crate) fn refusals(&self) -> Refusals {
        let get = |w: Refused| self.counts[w as usize].load(Ordering::Relaxed);
        Refusals {
            host: get(Refused::Host),
            origin: get(Refused::Origin),
            csrf: get(Refused::Csrf),
            login_throttled: get(Refused::LoginThrottled),
            login_busy: get(Refused::LoginBusy),
            login_failed: get(Refused::LoginFailed),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn gate(listen: &str, hosts: &[&str], origins: &[&str]) -> Gate {
        let own = |v: &[&str]| v.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
        Gate::new(listen.parse().unwrap(), false, &own(hosts), &own(origins))
    }

    #[test]
    fn the_listen_address_and_loopback_names_on_its_port_are_allowed_hosts() {
        let g = gate("127.0.0.1:8640", &[], &[]);
        for ok in [
            "127.0.0.1:8640",
            "localhost:8640",
            "LocalHost:8640",
            "[::1]:8640",
            "localhost",
            "127.0.0.1",
        ] {
            assert!(g.host_ok(ok), "{ok}");
        }
        for bad in [
            "evil.example:8640",
            "localhost:8641",
            "localhost.:8640",
            "127.0.0.1.evil.example:8640",
            "10.0.0.5:8640",
            "",
            "[::1",
            "localhost:x",
        ] {
            assert!(!g.host_ok(bad), "{bad}");
        }
        let v6 = gate("[::1]:9000", &[], &[]);
        assert!(v6.host_ok("[::1]:9000") && !v6.host_ok("[::1]:8640"));
    }

    #[test]
    fn configured_hosts_are_added_and_a_star_turns_the_check_off() {
        let g = gate(
            "192.168.1.10:8640",
            &["console.ship.local", "Bridge:8080"],
            &[],
        );
        assert!(g.host_ok("192.168.1.10:8640"));
        assert!(g.host_ok("console.ship.local"), "no port: any port");
        assert!(g.host_ok("console.ship.local:8640"));
        assert!(g.host_ok("bridge:8080") && !g.host_ok("bridge:8640"));
        assert!(!g.host_ok("192.168.1.11:8640"));
        assert!(gate("127.0.0.1:1", &["*"], &[]).host_ok("anything:5"));
    }

    #[test]
    fn on_every_interface_ip_literals_on_the_port_are_allowed_but_names_are_not() {
        let g = gate("0.0.0.0:8640", &[], &[]);
        assert!(g.host_ok("10.1.2.3:8640") && g.host_ok("[fe80::1]:8640"));
        assert!(!g.host_ok("10.1.2.3:9999"));
        assert!(!g.host_ok("rebind.evil.example:8640"));
    }

    #[test]
    fn an_origin_must_be_the_consoles_own_or_configured() {
        let g = gate("127.0.0.1:8640", &[], &["https://Ops.example.org/"]);
        let host = Some("127.0.0.1:8640");
        assert!(g.origin_ok("http://127.0.0.1:8640", host));
        assert!(g.origin_ok("https://ops.example.org", host));
        for bad in [
            "http://evil.example",
            "null",
            "https://127.0.0.1:8640",
            "http://localhost:8640",
            "http://127.0.0.1:8640.evil.example",
        ] {
            assert!(!g.origin_ok(bad, host), "{bad}");
        }
        // Without Host, the origin must name an allowed host itself.
        assert!(g.origin_ok("http://localhost:8640", None));
        assert!(!g.origin_ok("http://evil.example:8640", None));
        let tls = Gate::new("127.0.0.1:8643".parse().unwrap(), true, &[], &[]);
        assert!(tls.origin_ok("https://127.0.0.1:8643", Some("127.0.0.1:8643")));
        assert!(!tls.origin_ok("http://127.0.0.1:8643", Some("127.0.0.1:8643")));
        assert!(tls.host_ok("localhost:8643"));
    }
}
