//! The EvoLogics S2C AT interface over TCP (docs/acoustic.md#at-interface): parsers and
//! formatters.
//!
//! Host → modem: in-band commands `+++<AT command>\n`. `AT*SENDIM,<len>,<dst>,ack|noack,<data>`
//! and `AT*SEND,<len>,<dst>,<data>` carry `len` raw bytes, so they are parsed by length,
//! never by delimiters. Modem → host: replies `+++<cmd>:<len>:<reply>\r\n` and
//! notifications `+++AT:<len>:<body>\r\n`, also length-framed and binary-safe.
//!
//! [`CommandParser`] (used by the emulator) and [`FrameParser`] (used by the driver) are
//! incremental: feed bytes as they arrive, pull complete items. Both recover from garbage
//! by skipping to the next line or `+++`, and never panic on any input.

use std::fmt;

/// Most bytes of an instant message (docs/acoustic.md#frame-sizes-and-bit-rates).
pub const MAX_IM: usize = 64;
/// Most bytes of a burst in one `AT*SEND` (the emulator's buffer size).
pub const MAX_BURST: usize = 1024;
/// Longest command line the modem accepts (docs/acoustic.md#at-interface), excluding
/// binary payloads.
pub const MAX_COMMAND: usize = 1054;
/// Broadcast address.
pub const BROADCAST: u8 = 255;

/// The modem's documented error replies (docs/acoustic.md#at-interface).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ModemError {
    /// `ERROR WRONG FORMAT`: malformed command or garbage.
    WrongFormat,
    /// `ERROR WRONG DESTINATION ADDRESS`: no such node, or ack to broadcast.
    WrongDestinationAddress,
    /// `ERROR BUFFER FULL`: burst data beyond the buffer.
    BufferFull,
    /// `ERROR OUT OF RANGE`: a value (e.g. an IM over 64 bytes) beyond its limit.
    OutOfRange,
    /// `ERROR UNKNOWN COMMAND`.
    UnknownCommand,
}

impl ModemError {
    /// The exact reply text.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::WrongFormat => "ERROR WRONG FORMAT",
            Self::WrongDestinationAddress => "ERROR WRONG DESTINATION ADDRESS",
            Self::BufferFull => "ERROR BUFFER FULL",
            Self::OutOfRange => "ERROR OUT OF RANGE",
            Self::UnknownCommand => "ERROR UNKNOWN COMMAND",
        }
    }
}

impl fmt::Display for ModemError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A parsed host → modem command.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum AtCommand {
    /// `AT*SENDIM`: instant message, at most 64 bytes.
    SendIm {
        /// Destination address (255 = broadcast).
        dst: u8,
        /// Whether the receiver must acknowledge.
        ack: bool,
        /// Payload.
        data: Vec<u8>,
    },
    /// `AT*SEND`: burst data at the link's bit rate.
    SendBurst {
        /// Destination address.
        dst: u8,
        /// Payload.
        data: Vec<u8>,
    },
    /// `AT!AL<n>`: set the local address.
    SetLocalAddress(u8),
    /// `AT?AL`: get the local address.
    GetLocalAddress,
    /// `AT!AR<n>`: set the remote address.
    SetRemoteAddress(u8),
    /// `AT?AR`: get the remote address.
    GetRemoteAddress,
    /// `AT?S`: link status and free buffer.
    GetStatus,
    /// `AT!RI<n>`: instant message retry count.
    SetImRetry(u8),
    /// `AT?RI`: get the retry count.
    GetImRetry,
    /// `AT!L<n>`: source level, 0 (max) … 3 (−18 dB).
    SetSourceLevel(u8),
    /// `AT?L`: get the source level.
    GetSourceLevel,
    /// `AT?E`: RSSI of the last reception.
    GetRssi,
    /// `AT?I`: integrity of the last reception.
    GetIntegrity,
    /// `AT?T`: propagation time to the last peer, µs.
    GetPropagationTime,
    /// `ATZ<n>`: reset / drop data (0..=4).
    Reset(u8),
}

impl AtCommand {
    /// The command name as it appears in the reply frame (`AT*SENDIM`, `AT?AL`, ...).
    pub fn name(&self) -> &'static str {
        match self {
            Self::SendIm { .. } => "AT*SENDIM",
            Self::SendBurst { .. } => "AT*SEND",
            Self::SetLocalAddress(_) => "AT!AL",
            Self::GetLocalAddress => "AT?AL",
            Self::SetRemoteAddress(_) => "AT!AR",
            Self::GetRemoteAddress => "AT?AR",
            Self::GetStatus => "AT?S",
            Self::SetImRetry(_) => "AT!RI",
            Self::GetImRetry => "AT?RI",
            Self::SetSourceLevel(_) => "AT!L",
            Self::GetSourceLevel => "AT?L",
            Self::GetRssi => "AT?E",
            Self::GetIntegrity => "AT?I",
            Self::GetPropagationTime => "AT?T",
            Self::Reset(_) => "ATZ",
        }
    }

    /// The in-band wire form, `+++<command>\n` (Ethernet line ending,
    /// docs/acoustic.md#at-interface).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = b"+++".to_vec();
        match self {
            Self::SendIm { dst, ack, data } => {
                let flag = if *ack { "ack" } else { "noack" };
                out.extend(format!("AT*SENDIM,{},{dst},{flag},", data.len()).bytes());
                out.extend(data);
            }
            Self::SendBurst { dst, data } => {
                out.extend(format!("AT*SEND,{},{dst},", data.len()).bytes());
                out.extend(data);
            }
            Self::SetLocalAddress(n)
            | Self::SetRemoteAddress(n)
            | Self::SetImRetry(n)
            | Self::SetSourceLevel(n)
            | Self::Reset(n) => out.extend(format!("{}{n}", self.name()).bytes()),
            _ => out.extend(self.name().bytes()),
        }
        out.push(b'\n');
        out
    }
}

/// A command the modem refused while parsing, with the name to reply under.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rejected {
    /// Command name for the reply frame (`AT` when it could not be told).
    pub cmd: String,
    /// The error to reply with.
    pub error: ModemError,
}

/// Formats a reply frame `+++<cmd>:<len>:<body>\r\n`.
pub fn reply(cmd: &str, body: &[u8]) -> Vec<u8> {
    let mut out = format!("+++{cmd}:{}:", body.len()).into_bytes();
    out.extend(body);
    out.extend(b"\r\n");
    out
}

/// Formats a notification frame `+++AT:<len>:<body>\r\n`.
pub fn notification(body: &[u8]) -> Vec<u8> {
    reply("AT", body)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn parse_u8(s: &[u8]) -> Option<u8> {
    if s.is_empty() || s.len() > 3 || !s.iter().all(u8::is_ascii_digit) {
        return None;
    }
    std::str::from_utf8(s).ok()?.parse().ok()
}

fn parse_usize(s: &[u8]) -> Option<usize> {
    if s.is_empty() || s.len() > 6 || !s.iter().all(u8::is_ascii_digit) {
        return None;
    }
    std::str::from_utf8(s).ok()?.parse().ok()
}

/// Incremental parser of host → modem input (the emulator's side).
#[derive(Debug, Default)]
pub struct CommandParser {
    buf: Vec<u8>,
}

impl CommandParser {
    /// An empty parser.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Consumes `n` bytes from the front of the buffer.
    fn consume(&mut self, n: usize) {
        self.buf.drain(..n.min(self.buf.len()));
    }

    /// Consumes through the next `\n` (or everything) and rejects with `error`.
    fn skip_line(&mut self, cmd: &str, error: ModemError) -> Option<Result<AtCommand, Rejected>> {
        let n = self
            .buf
            .iter()
            .position(|&b| b == b'\n')
            .map_or(self.buf.len(), |i| i + 1);
        self.consume(n);
        Some(Err(Rejected {
            cmd: cmd.to_owned(),
            error,
        }))
    }

    /// The next complete command, a rejection, or `None` if more bytes are needed.
    fn next_item(&mut self) -> Option<Result<AtCommand, Rejected>> {
        // Bare line endings between commands are harmless.
        while matches!(self.buf.first(), Some(b'\n' | b'\r')) {
            self.consume(1);
        }
        if self.buf.is_empty() {
            return None;
        }
        if !self.buf.starts_with(b"+++") {
            // Not a command: in data mode a real modem would transmit it; over TCP Shoal
            // only speaks in-band commands, so it is garbage up to the next line or `+++`.
            let nl = self.buf.iter().position(|&b| b == b'\n').map(|i| i + 1);
            let cmd = find(&self.buf, b"+++");
            let cut = match (nl, cmd) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
            return match cut {
                Some(n) => {
                    self.consume(n);
                    Some(Err(Rejected {
                        cmd: "AT".into(),
                        error: ModemError::WrongFormat,
                    }))
                }
                None if self.buf.len() > MAX_COMMAND => {
                    let n = self.buf.len();
                    self.consume(n);
                    Some(Err(Rejected {
                        cmd: "AT".into(),
                        error: ModemError::WrongFormat,
                    }))
                }
                // Could still be the start of `+++` split across reads.
                None if self.buf.iter().all(|&b| b == b'+') => None,
                None => None,
            };
        }
        let body = self.buf.get(3..).unwrap_or_default();
        if body.starts_with(b"AT*SENDIM,") {
            self.data_command("AT*SENDIM", 10, 3)
        } else if body.starts_with(b"AT*SEND,") {
            self.data_command("AT*SEND", 8, 2)
        } else {
            let Some(nl) = self.buf.iter().position(|&b| b == b'\n') else {
                if self.buf.len() > MAX_COMMAND {
                    return self.skip_line("AT", ModemError::WrongFormat);
                }
                return None;
            };
            let line = self.buf.get(3..nl).unwrap_or_default();
            let line = line.strip_suffix(b"\r").unwrap_or(line).to_vec();
            self.consume(nl + 1);
            Some(parse_simple(&line))
        }
    }

    /// Parses `AT*SENDIM,<len>,<dst>,<flag>,<data>\n` (3 header fields) or
    /// `AT*SEND,<len>,<dst>,<data>\n` (2), reading `len` bytes of data.
    fn data_command(
        &mut self,
        cmd: &str,
        prefix: usize,
        fields: usize,
    ) -> Option<Result<AtCommand, Rejected>> {
        let start = 3 + prefix;
        let mut parts: Vec<Vec<u8>> = Vec::with_capacity(fields);
        let mut pos = start;
        for _ in 0..fields {
            let rest = self.buf.get(pos..).unwrap_or_default();
            match rest.iter().position(|&b| b == b',' || b == b'\n') {
                Some(i) if rest.get(i) == Some(&b',') && i <= 8 => {
                    parts.push(rest.get(..i).unwrap_or_default().to_vec());
                    pos += i + 1;
                }
                Some(_) => return self.skip_line(cmd, ModemError::WrongFormat),
                None if rest.len() > 8 => return self.skip_line(cmd, ModemError::WrongFormat),
                None => return None,
            }
        }
        let (Some(len), Some(dst)) = (
            parts.first().and_then(|s| parse_usize(s)),
            parts.get(1).cloned(),
        ) else {
            return self.skip_line(cmd, ModemError::WrongFormat);
        };
        let ack = match parts.get(2).map(Vec::as_slice) {
            None | Some(b"ack") => true,
            Some(b"noack") => false,
            Some(_) => return self.skip_line(cmd, ModemError::WrongFormat),
        };
        if len > MAX_COMMAND {
            // Too large to wait for: treat as a malformed line rather than buffer it.
            return self.skip_line(cmd, ModemError::WrongFormat);
        }
        let end = pos + len;
        let after = self.buf.get(end).copied()?;
        let crlf = after == b'\r';
        let term_len = if crlf {
            match self.buf.get(end + 1) {
                None => return None,
                Some(b'\n') => 2,
                Some(_) => 0,
            }
        } else if after == b'\n' {
            1
        } else {
            0
        };
        if term_len == 0 {
            // The data was not `len` bytes long: the line most likely ended at the first
            // newline after the header, so resynchronise there.
            let n = self
                .buf
                .get(pos..)
                .and_then(|r| r.iter().position(|&b| b == b'\n'))
                .map_or(self.buf.len(), |i| pos + i + 1);
            self.consume(n);
            return Some(Err(Rejected {
                cmd: cmd.to_owned(),
                error: ModemError::WrongFormat,
            }));
        }
        let data = self.buf.get(pos..end).unwrap_or_default().to_vec();
        self.consume(end + term_len);
        let Some(dst) = parse_u8(&dst) else {
            let error = if parse_usize(&dst).is_some() {
                ModemError::WrongDestinationAddress
            } else {
                ModemError::WrongFormat
            };
            return Some(Err(Rejected {
                cmd: cmd.to_owned(),
                error,
            }));
        };
        let reject = |error| {
            Some(Err(Rejected {
                cmd: cmd.to_owned(),
                error,
            }))
        };
        if fields == 3 {
            if data.len() > MAX_IM {
                return reject(ModemError::OutOfRange);
            }
            if dst == BROADCAST && ack {
                return reject(ModemError::WrongDestinationAddress);
            }
            Some(Ok(AtCommand::SendIm { dst, ack, data }))
        } else {
            if data.len() > MAX_BURST {
                return reject(ModemError::BufferFull);
            }
            Some(Ok(AtCommand::SendBurst { dst, data }))
        }
    }
}

impl Iterator for CommandParser {
    type Item = Result<AtCommand, Rejected>;

    /// The next complete command, a rejection, or `None` until more bytes are pushed.
    fn next(&mut self) -> Option<Self::Item> {
        self.next_item()
    }
}

/// Parses a command without binary data (the text after `+++`, line ending removed).
fn parse_simple(line: &[u8]) -> Result<AtCommand, Rejected> {
    let text = String::from_utf8_lossy(line);
    let name_of = |t: &str| -> String {
        t.chars()
            .take_while(|c| !c.is_ascii_digit() && *c != ',')
            .take(16)
            .collect()
    };
    let rej = |error| {
        Err(Rejected {
            cmd: name_of(&text),
            error,
        })
    };
    let num = |rest: &str| -> Option<u8> { parse_u8(rest.as_bytes()) };
    let with_num = |rest: &str, f: fn(u8) -> AtCommand| match num(rest) {
        Some(n) => Ok(f(n)),
        None => rej(ModemError::WrongFormat),
    };
    let t: &str = &text;
    if !t.starts_with("AT") {
        return rej(ModemError::WrongFormat);
    }
    match t {
        "AT?AL" => return Ok(AtCommand::GetLocalAddress),
        "AT?AR" => return Ok(AtCommand::GetRemoteAddress),
        "AT?S" => return Ok(AtCommand::GetStatus),
        "AT?RI" => return Ok(AtCommand::GetImRetry),
        "AT?L" => return Ok(AtCommand::GetSourceLevel),
        "AT?E" => return Ok(AtCommand::GetRssi),
        "AT?I" => return Ok(AtCommand::GetIntegrity),
        "AT?T" => return Ok(AtCommand::GetPropagationTime),
        "ATZ" => return Ok(AtCommand::Reset(0)),
        _ => {}
    }
    if let Some(rest) = t.strip_prefix("AT!AL") {
        return with_num(rest, AtCommand::SetLocalAddress);
    }
    if let Some(rest) = t.strip_prefix("AT!AR") {
        return with_num(rest, AtCommand::SetRemoteAddress);
    }
    if let Some(rest) = t.strip_prefix("AT!RI") {
        return with_num(rest, AtCommand::SetImRetry);
    }
    if let Some(rest) = t.strip_prefix("AT!L") {
        return match num(rest) {
            Some(n) if n <= 3 => Ok(AtCommand::SetSourceLevel(n)),
            Some(_) => rej(ModemError::OutOfRange),
            None => rej(ModemError::WrongFormat),
        };
    }
    if let Some(rest) = t.strip_prefix("ATZ") {
        return match num(rest) {
            Some(n) if n <= 4 => Ok(AtCommand::Reset(n)),
            Some(_) => rej(ModemError::OutOfRange),
            None => rej(ModemError::WrongFormat),
        };
    }
    if t.starts_with("AT*SENDIM") || t.starts_with("AT*SEND") {
        return rej(ModemError::WrongFormat);
    }
    rej(ModemError::UnknownCommand)
}

/// One modem → host frame: a reply (`cmd` is the command) or a notification (`cmd` = `AT`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AtFrame {
    /// Command name, or `AT` for notifications.
    pub cmd: String,
    /// The reply or notification body (may be binary).
    pub body: Vec<u8>,
}

impl AtFrame {
    /// The body as text, lossy (for logs and for matching reply strings).
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

/// Incremental parser of modem → host frames (the driver's side).
#[derive(Debug, Default)]
pub struct FrameParser {
    buf: Vec<u8>,
    garbage: usize,
}

impl FrameParser {
    /// An empty parser.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes skipped as garbage so far.
    pub fn garbage(&self) -> usize {
        self.garbage
    }

    fn drop_front(&mut self, n: usize) {
        let n = n.min(self.buf.len());
        self.garbage += n;
        self.buf.drain(..n);
    }

    /// The next complete frame, or `None` if more bytes are needed. Garbage is skipped.
    fn next_item(&mut self) -> Option<AtFrame> {
        loop {
            match find(&self.buf, b"+++") {
                Some(0) => {}
                Some(i) => self.drop_front(i),
                None => {
                    // Keep a possible partial `++` at the end.
                    let keep = self
                        .buf
                        .iter()
                        .rev()
                        .take(2)
                        .take_while(|&&b| b == b'+')
                        .count();
                    self.drop_front(self.buf.len() - keep);
                    return None;
                }
            }
            let rest = self.buf.get(3..).unwrap_or_default();
            let Some(c1) = rest.iter().position(|&b| b == b':') else {
                if rest.len() > 32 || rest.contains(&b'\n') {
                    self.drop_front(3);
                    continue;
                }
                return None;
            };
            let cmd = rest.get(..c1).unwrap_or_default();
            if c1 > 32 || !cmd.iter().all(|b| b.is_ascii_graphic()) {
                self.drop_front(3);
                continue;
            }
            let after = rest.get(c1 + 1..).unwrap_or_default();
            let Some(c2) = after.iter().position(|&b| b == b':') else {
                if after.len() > 6 || !after.iter().all(u8::is_ascii_digit) {
                    self.drop_front(3);
                    continue;
                }
                return None;
            };
            let Some(len) = parse_usize(after.get(..c2).unwrap_or_default()) else {
                self.drop_front(3);
                continue;
            };
            let body_start = 3 + c1 + 1 + c2 + 1;
            let total = body_start + len + 2;
            if self.buf.len() < total {
                return None;
            }
            let frame = AtFrame {
                cmd: String::from_utf8_lossy(cmd).into_owned(),
                body: self
                    .buf
                    .get(body_start..body_start + len)
                    .unwrap_or_default()
                    .to_vec(),
            };
            if self.buf.get(body_start + len..total) != Some(b"\r\n") {
                // Length did not match the terminator: resynchronise on the next `+++`.
                self.drop_front(3);
                continue;
            }
            self.buf.drain(..total);
            return Some(frame);
        }
    }
}

impl Iterator for FrameParser {
    type Item = AtFrame;

    /// The next complete frame, or `None` until more bytes are pushed.
    fn next(&mut self) -> Option<Self::Item> {
        self.next_item()
    }
}

/// A parsed notification body (`+++AT:<len>:<body>`).
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Notification {
    /// `RECVIM,...`: an instant message arrived.
    RecvIm(Received),
    /// `RECV,...`: burst data arrived.
    Recv(Received),
    /// `DELIVEREDIM,<dst>`.
    DeliveredIm(u8),
    /// `FAILEDIM,<dst>`: no ack came (the message may still have arrived).
    FailedIm(u8),
    /// `CANCELEDIM,<dst>`.
    CanceledIm(u8),
    /// `DELIVERED,<cnt>,<dst>`: burst delivered.
    Delivered {
        /// Bytes delivered.
        count: usize,
        /// Destination.
        dst: u8,
    },
    /// `FAILED,<cnt>,<dst>`: burst failed.
    Failed {
        /// Bytes not delivered.
        count: usize,
        /// Destination.
        dst: u8,
    },
    /// Anything else (`SENDSTART`, `RECVFAILED`, ...), as text.
    Other(String),
}

/// Metadata and payload of a received message.
#[derive(Debug, Clone, PartialEq)]
pub struct Received {
    /// Sender address.
    pub src: u8,
    /// Destination address (255 = broadcast).
    pub dst: u8,
    /// Whether the sender asked for an ack (instant messages).
    pub ack: bool,
    /// Reception duration, µs (instant messages); bit rate, bit/s (bursts).
    pub duration_us: u64,
    /// Received signal strength, dB.
    pub rssi: i32,
    /// Signal integrity, 0..=255 (over 100 is a clean reception).
    pub integrity: u32,
    /// Relative velocity, m/s.
    pub velocity_mps: f64,
    /// Propagation time, µs (bursts only; 0 for instant messages).
    pub propagation_us: u64,
    /// Payload.
    pub data: Vec<u8>,
}

impl Notification {
    /// Parses a notification body; `None` for malformed known notifications.
    pub fn parse(body: &[u8]) -> Option<Self> {
        let head_end = body.iter().position(|&b| b == b',').unwrap_or(body.len());
        let head = body.get(..head_end).unwrap_or_default();
        let rest = body.get(head_end + 1..).unwrap_or_default();
        let fields = |n: usize| -> Option<Vec<String>> {
            let s = std::str::from_utf8(rest).ok()?;
            let v: Vec<String> = s.split(',').map(str::to_owned).collect();
            (v.len() == n).then_some(v)
        };
        let addr = |s: &str| parse_u8(s.as_bytes());
        match head {
            b"RECVIM" | b"RECV" => {
                // len,src,dst,X,Y,rssi,integrity,Z,velocity... then `len` raw bytes.
                let n_meta = 8;
                let mut pos = 0;
                let mut meta = Vec::with_capacity(n_meta);
                for _ in 0..n_meta {
                    let r = rest.get(pos..)?;
                    let i = r.iter().position(|&b| b == b',')?;
                    meta.push(String::from_utf8_lossy(r.get(..i)?).into_owned());
                    pos += i + 1;
                }
                let len = parse_usize(meta.first()?.as_bytes())?;
                let data = rest.get(pos..)?;
                if data.len() != len {
                    return None;
                }
                let num = |i: usize| -> Option<u64> { meta.get(i)?.parse().ok() };
                let int = |i: usize| -> Option<i32> { meta.get(i)?.parse().ok() };
                let float = |i: usize| -> Option<f64> { meta.get(i)?.parse().ok() };
                if head == b"RECVIM" {
                    // RECVIM,len,src,dst,ack|noack,duration,rssi,integrity,velocity,data
                    Some(Self::RecvIm(Received {
                        src: addr(meta.get(1)?)?,
                        dst: addr(meta.get(2)?)?,
                        ack: meta.get(3)? == "ack",
                        duration_us: num(4)?,
                        rssi: int(5)?,
                        integrity: u32::try_from(num(6)?).ok()?,
                        velocity_mps: float(7)?,
                        propagation_us: 0,
                        data: data.to_vec(),
                    }))
                } else {
                    // RECV,len,src,dst,bitrate,rssi,integrity,ptime,velocity,data
                    Some(Self::Recv(Received {
                        src: addr(meta.get(1)?)?,
                        dst: addr(meta.get(2)?)?,
                        ack: true,
                        duration_us: num(3)?,
                        rssi: int(4)?,
                        integrity: u32::try_from(num(5)?).ok()?,
                        propagation_us: num(6)?,
                        velocity_mps: float(7)?,
                        data: data.to_vec(),
                    }))
                }
            }
            b"DELIVEREDIM" => Some(Self::DeliveredIm(addr(&fields(1)?[0])?)),
            b"FAILEDIM" => Some(Self::FailedIm(addr(&fields(1)?[0])?)),
            b"CANCELEDIM" => Some(Self::CanceledIm(addr(&fields(1)?[0])?)),
            b"DELIVERED" | b"FAILED" => {
                let f = fields(2)?;
                let count = parse_usize(f.first()?.as_bytes())?;
                let dst = addr(f.get(1)?)?;
                Some(if head == b"DELIVERED" {
                    Self::Delivered { count, dst }
                } else {
                    Self::Failed { count, dst }
                })
            }
            _ => Some(Self::Other(String::from_utf8_lossy(body).into_owned())),
        }
    }

    /// The notification body as the modem sends it.
    pub fn to_body(&self) -> Vec<u8> {
        match self {
            Self::RecvIm(r) => {
                let flag = if r.ack { "ack" } else { "noack" };
                let mut b = format!(
                    "RECVIM,{},{},{},{flag},{},{},{},{:.4},",
                    r.data.len(),
                    r.src,
                    r.dst,
                    r.duration_us,
                    r.rssi,
                    r.integrity,
                    r.velocity_mps
                )
                .into_bytes();
                b.extend(&r.data);
                b
            }
            Self::Recv(r) => {
                let mut b = format!(
                    "RECV,{},{},{},{},{},{},{},{:.4},",
                    r.data.len(),
                    r.src,
                    r.dst,
                    r.duration_us,
                    r.rssi,
                    r.integrity,
                    r.propagation_us,
                    r.velocity_mps
                )
                .into_bytes();
                b.extend(&r.data);
                b
            }
            Self::DeliveredIm(a) => format!("DELIVEREDIM,{a}").into_bytes(),
            Self::FailedIm(a) => format!("FAILEDIM,{a}").into_bytes(),
            Self::CanceledIm(a) => format!("CANCELEDIM,{a}").into_bytes(),
            Self::Delivered { count, dst } => format!("DELIVERED,{count},{dst}").into_bytes(),
            Self::Failed { count, dst } => format!("FAILED,{count},{dst}").into_bytes(),
            Self::Other(s) => s.clone().into_bytes(),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    fn all(p: &mut CommandParser) -> Vec<Result<AtCommand, Rejected>> {
        std::iter::from_fn(|| p.next()).collect()
    }

    #[test]
    fn sendim_with_binary_data_containing_newlines_is_parsed_by_length() {
        let cmd = AtCommand::SendIm {
            dst: 2,
            ack: true,
            data: b"a\nb+++\r\n".to_vec(),
        };
        let mut p = CommandParser::new();
        let bytes = cmd.to_bytes();
        // Byte by byte, as a slow TCP stream might deliver it.
        let mut out = Vec::new();
        for b in &bytes {
            p.push(&[*b]);
            out.extend(all(&mut p));
        }
        assert_eq!(out, vec![Ok(cmd)]);
    }

    #[test]
    fn every_command_round_trips_through_its_wire_form() {
        let cmds = [
            AtCommand::SendIm {
                dst: 255,
                ack: false,
                data: vec![0, 1, 2],
            },
            AtCommand::SendBurst {
                dst: 3,
                data: vec![9; 200],
            },
            AtCommand::SetLocalAddress(7),
            AtCommand::GetLocalAddress,
            AtCommand::SetRemoteAddress(2),
            AtCommand::GetRemoteAddress,
            AtCommand::GetStatus,
            AtCommand::SetImRetry(3),
            AtCommand::GetImRetry,
            AtCommand::SetSourceLevel(1),
            AtCommand::GetSourceLevel,
            AtCommand::GetRssi,
            AtCommand::GetIntegrity,
            AtCommand::GetPropagationTime,
            AtCommand::Reset(4),
        ];
        let mut p = CommandParser::new();
        for c in &cmds {
            p.push(&c.to_bytes());
        }
        assert_eq!(
            all(&mut p),
            cmds.iter().cloned().map(Ok).collect::<Vec<_>>()
        );
    }

    #[test]
    fn bad_input_gets_the_documented_error_strings() {
        let mut p = CommandParser::new();
        p.push(b"hello\n+++AT*SENDIM,65,2,ack,");
        p.push(&[b'x'; 65]);
        p.push(b"\n+++AT*SENDIM,3,2,maybe,abc\n+++AT*SENDIM,3,300,ack,abc\n+++AT?XYZ\n+++AT*SENDIM,5,2,ack,abc\n");
        p.push(b"+++AT*SENDIM,3,255,ack,abc\n+++AT*SEND,1100,2,x\n+++AT!L9\n+++AT?AL\n");
        let errs: Vec<_> = all(&mut p)
            .into_iter()
            .map(|r| match r {
                Ok(c) => c.name().to_owned(),
                Err(e) => format!("{}:{}", e.cmd, e.error),
            })
            .collect();
        assert_eq!(
            errs,
            [
                "AT:ERROR WRONG FORMAT",
                "AT*SENDIM:ERROR OUT OF RANGE",
                "AT*SENDIM:ERROR WRONG FORMAT",
                "AT*SENDIM:ERROR WRONG DESTINATION ADDRESS",
                "AT?XYZ:ERROR UNKNOWN COMMAND",
                "AT*SENDIM:ERROR WRONG FORMAT",
                "AT*SENDIM:ERROR WRONG DESTINATION ADDRESS",
                "AT*SEND:ERROR WRONG FORMAT",
                "AT!L:ERROR OUT OF RANGE",
                "AT?AL",
            ]
        );
    }

    #[test]
    fn frames_are_parsed_by_length_and_garbage_is_skipped() {
        let n = Notification::RecvIm(Received {
            src: 1,
            dst: 2,
            ack: true,
            duration_us: 180_000,
            rssi: -45,
            integrity: 180,
            velocity_mps: 0.25,
            propagation_us: 0,
            data: b"\r\n+++AT:3:x\r\n".to_vec(),
        });
        let mut p = FrameParser::new();
        p.push(b"junk\x00\xff");
        p.push(&reply("AT*SENDIM", b"OK"));
        p.push(&notification(&n.to_body()));
        // A wrong length is detected once enough bytes arrived, then parsing resynchronises.
        p.push(b"+++AT:20:short\r\n");
        p.push(&notification(b"DELIVEREDIM,2"));
        let a = p.next().unwrap();
        assert_eq!(
            (a.cmd.as_str(), a.body.as_slice()),
            ("AT*SENDIM", &b"OK"[..])
        );
        let b = p.next().unwrap();
        assert_eq!(Notification::parse(&b.body), Some(n));
        let c = p.next().unwrap();
        assert_eq!(
            Notification::parse(&c.body),
            Some(Notification::DeliveredIm(2))
        );
        assert!(p.next().is_none());
    }

    #[test]
    fn burst_notifications_round_trip() {
        for n in [
            Notification::Delivered { count: 100, dst: 3 },
            Notification::Failed { count: 5, dst: 4 },
            Notification::CanceledIm(9),
            Notification::FailedIm(1),
        ] {
            assert_eq!(Notification::parse(&n.to_body()), Some(n));
        }
    }
}
