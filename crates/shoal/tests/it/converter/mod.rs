//! The DDS-Acoustic Converter end to end, one module per area. They live here rather than
//! in `shoal-converter` because a simulated vehicle ([`shoal_proxy::run_sim`]) stands on
//! the vehicle side, and the converter library does not depend on the simulator.
//!
//! Every test runs the real modem emulator on 127.0.0.1 and real DDS participants. Each
//! uses its own DDS domains (from 100..130, 190..191 and 216..217, listed in the module);
//! domain A stands for the vehicle side, domain B for the station side.
//!
//! - `common`: emulator, participants and waiting helpers, and the demo's relay topology.
//! - `end_to_end`: AUV on domain A → VDT → emulated sea → CDT → domain B and tasks back
//!   (domains 101, 102).
//! - `reconnect`: the modem connection drops and comes back; queued tasks survive
//!   (domains 103, 104).
//! - `outage`: ten simulated minutes out of acoustic range; queued tasks all arrive
//!   afterwards (domains 107, 108).
//! - `relay`: the `run_emulated_relay` topology of `shoal up`'s acoustic demo (domains
//!   105, 106), and a relay riding on a USV (domains 121, 122).
//! - `impersonation`: a vehicle's acoustic key speaks only for its vehicle, a relay only
//!   for the vehicles it carries (domain 111).
//! - `keyframes`: a CDT lacking the keyframe a delta names asks the VDT for one (domain
//!   112).
//! - `redelivery`: at most once over the acoustic link: a finished task delivered again
//!   after the VDT and the vehicle restart is not run again (domains 109, 110).
//! - `failover`: a vehicle surfacing and diving switches between its IP path and the
//!   acoustic link; tasks exactly once, no state vector lost or duplicated (domains 190,
//!   191; `shoal bench acoustic` measures the same on 192, 193).
//! - `recording`: the relay's CDT feeding its frames and link events to the acoustic
//!   recorder, the file read by the reference Python MCAP reader (domains 216, 217).
//!
//! New converter tests go in the module of their area; a new area gets a module listed
//! here. The `shoal bench acoustic` figures are checked by the benchmark's own unit tests.

pub mod common;
mod end_to_end;
mod failover;
mod impersonation;
mod keyframes;
mod outage;
mod reconnect;
mod recording;
mod redelivery;
mod relay;
