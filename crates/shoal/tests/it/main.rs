//! Shoal's end-to-end and interop tests: one binary, one module per area.
//!
//! Every test here opens DDS participants, so it must run inside the private network
//! namespace the README's test command creates (`scripts/netns-run.sh`); each test uses
//! its own DDS domain id so tests running in parallel never see each other.
//!
//! Where new tests go:
//! - `station`: station + simulated vehicles in one process, the HTTP API, bad input.
//! - `attacks`: a station process attacked six ways (slow rule, floods, 10 MB samples, slow
//!   HTTP clients) while a real fleet's ingest rate is measured.
//! - `demo`: `shoal up`'s default scenario seen through the API (vehicles move, tasks run).
//! - `faults`: the station killed with SIGKILL and restarted.
//! - `federation`: two stations (ship and shore) federated over Zenoh on loopback.
//! - `lease`: the command lease at the vehicle: two federated stations that both reach it,
//!   a partition between them and its heal.
//! - `cli`: the `shoal` binary itself (`up`, configuration errors).
//! - `console`: the console's logins through the binary (on by default, the first admin
//!   shown once, `shoal query --token`).
//! - `proxies`: `shoal vehicle --proxy ...` against an independent vehicle implementation.
//! - `security`: `[security]` on: signed fleet, refused intruders, revocation, start-up
//!   errors.
//! - `scenario`: the services end to end — missions on three vehicles, one acoustic.
//! - `scenario_run`: `shoal scenario run` headless at 60x and its report directory.
//! - `converter`: the DDS-Acoustic Converter (VDT, CDT, the emulated relay) with a
//!   simulated vehicle behind it; its own module list says where its tests go.
//! - `wan`: `shoal bench federation`'s short run: three stations in network namespaces of
//!   their own over an emulated satellite link, exactly once across an outage.
//! - `interop`: foreign DDS implementations (Cyclone DDS, RTI Connext, Fast DDS) against
//!   the station, both directions; skipped with a reason when a peer is not installed.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod attacks;
mod cli;
mod common;
mod console;
mod converter;
mod demo;
mod faults;
mod federation;
mod interop;
mod lease;
mod proxies;
mod recorder;
mod scenario;
mod scenario_run;
mod security;
mod station;
mod wan;
