//! Shoal's acoustic side: the non-DDS parts of the DDS-Acoustic Converter (CDT/VDT).
//!
//! A submerged vehicle reaches the station only through an acoustic modem: tens to
//! thousands of bits per second, seconds of delay, high loss, half duplex. This crate holds
//! everything needed to use such a link, runtime-free where it can be:
//!
//! - [`pdu`]: compact messages by the DCCL rule (docs/acoustic.md#compact-messages) — a
//!   20-byte keyframe State Vector, 10-byte deltas, tasks, statuses, events,
//!   announcements, environment observations, acks — packed several to a 64-byte modem
//!   frame, with conversions to and from `shoal-model` types.
//! - [`channel`]: underwater acoustic channel physics (docs/acoustic.md#channel-physics):
//!   Mackenzie sound speed, Thorp absorption, spreading, Wenz noise, SNR → BER → PER.
//! - [`at`] and [`nl`]: parsers and formatters for the EvoLogics S2C AT interface
//!   (docs/acoustic.md#at-interface) and the EviNS network-layer protocol
//!   (docs/acoustic.md#nl-protocol), shared by the emulator and the drivers.
//! - [`emulator`]: N virtual modems on 127.0.0.1 speaking AT and NL over TCP, in one
//!   simulated sea with propagation delay, loss, half duplex and collisions.
//! - [`driver`]: the [`driver::ModemDriver`] trait and its AT and NL implementations.
//! - [`link`]: the acoustic link layer: priority classes with Goby-style priority growth
//!   (docs/acoustic.md#link-layer), TTL, ack and retransmission, newest-first telemetry,
//!   frame packing, TDMA (docs/acoustic.md#medium-access).
//! - [`relay`]: multi-hop relays (docs/acoustic.md#multi-hop-relays): the relay envelope,
//!   routes configured or learned, duplicate suppression, TTL per hop, and
//!   [`relay::RelayDriver`], which forwards for nodes out of the other end's range.
//!
//! tokio is used only at the network edges (emulator, drivers, link runner).

#![forbid(unsafe_code)]

pub mod at;
pub mod channel;
pub mod driver;
pub mod emulator;
pub mod link;
pub mod nl;
pub mod pdu;
pub mod relay;
pub mod secure;
