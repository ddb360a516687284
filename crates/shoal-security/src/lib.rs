//! Shoal's security library: who may say what on the swarm's links, and proof that they said it.
//!
//! The architecture's Security module, as a library the station, the DDS layer, the
//! DDS-Acoustic Converter and the CLI call. It has no I/O besides the key-store files and
//! no async.
//!
//! # Main types
//!
//! - [`dds`]: the OMG DDS Security 1.1 keystore IP links use (identity and permissions CAs,
//!   signed governance and per-participant permissions, a CRL, SROS2 layout), and
//!   [`dds::Enclave::check`], which reads a participant's files as the plugins will.
//! - The signed envelopes below ([`Envelope`], [`Gate`], [`Policy`]) are no longer used on
//!   IP links, which run DDS Security instead; they remain only until their attack corpus
//!   is moved to the standard path, and will be removed.
//! - [`KeyStore`] (station side, on disk): a station CA, the station's certificate, a
//!   certificate and a 256-bit acoustic key per vehicle, and a CRL. `init`, `issue_vehicle`,
//!   `list`, `revoke`, `rotate`, `renew_station`, `export_vehicle`. [`VehicleBundle`] is
//!   what a vehicle loads.
//! - IP links: [`SigningIdentity::sign`] (or [`sign`]) wraps a sample's bytes in an
//!   [`Envelope`] (Ed25519 signature over topic, payload, timestamp and counter);
//!   [`Verifier::verify`] checks chain, dates, revocation, signature, freshness and replay;
//!   [`Gate::admit`] adds the access [`Policy`] and counts refusals in
//!   [`RejectionCounts`].
//! - Acoustic link: [`AcousticTagger`] appends a counter and a truncated HMAC-SHA256 tag
//!   (32 or 64 bits) to each modem frame and checks them with a sliding replay window.
//! - [`Policy`]: TOML rules saying which identity may publish which topics for which
//!   instances; [`VehicleOwned`] gives the instance key of each model type.
//!
//! # How the other parts use it
//!
//! - Station start-up: `KeyStore::open(dir)`, then `store.station_identity()` to sign,
//!   `Gate::new(store.verifier(VerifierConfig::default())?, Policy::load(path)?)` to receive,
//!   and `store.acoustic_key(id)` for each vehicle the CDT serves.
//! - DDS layer, sending: `identity.sign(topic, &cdr_bytes, now_ms, counter)?.encode()`,
//!   with `counter` from [`envelope::counter_start_from_clock`] then `+1` per message;
//!   receiving: `gate.admit(&bytes, now_ms, |topic, payload| decode-and-owner)`, then
//!   deliver `admitted.envelope.payload()`.
//! - Acoustic converter: `tagger.seal(dst, &frame)` before `AT*SENDIM`;
//!   `tagger.open(src, dst, &data)` on `RECVIM`, then the policy check with the vehicle
//!   identity its address maps to. [`acoustic::OVERHEAD_32`] / [`acoustic::OVERHEAD_64`]
//!   are the bytes this costs per frame (a 64-byte instant message keeps 56 or 52).
//! - CLI (`shoal keys ...`): the [`KeyStore`] methods one to one; every error displays as
//!   one line naming the file and the problem.
//!
//! # Threat model
//!
//! The attacker can listen to, record, inject, delay and modify anything on the radio/Wi-Fi
//! IP link and in the water, knows every protocol and format, and may capture a vehicle
//! and read its keys. They do not control the station host.
//!
//! ## What is protected
//!
//! - **Origin and integrity** of every sample: on IP links an Ed25519 signature by a
//!   certificate the station CA issued covers the topic, payload, timestamp, counter and
//!   the signer's certificate id; on the acoustic link an HMAC tag covers source and
//!   destination address, counter and frame. A flipped bit anywhere is refused.
//! - **Replay**: per-sender counters checked against a sliding window (1024 on IP, 64
//!   acoustic); on IP also a freshness window on the timestamp (30 s old, 5 s ahead).
//! - **Stolen or retired keys**: revocation (an X.509 CRL signed by the CA) and rotation;
//!   expired certificates and an expired CA are refused.
//! - **Authorisation**: a vehicle, even with a valid certificate, publishes only its own
//!   data (no impersonation of another vehicle's position); only the station assigns tasks.
//!
//! ## What is not protected
//!
//! - **Confidentiality on the acoustic link**: frames are authenticated, not encrypted;
//!   anyone in range can read positions and tasks sent acoustically (IP links are
//!   encrypted by DDS Security).
//! - **Availability**: jamming the acoustic channel, flooding the radio, or a captured
//!   vehicle sending junk. Cheap checks run before signatures to limit the CPU cost, and
//!   refusals are counted so the operator can see an attack, but nothing stops it.
//! - **A captured vehicle until it is revoked**: it can speak as itself. A revoked
//!   vehicle's acoustic key must be removed from the CDT (`remove_key`); vehicles
//!   underwater learn of revocations only when they next receive a CRL.
//! - **Symmetric keys are shared**: the station can forge its vehicles' acoustic frames,
//!   and every holder of the fleet broadcast key can forge broadcasts.
//! - **Delay on the acoustic link**: frames carry a counter, not a timestamp, so a frame
//!   that an attacker blocked and replays later (once, in order) is accepted; application
//!   TTLs must bound how late a command may act.
//! - **Traffic analysis**: with DDS Security, discovery and samples are encrypted, but the
//!   participants' addresses, the RTPS headers and message sizes and timing are not.
//! - **The station host**: the CA key lives in the store directory (0600). Whoever owns
//!   the station owns the fleet; keep the store on the station only and back it up offline.
//! - **Clocks**: freshness needs station and vehicle clocks within the skew window.
//!
//! # Forging an acoustic tag
//!
//! A forged frame is accepted only if its tag matches: probability 2^-32 ≈ 2.3 × 10^-10
//! per attempt with 32-bit tags, 2^-64 ≈ 5.4 × 10^-20 with 64-bit tags, and each attempt
//! needs a fresh counter, so N attempts succeed with probability about N × 2^-bits. The
//! channel bounds N: a 64-byte instant message takes about 0.5 s on air at 976 bit/s plus
//! 0.14–0.2 s of modem overhead, so even a dedicated transmitter gets about one attempt per
//! second (a few with burst mode at 13.9 kbit/s, and every attempt occupies the shared,
//! half-duplex channel):
//!
//! | attempts | at 1 frame/s | 32-bit tag | 64-bit tag |
//! |---|---|---|---|
//! | 3 600 | one hour | 8.4 × 10^-7 | 2.0 × 10^-16 |
//! | 86 400 | one day | 2.0 × 10^-5 | 4.7 × 10^-15 |
//! | 31 557 600 | one year | 0.73 % | 1.7 × 10^-12 |
//!
//! At 10 frames/s multiply by ten. 32-bit tags fit the slowest links but assume that a
//! stream of `bad_tag` refusals (counted by [`RejectionCounts`]) raises an alarm and the
//! key is rotated long before a year of jamming; 64-bit tags, the default, need no such
//! assumption. Both are shorter than RFC 2104's advice (at least 80 bits), a deliberate
//! trade for frames of tens of bytes, as 802.15.4 and LoRaWAN make with 32-bit MICs.

#![forbid(unsafe_code)]

pub mod acoustic;
pub mod cert;
pub mod dds;
pub mod envelope;
pub mod files;
pub mod identity;
pub mod policy;
pub mod reject;
pub mod replay;
pub mod revocation;
pub mod store;
mod util;
pub mod verify;

pub use acoustic::{AcousticKey, AcousticTagger, TagSize};
pub use cert::{CertId, Certificate, PrivateKey, TrustAnchor};
pub use envelope::{Envelope, SigningIdentity, sign};
pub use files::{FileError, FileProblem};
pub use identity::{Identity, Role};
pub use policy::{Denied, Policy, PolicyError, VehicleOwned};
pub use reject::{Rejection, RejectionCounts, RejectionReason};
pub use replay::ReplayWindow;
pub use revocation::{RevocationList, RevokeReason};
pub use store::{KeyStore, StoreError, StoreOptions, VehicleBundle};
pub use util::RandomError;
pub use verify::{Admitted, Gate, VerifiedSender, Verifier, VerifierConfig};
