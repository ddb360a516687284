//! Shared helpers: emulator set-ups and a minimal raw AT client.

use std::net::SocketAddr;
use std::time::Duration;

use shoal_acoustic::at::{AtFrame, FrameParser};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle, ModemConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// A modem at `east_m` metres east of (43°N, 5°E), 20 m deep.
pub fn modem(address: u8, east_m: f64) -> ModemConfig {
    ModemConfig {
        address,
        name: format!("m{address}"),
        latitude_deg: 43.0,
        longitude_deg: 5.0 + east_m / (111_194.93 * 43f64.to_radians().cos()),
        depth_m: 20.0,
        ..ModemConfig::default()
    }
}

/// Starts an emulator with the given modems, 100× faster than real time.
pub async fn emulator(
    modems: Vec<ModemConfig>,
    tweak: impl FnOnce(&mut EmulatorConfig),
) -> EmulatorHandle {
    let mut cfg = EmulatorConfig {
        time_scale: 0.01,
        seed: 42,
        modems,
        ..EmulatorConfig::default()
    };
    tweak(&mut cfg);
    Emulator::start(cfg, std::future::pending()).await.unwrap()
}

/// A raw AT client.
pub struct AtClient {
    stream: TcpStream,
    parser: FrameParser,
}

impl AtClient {
    pub async fn connect(addr: SocketAddr) -> Self {
        Self {
            stream: TcpStream::connect(addr).await.unwrap(),
            parser: FrameParser::new(),
        }
    }

    pub async fn write(&mut self, bytes: &[u8]) {
        self.stream.write_all(bytes).await.unwrap();
    }

    /// The next frame, or None after `wait`.
    pub async fn frame(&mut self, wait: Duration) -> Option<AtFrame> {
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            if let Some(f) = self.parser.next() {
                return Some(f);
            }
            let mut buf = [0u8; 1024];
            let n = tokio::time::timeout_at(deadline, self.stream.read(&mut buf))
                .await
                .ok()?
                .ok()?;
            if n == 0 {
                return None;
            }
            self.parser.push(&buf[..n]);
        }
    }

    /// The next frame's `cmd:body` as text (panics after 5 s).
    pub async fn text(&mut self) -> String {
        let f = self
            .frame(Duration::from_secs(5))
            .await
            .expect("no frame from modem");
        format!("{}:{}", f.cmd, f.text())
    }

    /// Sends a command and returns its reply as `cmd:body`.
    pub async fn command(&mut self, line: &[u8]) -> String {
        self.write(line).await;
        self.text().await
    }
}

/// Reads NL lines.
pub struct NlClient {
    stream: TcpStream,
    parser: shoal_acoustic::nl::NlEventParser,
}

impl NlClient {
    pub async fn connect(addr: SocketAddr) -> Self {
        Self {
            stream: TcpStream::connect(addr).await.unwrap(),
            parser: shoal_acoustic::nl::NlEventParser::new(),
        }
    }

    pub async fn write(&mut self, bytes: &[u8]) {
        self.stream.write_all(bytes).await.unwrap();
    }

    pub async fn event(&mut self) -> shoal_acoustic::nl::NlEvent {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
        loop {
            if let Some(e) = self.parser.next() {
                return e;
            }
            let mut buf = [0u8; 1024];
            let n = tokio::time::timeout_at(deadline, self.stream.read(&mut buf))
                .await
                .expect("no NL line")
                .unwrap();
            assert!(n > 0, "NL connection closed");
            self.parser.push(&buf[..n]);
        }
    }
}
