//! The receiving side's core, with no network: every sample from a remote site passes
//! here, is checked, deduplicated and put in the [`FederatedPicture`], or refused and
//! counted by reason. Nothing a remote sends can make it panic or grow without bound.
//!
//! Sequenced streams (alarms, task transitions) are tracked per site and stream by a
//! [`SeqWindow`]: everything up to `contiguous` has been delivered, and a bounded set of
//! numbers above it. A number seen twice is a duplicate; a number past a gap asks for a
//! catch-up query (the transport sends it). A new epoch means the sender restarted and
//! numbers from 1 again; one of the few epochs heard before it is stale.
//!
//! Orders ([`crate::orders`]) come through [`Inbound::receive_order`], which checks them
//! against the command leases kept here and hands each new one to a delivery function.
//!
//! With end-to-end signatures required ([`Inbound::require_signatures`], with TLS), lease
//! records and orders must carry their maker's signature ([`crate::signed`]); one whose
//! signer's certificate is not known yet is held (bounded) until the site's identity
//! arrives ([`Inbound::identity`]) and then received again.
//!
//! Environment frames are not sequenced streams: nothing is caught up, and each summary
//! in a frame is taken or refused on its own against the one the picture holds.

use std::borrow::Cow;
use std::collections::{BTreeMap, BTreeSet, HashMap};

use tracing::{debug, warn};

use crate::config::{FederationConfig, Limits};
use crate::keys::{Key, Stream};
use crate::lease::{Applied, LeaseRefusal, LeaseTable};
use crate::orders::{self, OrderLedger, OrderRefusal, RelayedOrder, WarnGate};
use crate::picture::{FederatedPicture, PositionRefusal};
use crate::signed::{self, Awaiting, HeldSample, Hold, SignatureError, Verify};
use crate::wire::{self, DecodeError, Sequenced};

/// Why a received sample was not taken.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Refusal {
    /// The key expression is not one the federation publishes.
    #[error("not a federation key")]
    BadKey,
    /// The site is not in `remote_sites`.
    #[error("site {0} is not a configured remote site")]
    UnknownSite(String),
    /// Another session uses this site's own name.
    #[error("a remote session uses this site's name")]
    OwnSite,
    /// The site in the frame is not the site in the key expression.
    #[error("frame from site {frame} under the key of site {key}")]
    SiteMismatch {
        /// The site named by the key.
        key: String,
        /// The site named in the frame.
        frame: String,
    },
    /// The payload does not decode.
    #[error("malformed payload: {0}")]
    Malformed(#[from] DecodeError),
    /// From an earlier run of the sending site than the one heard now.
    #[error("from an earlier epoch of its site")]
    StaleEpoch,
    /// Already delivered.
    #[error("duplicate")]
    Duplicate,
    /// A position older than the one held.
    #[error("older than the position held")]
    StalePosition,
    /// A new remote vehicle beyond `limits.remote_vehicles`.
    #[error("too many remote vehicles")]
    TooManyVehicles,
    /// An environment summary of an earlier window than the one held for its property.
    #[error("environment summary older than the one held")]
    StaleEnvironment,
    /// An environment summary of a new (site, vehicle, property) beyond
    /// `limits.remote_environment`.
    #[error("too many remote environment summaries")]
    TooManyEnvironment,
    /// A catch-up query answered with more than `limits.catchup_replies`.
    #[error("catch-up reply beyond the limit")]
    CatchupOverflow,
    /// A catch-up reply for another site or stream than asked.
    #[error("catch-up reply for another site or stream")]
    CatchupKey,
    /// A command-lease record without authority, or beyond the limit.
    #[error("lease record refused: {0}")]
    Lease(#[from] LeaseRefusal),
    /// An order not delivered: malformed, not from the vehicle's lease holder, not for a
    /// vehicle of this site, already delivered, or no room.
    #[error("order refused: {0}")]
    Order(#[from] OrderRefusal),
    /// A lease record or order whose end-to-end signature is missing or wrong, or an
    /// identity frame that does not check out.
    #[error("{0}")]
    Signature(#[from] SignatureError),
    /// Held, not refused: taken once the signing site's certificate arrives.
    #[error("held until site {site}'s certificate arrives")]
    AwaitingIdentity {
        /// The signing site.
        site: String,
        /// Nobody asked for its certificate yet: ask.
        ask: bool,
    },
    /// Not held: the samples waiting for the site's certificate are at their limit.
    #[error("too many samples waiting for the signing site's certificate")]
    AwaitingIdentityFull,
}

impl Refusal {
    /// A stable short code for counters, e.g. `unknown_site`, `malformed:truncated`.
    pub fn reason(&self) -> String {
        match self {
            Self::BadKey => "bad_key".into(),
            Self::UnknownSite(_) => "unknown_site".into(),
            Self::OwnSite => "own_site".into(),
            Self::SiteMismatch { .. } => "site_mismatch".into(),
            Self::Malformed(e) => format!("malformed:{}", e.reason()),
            Self::StaleEpoch => "stale_epoch".into(),
            Self::Duplicate => "duplicate".into(),
            Self::StalePosition => "stale_position".into(),
            Self::TooManyVehicles => "too_many_vehicles".into(),
            Self::StaleEnvironment => "stale_environment".into(),
            Self::TooManyEnvironment => "too_many_environment".into(),
            Self::CatchupOverflow => "catchup_overflow".into(),
            Self::CatchupKey => "catchup_key".into(),
            Self::Lease(r) => r.reason().into(),
            Self::Order(r) => r.reason(),
            Self::Signature(e) => e.reason().into(),
            Self::AwaitingIdentity { .. } => "awaiting_identity".into(),
            Self::AwaitingIdentityFull => "awaiting_identity_full".into(),
        }
    }
}

/// A query for what a remote site's stream has after `after`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CatchupRequest {
    /// The remote site.
    pub site: String,
    /// The stream.
    pub stream: Stream,
    /// The epoch `after` counts in, if any was heard.
    pub epoch: Option<u64>,
    /// Everything up to this sequence number has been delivered.
    pub after: u64,
    /// Frames asked for at most (`limits.catchup_batch`).
    pub limit: usize,
}

/// The receiving side's counters.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct InboundCounters {
    /// Positions taken into the picture.
    pub positions: u64,
    /// Alarms delivered (each once).
    pub alarms: u64,
    /// Task transitions delivered (each once).
    pub transitions: u64,
    /// Command-lease records taken (stale ones are in the lease counters).
    pub leases: u64,
    /// Environment summaries taken into the picture (one per vehicle, property and
    /// window; those refused are counted by reason, per summary).
    pub environment: u64,
    /// Order samples received (whatever became of them).
    pub orders_received: u64,
    /// Orders accepted and delivered to the station (each once).
    pub orders_accepted: u64,
    /// Orders received again (the same frame, or the same task sent again) and dropped.
    pub order_duplicates: u64,
    /// Sequenced frames, and environment summaries, received again and suppressed.
    pub duplicates: u64,
    /// Sequence numbers given up: the sender no longer had them, or the reorder window
    /// overflowed.
    pub lost: u64,
    /// Catch-up queries asked.
    pub catchup_queries: u64,
    /// Catch-up replies received (duplicates included).
    pub catchup_replies: u64,
    /// Signed samples held until their signer's certificate arrived (then received again).
    pub held_for_identity: u64,
    /// Remote sites' certificates taken from their identity frames.
    pub identities: u64,
    /// Refusals by reason (duplicates are counted above, not here).
    pub refused: BTreeMap<String, u64>,
}

impl InboundCounters {
    /// Refusals of one reason so far.
    pub fn refused(&self, reason: &str) -> u64 {
        self.refused.get(reason).copied().unwrap_or(0)
    }
}

/// Earlier epochs of a stream remembered, to refuse their frames as stale.
const EPOCHS_REMEMBERED: usize = 4;

/// One remote stream's delivered sequence numbers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeqWindow {
    epoch: u64,
    contiguous: u64,
    above: BTreeSet<u64>,
    /// The epochs this stream had before, most recent last.
    earlier: Vec<u64>,
}

/// What a window says of a sequence number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admit {
    /// New; `gap` when some number below it has not arrived.
    New {
        /// A number below it is missing.
        gap: bool,
    },
    /// Already delivered.
    Duplicate,
    /// From an epoch the stream had before its current one.
    Stale,
}

impl SeqWindow {
    /// A window for a stream first heard under `epoch`.
    pub fn new(epoch: u64) -> Self {
        Self {
            epoch,
            contiguous: 0,
            above: BTreeSet::new(),
            earlier: Vec::new(),
        }
    }

    /// Records `seq` of `epoch` if new. Holds at most `capacity` numbers above a gap;
    /// past that the oldest gap is given up, and the numbers given up are added to `lost`.
    pub fn admit(&mut self, epoch: u64, seq: u64, capacity: usize, lost: &mut u64) -> Admit {
        if epoch != self.epoch {
            // Epochs are told apart, not ordered: a sender whose clock went back across a
            // restart starts a lower epoch, and must still be heard.
            if self.earlier.contains(&epoch) {
                return Admit::Stale;
            }
            let mut earlier = std::mem::take(&mut self.earlier);
            earlier.push(self.epoch);
            if earlier.len() > EPOCHS_REMEMBERED {
                earlier.remove(0);
            }
            *self = Self {
                earlier,
                ..Self::new(epoch)
            };
        }
        if seq <= self.contiguous || self.above.contains(&seq) {
            return Admit::Duplicate;
        }
        if seq == self.contiguous + 1 {
            self.contiguous = seq;
            self.absorb();
        } else {
            self.above.insert(seq);
            while self.above.len() > capacity {
                // The oldest gap is given up: jump to the lowest number held.
                if let Some(first) = self.above.pop_first() {
                    *lost += first - self.contiguous - 1;
                    self.contiguous = first;
                    self.absorb();
                }
            }
        }
        Admit::New {
            gap: !self.above.is_empty(),
        }
    }

    /// Gives up every number up to `upto` not yet delivered (the sender has answered a
    /// catch-up query and no longer has them); returns how many.
    pub fn settle(&mut self, upto: u64) -> u64 {
        if upto <= self.contiguous {
            return 0;
        }
        let held = self.above.range(..=upto).count() as u64;
        let missing = upto - self.contiguous - held;
        self.above.retain(|s| *s > upto);
        self.contiguous = upto;
        self.absorb();
        missing
    }

    /// Moves `contiguous` over the numbers held right above it.
    fn absorb(&mut self) {
        while self.above.first() == Some(&(self.contiguous + 1)) {
            self.above.pop_first();
            self.contiguous += 1;
        }
    }

    /// The epoch and the number up to which everything was delivered.
    pub fn position(&self) -> (u64, u64) {
        (self.epoch, self.contiguous)
    }
}

/// A catch-up query under way: the highest number its replies brought, and its end.
#[derive(Debug, Clone, Default)]
struct Pending {
    replies: usize,
    /// Highest (epoch, seq) received in this query's replies.
    highest: Option<(u64, u64)>,
    /// The answer's end frame, once it came.
    end: Option<wire::CatchupEnd>,
}

/// What follows a catch-up query.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CatchupOutcome {
    /// Nothing: this site has what the sender has.
    Done,
    /// The next part, to ask at once.
    More(CatchupRequest),
    /// The same query again after a while, while the site is online.
    Retry,
}

/// One site's receiving side.
#[derive(Debug)]
pub struct Inbound {
    site: String,
    remote_sites: Vec<String>,
    limits: Limits,
    windows: HashMap<(String, Stream), SeqWindow>,
    pending: HashMap<(String, Stream), Pending>,
    picture: FederatedPicture,
    leases: LeaseTable,
    /// Whether the command lease is in force here: orders are checked against it.
    lease_enabled: bool,
    orders: OrderLedger,
    order_warnings: WarnGate,
    /// The remote sites' certificates when end-to-end signatures are required.
    signatures: Option<Box<dyn Verify>>,
    awaiting: Awaiting,
    counters: InboundCounters,
}

impl Inbound {
    /// The receiving side of a (validated) configuration.
    pub fn new(config: &FederationConfig) -> Self {
        let l = &config.limits;
        let mut limits = l.clone();
        // On a slow link, parts that cross within a quarter of the timeout at the rate
        // the answering site paces them.
        if let Some(shaping) = config.link_shaping() {
            limits.catchup_batch = shaping.part_items(
                crate::config::CATCHUP_ITEM_BYTES,
                l.catchup_timeout_ms,
                l.catchup_batch,
            );
        }
        Self {
            site: config.site.clone(),
            remote_sites: config.remote_sites.clone(),
            limits,
            windows: HashMap::new(),
            pending: HashMap::new(),
            picture: FederatedPicture::new(
                l.remote_vehicles,
                l.remote_alarms,
                l.remote_transitions,
                l.remote_environment,
            ),
            leases: LeaseTable::new(
                &config.site,
                &config.lease.standby,
                &config.remote_sites,
                l.remote_vehicles,
            ),
            lease_enabled: config.lease.enabled,
            orders: OrderLedger::default(),
            order_warnings: WarnGate::default(),
            signatures: None,
            awaiting: Awaiting::default(),
            counters: InboundCounters::default(),
        }
    }

    /// From now on, lease records and orders are taken only with a signature that
    /// `verifier` checks with their maker's certificate.
    pub fn require_signatures(&mut self, verifier: Box<dyn Verify>) {
        self.signatures = Some(verifier);
    }

    /// Whether end-to-end signatures are required.
    pub fn signatures_required(&self) -> bool {
        self.signatures.is_some()
    }

    /// Takes `site`'s identity frame (its answer to `shoal/<site>/identity`) and returns
    /// the samples held for its certificate, to be received again in order.
    pub fn identity(
        &mut self,
        site: &str,
        payload: &[u8],
        now_ms: i64,
    ) -> Result<Vec<HeldSample>, Refusal> {
        let result = self.learn(site, payload, now_ms);
        self.count(&crate::keys::identity(site), result.as_ref().err());
        if result.is_err() {
            self.awaiting.unanswered(site);
        }
        result
    }

    fn learn(
        &mut self,
        site: &str,
        payload: &[u8],
        now_ms: i64,
    ) -> Result<Vec<HeldSample>, Refusal> {
        self.check_site(site)?;
        let Some(verifier) = self.signatures.as_mut() else {
            return Ok(Vec::new());
        };
        let chain = signed::decode_identity(payload)?;
        verifier.learn(site, &chain, now_ms)?;
        self.counters.identities += 1;
        Ok(self.awaiting.release(site))
    }

    /// `site`'s identity query went unanswered; true when samples wait for it, so that
    /// it is asked again.
    pub fn identity_unanswered(&mut self, site: &str) -> bool {
        self.awaiting.unanswered(site)
    }

    /// Samples held for their signers' certificates now.
    pub fn awaiting_identity(&self) -> usize {
        self.awaiting.len()
    }

    /// The frame of a lease record or order under `key` from `site`, its signature
    /// checked when signatures are required; held when the signer's certificate is not
    /// known yet.
    fn authenticate<'p>(
        &mut self,
        key: &str,
        site: &str,
        payload: &'p [u8],
        now_ms: i64,
    ) -> Result<Cow<'p, [u8]>, Refusal> {
        let Some(verifier) = &self.signatures else {
            // Without TLS there is no certificate to check against: the link's identity
            // is the authority, and a signed frame is read as its unsigned self.
            return Ok(match signed::open(key, payload)? {
                Some(opened) => Cow::Owned(opened.frame),
                None => Cow::Borrowed(payload),
            });
        };
        let opened = signed::open(key, payload)?.ok_or(SignatureError::Unsigned)?;
        if !verifier.knows(site, now_ms) {
            return Err(match self.awaiting.hold(site, key, payload) {
                Hold::AskNow => Refusal::AwaitingIdentity {
                    site: site.to_owned(),
                    ask: true,
                },
                Hold::Asked => Refusal::AwaitingIdentity {
                    site: site.to_owned(),
                    ask: false,
                },
                Hold::Full => Refusal::AwaitingIdentityFull,
            });
        }
        verifier.verify(
            site,
            opened.scheme,
            &opened.message,
            opened.signature,
            now_ms,
        )?;
        Ok(Cow::Owned(opened.frame))
    }

    /// The command leases this site knows.
    pub fn leases(&self) -> &LeaseTable {
        &self.leases
    }

    /// The command leases, to claim, hand over or fail over.
    pub fn leases_mut(&mut self) -> &mut LeaseTable {
        &mut self.leases
    }

    /// Since when a remote site has been offline (`None` while online; a site never heard
    /// counts as offline since this site started, `started_ms`).
    pub fn offline_since(&self, site: &str, started_ms: i64) -> Option<i64> {
        match self.picture.sites().find(|(s, _)| *s == site) {
            Some((_, status)) if status.online => None,
            Some((_, status)) => Some(status.since_ms),
            None => Some(started_ms),
        }
    }

    /// The picture built so far.
    pub fn picture(&self) -> &FederatedPicture {
        &self.picture
    }

    /// The counters so far.
    pub fn counters(&self) -> &InboundCounters {
        &self.counters
    }

    /// Takes one published sample; may ask for a catch-up query.
    pub fn receive(
        &mut self,
        key: &str,
        payload: &[u8],
        now_ms: i64,
    ) -> Result<Option<CatchupRequest>, Refusal> {
        let result = self.take(key, payload, now_ms, None);
        self.count(key, result.as_ref().err());
        result
    }

    /// Takes one order sample: checks it against the vehicle's lease as this site knows it
    /// and, when it is new, hands it to `deliver` (the station's bounded queue, which
    /// refuses when full). Only a delivered order is remembered, so one refused for want
    /// of room is taken when it is sent again.
    pub fn receive_order(
        &mut self,
        key: &str,
        payload: &[u8],
        now_ms: i64,
        deliver: impl FnOnce(RelayedOrder) -> Result<(), OrderRefusal>,
    ) -> Result<(), Refusal> {
        self.counters.orders_received += 1;
        let result = self.take_order(key, payload, now_ms, deliver);
        match &result {
            Ok(()) => self.counters.orders_accepted += 1,
            Err(Refusal::Order(OrderRefusal::Duplicate)) => {
                self.counters.order_duplicates += 1;
                debug!(key, "order already delivered");
            }
            Err(Refusal::AwaitingIdentity { .. }) => {
                self.counters.held_for_identity += 1;
                debug!(key, "order held until its sender's certificate arrives");
            }
            Err(refusal) => {
                *self.counters.refused.entry(refusal.reason()).or_default() += 1;
                let routine = matches!(refusal, Refusal::Order(r) if r.routine());
                if routine {
                    debug!(key, reason = %refusal, "order not for this site");
                } else if let Some(quiet) = self.order_warnings.admit(&refusal.reason(), now_ms) {
                    warn!(key, reason = %refusal, not_logged_since = quiet, "order refused");
                }
            }
        }
        result
    }

    fn take_order(
        &mut self,
        key: &str,
        payload: &[u8],
        now_ms: i64,
        deliver: impl FnOnce(RelayedOrder) -> Result<(), OrderRefusal>,
    ) -> Result<(), Refusal> {
        let Some(Key::Order {
            site,
            home,
            vehicle,
        }) = Key::parse(key)
        else {
            return Err(Refusal::BadKey);
        };
        // Only the home subscribes to its orders; one addressed elsewhere is not for here.
        if home != self.site {
            return Err(Refusal::BadKey);
        }
        self.check_site(site)?;
        let payload = self.authenticate(key, site, payload, now_ms)?;
        let frame = wire::decode_order(vehicle, &payload).map_err(OrderRefusal::Malformed)?;
        // The key's site is the authenticated sender; the envelope's is the lease holder
        // the task carries: they must be one.
        if frame.site != site {
            return Err(OrderRefusal::SiteMismatch {
                key: site.to_string(),
                frame: frame.site,
            }
            .into());
        }
        let admitted = self.orders.admit(
            site,
            frame.epoch,
            frame.seq,
            &frame.item,
            self.limits.reorder_window,
        )?;
        orders::check_received(
            &self.site,
            self.lease_enabled,
            self.leases.lease(vehicle),
            site,
            &frame.item,
        )?;
        deliver(RelayedOrder {
            from_site: frame.site,
            task: frame.item,
        })?;
        self.orders.delivered(admitted);
        Ok(())
    }

    /// Takes one reply to the catch-up query `request`.
    pub fn receive_catchup(
        &mut self,
        request: &CatchupRequest,
        key: &str,
        payload: &[u8],
        now_ms: i64,
    ) -> Result<(), Refusal> {
        self.counters.catchup_replies += 1;
        let result = if wire::is_catchup_end(payload) {
            self.take_end(request, key, payload)
        } else {
            self.take(key, payload, now_ms, Some(request)).map(|_| ())
        };
        self.count(key, result.as_ref().err());
        result
    }

    fn take_end(
        &mut self,
        request: &CatchupRequest,
        key: &str,
        payload: &[u8],
    ) -> Result<(), Refusal> {
        let (site, stream) = match Key::parse(key).ok_or(Refusal::BadKey)? {
            Key::Alarms { site } => (site, Stream::Alarms),
            Key::Task { site } => (site, Stream::Tasks),
            _ => return Err(Refusal::CatchupKey),
        };
        if request.site != site || request.stream != stream {
            return Err(Refusal::CatchupKey);
        }
        let end = wire::decode_catchup_end(payload)?;
        if end.site != site {
            return Err(Refusal::SiteMismatch {
                key: site.to_string(),
                frame: end.site,
            });
        }
        let pending = self
            .pending
            .get_mut(&(request.site.clone(), stream))
            .ok_or(Refusal::CatchupKey)?;
        pending.end = Some(end);
        Ok(())
    }

    /// Notes that a remote site's session came up or went down; when it comes up,
    /// returns the catch-up queries to ask it.
    pub fn site_alive(&mut self, key: &str, online: bool, now_ms: i64) -> Vec<CatchupRequest> {
        let site = match Key::parse(key) {
            Some(Key::Alive { site }) => site.to_string(),
            _ => {
                self.count(key, Some(&Refusal::BadKey));
                return Vec::new();
            }
        };
        if let Err(refusal) = self.check_site(&site) {
            self.count(key, Some(&refusal));
            return Vec::new();
        }
        self.picture.site(&site, online, now_ms);
        if !online {
            return Vec::new();
        }
        if let Some(verifier) = self.signatures.as_mut() {
            // A site whose session came up may present a new certificate: what it signs
            // waits for the identity the transport now asks for.
            verifier.forget(&site);
            self.awaiting.asking(&site);
        }
        Stream::ALL
            .into_iter()
            .filter_map(|stream| self.request(&site, stream))
            .collect()
    }

    /// Ends a catch-up query and says what comes next. An answer is complete when its
    /// end frame arrived: numbers below the oldest the sender keeps, and those inside the
    /// answer that it skipped, are given up (counted as lost: the sender no longer has
    /// them); if the sender has more, the next part is asked for at once when this one
    /// brought something, after a while when it brought nothing (the sender had no time
    /// left for it). An answer without its end frame (the wait ran out, or no queryable
    /// heard the query) gives nothing up and is asked again after a while.
    pub fn finish_catchup(&mut self, request: &CatchupRequest) -> CatchupOutcome {
        let key = (request.site.clone(), request.stream);
        let Some(pending) = self.pending.remove(&key) else {
            return CatchupOutcome::Done;
        };
        let Some(end) = pending.end else {
            return CatchupOutcome::Retry;
        };
        let window = self.windows.get_mut(&key);
        let behind = match window {
            Some(window) if window.epoch == end.epoch => {
                let mut lost = 0;
                if let Some((epoch, upto)) = pending.highest
                    && epoch == end.epoch
                {
                    lost += window.settle(upto);
                }
                lost += window.settle(end.oldest.saturating_sub(1));
                if lost > 0 {
                    debug!(site = %request.site, stream = request.stream.as_str(), lost, "numbers the sender no longer had");
                }
                self.counters.lost += lost;
                window.contiguous < end.highest
            }
            // A stream not heard yet in the sender's epoch: behind if it keeps anything.
            _ => end.oldest <= end.highest,
        };
        if !behind {
            CatchupOutcome::Done
        } else if pending.replies > 0 {
            self.request(&request.site, request.stream)
                .map_or(CatchupOutcome::Done, CatchupOutcome::More)
        } else {
            CatchupOutcome::Retry
        }
    }

    /// Forgets a catch-up query that was never sent.
    pub fn abandon_catchup(&mut self, request: &CatchupRequest) {
        self.pending.remove(&(request.site.clone(), request.stream));
    }

    /// A catch-up query asked again after the last came back incomplete, if the site is
    /// still online and none is under way.
    pub fn retry_catchup(&mut self, site: &str, stream: Stream) -> Option<CatchupRequest> {
        self.is_online(site)
            .then(|| self.request(site, stream))
            .flatten()
    }

    /// A catch-up query on every stream of every online site with none under way: a
    /// frame lost with no later one to reveal the gap (a publishing queue that was full,
    /// a link that dropped just then) would otherwise never be asked for. Each costs a
    /// query and an end frame when nothing is missing.
    pub fn poll_catchup(&mut self) -> Vec<CatchupRequest> {
        let online: Vec<String> = self
            .picture
            .sites()
            .filter(|(_, status)| status.online)
            .map(|(s, _)| s.to_string())
            .collect();
        online
            .iter()
            .flat_map(|site| Stream::ALL.map(|stream| (site, stream)))
            .filter_map(|(site, stream)| self.request(site, stream))
            .collect()
    }

    fn is_online(&self, site: &str) -> bool {
        self.picture
            .sites()
            .any(|(s, status)| s == site && status.online)
    }

    /// A catch-up query for a stream, unless one is already under way.
    fn request(&mut self, site: &str, stream: Stream) -> Option<CatchupRequest> {
        let key = (site.to_string(), stream);
        if self.pending.contains_key(&key) {
            return None;
        }
        self.pending.insert(key.clone(), Pending::default());
        self.counters.catchup_queries += 1;
        let (epoch, after) = match self.windows.get(&key) {
            Some(w) => (Some(w.epoch), w.contiguous),
            None => (None, 0),
        };
        Some(CatchupRequest {
            site: site.to_string(),
            stream,
            epoch,
            after,
            limit: self.limits.catchup_batch,
        })
    }

    fn check_site(&self, site: &str) -> Result<(), Refusal> {
        if site == self.site {
            return Err(Refusal::OwnSite);
        }
        if !self.remote_sites.iter().any(|s| s == site) {
            return Err(Refusal::UnknownSite(site.to_string()));
        }
        Ok(())
    }

    fn take(
        &mut self,
        key: &str,
        payload: &[u8],
        now_ms: i64,
        catchup: Option<&CatchupRequest>,
    ) -> Result<Option<CatchupRequest>, Refusal> {
        let parsed = Key::parse(key).ok_or(Refusal::BadKey)?;
        self.check_site(parsed.site())?;
        match parsed {
            Key::Position { site, vehicle } => {
                if catchup.is_some() {
                    return Err(Refusal::CatchupKey);
                }
                let p = wire::decode_position(vehicle, payload)?;
                self.picture
                    .position(site, p, now_ms)
                    .map_err(|r| match r {
                        PositionRefusal::Stale => Refusal::StalePosition,
                        PositionRefusal::Full => Refusal::TooManyVehicles,
                    })?;
                self.counters.positions += 1;
                Ok(None)
            }
            Key::Alarms { site } => {
                let frame = wire::decode_alarm(payload)?;
                let gap = self.sequenced(site, Stream::Alarms, &frame, catchup)?;
                self.picture.alarm(site, frame.seq, frame.item, now_ms);
                self.counters.alarms += 1;
                Ok(gap.then(|| self.request(site, Stream::Alarms)).flatten())
            }
            Key::Task { site } => {
                let frame = wire::decode_task(payload)?;
                let gap = self.sequenced(site, Stream::Tasks, &frame, catchup)?;
                self.picture.transition(site, frame.seq, frame.item, now_ms);
                self.counters.transitions += 1;
                Ok(gap.then(|| self.request(site, Stream::Tasks)).flatten())
            }
            Key::Environment { site, vehicle } => {
                if catchup.is_some() {
                    return Err(Refusal::CatchupKey);
                }
                let frame = wire::decode_environment(vehicle, payload)?;
                if frame.site != site {
                    return Err(Refusal::SiteMismatch {
                        key: site.to_string(),
                        frame: frame.site,
                    });
                }
                self.environment(site, frame, now_ms);
                Ok(None)
            }
            Key::Lease { site, vehicle } => {
                if catchup.is_some() {
                    return Err(Refusal::CatchupKey);
                }
                let payload = self.authenticate(key, site, payload, now_ms)?;
                let record = wire::decode_lease(vehicle, &payload)?;
                if self.leases.apply(site, record)? == Applied::Changed {
                    self.counters.leases += 1;
                }
                Ok(None)
            }
            // Not data of the picture: liveliness comes through `site_alive`, orders through
            // `receive_order` (and never in a catch-up reply).
            Key::Alive { .. } | Key::Order { .. } | Key::Identity { .. } => Err(Refusal::BadKey),
        }
    }

    /// Takes an environment frame's summaries into the picture, counting each refused one
    /// by its reason: the frame was read, and its summaries fare each on its own.
    fn environment(
        &mut self,
        site: &str,
        frame: Sequenced<crate::environment::EnvironmentAggregates>,
        now_ms: i64,
    ) {
        let vehicle = frame.item.vehicle_id.clone();
        let t = self
            .picture
            .environment_frame(site, (frame.epoch, frame.seq), frame.item, now_ms);
        self.counters.environment += t.taken;
        self.counters.duplicates += t.duplicate;
        for (refusal, n) in [
            (Refusal::StaleEnvironment, t.stale),
            (Refusal::TooManyEnvironment, t.full),
        ] {
            if n > 0 {
                debug!(site, vehicle = %vehicle, reason = %refusal, summaries = n, "environment summaries refused");
                *self.counters.refused.entry(refusal.reason()).or_default() += n;
            }
        }
    }

    /// Checks a sequenced frame's envelope and admits its number; true when a gap
    /// below it calls for a catch-up query.
    fn sequenced<T>(
        &mut self,
        site: &str,
        stream: Stream,
        frame: &Sequenced<T>,
        catchup: Option<&CatchupRequest>,
    ) -> Result<bool, Refusal> {
        if frame.site != site {
            return Err(Refusal::SiteMismatch {
                key: site.to_string(),
                frame: frame.site.clone(),
            });
        }
        let key = (site.to_string(), stream);
        if let Some(request) = catchup {
            if request.site != site || request.stream != stream {
                return Err(Refusal::CatchupKey);
            }
            let pending = self.pending.get_mut(&key).ok_or(Refusal::CatchupKey)?;
            pending.replies += 1;
            if pending.replies > self.limits.catchup_replies {
                return Err(Refusal::CatchupOverflow);
            }
            pending.highest = pending.highest.max(Some((frame.epoch, frame.seq)));
        }
        let window = self
            .windows
            .entry(key)
            .or_insert_with(|| SeqWindow::new(frame.epoch));
        match window.admit(
            frame.epoch,
            frame.seq,
            self.limits.reorder_window,
            &mut self.counters.lost,
        ) {
            Admit::New { gap } => Ok(gap && catchup.is_none()),
            Admit::Duplicate => Err(Refusal::Duplicate),
            Admit::Stale => Err(Refusal::StaleEpoch),
        }
    }

    fn count(&mut self, key: &str, refusal: Option<&Refusal>) {
        match refusal {
            None => {}
            Some(Refusal::Duplicate) => self.counters.duplicates += 1,
            Some(Refusal::AwaitingIdentity { .. }) => self.counters.held_for_identity += 1,
            Some(r) => {
                debug!(key, reason = %r, "federation sample refused");
                *self.counters.refused.entry(r.reason()).or_default() += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests;
