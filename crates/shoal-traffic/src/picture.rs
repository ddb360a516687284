//! The decoding core, free of I/O: lines in, target table and own ship as state, collision
//! warnings out. Time is passed in as monotonic `Instant`s so that tests do not sleep.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use serde::Serialize;
use tracing::{debug, trace};

use crate::config::TrafficConfig;
use crate::cpa::{ApproachWindow, Motion, OwnVehicle, TargetMotion, VesselApproach};
use crate::decode::{self, Class, DecodeError, Dimensions, Fact, PositionReport, StaticReport};
use crate::framing::{self, Assembly, EnvelopeError, Reassembler, VdmError};

/// Counters of what the picture read and dropped, per reason.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct TrafficStats {
    /// Non-empty lines offered.
    pub lines: u64,
    /// Sentences that changed the picture.
    pub accepted: u64,
    /// AIS messages decoded (a multi-sentence message counts once).
    pub ais_messages: u64,
    /// Own-ship updates (GGA, RMC, HDT, VDO).
    pub own_ship_updates: u64,
    /// Lines longer than `max_line_len`.
    pub too_long: u64,
    /// Lines that are not NMEA (control or non-ASCII bytes, no `$`/`!`, broken tag block).
    pub garbage: u64,
    /// Sentences without a `*hh` checksum.
    pub no_checksum: u64,
    /// Sentences whose checksum does not match.
    pub bad_checksum: u64,
    /// Well-formed sentences of a kind the picture does not read (VTG, GSV, …).
    pub unsupported_sentence: u64,
    /// AIS messages of a type the picture does not read (4, 21, …).
    pub unsupported_ais_type: u64,
    /// Sentences with a malformed field (VDM field count or range, decoder refusals).
    pub bad_fields: u64,
    /// AIS payloads with bad characters or too short for their type.
    pub bad_payload: u64,
    /// AIS messages with MMSI 0.
    pub bad_mmsi: u64,
    /// GGA without a fix or RMC with status void.
    pub no_fix: u64,
    /// Fragments continuing no message in progress (out of order, or first one lost).
    pub fragment_out_of_order: u64,
    /// Multi-sentence messages never completed (time-out, or a new first fragment).
    pub fragment_missing: u64,
    /// Multi-sentence messages dropped because `max_pending_fragments` were pending.
    pub fragment_over_limit: u64,
    /// Inputs the decoder panicked on (contained; a bug in the decoder).
    pub decoder_panics: u64,
    /// Targets evicted because `max_targets` were held.
    pub targets_evicted: u64,
    /// Targets dropped after `target_timeout_s` of silence.
    pub targets_expired: u64,
    /// Datagrams received on UDP inputs.
    pub udp_datagrams: u64,
    /// TCP connections established.
    pub tcp_connects: u64,
    /// TCP connection attempts that failed, and connections lost.
    pub tcp_failures: u64,
    /// Targets held now.
    pub targets: usize,
    /// Multi-sentence messages awaiting fragments now.
    pub pending_fragments: usize,
}

/// A target for the map and the HTTP API.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TargetView {
    /// Maritime Mobile Service Identity.
    pub mmsi: u32,
    /// AIS equipment class, once known.
    pub class: Option<Class>,
    /// Vessel name.
    pub name: Option<String>,
    /// Radio call sign.
    pub call_sign: Option<String>,
    /// IMO number.
    pub imo: Option<u32>,
    /// Ship type category code (AIS: 30 fishing, 36 sailing, 37 pleasure, 60 passenger,
    /// 70 cargo, 80 tanker, …).
    pub ship_type: Option<u8>,
    /// The ship type as text.
    pub ship_type_text: Option<String>,
    /// Antenna-to-hull distances, metres.
    pub dimensions: Option<Dimensions>,
    /// Latitude, degrees, as last reported.
    pub lat: Option<f64>,
    /// Longitude, degrees, as last reported.
    pub lon: Option<f64>,
    /// Course over ground, degrees true.
    pub cog_deg: Option<f64>,
    /// Speed over ground, knots.
    pub sog_kn: Option<f64>,
    /// True heading, degrees.
    pub heading_deg: Option<f64>,
    /// Navigational status code (class A).
    pub nav_status: Option<u8>,
    /// Seconds since the last message from it.
    pub age_s: f64,
    /// Seconds since its last position report, if any.
    pub position_age_s: Option<f64>,
    /// Messages heard from it.
    pub messages: u64,
}

/// The own ship, from GGA/RMC/HDT and AIS VDO.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct OwnShipView {
    /// MMSI, if an AIS VDO gave one.
    pub mmsi: Option<u32>,
    /// Name, if an AIS VDO gave one.
    pub name: Option<String>,
    /// Latitude, degrees.
    pub lat: Option<f64>,
    /// Longitude, degrees.
    pub lon: Option<f64>,
    /// Course over ground, degrees true.
    pub cog_deg: Option<f64>,
    /// Speed over ground, knots.
    pub sog_kn: Option<f64>,
    /// True heading, degrees.
    pub heading_deg: Option<f64>,
    /// Seconds since the last update.
    pub age_s: f64,
}

impl OwnShipView {
    /// Its motion for collision checks (as an `OwnVehicle`), if position, course and speed
    /// are all known.
    pub fn motion(&self) -> Option<Motion> {
        Some(Motion {
            lat: self.lat?,
            lon: self.lon?,
            cog_deg: self.cog_deg?,
            sog_kn: self.sog_kn?,
        })
    }
}

#[derive(Debug)]
struct Target {
    view: TargetView,
    heard: Instant,
    position_at: Option<Instant>,
}

#[derive(Debug, Default)]
struct OwnShip {
    view: OwnShipView,
    heard: Option<Instant>,
}

/// The traffic picture's state: feed it lines, read targets, own ship, counters and
/// collision warnings.
#[derive(Debug)]
pub struct Picture {
    targets: HashMap<u32, Target>,
    own: OwnShip,
    reassembler: Reassembler,
    stats: TrafficStats,
    max_line_len: usize,
    max_targets: usize,
    target_timeout: Duration,
    last_sweep: Option<Instant>,
}

/// How often ingestion sweeps out expired targets and fragments.
const SWEEP_EVERY: Duration = Duration::from_secs(1);

impl Picture {
    /// An empty picture with the limits and thresholds of `config`.
    pub fn new(config: &TrafficConfig) -> Self {
        Self {
            targets: HashMap::new(),
            own: OwnShip::default(),
            reassembler: Reassembler::new(config.max_pending_fragments, config.fragment_timeout()),
            stats: TrafficStats::default(),
            max_line_len: config.max_line_len,
            max_targets: config.max_targets,
            target_timeout: config.target_timeout(),
            last_sweep: None,
        }
    }

    /// Reads one line (with or without its line ending); anything wrong is counted and
    /// dropped. Returns whether it changed the picture.
    pub fn ingest_line(&mut self, line: &[u8], now: Instant) -> bool {
        if self
            .last_sweep
            .is_none_or(|t| now.saturating_duration_since(t) >= SWEEP_EVERY)
        {
            self.expire(now);
        }
        if line.trim_ascii().is_empty() {
            return false;
        }
        self.stats.lines += 1;
        if line.len() > self.max_line_len {
            self.stats.too_long += 1;
            return false;
        }
        let changed = self.ingest_checked(line, now);
        if changed {
            self.stats.accepted += 1;
        }
        changed
    }

    /// Counts a line dropped before it was whole (over-long in a stream).
    pub fn note_too_long(&mut self) {
        self.stats.lines += 1;
        self.stats.too_long += 1;
    }

    fn ingest_checked(&mut self, line: &[u8], now: Instant) -> bool {
        let sentence = match framing::envelope(line) {
            Ok(s) => s,
            Err(e) => {
                match e {
                    EnvelopeError::Garbage => self.stats.garbage += 1,
                    EnvelopeError::NoChecksum => self.stats.no_checksum += 1,
                    EnvelopeError::BadChecksum => self.stats.bad_checksum += 1,
                }
                trace!(?e, "dropped line");
                return false;
            }
        };
        let formatter = sentence.formatter();
        let proprietary = sentence.body.starts_with('P');
        match (sentence.start, formatter) {
            (b'!', Some(f @ ("VDM" | "VDO"))) => {
                let fragment = match framing::vdm_fields(sentence.body, f == "VDO") {
                    Ok(fr) => fr,
                    Err(VdmError::BadFields) => {
                        self.stats.bad_fields += 1;
                        return false;
                    }
                    Err(VdmError::BadPayload) => {
                        self.stats.bad_payload += 1;
                        return false;
                    }
                };
                let assembly = self.reassembler.push(&fragment, now);
                self.sync_fragment_stats();
                match assembly {
                    Assembly::Pending => false,
                    Assembly::OutOfOrder => {
                        self.stats.fragment_out_of_order += 1;
                        false
                    }
                    Assembly::Complete(p) => match decode::decode_ais(&p) {
                        Ok(facts) => {
                            self.stats.ais_messages += 1;
                            let heard = facts.first().and_then(|f| match f {
                                Fact::Position(r) if !r.own => Some(r.mmsi),
                                Fact::Static(r) if !r.own => Some(r.mmsi),
                                _ => None,
                            });
                            for f in facts {
                                self.apply(f, now);
                            }
                            if let Some(t) = heard.and_then(|m| self.targets.get_mut(&m)) {
                                t.view.messages += 1;
                            }
                            true
                        }
                        Err(e) => {
                            self.count(e);
                            false
                        }
                    },
                }
            }
            (b'$', Some("GGA" | "RMC" | "HDT")) if !proprietary => {
                match decode::decode_nav(sentence.body) {
                    Ok(f) => {
                        self.apply(f, now);
                        true
                    }
                    Err(e) => {
                        self.count(e);
                        false
                    }
                }
            }
            _ => {
                self.stats.unsupported_sentence += 1;
                false
            }
        }
    }

    fn count(&mut self, e: DecodeError) {
        debug!(%e, "dropped sentence");
        match e {
            DecodeError::UnsupportedAisType(_) => self.stats.unsupported_ais_type += 1,
            DecodeError::ShortPayload => self.stats.bad_payload += 1,
            DecodeError::BadFields => self.stats.bad_fields += 1,
            DecodeError::BadMmsi => self.stats.bad_mmsi += 1,
            DecodeError::NoFix => self.stats.no_fix += 1,
            DecodeError::DecoderPanic => self.stats.decoder_panics += 1,
        }
    }

    fn sync_fragment_stats(&mut self) {
        self.stats.fragment_missing = self.reassembler.dropped.missing;
        self.stats.fragment_over_limit = self.reassembler.dropped.over_limit;
        self.stats.pending_fragments = self.reassembler.pending();
    }

    fn apply(&mut self, fact: Fact, now: Instant) {
        match fact {
            Fact::Position(p) if p.own => self.own_position(&p, now),
            Fact::Static(s) if s.own => {
                self.own.view.mmsi = Some(s.mmsi);
                if s.name.is_some() {
                    self.own.view.name = s.name;
                }
                self.touch_own(now);
            }
            Fact::Position(p) => {
                let t = self.target(p.mmsi, now);
                t.view.class = Some(p.class);
                if let Some((lat, lon)) = p.position {
                    t.view.lat = Some(lat);
                    t.view.lon = Some(lon);
                    t.position_at = Some(now);
                }
                t.view.cog_deg = p.cog_deg;
                t.view.sog_kn = p.sog_kn;
                t.view.heading_deg = p.heading_deg;
                if p.nav_status.is_some() {
                    t.view.nav_status = p.nav_status;
                }
            }
            Fact::Static(s) => self.target_static(s, now),
            Fact::Gga { lat, lon } => {
                self.own.view.lat = Some(lat);
                self.own.view.lon = Some(lon);
                self.touch_own(now);
            }
            Fact::Rmc {
                position,
                sog_kn,
                cog_deg,
            } => {
                if let Some((lat, lon)) = position {
                    self.own.view.lat = Some(lat);
                    self.own.view.lon = Some(lon);
                }
                self.own.view.sog_kn = sog_kn.or(self.own.view.sog_kn);
                self.own.view.cog_deg = cog_deg.or(self.own.view.cog_deg);
                self.touch_own(now);
            }
            Fact::Hdt { heading_deg } => {
                self.own.view.heading_deg = Some(heading_deg);
                self.touch_own(now);
            }
        }
    }

    fn own_position(&mut self, p: &PositionReport, now: Instant) {
        let v = &mut self.own.view;
        v.mmsi = Some(p.mmsi);
        if let Some((lat, lon)) = p.position {
            v.lat = Some(lat);
            v.lon = Some(lon);
        }
        v.cog_deg = p.cog_deg.or(v.cog_deg);
        v.sog_kn = p.sog_kn.or(v.sog_kn);
        v.heading_deg = p.heading_deg.or(v.heading_deg);
        self.touch_own(now);
    }

    fn touch_own(&mut self, now: Instant) {
        self.own.heard = Some(now);
        self.stats.own_ship_updates += 1;
    }

    fn target_static(&mut self, s: StaticReport, now: Instant) {
        let t = self.target(s.mmsi, now);
        // Type 24 parts come separately: each fills only what it carries.
        t.view.class = Some(s.class);
        if s.name.is_some() {
            t.view.name = s.name;
        }
        if s.call_sign.is_some() {
            t.view.call_sign = s.call_sign;
        }
        if s.imo.is_some() {
            t.view.imo = s.imo;
        }
        if s.ship_type.is_some() {
            t.view.ship_type = s.ship_type;
            t.view.ship_type_text = s.ship_type_text;
        }
        if s.dimensions.is_some() {
            t.view.dimensions = s.dimensions;
        }
    }

    /// The entry for `mmsi`, created (evicting the least recently heard when full) if new,
    /// and marked heard now.
    fn target(&mut self, mmsi: u32, now: Instant) -> &mut Target {
        if !self.targets.contains_key(&mmsi) && self.targets.len() >= self.max_targets {
            let oldest = self
                .targets
                .iter()
                .min_by_key(|(_, t)| t.heard)
                .map(|(k, _)| *k);
            if let Some(k) = oldest {
                self.targets.remove(&k);
                self.stats.targets_evicted += 1;
            }
        }
        if !self.targets.contains_key(&mmsi) {
            self.stats.targets = self.targets.len() + 1;
        }
        let t = self.targets.entry(mmsi).or_insert_with(|| Target {
            view: TargetView {
                mmsi,
                class: None,
                name: None,
                call_sign: None,
                imo: None,
                ship_type: None,
                ship_type_text: None,
                dimensions: None,
                lat: None,
                lon: None,
                cog_deg: None,
                sog_kn: None,
                heading_deg: None,
                nav_status: None,
                age_s: 0.0,
                position_age_s: None,
                messages: 0,
            },
            heard: now,
            position_at: None,
        });
        t.heard = t.heard.max(now);
        t
    }

    /// Drops targets silent for longer than the time-out, and stale fragments.
    pub fn expire(&mut self, now: Instant) {
        self.last_sweep = Some(now);
        let timeout = self.target_timeout;
        let before = self.targets.len();
        self.targets
            .retain(|_, t| now.saturating_duration_since(t.heard) <= timeout);
        self.stats.targets_expired += (before - self.targets.len()) as u64;
        self.stats.targets = self.targets.len();
        self.reassembler.expire(now);
        self.sync_fragment_stats();
    }

    /// Number of targets held.
    pub fn len(&self) -> usize {
        self.targets.len()
    }

    /// Whether no target is held.
    pub fn is_empty(&self) -> bool {
        self.targets.is_empty()
    }

    /// One target, with its age as of `now`.
    pub fn target_view(&self, mmsi: u32, now: Instant) -> Option<TargetView> {
        self.targets.get(&mmsi).map(|t| view_at(t, now))
    }

    /// All targets, by MMSI, with ages as of `now` (expired ones are not included).
    pub fn targets(&self, now: Instant) -> Vec<TargetView> {
        let mut v: Vec<TargetView> = self
            .targets
            .values()
            .filter(|t| now.saturating_duration_since(t.heard) <= self.target_timeout)
            .map(|t| view_at(t, now))
            .collect();
        v.sort_by_key(|t| t.mmsi);
        v
    }

    /// The own ship, if any own-ship sentence was read.
    pub fn own_ship(&self, now: Instant) -> Option<OwnShipView> {
        let heard = self.own.heard?;
        let mut v = self.own.view.clone();
        v.age_s = now.saturating_duration_since(heard).as_secs_f64();
        Some(v)
    }

    /// The counters.
    pub fn stats(&self) -> TrafficStats {
        self.stats.clone()
    }

    /// Counts an I/O event of the service layer.
    pub(crate) fn stats_mut(&mut self) -> &mut TrafficStats {
        &mut self.stats
    }

    /// Every (vehicle, target) pair inside `window`: targets with a position and speed,
    /// their position dead-reckoned to `now` along their last course and speed.
    pub fn approaches(
        &self,
        vehicles: &[OwnVehicle],
        now: Instant,
        window: ApproachWindow,
    ) -> Vec<VesselApproach> {
        let targets: Vec<TargetMotion> = self
            .targets
            .values()
            .filter_map(|t| target_motion(t, now))
            .collect();
        crate::cpa::approaches(vehicles, &targets, window)
    }
}

fn view_at(t: &Target, now: Instant) -> TargetView {
    let mut v = t.view.clone();
    v.age_s = now.saturating_duration_since(t.heard).as_secs_f64();
    v.position_age_s = t
        .position_at
        .map(|p| now.saturating_duration_since(p).as_secs_f64());
    v
}

/// A target's motion now, if it can be known: a position and a speed, and a course unless
/// it is (nearly) stopped.
fn target_motion(t: &Target, now: Instant) -> Option<TargetMotion> {
    let (lat, lon) = (t.view.lat?, t.view.lon?);
    let sog = t.view.sog_kn?;
    let cog = match t.view.cog_deg {
        Some(c) => c,
        None if sog < 0.5 => 0.0,
        None => return None,
    };
    let sog = if t.view.cog_deg.is_none() { 0.0 } else { sog };
    let age = now.saturating_duration_since(t.position_at?).as_secs_f64();
    // Reports come every 2 s to 3 min: move the target to where it is now.
    let motion = Motion {
        lat,
        lon,
        cog_deg: cog,
        sog_kn: sog,
    }
    .advanced(age);
    Some(TargetMotion {
        mmsi: t.view.mmsi,
        name: t.view.name.clone(),
        motion,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::framing::checksum;

    // Encoded by pyais 3.3.1 (tests/traffic/ais_encode.py), fields as given there.
    const T1: &str = "!AIVDM,1,1,,A,13KF5P@P1s1hntRRIjFQj1H1P000,0*2B";
    const T2: &str = "!AIVDM,1,1,,A,23KF5PUP00:l;VIdWIu008L1P000,0*12";
    const T3: &str = "!AIVDM,1,1,,A,33KF5PoP3IOwJaHMMw8>3s>1P000,0*0E";
    const T18: &str = "!AIVDM,1,1,,B,B3KF5TP00VgVg8K=C62aWwP00000,0*40";
    const T19: &str = "!AIVDM,1,1,,A,C3KF5Th0=hLOfh8V>n1=8t00V:304::0000000000000BPP10Q00,0*3D";
    const T5A: &str =
        "!AIVDM,2,1,3,B,53KF5Q@2;=`0t`4;D00pu8@T>1=@580000000016<PD:<5G<NBj1C4jCRj@0,0*71";
    const T5B: &str = "!AIVDM,2,2,3,B,00000000000,2*24";
    const T24A: &str = "!AIVDM,1,1,,A,H3KF5V1059AV0400000000000000,0*2D";
    const T24B: &str = "!AIVDM,1,1,,A,H3KF5V4T1230000?8jl2000`5220,0*05";
    // Type 4 (base station report), a type the picture does not read.
    const T4: &str = "!AIVDM,1,1,,A,402<HH1va@Q231jL>0RLUh000000,0*20";
    // Type 1 for the type 5 target's MMSI: 60.2 N 25.0 E, 7.0 kn, 090.0, heading 91.
    const T1_OF_5: &str = "!AIVDM,1,1,,A,13KF5QOP161jL>0RLUh3Q2n1P000,0*00";

    fn nmea(start: char, body: &str) -> String {
        format!("{start}{body}*{:02X}", checksum(body))
    }

    fn picture() -> (Picture, Instant) {
        (Picture::new(&TrafficConfig::default()), Instant::now())
    }

    fn feed(p: &mut Picture, now: Instant, lines: &[&str]) {
        for l in lines {
            p.ingest_line(l.as_bytes(), now);
        }
    }

    fn close(a: Option<f64>, b: f64, tol: f64) -> bool {
        a.is_some_and(|a| (a - b).abs() <= tol)
    }

    #[test]
    fn type_1_2_3_class_a_positions() {
        let (mut p, t) = picture();
        feed(&mut p, t, &[T1, T2, T3]);
        let a = p.target_view(230_000_001, t).unwrap();
        assert_eq!(a.class, Some(Class::A));
        assert!(
            close(a.lat, 60.123456, 2e-6) && close(a.lon, 24.654321, 2e-6),
            "{a:?}"
        );
        assert!(close(a.sog_kn, 12.3, 0.05) && close(a.cog_deg, 45.6, 0.05));
        assert_eq!(a.heading_deg, Some(44.0));
        assert_eq!(a.nav_status, Some(0));
        let b = p.target_view(230_000_002, t).unwrap();
        assert!(close(b.lat, -33.8765, 2e-6) && close(b.lon, 151.2093, 2e-6));
        assert_eq!((b.heading_deg, b.nav_status), (Some(270.0), Some(5)));
        let c = p.target_view(230_000_003, t).unwrap();
        assert!(close(c.lon, -0.1275, 2e-6) && close(c.cog_deg, 359.9, 0.05));
        assert_eq!(c.nav_status, Some(7));
        let s = p.stats();
        assert_eq!((s.ais_messages, s.accepted, s.targets), (3, 3, 3));
    }

    #[test]
    fn type_18_class_b_position_without_heading() {
        let (mut p, t) = picture();
        feed(&mut p, t, &[T18]);
        let b = p.target_view(230_000_018, t).unwrap();
        assert_eq!(b.class, Some(Class::B));
        assert!(close(b.lat, -33.5, 2e-6) && close(b.lon, -70.25, 2e-6));
        assert!(close(b.sog_kn, 0.2, 0.05) && close(b.cog_deg, 271.3, 0.05));
        assert_eq!(b.heading_deg, None);
        assert_eq!(b.nav_status, None);
    }

    #[test]
    fn type_19_extended_class_b_position_and_static() {
        let (mut p, t) = picture();
        feed(&mut p, t, &[T19]);
        let b = p.target_view(230_000_019, t).unwrap();
        assert_eq!(b.class, Some(Class::B));
        assert!(
            close(b.lat, 60.1, 2e-6) && close(b.lon, 24.9, 2e-6),
            "{b:?}"
        );
        assert!(close(b.sog_kn, 5.5, 0.05) && close(b.cog_deg, 123.4, 0.05));
        assert_eq!(b.heading_deg, Some(120.0));
        assert_eq!(b.name.as_deref(), Some("SEA BEE"));
        assert_eq!(b.ship_type, Some(37));
        assert_eq!(
            b.dimensions,
            Some(Dimensions {
                to_bow: 8,
                to_stern: 2,
                to_port: 1,
                to_starboard: 2
            })
        );
        assert_eq!(p.stats().ais_messages, 1);
    }

    #[test]
    fn type_5_two_sentences_static_and_voyage() {
        let (mut p, t) = picture();
        assert!(!p.ingest_line(T5A.as_bytes(), t));
        assert_eq!(p.stats().pending_fragments, 1);
        assert!(p.ingest_line(T5B.as_bytes(), t));
        let s = p.target_view(230_000_005, t).unwrap();
        assert_eq!(s.class, Some(Class::A));
        assert_eq!(s.name.as_deref(), Some("NORDIC STAR"));
        assert_eq!(s.call_sign.as_deref(), Some("OJAB5"));
        assert_eq!(s.imo, Some(9_123_456));
        assert_eq!(s.ship_type, Some(70));
        assert_eq!(s.ship_type_text.as_deref(), Some("cargo"));
        assert_eq!(
            s.dimensions,
            Some(Dimensions {
                to_bow: 100,
                to_stern: 20,
                to_port: 10,
                to_starboard: 12
            })
        );
        assert_eq!((s.lat, s.lon), (None, None));
        assert_eq!(p.stats().pending_fragments, 0);
    }

    #[test]
    fn type_24_parts_a_and_b_fill_one_target() {
        let (mut p, t) = picture();
        feed(&mut p, t, &[T24A]);
        let a = p.target_view(230_000_024, t).unwrap();
        assert_eq!(a.name.as_deref(), Some("PARTY A"));
        assert_eq!(a.call_sign, None);
        feed(&mut p, t, &[T24B]);
        let b = p.target_view(230_000_024, t).unwrap();
        assert_eq!(
            b.name.as_deref(),
            Some("PARTY A"),
            "part B keeps part A's name"
        );
        assert_eq!(b.call_sign.as_deref(), Some("OH24B"));
        assert_eq!(b.ship_type, Some(36));
        assert_eq!(b.class, Some(Class::B));
        assert_eq!(
            b.dimensions,
            Some(Dimensions {
                to_bow: 5,
                to_stern: 5,
                to_port: 2,
                to_starboard: 2
            })
        );
        // Part B alone, then part A: same result, order does not matter.
        let (mut q, t) = picture();
        feed(&mut q, t, &[T24B, T24A]);
        let c = q.target_view(230_000_024, t).unwrap();
        assert_eq!((c.name, c.call_sign), (b.name, b.call_sign));
    }

    #[test]
    fn static_and_position_of_one_vessel_merge() {
        let (mut p, t) = picture();
        feed(&mut p, t, &[T5A, T5B, T1_OF_5]);
        assert_eq!(p.len(), 1);
        let v = p.target_view(230_000_005, t).unwrap();
        assert_eq!(v.name.as_deref(), Some("NORDIC STAR"));
        assert!(close(v.lat, 60.2, 2e-6) && close(v.lon, 25.0, 2e-6));
        assert!(close(v.sog_kn, 7.0, 0.05) && close(v.cog_deg, 90.0, 0.05));
        assert_eq!(v.heading_deg, Some(91.0));
        assert_eq!(v.messages, 2);
        // Type 19 carries both in one message: counted once.
        feed(&mut p, t, &[T19]);
        assert_eq!(p.target_view(230_000_019, t).unwrap().messages, 1);
    }

    #[test]
    fn own_ship_from_gga_rmc_hdt_any_talker() {
        let (mut p, t) = picture();
        assert!(p.own_ship(t).is_none());
        let gga = nmea(
            '$',
            "GNGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",
        );
        assert!(p.ingest_line(gga.as_bytes(), t), "{gga}");
        let o = p.own_ship(t).unwrap();
        assert!(
            close(o.lat, 48.1173, 1e-4) && close(o.lon, 11.516_667, 1e-4),
            "{o:?}"
        );
        assert_eq!(o.motion(), None, "no course and speed yet");
        let rmc = nmea(
            '$',
            "GPRMC,123520,A,4807.100,N,01131.100,E,022.4,084.4,230394,003.1,W",
        );
        assert!(p.ingest_line(rmc.as_bytes(), t));
        let o = p.own_ship(t).unwrap();
        assert!(
            close(o.sog_kn, 22.4, 1e-9) && close(o.cog_deg, 84.4, 1e-9),
            "{o:?}"
        );
        assert!(close(o.lat, 48.118_333, 1e-5));
        let m = o.motion().unwrap();
        assert!((m.sog_kn - 22.4).abs() < 1e-9 && (m.cog_deg - 84.4).abs() < 1e-9);
        let hdt = nmea('$', "HEHDT,271.5,T");
        assert!(p.ingest_line(hdt.as_bytes(), t));
        let hdt2 = nmea('$', "GPHDT,272.0,T");
        assert!(p.ingest_line(hdt2.as_bytes(), t));
        assert_eq!(p.own_ship(t).unwrap().heading_deg, Some(272.0));
        assert_eq!(p.stats().own_ship_updates, 4);
        assert_eq!(p.len(), 0, "own ship is not a target");
        // Void RMC and no-fix GGA are counted, not applied.
        let void = nmea('$', "GPRMC,123521,V,4900.000,N,01131.100,E,0,0,230394,,");
        let nofix = nmea('$', "GPGGA,123519,4900.000,N,01131.000,E,0,00,,,M,,M,,");
        feed(&mut p, t, &[&void, &nofix]);
        assert_eq!(p.stats().no_fix, 2);
        assert!(close(p.own_ship(t).unwrap().lat, 48.118_333, 1e-5));
    }

    #[test]
    fn own_ship_from_aivdo() {
        let (mut p, t) = picture();
        let vdo = T1.replace("AIVDM", "AIVDO");
        let body = &vdo[1..vdo.find('*').unwrap()];
        let vdo = nmea('!', body);
        assert!(p.ingest_line(vdo.as_bytes(), t));
        let o = p.own_ship(t).unwrap();
        assert_eq!(o.mmsi, Some(230_000_001));
        assert!(close(o.lat, 60.123456, 2e-6) && close(o.sog_kn, 12.3, 0.05));
        assert_eq!(p.len(), 0);
    }

    #[test]
    fn malformed_lines_are_counted_per_reason_and_good_ones_survive() {
        let (mut p, t) = picture();
        let long = format!("{T1}{}", " ".repeat(600));
        let bad_sum = T1.replace("*2B", "*2C");
        let no_sum = &T1[..T1.find('*').unwrap()];
        let bad_char = nmea('!', "AIVDM,1,1,,A,13KF5P@P1s1h ntRRIjFQj1H1P000,0");
        let bad_fields = nmea('!', "AIVDM,1,1,,A,13KF5P@P1s1hntRRIjFQj1H1P000");
        let short = nmea('!', "AIVDM,1,1,,A,13KF5P@P1s1h,0");
        let mmsi0 = nmea('!', "AIVDM,1,1,,A,1000000P1s1hntRRIjFQj1H1P000,0");
        let unknown_type = nmea('!', "AIVDM,1,1,,A,?3KF5P@P1s1hntRRIjFQj1H1P000,0");
        let vtg = nmea('$', "GPVTG,054.7,T,034.4,M,005.5,N,010.2,K");
        let proprietary = nmea('$', "PGRMZ,246,f,3");
        let bad_hdt = nmea('$', "HEHDT,abc,T");
        let lines: Vec<&[u8]> = vec![
            b"hello world",
            b"\xff\xfe\x00garbage",
            long.as_bytes(),
            T1.as_bytes(),
            bad_sum.as_bytes(),
            no_sum.as_bytes(),
            bad_char.as_bytes(),
            bad_fields.as_bytes(),
            short.as_bytes(),
            mmsi0.as_bytes(),
            unknown_type.as_bytes(),
            T4.as_bytes(),
            vtg.as_bytes(),
            proprietary.as_bytes(),
            bad_hdt.as_bytes(),
            T18.as_bytes(),
            // Fragments: second without first, then first, third (skips second).
            T5B.as_bytes(),
            b"",
            b"\r\n",
        ];
        for l in lines {
            p.ingest_line(l, t);
        }
        let s = p.stats();
        assert_eq!(s.garbage, 2, "{s:?}");
        assert_eq!(s.too_long, 1);
        assert_eq!(s.bad_checksum, 1);
        assert_eq!(s.no_checksum, 1);
        assert_eq!(s.bad_payload, 2, "bad character + short payload");
        assert_eq!(s.bad_fields, 2, "missing fill field + HDT number");
        assert_eq!(s.bad_mmsi, 1);
        assert_eq!(s.unsupported_ais_type, 2, "type 15 (?) and type 4");
        assert_eq!(s.unsupported_sentence, 2);
        assert_eq!(s.fragment_out_of_order, 1);
        assert_eq!(s.lines, 17, "empty lines are not counted");
        assert_eq!(s.accepted, 2);
        assert_eq!(p.len(), 2, "both good sentences landed");
        assert!(p.target_view(230_000_001, t).is_some());
        assert!(p.target_view(230_000_018, t).is_some());
    }

    #[test]
    fn fragments_out_of_order_missing_and_timed_out() {
        let (mut p, t) = picture();
        // Reversed order: the second arrives first (dropped), the first then waits.
        feed(&mut p, t, &[T5B, T5A]);
        assert_eq!(p.stats().fragment_out_of_order, 1);
        assert_eq!(p.stats().pending_fragments, 1);
        // A new first fragment with the same id: the old message is missing its end.
        feed(&mut p, t, &[T5A]);
        assert_eq!(p.stats().fragment_missing, 1);
        // Time-out: after 5 s the pending one is gone, the late end does not complete.
        let later = t + Duration::from_secs(6);
        feed(&mut p, later, &[T5B]);
        let s = p.stats();
        assert_eq!(
            (s.fragment_missing, s.fragment_out_of_order),
            (2, 2),
            "{s:?}"
        );
        assert_eq!(s.pending_fragments, 0);
        assert!(p.is_empty());
        // And in order afterwards it still works.
        feed(&mut p, later, &[T5A, T5B]);
        assert_eq!(p.len(), 1);
    }

    #[test]
    fn pending_fragments_are_bounded() {
        let cfg = TrafficConfig {
            max_pending_fragments: 4,
            ..TrafficConfig::default()
        };
        let mut p = Picture::new(&cfg);
        let t = Instant::now();
        for seq in 0..10 {
            for ch in ["A", "B"] {
                let l = nmea('!', &format!("AIVDM,2,1,{seq},{ch},53KF5Q@2,0"));
                p.ingest_line(l.as_bytes(), t);
            }
        }
        let s = p.stats();
        assert_eq!(s.pending_fragments, 4);
        assert_eq!(s.fragment_over_limit, 16);
    }

    #[test]
    fn targets_are_bounded_oldest_evicted_and_expire() {
        let cfg = TrafficConfig {
            max_targets: 2,
            target_timeout_s: 60,
            ..TrafficConfig::default()
        };
        let mut p = Picture::new(&cfg);
        let t = Instant::now();
        p.ingest_line(T1.as_bytes(), t);
        p.ingest_line(T2.as_bytes(), t + Duration::from_secs(1));
        p.ingest_line(T3.as_bytes(), t + Duration::from_secs(2));
        assert_eq!(p.len(), 2);
        assert!(p.target_view(230_000_001, t).is_none(), "oldest evicted");
        assert_eq!(p.stats().targets_evicted, 1);
        // Heard again keeps it alive; silence drops it.
        p.ingest_line(T3.as_bytes(), t + Duration::from_secs(50));
        let later = t + Duration::from_secs(100);
        assert_eq!(p.targets(later).len(), 1, "expired hidden before the sweep");
        p.expire(later);
        assert_eq!(p.len(), 1);
        assert_eq!(p.stats().targets_expired, 1);
        let v = p.target_view(230_000_003, later).unwrap();
        assert!((v.age_s - 50.0).abs() < 1e-6 && v.messages == 2);
    }

    #[test]
    fn approaches_from_the_table_are_dead_reckoned() {
        let (mut p, t) = picture();
        // Type 1 target at 60.123456 N 24.654321 E, 12.3 kn on 045.6.
        p.ingest_line(T1.as_bytes(), t);
        // A vehicle 1 nm along the target's track, steaming towards it.
        let dist = 1852.0;
        let c = 45.6f64.to_radians();
        let lat = 60.123456 + (dist * c.cos() / crate::cpa::EARTH_RADIUS_M).to_degrees();
        let lon = 24.654321
            + (dist * c.sin() / (crate::cpa::EARTH_RADIUS_M * 60.123456f64.to_radians().cos()))
                .to_degrees();
        let vehicles = [OwnVehicle {
            id: "usv-1".into(),
            motion: Motion {
                lat,
                lon,
                cog_deg: 225.6,
                sog_kn: 4.0,
            },
        }];
        let window = ApproachWindow {
            within_m: 500.0,
            past_s: 0.0,
            ahead_s: 600.0,
        };
        let u = p.approaches(&vehicles, t, window);
        assert_eq!(u.len(), 1, "{u:?}");
        let w = &u[0];
        assert_eq!((w.vehicle_id.as_str(), w.mmsi), ("usv-1", 230_000_001));
        assert!(w.cpa_m < 5.0, "{w:?}");
        assert!((w.tcpa_s - 1852.0 / (16.3 * crate::cpa::MS_PER_KNOT)).abs() < 2.0);
        // 60 s later the target has been dead-reckoned 379 m closer.
        let u = p.approaches(&vehicles, t + Duration::from_secs(60), window);
        assert_eq!(u.len(), 1);
        assert!(u[0].range_m < w.range_m - 300.0, "{u:?}");
        // The vehicle turns away: cleared.
        let away = [OwnVehicle {
            id: "usv-1".into(),
            motion: Motion {
                cog_deg: 45.6,
                sog_kn: 20.0,
                ..vehicles[0].motion
            },
        }];
        assert!(p.approaches(&away, t, window).is_empty());
    }
}
