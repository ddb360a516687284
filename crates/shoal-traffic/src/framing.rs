//! NMEA 0183 framing: splitting byte streams into bounded lines, checking a sentence's
//! envelope (characters, tag block, checksum) and reassembling multi-sentence AIS
//! messages within limits. The fields inside are decoded by `nmea-parser` (see `decode`).

use std::collections::HashMap;
use std::time::{Duration, Instant};

/// Splits a byte stream into lines of at most `max` bytes; longer lines are skipped up to
/// their end, and reported once each.
#[derive(Debug)]
pub struct LineSplitter {
    buf: Vec<u8>,
    max: usize,
    // Inside a line already reported as too long: discard until its newline.
    skipping: bool,
}

/// One piece of a split stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Piece<'a> {
    /// A complete line, without its line ending.
    Line(&'a [u8]),
    /// A line exceeded the limit and is being dropped.
    TooLong,
}

impl LineSplitter {
    /// A splitter for lines of at most `max` bytes.
    pub fn new(max: usize) -> Self {
        Self {
            buf: Vec::with_capacity(max.min(4096)),
            max,
            skipping: false,
        }
    }

    /// Feeds `data`, calling `on` for each complete line and each over-long one.
    pub fn push(&mut self, data: &[u8], mut on: impl FnMut(Piece<'_>)) {
        for chunk in data.split_inclusive(|b| *b == b'\n') {
            let ends = chunk.last() == Some(&b'\n');
            let body = if ends {
                &chunk[..chunk.len() - 1]
            } else {
                chunk
            };
            if !self.skipping {
                if self.buf.len() + body.len() > self.max {
                    self.buf.clear();
                    self.skipping = true;
                    on(Piece::TooLong);
                } else {
                    self.buf.extend_from_slice(body);
                }
            }
            if ends {
                if !self.skipping {
                    on(Piece::Line(&self.buf));
                }
                self.buf.clear();
                self.skipping = false;
            }
        }
    }

    /// Ends the stream (a datagram's end, or a closed connection): a partial line is a line.
    pub fn finish(&mut self, mut on: impl FnMut(Piece<'_>)) {
        if !self.skipping && !self.buf.is_empty() {
            on(Piece::Line(&self.buf));
        }
        self.buf.clear();
        self.skipping = false;
    }
}

/// Why a line was not accepted as a sentence.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EnvelopeError {
    /// Not printable ASCII, no `$`/`!` start, or a broken tag block.
    Garbage,
    /// No `*hh` checksum.
    NoChecksum,
    /// The checksum does not match.
    BadChecksum,
}

/// A checked sentence: its start character and the text between it and `*`.
#[derive(Debug, PartialEq, Eq)]
pub struct Sentence<'a> {
    /// `$` (parametric) or `!` (encapsulated, AIS).
    pub start: u8,
    /// Address and fields, without the start character and checksum.
    pub body: &'a str,
}

impl Sentence<'_> {
    /// The three-letter sentence formatter (`GGA`, `VDM`), whatever the talker.
    pub fn formatter(&self) -> Option<&str> {
        let address = self.body.split(',').next()?;
        if address.len() == 5 && address.bytes().all(|b| b.is_ascii_alphanumeric()) {
            address.get(2..5)
        } else {
            None
        }
    }
}

/// Checks a line's envelope: printable ASCII, an optional IEC 61162-450 tag block, a start
/// character and a valid checksum.
pub fn envelope(line: &[u8]) -> Result<Sentence<'_>, EnvelopeError> {
    let line = line.trim_ascii();
    if !line.iter().all(|b| (0x20..0x7f).contains(b)) {
        return Err(EnvelopeError::Garbage);
    }
    let mut s = std::str::from_utf8(line).map_err(|_| EnvelopeError::Garbage)?;
    if let Some(rest) = s.strip_prefix('\\') {
        // A tag block (`\s:rx1,c:1700000000*hh\`) carries source and time, not used here.
        let end = rest.find('\\').ok_or(EnvelopeError::Garbage)?;
        s = &rest[end + 1..];
    }
    let start = match s.as_bytes().first() {
        Some(b @ (b'$' | b'!')) => *b,
        _ => return Err(EnvelopeError::Garbage),
    };
    let star = s.rfind('*').ok_or(EnvelopeError::NoChecksum)?;
    let given = &s[star + 1..];
    if given.len() != 2 {
        return Err(EnvelopeError::NoChecksum);
    }
    let given = u8::from_str_radix(given, 16).map_err(|_| EnvelopeError::NoChecksum)?;
    let body = &s[1..star];
    if checksum(body) != given {
        return Err(EnvelopeError::BadChecksum);
    }
    Ok(Sentence { start, body })
}

/// The XOR checksum of a sentence body, as NMEA writes it (for sentences we build).
pub fn checksum(body: &str) -> u8 {
    body.bytes().fold(0u8, |a, b| a ^ b)
}

/// The fields of one `!xxVDM`/`!xxVDO` sentence.
#[derive(Debug, PartialEq, Eq)]
pub struct VdmFragment<'a> {
    /// VDO: the own vessel's report.
    pub own: bool,
    /// Total fragments of the message (1..=9).
    pub count: u8,
    /// This fragment's number (1..=count).
    pub number: u8,
    /// Sequential message id (empty for single-sentence messages).
    pub seq: &'a str,
    /// Radio channel (`A`, `B`, `1`, `2` or empty).
    pub channel: &'a str,
    /// Six-bit armoured payload.
    pub payload: &'a str,
    /// Fill bits (0..=5) at the payload's end.
    pub fill: u8,
}

/// Why a VDM/VDO sentence's fields were refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VdmError {
    /// Wrong field count or a field out of its range.
    BadFields,
    /// A payload character outside AIS six-bit armouring.
    BadPayload,
}

/// Whether `c` is a six-bit armoured payload character (`0`..`W`, `` ` ``..`w`).
pub fn is_sixbit(c: u8) -> bool {
    matches!(c, b'0'..=b'W' | b'`'..=b'w')
}

/// The six-bit value of an armoured payload character (`is_sixbit` must hold).
pub fn sixbit_value(c: u8) -> u8 {
    let v = c.wrapping_sub(48);
    if v > 40 { v - 8 } else { v }
}

/// Splits a VDM/VDO sentence body into its fields.
pub fn vdm_fields(body: &str, own: bool) -> Result<VdmFragment<'_>, VdmError> {
    let f: Vec<&str> = body.split(',').collect();
    let [_, count, number, seq, channel, payload, fill] = f.as_slice() else {
        return Err(VdmError::BadFields);
    };
    let count: u8 = count.parse().map_err(|_| VdmError::BadFields)?;
    let number: u8 = number.parse().map_err(|_| VdmError::BadFields)?;
    let fill: u8 = fill.parse().map_err(|_| VdmError::BadFields)?;
    if !(1..=9).contains(&count) || !(1..=count).contains(&number) || fill > 5 {
        return Err(VdmError::BadFields);
    }
    if seq.len() > 1 || channel.len() > 1 {
        return Err(VdmError::BadFields);
    }
    if payload.is_empty() || !payload.bytes().all(is_sixbit) {
        return Err(VdmError::BadPayload);
    }
    Ok(VdmFragment {
        own,
        count,
        number,
        seq,
        channel,
        payload,
        fill,
    })
}

/// A reassembled AIS message: the whole payload and its fill bits.
#[derive(Debug, PartialEq, Eq)]
pub struct AisPayload {
    /// VDO: the own vessel's report.
    pub own: bool,
    /// The six-bit armoured payload.
    pub payload: String,
    /// Fill bits of the last fragment.
    pub fill: u8,
}

/// What happened to a fragment given to the reassembler.
#[derive(Debug, PartialEq, Eq)]
pub enum Assembly {
    /// The message is complete.
    Complete(AisPayload),
    /// Waiting for more fragments.
    Pending,
    /// A fragment that continues no message in progress (out of order, or its first
    /// fragment was lost); it is dropped, and so is the message it broke.
    OutOfOrder,
}

#[derive(Debug)]
struct Partial {
    count: u8,
    next: u8,
    payload: String,
    started: Instant,
}

/// Counts of fragments lost by the reassembler's limits.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Dropped {
    /// Messages whose next fragment never came (time-out, or replaced by a new first one).
    pub missing: u64,
    /// Messages dropped because too many were pending.
    pub over_limit: u64,
}

/// Reassembles multi-sentence AIS messages, holding at most `max` partial ones for at most
/// `timeout` each: a sender cannot make it hold more.
#[derive(Debug)]
pub struct Reassembler {
    // Keyed by (VDO, sequential id, channel): how receivers tell concurrent messages apart.
    pending: HashMap<(bool, String, String), Partial>,
    max: usize,
    timeout: Duration,
    /// Losses so far.
    pub dropped: Dropped,
}

impl Reassembler {
    /// A reassembler within these limits.
    pub fn new(max: usize, timeout: Duration) -> Self {
        Self {
            pending: HashMap::new(),
            max,
            timeout,
            dropped: Dropped::default(),
        }
    }

    /// Messages awaiting fragments.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// Takes one fragment.
    pub fn push(&mut self, f: &VdmFragment<'_>, now: Instant) -> Assembly {
        if f.count == 1 {
            return Assembly::Complete(AisPayload {
                own: f.own,
                payload: f.payload.to_string(),
                fill: f.fill,
            });
        }
        let key = (f.own, f.seq.to_string(), f.channel.to_string());
        if f.number == 1 {
            if self.pending.remove(&key).is_some() {
                self.dropped.missing += 1;
            }
            self.expire(now);
            if self.pending.len() >= self.max {
                let oldest = self
                    .pending
                    .iter()
                    .min_by_key(|(_, p)| p.started)
                    .map(|(k, _)| k.clone());
                if let Some(k) = oldest {
                    self.pending.remove(&k);
                    self.dropped.over_limit += 1;
                }
            }
            self.pending.insert(
                key,
                Partial {
                    count: f.count,
                    next: 2,
                    payload: f.payload.to_string(),
                    started: now,
                },
            );
            return Assembly::Pending;
        }
        let Some(p) = self.pending.get_mut(&key) else {
            return Assembly::OutOfOrder;
        };
        if p.count != f.count
            || p.next != f.number
            || now.saturating_duration_since(p.started) > self.timeout
        {
            self.pending.remove(&key);
            return Assembly::OutOfOrder;
        }
        p.payload.push_str(f.payload);
        p.next += 1;
        if f.number < f.count {
            return Assembly::Pending;
        }
        match self.pending.remove(&key) {
            Some(p) => Assembly::Complete(AisPayload {
                own: f.own,
                payload: p.payload,
                fill: f.fill,
            }),
            None => Assembly::OutOfOrder,
        }
    }

    /// Drops the partial messages older than the time-out.
    pub fn expire(&mut self, now: Instant) {
        let timeout = self.timeout;
        let before = self.pending.len();
        self.pending
            .retain(|_, p| now.saturating_duration_since(p.started) <= timeout);
        self.dropped.missing += (before - self.pending.len()) as u64;
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn lines(s: &mut LineSplitter, data: &[u8]) -> Vec<String> {
        let mut out = Vec::new();
        s.push(data, |p| {
            out.push(match p {
                Piece::Line(l) => String::from_utf8_lossy(l).into_owned(),
                Piece::TooLong => "<long>".into(),
            });
        });
        out
    }

    #[test]
    fn splitter_joins_chunks_and_drops_long_lines_whole() {
        let mut s = LineSplitter::new(10);
        assert_eq!(lines(&mut s, b"abc"), Vec::<String>::new());
        assert_eq!(lines(&mut s, b"def\r\nxy\n"), vec!["abcdef\r", "xy"]);
        // 12 bytes in two chunks, then a good line: the long one is reported once.
        assert_eq!(lines(&mut s, b"0123456"), Vec::<String>::new());
        assert_eq!(lines(&mut s, b"789ab"), vec!["<long>"]);
        assert_eq!(lines(&mut s, b"cdef\nok\n"), vec!["ok"]);
        let mut last = Vec::new();
        s.push(b"tail", |_| {});
        s.finish(|p| last.push(format!("{p:?}")));
        assert_eq!(last, vec![format!("{:?}", Piece::Line(b"tail"))]);
    }

    #[test]
    fn envelope_checks_checksum_start_and_characters() {
        let good = "$GPHDT,123.4,T*31";
        let s = envelope(good.as_bytes()).unwrap();
        assert_eq!(s.start, b'$');
        assert_eq!(s.formatter(), Some("HDT"));
        assert_eq!(
            envelope(b"$GPHDT,123.4,T*32"),
            Err(EnvelopeError::BadChecksum)
        );
        assert_eq!(envelope(b"$GPHDT,123.4,T"), Err(EnvelopeError::NoChecksum));
        assert_eq!(
            envelope(b"$GPHDT,123.4,T*3"),
            Err(EnvelopeError::NoChecksum)
        );
        assert_eq!(envelope(b"GPHDT,123.4,T*31"), Err(EnvelopeError::Garbage));
        assert_eq!(envelope(b"$GPHDT,\xff*31"), Err(EnvelopeError::Garbage));
        assert_eq!(envelope(b"\\s:x*00"), Err(EnvelopeError::Garbage));
        let tagged = format!("\\s:rx1*00\\{good}\r\n");
        assert_eq!(envelope(tagged.as_bytes()).unwrap().body, "GPHDT,123.4,T");
    }

    #[test]
    fn vdm_fields_are_range_checked() {
        let f = vdm_fields(
            "AIVDM,2,1,3,B,55P5TL01VIaAL@7WKO@mBplU@<PDhh000000001S;AJ::4A80?4i@E53,0",
            false,
        )
        .unwrap();
        assert_eq!(
            (f.count, f.number, f.seq, f.channel, f.fill),
            (2, 1, "3", "B", 0)
        );
        assert_eq!(
            vdm_fields("AIVDM,1,2,,A,15M67FC000G?ufbE`FepT@3n00Sa,0", false),
            Err(VdmError::BadFields)
        );
        assert_eq!(
            vdm_fields("AIVDM,1,1,,A,15M67 C000,0", false),
            Err(VdmError::BadPayload)
        );
        assert_eq!(
            vdm_fields("AIVDM,1,1,,A,15M67FC000,6", false),
            Err(VdmError::BadFields)
        );
        assert_eq!(vdm_fields("AIVDM,1,1,,A", false), Err(VdmError::BadFields));
    }

    fn frag<'a>(count: u8, number: u8, seq: &'a str, payload: &'a str) -> VdmFragment<'a> {
        VdmFragment {
            own: false,
            count,
            number,
            seq,
            channel: "A",
            payload,
            fill: 0,
        }
    }

    #[test]
    fn reassembler_orders_limits_and_times_out() {
        let t0 = Instant::now();
        let mut r = Reassembler::new(2, Duration::from_secs(5));
        assert_eq!(r.push(&frag(2, 1, "1", "AB"), t0), Assembly::Pending);
        let done = r.push(&frag(2, 2, "1", "CD"), t0);
        assert!(matches!(done, Assembly::Complete(ref p) if p.payload == "ABCD"));
        // Second fragment with no first: out of order.
        assert_eq!(r.push(&frag(2, 2, "2", "CD"), t0), Assembly::OutOfOrder);
        // Fragment 3 right after 1: out of order, and the message is gone.
        assert_eq!(r.push(&frag(3, 1, "3", "A"), t0), Assembly::Pending);
        assert_eq!(r.push(&frag(3, 3, "3", "C"), t0), Assembly::OutOfOrder);
        assert_eq!(r.pending(), 0);
        // A new first fragment replaces an unfinished one: counted missing.
        r.push(&frag(2, 1, "4", "A"), t0);
        r.push(&frag(2, 1, "4", "A"), t0);
        assert_eq!(r.dropped.missing, 1);
        // Limit: a third pending message evicts the oldest.
        r.push(&frag(2, 1, "5", "A"), t0 + Duration::from_millis(1));
        r.push(&frag(2, 1, "6", "A"), t0 + Duration::from_millis(2));
        assert_eq!(r.pending(), 2);
        assert_eq!(r.dropped.over_limit, 1);
        // Time-out.
        r.expire(t0 + Duration::from_secs(6));
        assert_eq!(r.pending(), 0);
        assert_eq!(r.dropped.missing, 3);
        // A late second fragment after the time-out does not complete.
        r.push(&frag(2, 1, "7", "A"), t0);
        assert_eq!(
            r.push(&frag(2, 2, "7", "B"), t0 + Duration::from_secs(9)),
            Assembly::OutOfOrder
        );
    }
}
