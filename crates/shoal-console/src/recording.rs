//! `POST /api/recordings/tracks`: the vehicles' tracks in one MCAP recording (the files
//! `shoal record` writes), for the console's replay.
//!
//! - The body is the file's bytes, sent as `application/octet-stream` or
//!   `application/x-mcap` (or with no `Content-Type`; anything else is 415), at most
//!   `[console.limits] max_recording_bytes` (413, refused from `Content-Length` before the
//!   body is read when it says so).
//! - At most [`MAX_CONCURRENT_RECORDINGS`](crate::limits::MAX_CONCURRENT_RECORDINGS)
//!   recordings are read at once; another waits at
//!   most [`RECORDING_QUEUE`](crate::limits::RECORDING_QUEUE) for its turn, then gets 503.
//! - The file is read front to back by the recorder's reader ([`McapMessages`]) on a
//!   blocking thread, never on the async ones; it stops when the request ends (a client
//!   gone, `request_timeout_s`). Every message is decoded and validated as `shoal replay`
//!   does ([`decode_message`]); each valid state vector goes into its vehicle's track and
//!   the vehicle's kind comes from its recorded announcement (else from the station's
//!   fleet, else `null`).
//! - A truncated or corrupt file answers what was readable before the damage, with the
//!   reader's error naming the byte offset where reading stopped (200); a file in which
//!   no Shoal message could be read answers 400 with that error.
//! - The answer is bounded: at most [`MAX_VEHICLES`] vehicles (the state vectors of
//!   vehicles first seen after them are counted in `omitted`), at most
//!   [`MAX_ROWS_PER_VEHICLE`] rows per vehicle and [`MAX_TOTAL_ROWS`] in all. A longer
//!   track is thinned evenly (every n-th state vector of the vehicle, its last one kept)
//!   and `thinned` says so; memory stays bounded while reading too, since the
//!   thinning is done as the file is read.
//!
//! Nothing is stored: the recording is read, answered and dropped.

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use axum::Json;
use axum::body::Bytes;
use axum::extract::{FromRequest, Request, State};
use axum::http::{HeaderMap, StatusCode, header};
use serde::Serialize;
use shoal_model::{StateVector, VehicleKind};
use shoal_recorder::{McapMessages, Sample, decode_message};
use tracing::info;

use crate::{ApiError, AppState, extract};

/// Most vehicles in one answer.
pub const MAX_VEHICLES: usize = 1_000;
/// Most rows of one vehicle in one answer (as many as `GET /api/vehicles/{id}/track`
/// returns at most).
pub const MAX_ROWS_PER_VEHICLE: usize = 10_000;
/// Most rows of all vehicles together in one answer (about 25 MB of JSON): with many
/// vehicles each gets `MAX_TOTAL_ROWS / vehicles`.
pub const MAX_TOTAL_ROWS: usize = 100_000;

/// The answer: each vehicle's track and what the reader met.
#[derive(Debug, Serialize)]
pub(crate) struct Tracks {
    /// The vehicles with at least one state vector, by id.
    vehicles: Vec<VehicleTrack>,
    /// Messages of Shoal channels read (every topic).
    messages: u64,
    /// Messages not used: on channels that are not Shoal channels, or that do not
    /// decode as their topic's type or are not valid.
    skipped: u64,
    /// Valid state vectors read.
    state_vectors: u64,
    /// Whether some vehicle's track holds fewer rows than it has state vectors in the
    /// file, or vehicles were left out (`omitted`).
    thinned: bool,
    /// State vectors of vehicles left out: those first seen after [`MAX_VEHICLES`] others.
    omitted: u64,
    /// The earliest and latest `timestamp_ms` of the rows returned.
    from_ms: Option<i64>,
    to_ms: Option<i64>,
    /// Why reading stopped before the end of the file (naming the byte offset), if it did.
    error: Option<String>,
}

/// One vehicle's track.
#[derive(Debug, Serialize)]
struct VehicleTrack {
    vehicle_id: String,
    /// From its announcement in the recording, else from the station's fleet.
    kind: Option<VehicleKind>,
    /// Its valid state vectors in the file (more than `rows` when thinned).
    state_vectors: u64,
    /// Its state vectors, by time: as `GET /api/vehicles/{id}/track` returns them.
    rows: Vec<StateVector>,
}

/// The media types a recording may be sent as (and no `Content-Type` at all).
fn is_mcap(headers: &HeaderMap) -> bool {
    let Some(ct) = headers.get(header::CONTENT_TYPE) else {
        return true;
    };
    let essence = ct
        .to_str()
        .unwrap_or("")
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    matches!(
        essence.as_str(),
        "application/octet-stream" | "application/x-mcap"
    )
}

fn too_large(limit: usize) -> ApiError {
    ApiError::PayloadTooLarge(format!(
        "the recording is larger than {limit} bytes ({:.1} MiB), the most this console \
         opens ([console.limits] max_recording_bytes); replay a shorter file",
        limit as f64 / f64::from(1u32 << 20)
    ))
}

/// Sets its flag when dropped: the handler's future dropped (the client left, the
/// request timed out) stops the blocking reader.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// `POST /api/recordings/tracks` (see the module's documentation).
pub(crate) async fn tracks(
    State(app): State<AppState>,
    req: Request,
) -> Result<Json<Tracks>, ApiError> {
    let limit = app.limits.config.max_recording_bytes;
    if !is_mcap(req.headers()) {
        return Err(ApiError::UnsupportedMediaType(
            "send the recording's bytes as application/octet-stream or application/x-mcap".into(),
        ));
    }
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit as u64) {
        return Err(too_large(limit));
    }
    // The turn before the body: the bodies held at once are bounded too.
    let turn = app.limits.recording_turn().await?;
    let body = Bytes::from_request(req, &()).await.map_err(|e| {
        if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
            too_large(limit)
        } else {
            extract::bytes_rejection(&e)
        }
    })?;
    if body.is_empty() {
        return Err(ApiError::BadRequest(
            "the body is empty: send the bytes of one MCAP file (shoal record's .mcap)".into(),
        ));
    }
    let stop = Arc::new(AtomicBool::new(false));
    let _stop = StopOnDrop(stop.clone());
    let size = body.len();
    let mut tracks = tokio::task::spawn_blocking(move || {
        let _turn = turn;
        read_tracks(&body, &stop)
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?;
    if tracks.messages == 0
        && let Some(error) = &tracks.error
    {
        return Err(ApiError::BadRequest(format!(
            "no Shoal message could be read from this file: {error}"
        )));
    }
    for v in tracks.vehicles.iter_mut().filter(|v| v.kind.is_none()) {
        v.kind = app
            .station
            .vehicle(&v.vehicle_id)
            .map(|view| view.announcement.kind);
    }
    info!(
        bytes = size,
        messages = tracks.messages,
        vehicles = tracks.vehicles.len(),
        thinned = tracks.thinned,
        error = tracks.error.as_deref().unwrap_or(""),
        "a recording was opened in the replay"
    );
    Ok(Json(tracks))
}

/// Reads the tracks of the MCAP file `bytes` until its end, its damage, or `stop`.
pub(crate) fn read_tracks(bytes: &[u8], stop: &AtomicBool) -> Tracks {
    let mut reader = McapMessages::new(bytes);
    let mut collect = Collect::default();
    let mut error = None;
    for item in reader.by_ref() {
        if stop.load(Ordering::Relaxed) {
            error = Some("stopped: the request ended before the file was read".to_owned());
            break;
        }
        match item {
            Err(e) => {
                error = Some(e.to_string());
                break;
            }
            Ok(message) => match decode_message(&message) {
                Ok(Sample::StateVector(s)) => collect.add(s),
                Ok(Sample::VehicleAnnouncement(a)) => collect.announce(a.vehicle_id, a.kind),
                Ok(_) => {}
                Err(_) => collect.unusable += 1,
            },
        }
    }
    let stats = reader.stats();
    let mut tracks = collect.finish();
    tracks.messages = stats.messages;
    tracks.skipped += stats.unknown_messages;
    tracks.error = error;
    tracks
}

/// One vehicle's track while the file is read: every `stride`-th of its state vectors
/// (by their order in the file), and the latest one.
#[derive(Debug)]
struct Track {
    /// Its state vectors seen so far.
    seen: u64,
    /// Kept are those whose ordinal (0, 1, ...) is a multiple of this; doubles as the
    /// track grows.
    stride: u64,
    rows: Vec<(u64, StateVector)>,
    /// The latest state vector when it is not in `rows`.
    last: Option<StateVector>,
}

impl Track {
    fn new() -> Self {
        Self {
            seen: 0,
            stride: 1,
            rows: Vec::new(),
            last: None,
        }
    }

    fn push(&mut self, s: StateVector) {
        let n = self.seen;
        self.seen += 1;
        if n.is_multiple_of(self.stride) {
            self.rows.push((n, s));
            self.last = None;
        } else {
            self.last = Some(s);
        }
    }

    /// Keeps every other row: the stride doubles. Returns how many rows were dropped.
    fn halve(&mut self) -> usize {
        let before = self.rows.len();
        self.stride = self.stride.saturating_mul(2);
        let stride = self.stride;
        // The latest row stays, as `last`, when the new stride would drop it.
        if self.last.is_none()
            && self
                .rows
                .last()
                .is_some_and(|(n, _)| !n.is_multiple_of(stride))
        {
            self.last = self.rows.pop().map(|(_, s)| s);
        }
        self.rows.retain(|(n, _)| n.is_multiple_of(stride));
        before - self.rows.len()
    }

    /// The rows by time, at most `cap` (at least 1), evenly chosen, the first and the
    /// last kept.
    fn finish(self, cap: usize) -> Vec<StateVector> {
        let mut rows: Vec<StateVector> = self.rows.into_iter().map(|(_, s)| s).collect();
        rows.extend(self.last);
        // Recorded in arrival order; the replay looks rows up by time.
        rows.sort_by_key(|s| s.timestamp_ms);
        if rows.len() <= cap {
            return rows;
        }
        if cap <= 1 {
            return rows.pop().into_iter().collect();
        }
        let len = rows.len();
        let mut picked = Vec::with_capacity(cap);
        let mut next = 0;
        for (i, row) in rows.into_iter().enumerate() {
            // The k-th of `cap` picks is row k·(len-1)/(cap-1): 0 first, len-1 last.
            if i == next * (len - 1) / (cap - 1) {
                picked.push(row);
                next += 1;
            }
        }
        picked
    }
}

/// The tracks being collected, bounded while the file is read.
#[derive(Debug, Default)]
struct Collect {
    tracks: HashMap<String, Track>,
    kinds: HashMap<String, VehicleKind>,
    /// Rows held in all tracks.
    held: usize,
    state_vectors: u64,
    omitted: u64,
    /// Messages that do not decode or validate.
    unusable: u64,
}

impl Collect {
    /// The most rows each of `vehicles` vehicles may have in the answer.
    fn cap(vehicles: usize) -> usize {
        (MAX_TOTAL_ROWS / vehicles.max(1)).clamp(1, MAX_ROWS_PER_VEHICLE)
    }

    fn announce(&mut self, vehicle_id: String, kind: VehicleKind) {
        // Announcements of vehicles with no track are kept too (they may come first),
        // within a bound.
        if self.kinds.len() < 2 * MAX_VEHICLES || self.kinds.contains_key(&vehicle_id) {
            self.kinds.insert(vehicle_id, kind);
        }
    }

    fn add(&mut self, s: StateVector) {
        self.state_vectors += 1;
        let known = self.tracks.contains_key(&s.vehicle_id);
        if !known && self.tracks.len() >= MAX_VEHICLES {
            self.omitted += 1;
            return;
        }
        let cap = Self::cap(self.tracks.len() + usize::from(!known));
        let track = self
            .tracks
            .entry(s.vehicle_id.clone())
            .or_insert_with(Track::new);
        let before = track.rows.len();
        track.push(s);
        self.held += track.rows.len() - before;
        // Each track holds at most twice its share while reading...
        if track.rows.len() > 2 * cap {
            self.held -= track.halve();
        }
        // ...and, as vehicles appear and shares shrink, all of them together at most
        // twice the answer's rows (plus one a vehicle).
        if self.held > 2 * MAX_TOTAL_ROWS {
            for t in self.tracks.values_mut().filter(|t| t.rows.len() > cap) {
                self.held -= t.halve();
            }
        }
    }

    fn finish(self) -> Tracks {
        let cap = Self::cap(self.tracks.len());
        let mut thinned = self.omitted > 0;
        let mut vehicles: Vec<VehicleTrack> = self
            .tracks
            .into_iter()
            .map(|(vehicle_id, track)| {
                let state_vectors = track.seen;
                let rows = track.finish(cap);
                thinned |= (rows.len() as u64) < state_vectors;
                VehicleTrack {
                    kind: self.kinds.get(&vehicle_id).copied(),
                    vehicle_id,
                    state_vectors,
                    rows,
                }
            })
            .collect();
        vehicles.sort_by(|a, b| a.vehicle_id.cmp(&b.vehicle_id));
        let times = vehicles
            .iter()
            .flat_map(|v| v.rows.iter().map(|r| r.timestamp_ms));
        let from_ms = times.clone().min();
        let to_ms = times.max();
        Tracks {
            vehicles,
            messages: 0,
            skipped: self.unusable,
            state_vectors: self.state_vectors,
            thinned,
            omitted: self.omitted,
            from_ms,
            to_ms,
            error: None,
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn sv(id: &str, t: i64) -> StateVector {
        StateVector {
            vehicle_id: id.into(),
            timestamp_ms: t,
            latitude_deg: 63.44,
            longitude_deg: 10.37,
            depth_m: 4.0,
            altitude_m: -1.0,
            speed_mps: 1.0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: 90.0,
        }
    }

    fn times(v: &VehicleTrack) -> Vec<i64> {
        v.rows.iter().map(|r| r.timestamp_ms).collect()
    }

    #[test]
    fn a_short_track_is_whole_and_sorted_by_time() {
        let mut c = Collect::default();
        for t in [3, 1, 2] {
            c.add(sv("auv-1", t));
        }
        c.announce("auv-1".into(), VehicleKind::Auv);
        let out = c.finish();
        assert!(!out.thinned);
        assert_eq!(out.vehicles.len(), 1);
        assert_eq!(times(&out.vehicles[0]), [1, 2, 3]);
        assert_eq!(out.vehicles[0].kind, Some(VehicleKind::Auv));
        assert_eq!((out.from_ms, out.to_ms), (Some(1), Some(3)));
    }

    #[test]
    fn a_long_track_is_thinned_evenly_keeping_its_first_and_last_rows() {
        let mut c = Collect::default();
        let n = 3 * MAX_ROWS_PER_VEHICLE as i64 + 17;
        for t in 0..n {
            c.add(sv("auv-1", t));
        }
        // Never more than twice the share held while reading.
        assert!(c.held <= 2 * MAX_ROWS_PER_VEHICLE, "{}", c.held);
        let out = c.finish();
        assert!(out.thinned);
        let v = &out.vehicles[0];
        assert_eq!(v.state_vectors, n as u64);
        let t = times(v);
        assert_eq!(t.len(), MAX_ROWS_PER_VEHICLE);
        assert_eq!((t[0], *t.last().unwrap()), (0, n - 1));
        // Evenly: the gaps differ by at most a factor of two or so (the stride, then the
        // final pick), never a hole.
        let gaps: Vec<i64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        let (lo, hi) = (*gaps.iter().min().unwrap(), *gaps.iter().max().unwrap());
        assert!(lo >= 1 && hi <= 4 * lo + 4, "gaps {lo}..{hi}");
    }

    #[test]
    fn many_vehicles_share_the_rows_and_the_rest_are_omitted() {
        let mut c = Collect::default();
        for v in 0..MAX_VEHICLES + 5 {
            for t in 0..300 {
                c.add(sv(&format!("v{v}"), t));
            }
            assert!(c.held <= 2 * MAX_TOTAL_ROWS + MAX_VEHICLES, "{}", c.held);
        }
        let out = c.finish();
        assert_eq!(out.vehicles.len(), MAX_VEHICLES);
        assert_eq!(out.omitted, 5 * 300);
        assert!(out.thinned);
        let total: usize = out.vehicles.iter().map(|v| v.rows.len()).sum();
        assert!(total <= MAX_TOTAL_ROWS, "{total}");
        for v in &out.vehicles {
            let t = times(v);
            assert_eq!((t[0], *t.last().unwrap()), (0, 299), "{}", v.vehicle_id);
        }
    }

    #[test]
    fn media_types() {
        let mut h = HeaderMap::new();
        assert!(is_mcap(&h));
        for (ct, ok) in [
            ("application/octet-stream", true),
            ("Application/X-MCAP; x=1", true),
            ("application/json", false),
            ("text/plain", false),
        ] {
            h.insert(header::CONTENT_TYPE, ct.parse().unwrap());
            assert_eq!(is_mcap(&h), ok, "{ct}");
        }
    }

    #[test]
    fn garbage_reads_nothing_and_says_where() {
        let out = read_tracks(b"not an MCAP file at all", &AtomicBool::new(false));
        assert_eq!(out.messages, 0);
        let e = out.error.unwrap();
        assert!(e.contains("offset 0"), "{e}");
    }
}
