//! Configuration of the VDT and the CDT: typed serde structs, `deny_unknown_fields`, with
//! defaults for everything but the address book.
//!
//! Every duration is in **simulated (sea) seconds**: the wall-clock duration is the value
//! times [`VdtConfig::time_scale`] / [`CdtConfig::time_scale`], which must match the modem
//! emulator's `time_scale` (1.0 against a real modem).

use std::net::SocketAddr;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use shoal_acoustic::link::{LinkConfig, Mac};
use shoal_acoustic::pdu::AddressBook;
use shoal_acoustic::pdu::convert::MAX_ADDRESS;
use shoal_acoustic::relay::{RelayConfig, TrustedRelay};
use shoal_model::Warp;

use crate::error::ConverterError;
pub use crate::failover::IpPathConfig;
use crate::tap::FrameTap;

/// Which modem protocol the converter speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModemKind {
    /// EvoLogics S2C AT commands over TCP (docs/acoustic.md#at-interface); port 9200 on a
    /// real modem.
    EvologicsAt,
    /// The EviNS network-layer protocol over TCP (docs/acoustic.md#nl-protocol), as in the
    /// SWARMs sea trials.
    EvinsNl,
}

/// Where and how to reach the modem.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModemSettings {
    /// Protocol.
    pub kind: ModemKind,
    /// TCP address of the modem's AT or NL interface.
    pub address: SocketAddr,
    /// `evins_nl` only: whether the NL protocol reports `NL,delivered`/`NL,failed`
    /// (`staticrack` and other `*ack` protocols do).
    pub nl_delivery_reports: bool,
}

impl Default for ModemSettings {
    fn default() -> Self {
        Self {
            kind: ModemKind::EvologicsAt,
            address: SocketAddr::from(([127, 0, 0, 1], 9200)),
            nl_delivery_reports: true,
        }
    }
}

/// One row of the address book: a vehicle id and the acoustic address of its modem.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AddressEntry {
    /// Shoal vehicle id.
    pub vehicle_id: String,
    /// Acoustic address, 1..=15 (the compact PDUs name vehicles in 4 bits:
    /// docs/acoustic.md#compact-messages).
    pub address: u8,
}

/// A vehicle allowed to forward other vehicles' PDUs to a CDT (a multi-hop relay).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RelayEntry {
    /// The forwarding vehicle's id (in the address book).
    pub relay: String,
    /// The vehicles it may speak for (in the address book).
    pub carries: Vec<String>,
}

/// Time to live per message class, seconds (simulated).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TtlConfig {
    /// Alarms and aborts.
    pub emergency_s: f64,
    /// Tasks, task status, announcements, other events.
    pub control_s: f64,
    /// State vectors (stale state is dropped, not queued).
    pub telemetry_s: f64,
    /// Environment observations.
    pub bulk_s: f64,
}

impl Default for TtlConfig {
    fn default() -> Self {
        let l = LinkConfig::default();
        Self {
            emergency_s: l.emergency.ttl.as_secs_f64(),
            control_s: l.control.ttl.as_secs_f64(),
            telemetry_s: l.telemetry.ttl.as_secs_f64(),
            bulk_s: l.bulk.ttl.as_secs_f64(),
        }
    }
}

/// Link-layer settings the operator usually touches; the rest keep
/// [`LinkConfig::default`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LinkSettings {
    /// TTL per class.
    pub ttl: TtlConfig,
    /// Medium access: `{ kind = "free" }` or TDMA slots for several vehicles on one channel.
    pub mac: Mac,
    /// Largest frame, bytes (64 = one instant message).
    pub max_frame: usize,
    /// First retransmission delay of acknowledged classes, seconds; doubles per attempt.
    pub backoff_initial_s: f64,
    /// Longest retransmission delay, seconds.
    pub backoff_max_s: f64,
}

impl Default for LinkSettings {
    fn default() -> Self {
        let l = LinkConfig::default();
        Self {
            ttl: TtlConfig::default(),
            mac: l.mac,
            max_frame: l.max_frame,
            backoff_initial_s: l.backoff_initial.as_secs_f64(),
            backoff_max_s: l.backoff_max.as_secs_f64(),
        }
    }
}

fn secs(field: &str, v: f64) -> Result<Duration, ConverterError> {
    if v.is_finite() && v > 0.0 {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(ConverterError::Config(format!(
            "{field} must be a positive number of seconds, not {v}"
        )))
    }
}

impl LinkSettings {
    /// The link layer configuration in simulated time (not yet scaled).
    pub fn link_config(&self) -> Result<LinkConfig, ConverterError> {
        let mut l = LinkConfig::default();
        l.emergency.ttl = secs("link.ttl.emergency_s", self.ttl.emergency_s)?;
        l.control.ttl = secs("link.ttl.control_s", self.ttl.control_s)?;
        l.telemetry.ttl = secs("link.ttl.telemetry_s", self.ttl.telemetry_s)?;
        l.bulk.ttl = secs("link.ttl.bulk_s", self.ttl.bulk_s)?;
        l.mac = self.mac;
        if !(8..=shoal_acoustic::pdu::MAX_FRAME).contains(&self.max_frame) {
            return Err(ConverterError::Config(format!(
                "link.max_frame must be 8..={} bytes, not {}",
                shoal_acoustic::pdu::MAX_FRAME,
                self.max_frame
            )));
        }
        l.max_frame = self.max_frame;
        l.backoff_initial = secs("link.backoff_initial_s", self.backoff_initial_s)?;
        l.backoff_max = secs("link.backoff_max_s", self.backoff_max_s)?;
        Ok(l)
    }
}

/// Which of the vehicle's topics the VDT sends acoustically.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[allow(clippy::struct_excessive_bools)]
pub struct AcousticTopics {
    /// `shoal/state_vector` (telemetry class, keyframe + delta).
    pub state: bool,
    /// `shoal/vehicle_announcement` (control class, repeated).
    pub announcement: bool,
    /// `shoal/task_status` (control class, only for tasks that came acoustically).
    pub task_status: bool,
    /// `shoal/event` (alarm and critical: emergency class; others: control class).
    pub events: bool,
    /// `shoal/environment` (bulk class, rate-limited per property).
    pub environment: bool,
}

impl Default for AcousticTopics {
    fn default() -> Self {
        Self {
            state: true,
            announcement: true,
            task_status: true,
            events: true,
            environment: false,
        }
    }
}

/// Configuration of a Vehicle Data Terminal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VdtConfig {
    /// The vehicle's modem.
    pub modem: ModemSettings,
    /// Acoustic address of the CDT's modem (where everything is sent), 1..=15.
    pub cdt_address: u8,
    /// Vehicle id ↔ acoustic address, for every vehicle this VDT serves.
    pub vehicles: Vec<AddressEntry>,
    /// Topics that go acoustic.
    pub topics: AcousticTopics,
    /// At most one state vector per vehicle per this many seconds (the freshest wins).
    pub state_interval_s: f64,
    /// The announcement is repeated this often, so a CDT or station that starts late
    /// learns the vehicle (seconds).
    pub announce_interval_s: f64,
    /// At most one observation per vehicle and property per this many seconds.
    pub environment_interval_s: f64,
    /// Link layer settings.
    pub link: LinkSettings,
    /// Multi-hop relaying through this vehicle's modem (docs/acoustic.md#multi-hop-relays):
    /// routes to the CDT through other vehicles, and forwarding for vehicles farther out.
    pub relay: RelayConfig,
    /// The vehicle's IP path beside the acoustic link, and the automatic failover between
    /// them (docs/acoustic.md#link-failover); off by default.
    pub ip: IpPathConfig,
    /// Wall-clock seconds per simulated second (match the emulator's `time_scale`).
    pub time_scale: f64,
    /// The simulated clock of a scenario run, for every timestamp this converter makes
    /// (`None`: the system clock). Its speed-up must be `1 / time_scale`.
    #[serde(skip)]
    pub clock: Option<Warp>,
}

impl Default for VdtConfig {
    fn default() -> Self {
        Self {
            modem: ModemSettings::default(),
            cdt_address: 1,
            vehicles: Vec::new(),
            topics: AcousticTopics::default(),
            // A 10-byte delta takes ~0.18 s on air at 976 bit/s
            // (docs/acoustic.md#frame-sizes-and-bit-rates): one every 2 s leaves the channel
            // mostly free for tasks and the station's acks.
            state_interval_s: 2.0,
            announce_interval_s: 60.0,
            environment_interval_s: 30.0,
            link: LinkSettings::default(),
            relay: RelayConfig::default(),
            ip: IpPathConfig::default(),
            time_scale: 1.0,
            clock: None,
        }
    }
}

/// Where a modem is, degrees (WGS84).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModemPosition {
    /// Latitude, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees.
    pub longitude_deg: f64,
}

/// Configuration of a Control Data Terminal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CdtConfig {
    /// The station's (or relay's) modem.
    pub modem: ModemSettings,
    /// This CDT's own acoustic address, 1..=15 (named in keyframe acks).
    pub address: u8,
    /// Vehicle id ↔ acoustic address of every vehicle this CDT serves.
    pub vehicles: Vec<AddressEntry>,
    /// Vehicles whose modems may forward PDUs about other vehicles. Without an entry here
    /// a frame may speak only for the vehicle whose modem (and, on a tagged link, whose
    /// key) sent it: anything else is refused as impersonation.
    pub relays: Vec<RelayEntry>,
    /// A per-vehicle link-status event is republished at most this often (seconds).
    pub link_status_interval_s: f64,
    /// Watch the station's domain for vehicles that also have an IP path (`[vdt.ip]`) and
    /// hold their tasks back while they are on it (docs/acoustic.md#link-failover). Off:
    /// every task of an acoustic vehicle goes over the water.
    pub ip_failover: bool,
    /// A vehicle heard over IP (its own participant on the station's domain) within this
    /// many seconds is on IP: its tasks wait there and none goes acoustically
    /// (docs/acoustic.md#link-failover).
    pub ip_silence_s: f64,
    /// Where this CDT's modem is (a moored buoy, the station's own transducer), named in
    /// the link status so the console can draw it; with `carrier`, where it starts.
    pub position: Option<ModemPosition>,
    /// The vehicle carrying this CDT's modem (a USV), by the id it publishes: the modem is
    /// wherever that vehicle reports itself, named in the link status.
    pub carrier: Option<String>,
    /// Link layer settings.
    pub link: LinkSettings,
    /// Multi-hop relaying through this CDT's modem (docs/acoustic.md#multi-hop-relays);
    /// the `relays` entries are added to its trusted relays ([`Self::relay_config`]).
    pub relay: RelayConfig,
    /// Wall-clock seconds per simulated second (match the emulator's `time_scale`).
    pub time_scale: f64,
    /// The simulated clock of a scenario run, for every timestamp this converter makes
    /// (`None`: the system clock). Its speed-up must be `1 / time_scale`.
    #[serde(skip)]
    pub clock: Option<Warp>,
    /// Where a copy of every frame sent and received and every message's fate goes (a
    /// recorder's queue, [`crate::tap`]); `None`: nowhere. Never makes the CDT wait.
    #[serde(skip)]
    pub tap: Option<FrameTap>,
}

impl Default for CdtConfig {
    fn default() -> Self {
        Self {
            modem: ModemSettings::default(),
            address: 1,
            vehicles: Vec::new(),
            relays: Vec::new(),
            link_status_interval_s: 30.0,
            ip_failover: false,
            ip_silence_s: 5.0,
            position: None,
            carrier: None,
            link: LinkSettings::default(),
            relay: RelayConfig::default(),
            time_scale: 1.0,
            clock: None,
            tap: None,
        }
    }
}

impl VdtConfig {
    /// This converter's time now, ms since the Unix epoch (see [`Self::clock`]).
    pub fn now_ms(&self) -> i64 {
        self.clock.map_or_else(shoal_model::now_ms, |w| w.now_ms())
    }
}

impl CdtConfig {
    /// This converter's time now, ms since the Unix epoch (see [`Self::clock`]).
    pub fn now_ms(&self) -> i64 {
        self.clock.map_or_else(shoal_model::now_ms, |w| w.now_ms())
    }
}

/// Whether `id` is a valid Shoal vehicle id.
fn valid_vehicle_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= shoal_model::MAX_VEHICLE_ID_LEN
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"_.-".contains(&b))
}

/// Builds and checks the address book: ids valid, addresses 1..=15, no duplicates.
pub(crate) fn address_book(entries: &[AddressEntry]) -> Result<AddressBook, ConverterError> {
    if entries.is_empty() {
        return Err(ConverterError::Config(
            "vehicles: the address book lists no vehicle".into(),
        ));
    }
    let mut book = AddressBook::new();
    let mut seen_addr = std::collections::HashSet::new();
    let mut seen_id = std::collections::HashSet::new();
    for e in entries {
        if e.address == 0 || e.address > MAX_ADDRESS {
            return Err(ConverterError::Config(format!(
                "vehicles: {} has address {}; acoustic addresses are 1..={MAX_ADDRESS}",
                e.vehicle_id, e.address
            )));
        }
        if !valid_vehicle_id(&e.vehicle_id) {
            return Err(ConverterError::Config(format!(
                "vehicles: {:?} is not a valid vehicle id",
                e.vehicle_id
            )));
        }
        if !seen_addr.insert(e.address) || !seen_id.insert(e.vehicle_id.as_str()) {
            return Err(ConverterError::Config(format!(
                "vehicles: {} / address {} listed twice",
                e.vehicle_id, e.address
            )));
        }
        book.insert(e.vehicle_id.clone(), e.address)
            .map_err(|err| ConverterError::Config(format!("vehicles: {err}")))?;
    }
    Ok(book)
}

pub(crate) fn check_scale(time_scale: f64) -> Result<(), ConverterError> {
    if time_scale.is_finite() && time_scale > 0.0 {
        Ok(())
    } else {
        Err(ConverterError::Config(format!(
            "time_scale must be > 0, not {time_scale}"
        )))
    }
}

pub(crate) fn check_address(field: &str, a: u8) -> Result<(), ConverterError> {
    if a == 0 || a > MAX_ADDRESS {
        return Err(ConverterError::Config(format!(
            "{field} must be 1..={MAX_ADDRESS}, not {a}"
        )));
    }
    Ok(())
}

impl VdtConfig {
    /// Checks the configuration; the error names the key.
    pub fn check(&self) -> Result<(), ConverterError> {
        address_book(&self.vehicles)?;
        check_address("cdt_address", self.cdt_address)?;
        if self.vehicles.iter().any(|v| v.address == self.cdt_address) {
            return Err(ConverterError::Config(
                "cdt_address is also a vehicle's address".into(),
            ));
        }
        check_scale(self.time_scale)?;
        secs("state_interval_s", self.state_interval_s)?;
        secs("announce_interval_s", self.announce_interval_s)?;
        secs("environment_interval_s", self.environment_interval_s)?;
        self.relay
            .check()
            .map_err(|e| ConverterError::Config(e.to_string()))?;
        self.ip.check()?;
        self.link.link_config().map(|_| ())
    }
}

impl CdtConfig {
    /// Checks the configuration; the error names the key.
    pub fn check(&self) -> Result<(), ConverterError> {
        address_book(&self.vehicles)?;
        check_address("address", self.address)?;
        if self.vehicles.iter().any(|v| v.address == self.address) {
            return Err(ConverterError::Config(
                "address is also a vehicle's address".into(),
            ));
        }
        check_scale(self.time_scale)?;
        secs("link_status_interval_s", self.link_status_interval_s)?;
        secs("ip_silence_s", self.ip_silence_s)?;
        if let Some(p) = self.position {
            let ok = p.latitude_deg.is_finite()
                && p.longitude_deg.is_finite()
                && p.latitude_deg.abs() <= 90.0
                && p.longitude_deg.abs() <= 180.0;
            if !ok {
                return Err(ConverterError::Config(format!(
                    "position must be latitude_deg -90..=90 and longitude_deg -180..=180, not {p:?}"
                )));
            }
        }
        if let Some(c) = &self.carrier
            && !valid_vehicle_id(c)
        {
            return Err(ConverterError::Config(format!(
                "carrier: {c:?} is not a valid vehicle id"
            )));
        }
        self.relay_config()?;
        self.link.link_config().map(|_| ())
    }

    /// The relay settings of this CDT's modem: [`Self::relay`], with every relay of
    /// [`Self::relays`] trusted to carry the vehicles it is listed with.
    pub fn relay_config(&self) -> Result<RelayConfig, ConverterError> {
        let mut relay = self.relay.clone();
        for (r, carries) in self.relay_rules()? {
            match relay.trusted.iter_mut().find(|t| t.relay == r) {
                Some(t) => t.carries.extend(carries),
                None => relay.trusted.push(TrustedRelay { relay: r, carries }),
            }
        }
        relay
            .check()
            .map_err(|e| ConverterError::Config(e.to_string()))?;
        Ok(relay)
    }

    /// The relays as (relay address, addresses it may speak for), checked against the
    /// address book.
    pub(crate) fn relay_rules(&self) -> Result<Vec<(u8, Vec<u8>)>, ConverterError> {
        let book = address_book(&self.vehicles)?;
        let addr = |id: &str| {
            book.addr(id).map_err(|_| {
                ConverterError::Config(format!(
                    "relays: {id:?} is not in the address book (vehicles)"
                ))
            })
        };
        let mut rules: Vec<(u8, Vec<u8>)> = Vec::new();
        for r in &self.relays {
            let relay = addr(&r.relay)?;
            if rules.iter().any(|(a, _)| *a == relay) {
                return Err(ConverterError::Config(format!(
                    "relays: {} listed twice",
                    r.relay
                )));
            }
            let carried = r
                .carries
                .iter()
                .map(|id| addr(id))
                .collect::<Result<Vec<u8>, _>>()?;
            if carried.contains(&relay) {
                return Err(ConverterError::Config(format!(
                    "relays: {} carries itself",
                    r.relay
                )));
            }
            rules.push((relay, carried));
        }
        Ok(rules)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn a_minimal_vdt_config_parses_with_defaults() {
        let c: VdtConfig = toml::from_str(
            r#"
            cdt_address = 1
            vehicles = [{ vehicle_id = "auv-1", address = 2 }]
            [modem]
            kind = "evins_nl"
            address = "127.0.0.1:9300"
            "#,
        )
        .unwrap();
        assert_eq!(c.modem.kind, ModemKind::EvinsNl);
        assert!(c.topics.state && !c.topics.environment);
        c.check().unwrap();
    }

    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Example {
        vdt: VdtConfig,
        cdt: CdtConfig,
    }

    #[test]
    fn the_example_file_parses_checks_and_matches_the_defaults() {
        let text = include_str!("../converter.example.toml");
        let e: Example = toml::from_str(text).unwrap();
        e.vdt.check().unwrap();
        e.cdt.check().unwrap();
        assert_eq!(e.vdt.link, LinkSettings::default());
        assert_eq!(e.vdt.topics, AcousticTopics::default());
        assert_eq!(e.vdt.relay, RelayConfig::default());
        assert_eq!(e.vdt.ip, IpPathConfig::default());
        assert_eq!(e.cdt.ip_silence_s, CdtConfig::default().ip_silence_s);
        assert_eq!(e.cdt.relay, RelayConfig::default());
        assert_eq!(e.cdt.link, LinkSettings::default());
        let d = VdtConfig::default();
        assert_eq!(
            (e.vdt.state_interval_s, e.vdt.announce_interval_s),
            (d.state_interval_s, d.announce_interval_s)
        );
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let r: Result<CdtConfig, _> = toml::from_str("adress = 1");
        assert!(r.is_err());
    }

    #[test]
    fn addresses_outside_the_4_bit_field_are_rejected() {
        let c = CdtConfig {
            vehicles: vec![AddressEntry {
                vehicle_id: "auv-1".into(),
                address: 16,
            }],
            ..CdtConfig::default()
        };
        assert!(c.check().unwrap_err().to_string().contains("1..=15"));
    }

    #[test]
    fn relays_must_name_vehicles_of_the_address_book() {
        let book = vec![
            AddressEntry {
                vehicle_id: "auv-1".into(),
                address: 2,
            },
            AddressEntry {
                vehicle_id: "auv-2".into(),
                address: 3,
            },
        ];
        let with = |relay: &str, carries: &[&str]| CdtConfig {
            vehicles: book.clone(),
            relays: vec![RelayEntry {
                relay: relay.into(),
                carries: carries.iter().map(|c| (*c).to_string()).collect(),
            }],
            ..CdtConfig::default()
        };
        assert_eq!(
            with("auv-1", &["auv-2"]).relay_rules().unwrap(),
            vec![(2, vec![3])]
        );
        let unknown = with("auv-1", &["auv-9"]).check().unwrap_err().to_string();
        assert!(
            unknown.contains("\"auv-9\" is not in the address book"),
            "{unknown}"
        );
        let itself = with("auv-1", &["auv-1"]).check().unwrap_err().to_string();
        assert!(itself.contains("carries itself"), "{itself}");
        let mut twice = with("auv-1", &["auv-2"]);
        twice.relays.push(twice.relays[0].clone());
        let twice = twice.check().unwrap_err().to_string();
        assert!(twice.contains("auv-1 listed twice"), "{twice}");
    }

    #[test]
    fn the_modems_position_and_carrier_are_optional_and_checked() {
        let book = vec![AddressEntry {
            vehicle_id: "auv-1".into(),
            address: 2,
        }];
        let c: CdtConfig = toml::from_str(
            r#"
            vehicles = [{ vehicle_id = "auv-1", address = 2 }]
            carrier = "usv-1"
            position = { latitude_deg = 63.464, longitude_deg = 10.38 }
            "#,
        )
        .unwrap();
        c.check().unwrap();
        assert_eq!(c.carrier.as_deref(), Some("usv-1"));
        let off_earth = CdtConfig {
            vehicles: book.clone(),
            position: Some(ModemPosition {
                latitude_deg: 91.0,
                longitude_deg: 0.0,
            }),
            ..CdtConfig::default()
        };
        assert!(
            off_earth
                .check()
                .unwrap_err()
                .to_string()
                .contains("position")
        );
        let spaced = CdtConfig {
            vehicles: book,
            carrier: Some("usv 1".into()),
            ..CdtConfig::default()
        };
        assert!(spaced.check().unwrap_err().to_string().contains("carrier"));
    }

    #[test]
    fn relay_settings_are_checked_and_the_cdts_relays_become_trusted() {
        let c: VdtConfig = toml::from_str(
            r#"
            vehicles = [{ vehicle_id = "auv-far", address = 4 }]
            [relay]
            routes = [{ dst = 1, via = 3 }]
            ttl = 3
            "#,
        )
        .unwrap();
        c.check().unwrap();
        assert_eq!(c.relay.routes[0].via, 3);
        let bad = VdtConfig {
            relay: RelayConfig {
                ttl: 9,
                ..RelayConfig::default()
            },
            ..c
        };
        assert!(bad.check().unwrap_err().to_string().contains("relay.ttl"));
        let cdt = CdtConfig {
            vehicles: vec![
                AddressEntry {
                    vehicle_id: "auv-near".into(),
                    address: 3,
                },
                AddressEntry {
                    vehicle_id: "auv-far".into(),
                    address: 4,
                },
            ],
            relays: vec![RelayEntry {
                relay: "auv-near".into(),
                carries: vec!["auv-far".into()],
            }],
            ..CdtConfig::default()
        };
        assert_eq!(
            cdt.relay_config().unwrap().trusted,
            vec![TrustedRelay {
                relay: 3,
                carries: vec![4]
            }]
        );
    }

    #[test]
    fn the_ip_path_is_off_by_default_and_its_bad_values_are_refused() {
        let c: VdtConfig = toml::from_str(
            r#"
            vehicles = [{ vehicle_id = "auv-1", address = 2 }]
            [ip]
            enabled = true
            domain_id = 7
            up_after_s = -3.0
            "#,
        )
        .unwrap();
        let e = c.check().unwrap_err().to_string();
        assert!(e.contains("ip.up_after_s") && e.contains("-3"), "{e}");
        assert!(!VdtConfig::default().ip.enabled);
        assert!(
            !CdtConfig::default().ip_failover,
            "a CDT holds no task back unless asked"
        );
        let typo: Result<VdtConfig, _> = toml::from_str("[ip]\nenable = true");
        assert!(typo.is_err());
        let cdt = CdtConfig {
            vehicles: vec![AddressEntry {
                vehicle_id: "auv-1".into(),
                address: 2,
            }],
            ip_silence_s: 0.0,
            ..CdtConfig::default()
        };
        let e = cdt.check().unwrap_err().to_string();
        assert!(e.contains("ip_silence_s"), "{e}");
    }

    #[test]
    fn ttls_reach_the_link_config() {
        let mut s = LinkSettings::default();
        s.ttl.control_s = 42.0;
        assert_eq!(
            s.link_config().unwrap().control.ttl,
            Duration::from_secs(42)
        );
        s.ttl.bulk_s = -1.0;
        assert!(s.link_config().is_err());
    }
}
