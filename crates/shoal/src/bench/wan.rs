//! A WAN emulator in user space for `bench federation`: netem's job (delay, rate, loss,
//! outage) done on TUN devices, because this machine's kernel has no netem qdisc.
//!
//! - [`Namespaces`]: one network namespace per site (loopback up with multicast, as
//!   `scripts/netns-run.sh --setup` makes them), deleted when dropped, also on an error.
//! - [`Wan`]: a TUN device `wan0` in each site's namespace (10.77.0.x/24) and a thread
//!   that forwards the IP packets between them by destination address through each
//!   site's [`Link`]: the site's uplink on the way out, the destination's downlink on the
//!   way in. A packet from a ship to the shore crosses the ship's satellite uplink and the
//!   shore's (unimpaired) downlink; its TCP is end to end, so the stations' own TCP sees
//!   the delay, the rate and every loss, as over a real link.
//! - [`Pipe`]: one direction of a link, with no I/O (tested below): a tail-drop FIFO of
//!   `queue_bytes` in front of a serialiser at `rate_bps`, then `one_way` delay; seeded
//!   random loss on arrival; an outage drops everything offered and what is in flight.
//! - [`in_netns`]: runs a closure on a fresh thread that entered a namespace, so that a
//!   socket (or the TUN device) it opens belongs to that namespace.
//!
//! Unlike netem: no jitter and so no reordering, loss is independent per packet (no
//! Gilbert-Elliott bursts), the delay is applied after serialisation (netem's `rate`
//! does the same), and time is the emulator thread's: a packet leaves within ~0.1 ms of
//! its due time on an idle machine, later when the machine is busy.

use std::collections::VecDeque;
use std::net::Ipv4Addr;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use rand::{RngExt as _, SeedableRng as _};
use rand_xoshiro::SplitMix64;

/// The WAN subnet; every site's TUN has one address in it and nothing else is routed.
pub(super) const SUBNET: [u8; 3] = [10, 77, 0];
/// Name of the TUN device in each site's namespace.
const DEVICE: &str = "wan0";
/// Largest packet read from a TUN device (its MTU is 1500).
const MAX_PACKET: usize = 2048;

/// One direction of a link: what impairs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Profile {
    /// Propagation delay, after serialisation.
    pub(super) one_way: Duration,
    /// Serialisation rate, bits per second; `None`: unlimited.
    pub(super) rate_bps: Option<f64>,
    /// Probability that a packet is lost, [0, 1].
    pub(super) loss: f64,
    /// Bytes the modem's buffer holds waiting for the serialiser; a packet that does not
    /// fit is dropped (tail drop).
    pub(super) queue_bytes: usize,
}

impl Profile {
    /// No delay, no rate limit, no loss: a site on a terrestrial link.
    pub(super) const CLEAR: Self = Self {
        one_way: Duration::ZERO,
        rate_bps: None,
        loss: 0.0,
        queue_bytes: usize::MAX,
    };
}

/// What became of the packets offered to one direction of a link.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct PipeCounters {
    pub(super) offered_packets: u64,
    /// IP bytes (headers included) offered: what the site sent into the WAN.
    pub(super) offered_bytes: u64,
    pub(super) delivered_packets: u64,
    pub(super) delivered_bytes: u64,
    pub(super) dropped_loss: u64,
    pub(super) dropped_queue: u64,
    pub(super) dropped_outage: u64,
    /// Bytes waiting for the serialiser now (the modem's backlog).
    pub(super) queued_bytes: u64,
    /// The most ever waiting.
    pub(super) max_queued_bytes: u64,
}

/// A packet on its way.
#[derive(Debug)]
struct InFlight {
    /// When its last bit has left the serialiser (it stops counting as queued).
    serialised: Duration,
    /// When it comes out of the far end.
    due: Duration,
    packet: Vec<u8>,
    to: usize,
}

/// One direction of a link (see the module doc). Times are offsets from the emulator's
/// start; they never go back.
#[derive(Debug)]
pub(super) struct Pipe {
    profile: Profile,
    rng: SplitMix64,
    in_flight: VecDeque<InFlight>,
    /// When the serialiser is free again.
    busy_until: Duration,
    outage: bool,
    counters: PipeCounters,
}

impl Pipe {
    pub(super) fn new(profile: Profile, seed: u64) -> Self {
        Self {
            profile,
            rng: SplitMix64::seed_from_u64(seed),
            in_flight: VecDeque::new(),
            busy_until: Duration::ZERO,
            outage: false,
            counters: PipeCounters::default(),
        }
    }

    /// Bytes not yet serialised at `now`.
    fn backlog(&self, now: Duration) -> usize {
        self.in_flight
            .iter()
            .rev()
            .take_while(|p| p.serialised > now)
            .map(|p| p.packet.len())
            .sum()
    }

    /// Takes a packet for site `to` at `now`; false when it was dropped.
    pub(super) fn offer(&mut self, now: Duration, packet: Vec<u8>, to: usize) -> bool {
        let len = packet.len();
        self.counters.offered_packets += 1;
        self.counters.offered_bytes += len as u64;
        if self.outage {
            self.counters.dropped_outage += 1;
            return false;
        }
        if self.profile.loss > 0.0 && self.rng.random::<f64>() < self.profile.loss {
            self.counters.dropped_loss += 1;
            return false;
        }
        let Some(rate) = self.profile.rate_bps else {
            let due = now + self.profile.one_way;
            self.in_flight.push_back(InFlight {
                serialised: now,
                due,
                packet,
                to,
            });
            return true;
        };
        let backlog = self.backlog(now);
        if backlog + len > self.profile.queue_bytes {
            self.counters.dropped_queue += 1;
            return false;
        }
        #[allow(clippy::cast_precision_loss)]
        let serialising = Duration::from_secs_f64(len as f64 * 8.0 / rate);
        let serialised = self.busy_until.max(now) + serialising;
        self.busy_until = serialised;
        self.in_flight.push_back(InFlight {
            serialised,
            due: serialised + self.profile.one_way,
            packet,
            to,
        });
        let queued = (backlog + len) as u64;
        self.counters.max_queued_bytes = self.counters.max_queued_bytes.max(queued);
        true
    }

    /// When the next packet comes out, if one is on its way.
    pub(super) fn next_due(&self) -> Option<Duration> {
        self.in_flight.front().map(|p| p.due)
    }

    /// The next packet due by `now`, with the site it is for.
    pub(super) fn pop_due(&mut self, now: Duration) -> Option<(Vec<u8>, usize)> {
        if self.in_flight.front()?.due > now {
            return None;
        }
        let p = self.in_flight.pop_front()?;
        self.counters.delivered_packets += 1;
        self.counters.delivered_bytes += p.packet.len() as u64;
        Some((p.packet, p.to))
    }

    /// Starts or ends an outage; starting one loses what is on its way.
    pub(super) fn set_outage(&mut self, on: bool, now: Duration) {
        if on && !self.outage {
            self.counters.dropped_outage += self.in_flight.len() as u64;
            self.in_flight.clear();
            self.busy_until = now;
        }
        self.outage = on;
    }

    /// The counters, with the backlog at `now`.
    pub(super) fn counters(&self, now: Duration) -> PipeCounters {
        PipeCounters {
            queued_bytes: self.backlog(now) as u64,
            ..self.counters
        }
    }
}

/// Both directions of one site's link to the WAN.
#[derive(Debug)]
struct Link {
    up: Pipe,
    down: Pipe,
}

/// One site of the emulated WAN.
#[derive(Debug, Clone)]
pub(super) struct SiteLink {
    /// Its network namespace.
    pub(super) netns: String,
    /// Its address, 10.77.0.`host`.
    pub(super) host: u8,
    /// Its link: the same profile both ways.
    pub(super) profile: Profile,
}

/// Counters of one site's link, both ways.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LinkCounters {
    /// What the site sent into the WAN.
    pub(super) up: PipeCounters,
    /// What the WAN sent to the site.
    pub(super) down: PipeCounters,
}

/// The emulator's state, shared between its thread and the benchmark.
#[derive(Debug)]
struct Core {
    start: Instant,
    links: Vec<Link>,
    hosts: Vec<u8>,
    /// Packets for no site of the WAN (IPv6, multicast, another address): dropped.
    unroutable: u64,
}

impl Core {
    fn now(&self) -> Duration {
        self.start.elapsed()
    }

    /// The site a packet is for, by its IPv4 destination.
    fn route(&self, packet: &[u8]) -> Option<usize> {
        if packet.len() < 20 || packet[0] >> 4 != 4 || packet[16..19] != SUBNET {
            return None;
        }
        self.hosts.iter().position(|h| *h == packet[19])
    }

    fn offer(&mut self, from: usize, packet: Vec<u8>) {
        let now = self.now();
        match self.route(&packet) {
            Some(to) if to != from => {
                self.links[from].up.offer(now, packet, to);
            }
            _ => self.unroutable += 1,
        }
    }

    /// Moves what is due: uplinks into the destinations' downlinks, downlinks out to
    /// `deliver`. Returns when the next packet is due.
    fn step(&mut self, deliver: &mut dyn FnMut(usize, &[u8])) -> Option<Duration> {
        let now = self.now();
        for i in 0..self.links.len() {
            while let Some((packet, to)) = self.links[i].up.pop_due(now) {
                self.links[to].down.offer(now, packet, to);
            }
        }
        for (i, link) in self.links.iter_mut().enumerate() {
            while let Some((packet, _)) = link.down.pop_due(now) {
                deliver(i, &packet);
            }
        }
        self.links
            .iter()
            .flat_map(|l| [l.up.next_due(), l.down.next_due()])
            .flatten()
            .min()
    }
}

/// The running emulator; stops (and its TUN devices vanish) when dropped.
#[derive(Debug)]
pub(super) struct Wan {
    core: Arc<Mutex<Core>>,
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

fn lock(core: &Mutex<Core>) -> std::sync::MutexGuard<'_, Core> {
    core.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Wan {
    /// Creates each site's TUN device in its namespace and starts forwarding; `seed`
    /// seeds every link's loss (each direction its own stream).
    pub(super) fn start(sites: &[SiteLink], seed: u64) -> Result<Self> {
        let mut devices = Vec::new();
        for s in sites {
            let host = s.host;
            let device = in_netns(&s.netns, move || {
                let mut config = tun::Configuration::default();
                config
                    .tun_name(DEVICE)
                    .layer(tun::Layer::L3)
                    .address(Ipv4Addr::new(SUBNET[0], SUBNET[1], SUBNET[2], host))
                    .netmask(Ipv4Addr::new(255, 255, 255, 0))
                    .mtu(1500)
                    .up();
                tun::create(&config).map_err(std::io::Error::other)
            })
            .with_context(|| format!("cannot create the TUN device in {}", s.netns))?;
            devices.push(Arc::new(device));
        }
        let links = sites
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let i = i as u64;
                Link {
                    up: Pipe::new(s.profile, seed ^ (2 * i + 1).wrapping_mul(0x9E37_79B9)),
                    down: Pipe::new(s.profile, seed ^ (2 * i + 2).wrapping_mul(0x9E37_79B9)),
                }
            })
            .collect();
        let core = Arc::new(Mutex::new(Core {
            start: Instant::now(),
            links,
            hosts: sites.iter().map(|s| s.host).collect(),
            unroutable: 0,
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, rx) = mpsc::channel::<(usize, Vec<u8>)>();
        let mut threads = Vec::new();
        for (i, device) in devices.iter().enumerate() {
            let (device, tx, stop) = (Arc::clone(device), tx.clone(), Arc::clone(&stop));
            threads.push(
                std::thread::Builder::new()
                    .name(format!("wan-read-{i}"))
                    .spawn(move || {
                        let mut buf = vec![0u8; MAX_PACKET];
                        while !stop.load(Ordering::Relaxed) {
                            match device.recv_timeout(&mut buf, Duration::from_millis(200)) {
                                Ok(0) => {}
                                Ok(n) => {
                                    if tx.send((i, buf[..n].to_vec())).is_err() {
                                        return;
                                    }
                                }
                                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                                Err(e) => {
                                    eprintln!("wan: reading site {i}'s TUN device failed: {e}");
                                    return;
                                }
                            }
                        }
                    })?,
            );
        }
        drop(tx);
        let (c, s) = (Arc::clone(&core), Arc::clone(&stop));
        threads.push(
            std::thread::Builder::new()
                .name("wan-forward".into())
                .spawn(move || forward(&c, &devices, &rx, &s))?,
        );
        Ok(Self {
            core,
            stop,
            threads,
        })
    }

    /// Starts or ends an outage of site `site`'s link, both ways.
    pub(super) fn set_outage(&self, site: usize, on: bool) {
        let mut core = lock(&self.core);
        let now = core.now();
        if let Some(l) = core.links.get_mut(site) {
            l.up.set_outage(on, now);
            l.down.set_outage(on, now);
        }
    }

    /// Each site's counters now, and the unroutable packets.
    pub(super) fn counters(&self) -> (Vec<LinkCounters>, u64) {
        let core = lock(&self.core);
        let now = core.now();
        let links = core
            .links
            .iter()
            .map(|l| LinkCounters {
                up: l.up.counters(now),
                down: l.down.counters(now),
            })
            .collect();
        (links, core.unroutable)
    }
}

impl Drop for Wan {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// The forwarding thread: packets read from the devices go in, due packets go out.
fn forward(
    core: &Mutex<Core>,
    devices: &[Arc<tun::Device>],
    rx: &mpsc::Receiver<(usize, Vec<u8>)>,
    stop: &AtomicBool,
) {
    let mut deliver = |site: usize, packet: &[u8]| {
        // A full or vanished device loses the packet, as a modem would.
        let _ = devices[site].send(packet);
    };
    while !stop.load(Ordering::Relaxed) {
        let next = lock(core).step(&mut deliver);
        let now = lock(core).now();
        let wait = next
            .map_or(Duration::from_millis(50), |due| due.saturating_sub(now))
            .min(Duration::from_millis(50));
        match rx.recv_timeout(wait) {
            Ok((from, packet)) => {
                let mut c = lock(core);
                c.offer(from, packet);
                // Whatever else has arrived, in one go.
                while let Ok((from, packet)) = rx.try_recv() {
                    c.offer(from, packet);
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => return,
        }
    }
}

/// Runs `f` on a fresh thread inside network namespace `netns` (`/run/netns/<netns>`):
/// sockets and devices it opens belong to that namespace, whichever thread uses them
/// later. A fresh thread, never a pooled one, so no other work runs in the namespace.
pub(super) fn in_netns<T: Send + 'static>(
    netns: &str,
    f: impl FnOnce() -> std::io::Result<T> + Send + 'static,
) -> Result<T> {
    let path = format!("/run/netns/{netns}");
    std::thread::Builder::new()
        .name("in-netns".into())
        .spawn(move || -> Result<T> {
            let ns = std::fs::File::open(&path).with_context(|| format!("cannot open {path}"))?;
            nix::sched::setns(&ns, nix::sched::CloneFlags::CLONE_NEWNET)
                .with_context(|| format!("cannot enter {path}"))?;
            Ok(f()?)
        })?
        .join()
        .map_err(|_| anyhow::anyhow!("the thread in {netns} panicked"))?
}

/// Network namespaces made for a run, deleted when dropped.
#[derive(Debug)]
pub(super) struct Namespaces {
    names: Vec<String>,
}

fn ip(args: &[&str]) -> Result<()> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .context("cannot run `ip` (iproute2)")?;
    if !out.status.success() {
        bail!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(())
}

impl Namespaces {
    /// Makes `<prefix>-<site>` for each site: loopback up with multicast and a route for
    /// multicast on it, so DDS inside a site stays on its loopback.
    pub(super) fn create(prefix: &str, sites: &[&str]) -> Result<Self> {
        let mut me = Self { names: Vec::new() };
        for site in sites {
            let name = format!("{prefix}-{site}");
            ip(&["netns", "add", &name])?;
            me.names.push(name.clone());
            ip(&["-n", &name, "link", "set", "lo", "up"])?;
            ip(&["-n", &name, "link", "set", "lo", "multicast", "on"])?;
            ip(&["-n", &name, "route", "replace", "224.0.0.0/4", "dev", "lo"])?;
        }
        Ok(me)
    }

    /// Sets a (per-namespace) sysctl in every site's namespace, as `sysctl -w` would.
    pub(super) fn sysctl(&self, key: &str, value: &str) -> Result<()> {
        for name in &self.names {
            let out = Command::new("ip")
                .args([
                    "netns",
                    "exec",
                    name,
                    "sysctl",
                    "-qw",
                    &format!("{key}={value}"),
                ])
                .output()
                .context("cannot run ip netns exec sysctl")?;
            if !out.status.success() {
                bail!(
                    "sysctl {key}={value} in {name}: {}",
                    String::from_utf8_lossy(&out.stderr).trim()
                );
            }
        }
        Ok(())
    }

    /// The namespace of site `i` (in the order given).
    pub(super) fn name(&self, i: usize) -> &str {
        &self.names[i]
    }

    /// Deletes namespaces `shoal-wan-<pid>-*` left by a run whose process is gone
    /// (killed before it could clean up).
    pub(super) fn delete_stale() {
        let Ok(entries) = std::fs::read_dir("/run/netns") else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(pid) = name
                .strip_prefix("shoal-wan-")
                .and_then(|rest| rest.split('-').next())
            else {
                continue;
            };
            if pid.parse::<u32>().is_ok() && !std::path::Path::new(&format!("/proc/{pid}")).exists()
            {
                let _ = ip(&["netns", "delete", &name]);
            }
        }
    }
}

impl Drop for Namespaces {
    fn drop(&mut self) {
        for name in self.names.drain(..) {
            if let Err(e) = ip(&["netns", "delete", &name]) {
                eprintln!("wan: {e}");
            }
        }
    }
}

/// Whether this process can build the emulated WAN: root, `/dev/net/tun` and `ip`.
/// `Err` says what is missing.
pub(super) fn check_can_run() -> Result<()> {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let root = status
        .lines()
        .find_map(|l| l.strip_prefix("Uid:"))
        .and_then(|v| v.split_whitespace().nth(1))
        == Some("0");
    if !root {
        bail!("not root: network namespaces and TUN devices need root");
    }
    if !std::path::Path::new("/dev/net/tun").exists() {
        bail!("no /dev/net/tun: the kernel has no TUN driver here");
    }
    ip(&["-V"]).context("no `ip` command (iproute2)")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn satellite() -> Profile {
        Profile {
            one_way: ms(300),
            rate_bps: Some(64_000.0),
            loss: 0.0,
            queue_bytes: 4000,
        }
    }

    #[test]
    fn a_packet_is_serialised_at_the_rate_then_delayed() {
        let mut p = Pipe::new(satellite(), 1);
        // 1000 bytes at 64 kbit/s: 125 ms on the wire, then 300 ms of flight.
        assert!(p.offer(ms(0), vec![0; 1000], 1));
        assert!(p.offer(ms(0), vec![0; 1000], 1));
        assert_eq!(p.next_due(), Some(ms(425)));
        assert!(p.pop_due(ms(424)).is_none());
        assert_eq!(
            p.pop_due(ms(425)).map(|(b, to)| (b.len(), to)),
            Some((1000, 1))
        );
        // The second waited for the first: 250 ms of serialisation.
        assert_eq!(p.next_due(), Some(ms(550)));
        assert_eq!(p.counters(ms(100)).queued_bytes, 1000);
        assert_eq!(p.counters(ms(300)).queued_bytes, 0);
    }

    #[test]
    fn a_full_queue_drops_the_tail() {
        let mut p = Pipe::new(satellite(), 1);
        for _ in 0..4 {
            assert!(p.offer(ms(0), vec![0; 1000], 1));
        }
        assert!(!p.offer(ms(0), vec![0; 1000], 1));
        let c = p.counters(ms(0));
        assert_eq!(
            (c.dropped_queue, c.queued_bytes, c.max_queued_bytes),
            (1, 4000, 4000)
        );
        // Once one has left the serialiser, there is room again.
        assert!(p.offer(ms(126), vec![0; 1000], 1));
    }

    #[test]
    fn loss_is_seeded_and_near_its_rate() {
        let lossy = Profile {
            loss: 0.02,
            ..Profile::CLEAR
        };
        let run = |seed| {
            let mut p = Pipe::new(lossy, seed);
            (0..50_000)
                .map(|i| p.offer(ms(i), vec![0; 40], 1))
                .filter(|kept| !kept)
                .count()
        };
        let lost = run(7);
        assert_eq!(lost, run(7), "the same seed loses the same packets");
        assert!((800..1200).contains(&lost), "{lost} of 50000 at 2 %");
    }

    #[test]
    fn an_outage_drops_what_is_offered_and_in_flight() {
        let mut p = Pipe::new(satellite(), 1);
        assert!(p.offer(ms(0), vec![0; 100], 1));
        p.set_outage(true, ms(10));
        assert!(!p.offer(ms(20), vec![0; 100], 1));
        assert!(p.pop_due(ms(1000)).is_none());
        assert_eq!(p.counters(ms(20)).dropped_outage, 2);
        p.set_outage(false, ms(30));
        assert!(p.offer(ms(30), vec![0; 100], 1));
        assert!(p.pop_due(ms(343)).is_some());
    }

    #[test]
    fn packets_are_routed_by_ipv4_destination_in_the_subnet_only() {
        let core = Core {
            start: Instant::now(),
            links: vec![],
            hosts: vec![1, 2, 3],
            unroutable: 0,
        };
        let mut packet = vec![0x45u8; 40];
        packet[16..20].copy_from_slice(&[10, 77, 0, 2]);
        assert_eq!(core.route(&packet), Some(1));
        packet[16..20].copy_from_slice(&[10, 77, 1, 2]);
        assert_eq!(core.route(&packet), None);
        packet[16..20].copy_from_slice(&[239, 255, 0, 1]);
        assert_eq!(core.route(&packet), None);
        packet[0] = 0x60;
        assert_eq!(core.route(&packet), None, "IPv6 is not routed");
        assert_eq!(core.route(&[0x45; 10]), None);
    }
}
