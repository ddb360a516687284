//! Integration tests of shoal-acoustic: everything here talks TCP on 127.0.0.1.
//!
//! Where new tests go:
//! - `emulator`: raw AT / NL sessions against the modem emulator (protocol, physics, bad input).
//! - `driver`: the AT and NL drivers against the emulator and against scripted fake modems
//!   (BUSY, dropped connections).
//! - `link`: the link layer over a driver over the emulator (priorities, loss, TTL).
//! - `relay`: multi-hop relays over a chain of emulated modems (forwarding, tags end to
//!   end, no direct path).
//!
//! The emulator runs with `time_scale` < 1 so simulated seconds pass in milliseconds;
//! driver and link timings are scaled by the same factor.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;
mod driver;
mod emulator;
mod link;
mod relay;
