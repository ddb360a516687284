//! Automatic IP ↔ acoustic link failover: which link a vehicle's data uses now
//! (docs/acoustic.md#link-failover).
//!
//! A vehicle with a radio or Wi-Fi link at the surface and an acoustic modem below it
//! sends over IP whenever the station can be reached there, and over the acoustic link
//! otherwise. [`Failover`] makes that decision without any I/O, from evidence the caller
//! feeds it, on a monotonic clock the caller passes in (so tests drive it step by step and
//! a step of the system clock changes nothing):
//!
//! - [`Failover::heard_ip`]: the station was heard over the IP path just now (the VDT
//!   feeds it when DDS has matched the station's readers to its IP-side writers: discovery
//!   traffic crossed the path both ways, and a match ends when the station's lease runs
//!   out, so silence ends it too), with how many readers are matched.
//! - [`Failover::ip_down`]: the IP path is gone for certain (its interface or participant
//!   went away): no reason to wait for a timeout.
//! - [`Failover::poll`]: the decision at `now`, and the [`Switch`] when it changed.
//!
//! Hysteresis, so a flapping radio at the surface does not thrash the vehicle between
//! links: IP is taken only after it has been heard without a gap, and with no reader
//! newly matched, for `up_after`, and never sooner than `min_acoustic` after falling back
//! to acoustic. A reader matched late restarts the wait because the station's side has
//! several readers (the station's own, a CDT's, a recorder's), each found by discovery on
//! its own: data moved to IP when only the first had matched would miss the others. The
//! way down has no delay beyond `down_after` of silence: data sent on a dead IP path is
//! lost, data sent acoustically while IP is still up is merely slower.

use std::time::Duration;

use serde::{Deserialize, Serialize};
use shoal_model::{Event, EventKind, LinkKind, Severity};
use tokio::time::Instant;

use crate::error::ConverterError;

/// `[vdt.ip]`: the vehicle's IP path to the station, beside its acoustic link. Seconds are
/// simulated seconds, like every converter duration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpPathConfig {
    /// Use the IP path when the station can be reached over it (off: acoustic only).
    pub enabled: bool,
    /// The station's DDS domain, joined over IP by the VDT's IP-side participant.
    pub domain_id: u16,
    /// Interfaces of the IP path (the radio's or Wi-Fi's address); loopback by default.
    pub interfaces: Vec<std::net::IpAddr>,
    /// The station must be heard over IP without a gap for this long before the vehicle
    /// moves its data there, s.
    pub up_after_s: f64,
    /// IP silent for this long: back to the acoustic link, s.
    pub down_after_s: f64,
    /// After falling back to acoustic, stay there at least this long, s.
    pub min_acoustic_s: f64,
    /// The IP-side participant exists only while the vehicle reports a depth of at most
    /// this, metres: a radio antenna works only above the water. `None`: always (the
    /// radio's own reach decides).
    pub radio_max_depth_m: Option<f64>,
    /// Open the IP participant without DDS Security (labs only). Anyone on the domain could
    /// then hand the vehicle tasks through it, so without this the IP path needs the
    /// vehicle's credentials ([`crate::run_vdt_secured`]).
    pub insecure: bool,
}

impl Default for IpPathConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            domain_id: 0,
            interfaces: vec![std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST)],
            // A few discovery rounds: a radio that just came up often drops again.
            up_after_s: 3.0,
            // Cyclone's lease on a silent peer is 10 s; a match we still hold after a
            // silent drop ends with it, so this only adds to that.
            down_after_s: 2.0,
            min_acoustic_s: 10.0,
            radio_max_depth_m: Some(0.5),
            insecure: false,
        }
    }
}

impl IpPathConfig {
    /// Checks the section; the error names the key.
    pub fn check(&self) -> Result<(), ConverterError> {
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(ConverterError::Config(format!(
                    "ip.{key} must be a positive number of seconds, not {v}"
                )))
            }
        };
        positive("up_after_s", self.up_after_s)?;
        positive("down_after_s", self.down_after_s)?;
        if !(self.min_acoustic_s.is_finite() && self.min_acoustic_s >= 0.0) {
            return Err(ConverterError::Config(format!(
                "ip.min_acoustic_s must be 0 or more seconds, not {}",
                self.min_acoustic_s
            )));
        }
        if self.domain_id > 232 {
            return Err(ConverterError::Config(format!(
                "ip.domain_id must be 0..=232, not {}",
                self.domain_id
            )));
        }
        if self.enabled && self.interfaces.is_empty() {
            return Err(ConverterError::Config(
                "ip.interfaces must list at least one address".into(),
            ));
        }
        if let Some(d) = self.radio_max_depth_m
            && !(d.is_finite() && d >= 0.0)
        {
            return Err(ConverterError::Config(format!(
                "ip.radio_max_depth_m must be 0 or more metres, not {d}"
            )));
        }
        Ok(())
    }

    /// The decision's timing in wall-clock time at `time_scale`.
    pub(crate) fn timing(&self, time_scale: f64) -> Timing {
        let wall = |s: f64| crate::common::wall(s, time_scale);
        Timing {
            up_after: wall(self.up_after_s),
            down_after: wall(self.down_after_s),
            min_acoustic: wall(self.min_acoustic_s),
        }
    }
}

/// The durations [`Failover`] decides by (wall-clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// IP heard without a gap this long before moving to it.
    pub up_after: Duration,
    /// IP silent this long: acoustic.
    pub down_after: Duration,
    /// Least time on acoustic after falling back.
    pub min_acoustic: Duration,
}

/// A change of link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Switch {
    /// The link now in use.
    pub to: LinkKind,
    /// When the decision was taken.
    pub at: Instant,
    /// How long the previous link was in use.
    pub after: Duration,
}

/// Which link a vehicle uses now: IP or acoustic (see the module docs).
#[derive(Debug, Clone)]
pub struct Failover {
    timing: Timing,
    link: LinkKind,
    /// Start of the current unbroken run of IP evidence.
    ip_since: Option<Instant>,
    /// Latest IP evidence.
    ip_heard: Option<Instant>,
    /// Readers matched at the latest evidence.
    readers: usize,
    /// When the link last changed (or the decision started).
    since: Instant,
    /// When the vehicle last fell back to acoustic.
    fell_back: Option<Instant>,
    switches: u64,
}

impl Failover {
    /// Starts on the acoustic link at `now`: IP has to prove itself first.
    pub fn new(timing: Timing, now: Instant) -> Self {
        Self {
            timing,
            link: LinkKind::Acoustic,
            ip_since: None,
            ip_heard: None,
            readers: 0,
            since: now,
            fell_back: None,
            switches: 0,
        }
    }

    /// The link in use.
    pub fn link(&self) -> LinkKind {
        self.link
    }

    /// Link changes so far.
    pub fn switches(&self) -> u64 {
        self.switches
    }

    /// Readers matched at the latest IP evidence (0 after the path went down).
    pub fn readers(&self) -> usize {
        self.readers
    }

    /// The station was heard over IP at `now`, with `readers` of its readers matched.
    pub fn heard_ip(&mut self, now: Instant, readers: usize) {
        // A gap longer than the silence timeout breaks the run: the path must prove itself
        // again for `up_after`. So does a reader matched since, while still on acoustic:
        // discovery is still crossing the path, and a reader not yet matched would miss
        // what goes over IP. On IP a new reader changes nothing.
        let fresh = self
            .ip_heard
            .is_some_and(|t| now.saturating_duration_since(t) < self.timing.down_after);
        let more = readers > self.readers && self.link == LinkKind::Acoustic;
        if !fresh || more {
            self.ip_since = Some(now);
        }
        self.ip_heard = Some(now);
        self.readers = readers;
    }

    /// The IP path is gone for certain at `now` (interface or participant down).
    pub fn ip_down(&mut self, _now: Instant) {
        self.ip_heard = None;
        self.ip_since = None;
        self.readers = 0;
    }

    /// The decision at `now`; the switch if it changed.
    pub fn poll(&mut self, now: Instant) -> Option<Switch> {
        let t = self.timing;
        let heard_recently = self
            .ip_heard
            .is_some_and(|h| now.saturating_duration_since(h) < t.down_after);
        let to = match self.link {
            LinkKind::Acoustic => {
                let steady = self
                    .ip_since
                    .is_some_and(|s| now.saturating_duration_since(s) >= t.up_after);
                let dwelt = self
                    .fell_back
                    .is_none_or(|f| now.saturating_duration_since(f) >= t.min_acoustic);
                (heard_recently && steady && dwelt).then_some(LinkKind::Ip)
            }
            _ => (!heard_recently).then_some(LinkKind::Acoustic),
        }?;
        let after = now.saturating_duration_since(self.since);
        self.link = to;
        self.since = now;
        self.switches += 1;
        if to == LinkKind::Acoustic {
            self.fell_back = Some(now);
            self.ip_since = None;
            self.readers = 0;
        }
        Some(Switch { to, at: now, after })
    }
}

/// The event that tells the station (and its console) a vehicle changed links: severity
/// info, kind `other`, id `<vehicle>-link-<ip|acoustic>-<ms>` (unique per switch, so the
/// history keeps every one, unlike the `link.<vehicle>` status that holds the latest).
pub fn switch_event(vehicle_id: &str, to: LinkKind, at_ms: i64, text: String) -> Event {
    let name = if to == LinkKind::Ip { "ip" } else { "acoustic" };
    Event {
        event_id: format!("{vehicle_id}-link-{name}-{at_ms}"),
        timestamp_ms: at_ms,
        severity: Severity::Info,
        kind: EventKind::Other,
        vehicle_id: vehicle_id.to_owned(),
        task_id: String::new(),
        text,
    }
}

/// Whether `e` is a [`switch_event`], and to which link.
pub fn switched_to(e: &Event) -> Option<LinkKind> {
    let rest = e.event_id.strip_prefix(e.vehicle_id.as_str())?;
    if e.kind != EventKind::Other {
        return None;
    }
    if rest.starts_with("-link-ip-") {
        Some(LinkKind::Ip)
    } else if rest.starts_with("-link-acoustic-") {
        Some(LinkKind::Acoustic)
    } else {
        None
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn timing() -> Timing {
        Timing {
            up_after: Duration::from_secs(3),
            down_after: Duration::from_secs(2),
            min_acoustic: Duration::from_secs(10),
        }
    }

    fn s(x: f64) -> Duration {
        Duration::from_secs_f64(x)
    }

    /// Feeds IP evidence every 0.5 s over `[from, to)` seconds after `t0`, polling each time;
    /// returns the switches.
    fn hear(f: &mut Failover, t0: Instant, from: f64, to: f64) -> Vec<(LinkKind, f64)> {
        let mut out = Vec::new();
        let mut x = from;
        while x < to {
            f.heard_ip(t0 + s(x), 1);
            if let Some(sw) = f.poll(t0 + s(x)) {
                out.push((sw.to, x));
            }
            x += 0.5;
        }
        out
    }

    #[test]
    fn starts_acoustic_and_takes_ip_only_once_it_has_been_heard_for_up_after() {
        let t0 = Instant::now();
        let mut f = Failover::new(timing(), t0);
        assert_eq!(f.link(), LinkKind::Acoustic);
        assert_eq!(f.poll(t0 + s(100.0)), None);
        let sw = hear(&mut f, t0, 20.0, 30.0);
        assert_eq!(sw, vec![(LinkKind::Ip, 23.0)]);
        assert_eq!(f.switches(), 1);
    }

    #[test]
    fn a_reader_matched_late_restarts_the_wait_on_acoustic_but_not_on_ip() {
        let t0 = Instant::now();
        let mut f = Failover::new(timing(), t0);
        // One reader from 0 s; a second (the station's, after a CDT's) at 2.5 s: IP only
        // 3 s after the second.
        assert_eq!(hear(&mut f, t0, 0.0, 2.5), vec![]);
        let mut switched = Vec::new();
        for half in 5..=12 {
            let at = t0 + s(f64::from(half) * 0.5);
            f.heard_ip(at, 2);
            switched.extend(f.poll(at).map(|w| (w.to, f64::from(half) * 0.5)));
        }
        assert_eq!(switched, vec![(LinkKind::Ip, 5.5)]);
        // On IP, more readers are no reason to leave it; fewer (but some) neither.
        f.heard_ip(t0 + s(6.0), 3);
        f.heard_ip(t0 + s(6.5), 1);
        assert_eq!(f.poll(t0 + s(6.5)), None);
        assert_eq!(f.link(), LinkKind::Ip);
    }

    #[test]
    fn silence_for_down_after_falls_back_to_acoustic_and_ip_down_at_once() {
        let t0 = Instant::now();
        let mut f = Failover::new(timing(), t0);
        hear(&mut f, t0, 0.0, 5.0);
        assert_eq!(f.link(), LinkKind::Ip);
        // Last heard at 4.5 s: still IP at 6.4 s, acoustic at 6.5 s.
        assert_eq!(f.poll(t0 + s(6.4)), None);
        let sw = f.poll(t0 + s(6.5)).unwrap();
        assert_eq!((sw.to, sw.after), (LinkKind::Acoustic, s(3.5)));

        // A path known to be gone needs no timeout.
        let mut f = Failover::new(timing(), t0);
        hear(&mut f, t0, 0.0, 5.0);
        f.ip_down(t0 + s(5.0));
        assert_eq!(f.poll(t0 + s(5.0)).map(|w| w.to), Some(LinkKind::Acoustic));
    }

    #[test]
    fn a_flapping_radio_does_not_thrash_the_vehicle_between_links() {
        let t0 = Instant::now();
        let mut f = Failover::new(timing(), t0);
        hear(&mut f, t0, 0.0, 5.0);
        assert_eq!(f.link(), LinkKind::Ip);
        // Up 1 s, down 3 s, for a minute: never 3 s without a gap, so after the first fall
        // back it stays acoustic.
        let mut switches = Vec::new();
        let mut x = 5.0;
        while x < 65.0 {
            switches.extend(hear(&mut f, t0, x, x + 1.0));
            if let Some(sw) = f.poll(t0 + s(x + 3.0)) {
                switches.push((sw.to, x + 3.0));
            }
            x += 4.0;
        }
        assert_eq!(switches, vec![(LinkKind::Acoustic, 8.0)], "{switches:?}");
        assert_eq!(f.switches(), 2);
    }

    #[test]
    fn after_falling_back_ip_is_retaken_no_sooner_than_min_acoustic() {
        let t0 = Instant::now();
        let mut f = Failover::new(timing(), t0);
        hear(&mut f, t0, 0.0, 5.0);
        f.ip_down(t0 + s(5.0));
        assert_eq!(f.poll(t0 + s(5.0)).map(|w| w.to), Some(LinkKind::Acoustic));
        // Heard steadily again from 6 s: up_after is met at 9 s, min_acoustic at 15 s.
        let sw = hear(&mut f, t0, 6.0, 20.0);
        assert_eq!(sw, vec![(LinkKind::Ip, 15.0)]);
    }

    #[test]
    fn a_switch_event_is_a_valid_event_and_is_recognised() {
        use shoal_model::Validate;
        let longest = "v".repeat(shoal_model::MAX_VEHICLE_ID_LEN);
        for to in [LinkKind::Ip, LinkKind::Acoustic] {
            let e = switch_event(&longest, to, 1_800_000_000_000, "switched".into());
            assert_eq!(e.validate(), Ok(()), "{e:?}");
            assert_eq!(switched_to(&e), Some(to));
        }
        let mut other = switch_event("auv-1", LinkKind::Ip, 1, String::new());
        other.event_id = "auv-1-ac-1-2".into();
        assert_eq!(switched_to(&other), None);
    }

    #[test]
    fn bad_ip_settings_are_refused_naming_the_key() {
        let ok = IpPathConfig {
            enabled: true,
            ..IpPathConfig::default()
        };
        ok.check().unwrap();
        let cases: [(IpPathConfig, &str); 6] = [
            (
                IpPathConfig {
                    up_after_s: 0.0,
                    ..ok.clone()
                },
                "ip.up_after_s",
            ),
            (
                IpPathConfig {
                    down_after_s: f64::NAN,
                    ..ok.clone()
                },
                "ip.down_after_s",
            ),
            (
                IpPathConfig {
                    min_acoustic_s: -1.0,
                    ..ok.clone()
                },
                "ip.min_acoustic_s",
            ),
            (
                IpPathConfig {
                    domain_id: 233,
                    ..ok.clone()
                },
                "ip.domain_id",
            ),
            (
                IpPathConfig {
                    interfaces: Vec::new(),
                    ..ok.clone()
                },
                "ip.interfaces",
            ),
            (
                IpPathConfig {
                    radio_max_depth_m: Some(-0.1),
                    ..ok
                },
                "ip.radio_max_depth_m",
            ),
        ];
        for (cfg, key) in cases {
            let e = cfg.check().unwrap_err().to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
        // Parsed from TOML, an unknown key is refused too.
        let bad: Result<IpPathConfig, _> = toml::from_str("enabled = true\nup_after = 3.0");
        assert!(bad.is_err());
    }
}
