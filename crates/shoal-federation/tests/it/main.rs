//! The federation's integration tests: real Zenoh sessions in one process, talking over
//! tcp/127.0.0.1 (and tls/127.0.0.1) only (multicast scouting and gossip off in every configuration).
//!
//! One test binary; where new tests go:
//! - `common`: ports, configurations, a router to cut the link with, waiting helpers.
//! - `two_sites`: positions at the configured rate, coalesced; an alarm crosses once.
//! - `outage`: the link goes down and comes back; both sides catch up exactly.
//! - `three_sites`: two ships and a shore (also as their router); unknown sites and bad
//!   payloads are refused.
//! - `lease`: the command lease claimed, handed over, refused without authority, taken
//!   over by the standby in a partition and given up by the old holder when it heals.
//! - `orders`: the lease holder commands another site's vehicle through its home site;
//!   orders without the lease or forged are refused and never delivered.
//! - `python_client`: an independent PyPI `eclipse-zenoh` client decodes from the doc.
//! - `tls`: site identity over mutual TLS (`tls/127.0.0.1`): an expired certificate and a
//!   common name not accepted never reach the shore; bad files stop the start.
//! - `encoding_size`: the WAN encoding measured against CDR (+ zstd) on a realistic fleet.
//! - `environment`: environment observations cross as one summary per vehicle, property
//!   and window (`environment.mode = "aggregated"`), nothing with the mode off; a site
//!   not configured is refused.

// Test code: a failed step is a failed test.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;
mod encoding_size;
mod environment;
mod lease;
mod orders;
mod outage;
mod python_client;
mod three_sites;
mod tls;
mod two_sites;
