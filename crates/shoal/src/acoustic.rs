//! Integrator tools for the acoustic link: `shoal pdu` and `shoal modem-emu`.

use std::io::{IsTerminal, Read, Write};
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Subcommand;
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, ModemConfig};
use shoal_acoustic::pdu;

/// `shoal pdu` subcommands.
#[derive(Debug, Subcommand)]
pub enum PduCommand {
    /// Encode a PDU (a JSON object) or a frame of PDUs (a JSON array) to hex; prints the size.
    Encode {
        /// The JSON, or `-` (the default) to read it from standard input.
        #[arg(default_value = "-")]
        json: String,
    },
    /// Decode a frame given in hex to JSON.
    Decode {
        /// Hex digits (whitespace allowed).
        hex: String,
    },
    /// Print every message's size in bits and bytes, against the DCCL reference (20 B).
    Sizes,
}

/// Runs `shoal pdu ...`.
pub fn pdu(cmd: PduCommand) -> Result<()> {
    match cmd {
        PduCommand::Encode { json } => {
            let text = if json == "-" {
                let mut s = String::new();
                std::io::stdin()
                    .read_to_string(&mut s)
                    .context("cannot read standard input")?;
                s
            } else {
                json
            };
            let encoded = pdu::encode_json(&text).context("cannot encode")?;
            println!("{}", pdu::to_hex(&encoded.bytes));
            eprintln!("{} bits, {} bytes", encoded.bits, encoded.bytes.len());
            Ok(())
        }
        PduCommand::Decode { hex } => {
            let bytes = pdu::from_hex(&hex).context("not hex")?;
            println!("{}", pdu::decode_to_json(&bytes).context("cannot decode")?);
            Ok(())
        }
        PduCommand::Sizes => {
            println!("{:<40} {:>6} {:>6}", "message", "bits", "bytes");
            for row in pdu::size_table() {
                println!("{:<40} {:>6} {:>6}", row.message, row.bits, row.bytes);
            }
            println!(
                "reference: DCCL State Vector 20 B (158 bits); SWARMs ASCII State Vector 51 B"
            );
            // Layout 2 is variable-length: the table shows one sample, the benchmark the
            // spread over a real track.
            println!(
                "predicted_delta (layout 2) varies with how well the keyframe predicts the state; \
                 `shoal bench acoustic` gives its median and p90 over a manoeuvring track"
            );
            print_tag_cost();
            Ok(())
        }
    }
}

/// What frame authentication costs on a 64-byte instant message: the counter and tag
/// bytes, and how many state keyframes (and keyframe + deltas) still fit.
fn print_tag_cost() {
    use shoal_security::{TagSize, acoustic};
    let table = pdu::size_table();
    let size_of = |prefix: &str| {
        table
            .iter()
            .find(|r| r.message.starts_with(prefix))
            .map_or(0, |r| r.bytes)
    };
    let (key, delta) = (size_of("state_keyframe"), size_of("state_delta"));
    println!();
    println!(
        "frame authentication (counter + truncated HMAC-SHA256), {}-byte instant message:",
        pdu::MAX_FRAME
    );
    println!(
        "{:<16} {:>9} {:>9} {:>14} {:>20}  no longer fits",
        "tag", "overhead", "payload", "keyframes/msg", "1 keyframe + deltas"
    );
    for (name, overhead) in [
        ("none", 0),
        ("32-bit", acoustic::OVERHEAD_32),
        ("64-bit (default)", acoustic::OVERHEAD_64),
    ] {
        let room = pdu::MAX_FRAME - overhead;
        let keyframes = room.checked_div(key).unwrap_or(0);
        let deltas = room.saturating_sub(key).checked_div(delta).unwrap_or(0);
        let too_big: Vec<&str> = table
            .iter()
            .filter(|r| r.bytes > room)
            .map(|r| r.message)
            .collect();
        println!(
            "{name:<16} {:>7} B {:>7} B {keyframes:>14} {:>20}  {}",
            overhead,
            room,
            format!("1 + {deltas}"),
            if too_big.is_empty() {
                "-".to_string()
            } else {
                too_big.join(", ")
            }
        );
    }
    println!(
        "forgery per attempt: 32-bit {:.1e}, 64-bit {:.1e}",
        TagSize::Bits32.forgery_probability(),
        TagSize::Bits64.forgery_probability()
    );
}

/// Options of `shoal modem-emu`.
#[derive(Debug, clap::Args)]
pub struct ModemEmuArgs {
    /// Emulator configuration (TOML: seed, time_scale, channel, fixed_per, modems...); when
    /// given, the flags below that describe modems are ignored.
    #[arg(long, value_name = "FILE")]
    emu_config: Option<PathBuf>,
    /// Number of modems (addresses 1..=N).
    #[arg(long, default_value_t = 2)]
    modems: u8,
    /// AT port of modem 1 (modem i listens on port+i-1; 0 picks free ports).
    #[arg(long, default_value_t = 9200)]
    at_port: u16,
    /// NL port of modem 1 (modem i listens on port+i-1; 0 picks free ports).
    #[arg(long, default_value_t = 9300)]
    nl_port: u16,
    /// Distance between neighbouring modems, metres (placed on a line running east).
    #[arg(long, default_value_t = 1000.0)]
    spacing_m: f64,
    /// Depth of every modem, metres.
    #[arg(long, default_value_t = 20.0)]
    depth_m: f64,
    /// Use this packet error rate for every packet instead of the channel model.
    #[arg(long)]
    per: Option<f64>,
    /// Random seed (same seed and traffic: same losses).
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

fn emulator_config(a: &ModemEmuArgs) -> Result<EmulatorConfig> {
    if let Some(path) = &a.emu_config {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let de = toml::Deserializer::parse(&text)
            .map_err(|e| anyhow::anyhow!("{}: {}", path.display(), e.message()))?;
        return serde_path_to_error::deserialize(de).map_err(|e| {
            anyhow::anyhow!(
                "{}: invalid `{}`: {}",
                path.display(),
                e.path(),
                e.inner().message()
            )
        });
    }
    if a.modems == 0 || a.modems > 254 {
        bail!("--modems must be 1..=254");
    }
    if let Some(p) = a.per
        && !(0.0..=1.0).contains(&p)
    {
        bail!("--per must be a probability in [0, 1]");
    }
    let origin = shoal_model::geo::LocalFrame::new(shoal_model::GeoPoint {
        latitude_deg: 63.465,
        longitude_deg: 10.37,
    });
    let modems = (1..=a.modems)
        .map(|i| {
            let offset = u16::from(i - 1);
            let port = |base: u16| {
                if base == 0 {
                    Ok(0)
                } else {
                    base.checked_add(offset).context("port out of range")
                }
            };
            let at = origin.to_geo(f64::from(offset) * a.spacing_m, 0.0);
            Ok(ModemConfig {
                address: i,
                name: format!("modem-{i}"),
                at_port: port(a.at_port)?,
                nl_port: port(a.nl_port)?,
                latitude_deg: at.latitude_deg,
                longitude_deg: at.longitude_deg,
                depth_m: a.depth_m,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(EmulatorConfig {
        seed: a.seed,
        fixed_per: a.per,
        modems,
        ..EmulatorConfig::default()
    })
}

/// Runs `shoal modem-emu` until Ctrl-C, with a live status line.
pub async fn modem_emu(args: ModemEmuArgs) -> Result<()> {
    let config = emulator_config(&args)?;
    let shutdown = crate::daemons::shutdown_signal(false);
    let stop = shutdown.clone();
    let handle = Emulator::start(config, async move { stop.cancelled().await })
        .await
        .context("cannot start the modem emulator")?;
    for m in handle.modems() {
        eprintln!(
            "modem {:>3} {:<10} EvoLogics AT on {}  EviNS NL on {}",
            m.address, m.name, m.at, m.nl
        );
    }
    eprintln!("Ctrl-C stops the emulator.");
    let tty = std::io::stderr().is_terminal();
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    let mut n = 0u64;
    loop {
        tokio::select! {
            () = shutdown.cancelled() => break,
            _ = tick.tick() => {
                n += 1;
                let stats = handle.stats();
                let line = if stats.is_empty() {
                    "no frames yet".to_string()
                } else {
                    stats.iter().map(|s| format!("{}→{}: {} frames {} ok {} lost {} coll",
                        s.src, s.dst, s.frames, s.delivered, s.lost, s.collisions)).collect::<Vec<_>>().join(" | ")
                };
                // A live line on a terminal; a log line every 10 s otherwise.
                if tty {
                    eprint!("\r\x1b[2K{line}");
                    let _ = std::io::stderr().flush();
                } else if n.is_multiple_of(10) {
                    eprintln!("{line}");
                }
            }
        }
    }
    if tty {
        eprintln!();
    }
    handle.stopped().await;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args() -> ModemEmuArgs {
        ModemEmuArgs {
            emu_config: None,
            modems: 3,
            at_port: 9200,
            nl_port: 0,
            spacing_m: 500.0,
            depth_m: 10.0,
            per: None,
            seed: 1,
        }
    }

    #[test]
    fn modems_are_laid_out_on_consecutive_ports_and_spaced() {
        let c = emulator_config(&args()).unwrap();
        assert_eq!(
            c.modems.iter().map(|m| m.at_port).collect::<Vec<_>>(),
            [9200, 9201, 9202]
        );
        assert!(c.modems.iter().all(|m| m.nl_port == 0));
        let (a, b) = (&c.modems[0], &c.modems[1]);
        let d = shoal_model::geo::distance_m(
            a.latitude_deg,
            a.longitude_deg,
            b.latitude_deg,
            b.longitude_deg,
        );
        assert!((d - 500.0).abs() < 1.0, "{d}");
    }

    #[test]
    fn a_bad_packet_error_rate_is_refused() {
        let mut a = args();
        a.per = Some(1.5);
        assert!(
            emulator_config(&a)
                .unwrap_err()
                .to_string()
                .contains("--per")
        );
    }
}
