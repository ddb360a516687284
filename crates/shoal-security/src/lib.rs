//! Shoal's security library: who may say what on the swarm's links, and proof that they said it.
//!
//! The architecture's Security module, as a library the DDS layer, the DDS-Acoustic
//! Converter and the CLI call. It has no I/O besides the key-store files and no async.
//! There is one mechanism per link: OMG DDS Security 1.1 on IP links, truncated HMAC tags
//! on the acoustic link.
//!
//! # Main types
//!
//! - [`dds`]: the OMG DDS Security 1.1 keystore IP links use (identity and permissions CAs,
//!   signed governance and per-participant permissions, a CRL, SROS2 layout), and
//!   [`dds::Enclave::check`], which reads a participant's files as the plugins will. The
//!   plugins themselves are Cyclone DDS's; `shoal-dds/src/omg.rs` loads them.
//! - [`AcousticTagger`] (acoustic link): appends a counter and a truncated HMAC-SHA256 tag
//!   (32 or 64 bits) to each modem frame under the sending vehicle's [`AcousticKey`], and
//!   checks them with a sliding [`ReplayWindow`] per sender; what it refuses is a
//!   [`Rejection`], counted by [`RejectionReason`] in [`RejectionCounts`].
//! - [`KeyStore`] (station side, on disk): a 256-bit acoustic key per vehicle, with a
//!   station CA, the station's certificate, an Ed25519 certificate per vehicle naming its
//!   enrolment, and a CRL. `init`, `issue_vehicle`, `list`, `revoke`, `rotate`,
//!   `renew_station`, `export_vehicle`, and `issue_site` (a federation site's TLS
//!   certificate, [`SiteName`]). [`VehicleBundle`] loads and checks what
//!   `export_vehicle` writes. The DDS Security keystore lives beside it (`<store>/dds`).
//!
//! # How the other parts use it
//!
//! - CLI (`shoal keys ...`, and `shoal up`/`shoal station` on first run): the [`KeyStore`]
//!   and [`dds::DdsKeystore`] methods side by side (issue, revoke, rotate and export act on
//!   both); every error displays as one line naming the file and the problem.
//! - DDS layer (`shoal-dds/src/omg.rs`): [`dds::Enclave::check`] before a participant is
//!   created, then the enclave's files as the plugins' properties;
//!   [`dds::vehicle_partition`] ties a vehicle's samples to its partition.
//! - Acoustic link (`shoal-acoustic/src/secure.rs`, set up by the converter with
//!   `store.acoustic_key(id)` for each vehicle the CDT serves): `tagger.seal(dst, &frame)`
//!   before transmitting, `tagger.open(src, dst, &data)` on reception.
//!   [`acoustic::OVERHEAD_32`] / [`acoustic::OVERHEAD_64`] are the bytes this costs per
//!   frame (a 64-byte instant message keeps 56 or 52).
//!
//! # Threat model
//!
//! The attacker can listen to, record, inject, delay and modify anything on the radio/Wi-Fi
//! IP link and in the water, knows every protocol and format, and may capture a vehicle
//! and read its keys. They do not control the station host.
//!
//! ## What is protected
//!
//! - **Origin and integrity** of every sample: on IP links DDS Security authenticates each
//!   participant by a certificate from the identity CA (PKI-DH) and protects discovery and
//!   samples with AES-GCM (or GMAC where the governance says `sign`); on the acoustic link
//!   an HMAC tag covers source and destination address, counter and frame. A flipped bit
//!   anywhere is refused.
//! - **Replay**: on IP links, RTPS sequence numbers under DDS Security's authenticated
//!   encryption (the attack corpus in `tests/security` replays live and old captures, and
//!   none is accepted); on the acoustic link, per-sender counters checked against a sliding
//!   window of 64.
//! - **Stolen or retired keys**: revocation (for IP links the identity CA's CRL, which a
//!   running station checks every `security.crl_check_s`; for the acoustic link, removing
//!   the vehicle's acoustic key) and rotation; expired certificates are refused.
//! - **Authorisation on IP links**: signed permissions let a vehicle publish only its own
//!   topics in its own partition and never a task; the station refuses a sample naming
//!   another vehicle than the partition it came in.
//! - **Authorisation on the acoustic link**: the CDT accepts a PDU about a vehicle only
//!   from the modem whose key opened the frame, or from a relay configured to carry that
//!   vehicle; others are refused, counted and raise an alarm naming the sender.
//!
//! ## What is not protected
//!
//! - **Confidentiality on the acoustic link**: frames are authenticated, not encrypted;
//!   anyone in range can read positions and tasks sent acoustically (IP links are
//!   encrypted by DDS Security unless the governance says otherwise).
//! - **A configured relay's key** speaks for every vehicle the relay carries: capturing a
//!   relay is capturing those vehicles' reports too.
//! - **Availability**: jamming the acoustic channel, flooding the radio, or a captured
//!   vehicle sending junk. Refusals are counted so the operator can see an attack, but
//!   nothing stops it.
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
//! - **The station host**: the CA keys live in the store directory (0600). Whoever owns
//!   the station owns the fleet; keep the store on the station only and back it up offline.
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
pub mod files;
pub mod identity;
pub mod reject;
pub mod replay;
pub mod revocation;
pub mod store;
mod util;

pub use acoustic::{AcousticKey, AcousticTagger, TagSize};
pub use cert::{Certificate, PrivateKey, SiteName, TrustAnchor};
pub use files::{FileError, FileProblem};
pub use identity::{Identity, Role};
pub use reject::{Rejection, RejectionCounts, RejectionReason};
pub use replay::ReplayWindow;
pub use revocation::{RevocationList, RevokeReason};
pub use store::{KeyStore, StoreError, StoreOptions, VehicleBundle};
pub use util::RandomError;
