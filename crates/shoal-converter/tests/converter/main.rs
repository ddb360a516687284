//! Integration tests of the DDS-Acoustic Converter: one binary, one module per area.
//!
//! Every test runs the real modem emulator on 127.0.0.1 and real DDS participants, so it
//! must run inside the loopback-only network namespace:
//! `scripts/netns-run.sh shoal-conv -- cargo test -p shoal-converter`.
//! Each test uses its own DDS domains (from 100..130, listed in the module) so tests can
//! run in parallel; domain A stands for the vehicle side, domain B for the station side.
//!
//! - `common`: emulator, participants and waiting helpers.
//! - `end_to_end`: AUV on domain A → VDT → emulated sea → CDT → domain B and tasks back
//!   (domains 101, 102).
//! - `reconnect`: the modem connection drops and comes back; queued tasks survive
//!   (domains 103, 104).
//! - `outage`: ten simulated minutes out of acoustic range; queued tasks all arrive
//!   afterwards (domains 107, 108).
//! - `relay`: the `run_acoustic_demo` topology (domains 105, 106).
//! - `bench`: the `shoal bench acoustic` figures meet their goals (no DDS).
//!
//! New tests go in the module of their area; a new area gets a module listed here.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod bench;
mod common;
mod end_to_end;
mod outage;
mod reconnect;
mod relay;
