//! One DDS participant on its own thread, reading one topic and writing another, with fixed
//! hand-over buffers: the control thread never calls into the DDS library (which allocates and
//! starts threads of its own), so its tick path stays allocation-free.
//!
//! Inbound: the transport thread takes every sample as it arrives and copies the newest into the
//! inbox (a newer one overwrites an unread older one: the control loop wants the newest state, as
//! the robot's KEEP_LAST 1 reader would give it). Outbound: the control thread copies its sample
//! into the outbox and wakes the transport thread, which writes it.
use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use rustdds::mio1::{Events, Interest, Poll, Token, Waker};
use rustdds::no_key::{DataReader, DataWriter};
use rustdds::policy::{History, Reliability};
use rustdds::{DomainParticipantBuilder, QosPolicies, QosPolicyBuilder, RTPSEntity, TopicKind};

use super::raw::{CdrSample, RawCdr};
use super::DdsError;

/// Largest sample kept whole (LowState_ is 2092 bytes with its header). A longer one keeps its
/// true length, so the decoder rejects it by size.
pub const SAMPLE_CAP: usize = 4096;

const READ: Token = Token(0);
const WAKE: Token = Token(1);
/// How often the transport thread looks at discovery for other writers on its topic.
const DISCOVERY_CHECK: Duration = Duration::from_millis(200);

/// One side of the link: what it reads and what it writes.
#[derive(Clone, Debug)]
pub struct Topics {
    pub read_topic: &'static str,
    pub read_type: &'static str,
    pub write_topic: &'static str,
    pub write_type: &'static str,
}

/// Where the participant lives.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Endpoint {
    /// The network interface's name (`eth0`, `lo`) or one of its IPv4 addresses.
    pub interface: String,
    pub domain: u16,
}

impl std::str::FromStr for Endpoint {
    type Err = String;
    /// `IFACE[,DOMAIN]`: `enp3s0` (domain 0, the robot's), `lo,1` (unitree_mujoco's default).
    fn from_str(s: &str) -> Result<Self, String> {
        let (iface, domain) = match s.split_once(',') {
            Some((i, d)) => {
                let d: u16 = d.trim().parse().map_err(|_| {
                    format!(
                        "'{s}': the domain after the comma must be a number 0-232 (the robot uses 0, unitree_mujoco 1)"
                    )
                })?;
                (i.trim(), d)
            }
            None => (s.trim(), 0),
        };
        if iface.is_empty() {
            return Err(format!(
                "'{s}': name the network interface the robot is on, e.g. 'eth0' or 'lo,1'"
            ));
        }
        // RTPS maps the domain to UDP ports 7400 + 250·domain (+ offsets); 232 is the last that fits.
        if domain > 232 {
            return Err(format!("'{s}': DDS domain {domain} is out of range (0-232)"));
        }
        Ok(Endpoint {
            interface: iface.to_string(),
            domain,
        })
    }
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{},{}", self.interface, self.domain)
    }
}

/// The IPv4 address DDS should use for `interface` (a name, or an address given directly).
pub fn interface_address(interface: &str) -> Result<IpAddr, DdsError> {
    if let Ok(ip) = interface.parse::<IpAddr>() {
        return Ok(ip);
    }
    let addrs = nix::ifaddrs::getifaddrs().map_err(|e| DdsError::Interface {
        interface: interface.into(),
        why: format!("cannot list network interfaces: {e}"),
    })?;
    let mut names = Vec::new();
    for a in addrs {
        if !names.contains(&a.interface_name) {
            names.push(a.interface_name.clone());
        }
        if a.interface_name == interface {
            if let Some(sin) = a.address.as_ref().and_then(|s| s.as_sockaddr_in()) {
                return Ok(IpAddr::V4(sin.ip()));
            }
        }
    }
    Err(DdsError::Interface {
        interface: interface.into(),
        why: if names.iter().any(|n| n == interface) {
            "it has no IPv4 address (the G1's network is 192.168.123.0/24: give this host e.g. 192.168.123.99/24)"
                .into()
        } else {
            format!("no such interface; this machine has: {}", names.join(", "))
        },
    })
}

/// What the transport thread counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LinkCounters {
    pub samples_in: u64,
    pub samples_out: u64,
    /// Samples handed to `send` that a newer one replaced before the transport thread wrote them
    /// (the outbox keeps the newest, as the robot wants the newest command).
    pub coalesced: u64,
    pub write_errors: u64,
    pub read_errors: u64,
    /// Writers on our write topic that belong to another participant (another program
    /// commanding the same thing), most seen at once.
    pub other_writers: u64,
}

struct Inbox {
    seq: u64,
    /// True length of the newest sample (may exceed `bytes.len()`).
    len: usize,
    bytes: Vec<u8>,
}

struct Outbox {
    seq: u64,
    len: usize,
    bytes: Vec<u8>,
}

struct Shared {
    inbox: Mutex<Inbox>,
    arrived: Condvar,
    outbox: Mutex<Outbox>,
    stop: AtomicBool,
    samples_in: AtomicU64,
    samples_out: AtomicU64,
    coalesced: AtomicU64,
    write_errors: AtomicU64,
    read_errors: AtomicU64,
    other_writers_now: AtomicU64,
    other_writers_max: AtomicU64,
    /// The first other writer seen, for the error message.
    other_writer: Mutex<Option<String>>,
    thread_failed: Mutex<Option<String>>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic on the transport thread leaves the buffers as they were: still usable.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A running participant. Dropping it stops the thread.
pub struct DdsLink {
    shared: Arc<Shared>,
    waker: Arc<Waker>,
    thread: Option<JoinHandle<()>>,
    endpoint: Endpoint,
    topics: Topics,
}

impl DdsLink {
    /// Starts the participant on `endpoint` and waits `discovery` for peers; with `refuse_other_writers`,
    /// fails if another participant already writes our write topic.
    pub fn open(
        endpoint: &Endpoint,
        topics: Topics,
        discovery: Duration,
        refuse_other_writers: bool,
    ) -> Result<Self, DdsError> {
        let ip = interface_address(&endpoint.interface)?;
        let shared = Arc::new(Shared {
            inbox: Mutex::new(Inbox {
                seq: 0,
                len: 0,
                bytes: vec![0; SAMPLE_CAP],
            }),
            arrived: Condvar::new(),
            outbox: Mutex::new(Outbox {
                seq: 0,
                len: 0,
                bytes: vec![0; SAMPLE_CAP],
            }),
            stop: AtomicBool::new(false),
            samples_in: AtomicU64::new(0),
            samples_out: AtomicU64::new(0),
            coalesced: AtomicU64::new(0),
            write_errors: AtomicU64::new(0),
            read_errors: AtomicU64::new(0),
            other_writers_now: AtomicU64::new(0),
            other_writers_max: AtomicU64::new(0),
            other_writer: Mutex::new(None),
            thread_failed: Mutex::new(None),
        });
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<Arc<Waker>, DdsError>>();
        let (sh, ep, tp) = (shared.clone(), endpoint.clone(), topics.clone());
        let thread = std::thread::Builder::new()
            .name("dds".into())
            .spawn(move || transport(sh, ep, tp, ip, ready_tx))
            .map_err(|e| DdsError::Setup(format!("cannot start the DDS thread: {e}")))?;
        let waker = match ready_rx.recv() {
            Ok(Ok(w)) => w,
            Ok(Err(e)) => {
                let _ = thread.join();
                return Err(e);
            }
            Err(_) => {
                let _ = thread.join();
                return Err(DdsError::Setup("the DDS thread died while starting".into()));
            }
        };
        let link = DdsLink {
            shared,
            waker,
            thread: Some(thread),
            endpoint: endpoint.clone(),
            topics,
        };
        std::thread::sleep(discovery);
        if refuse_other_writers {
            if let Some(other) = link.other_writer() {
                return Err(DdsError::OtherWriter {
                    topic: link.topics.write_topic,
                    endpoint: link.endpoint.clone(),
                    writer: other,
                });
            }
        }
        Ok(link)
    }

    pub fn endpoint(&self) -> &Endpoint {
        &self.endpoint
    }

    pub fn topics(&self) -> &Topics {
        &self.topics
    }

    /// Waits until a sample newer than `seen` is in the inbox, or `timeout`. On arrival, copies it
    /// into `out` (up to its length) and returns `(seq, true length)`. Allocation-free.
    pub fn wait_newer(&self, seen: u64, timeout: Duration, out: &mut [u8]) -> Result<Option<(u64, usize)>, DdsError> {
        let deadline = Instant::now() + timeout;
        let mut inbox = lock(&self.shared.inbox);
        loop {
            if inbox.seq > seen {
                let n = inbox.len.min(out.len()).min(inbox.bytes.len());
                out[..n].copy_from_slice(&inbox.bytes[..n]);
                return Ok(Some((inbox.seq, inbox.len)));
            }
            if let Some(why) = self.failed() {
                return Err(DdsError::Thread(why));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            inbox = self
                .shared
                .arrived
                .wait_timeout(inbox, deadline - now)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    /// Hands `sample` (header included) to the transport thread for writing. Allocation-free.
    pub fn send(&self, sample: &[u8]) -> Result<(), DdsError> {
        if let Some(why) = self.failed() {
            return Err(DdsError::Thread(why));
        }
        {
            let mut out = lock(&self.shared.outbox);
            let n = sample.len().min(out.bytes.len());
            out.bytes[..n].copy_from_slice(&sample[..n]);
            out.len = n;
            out.seq += 1;
        }
        self.waker
            .wake()
            .map_err(|e| DdsError::Thread(format!("cannot wake the DDS thread: {e}")))
    }

    /// Another participant's writer on our write topic, if one is seen now.
    pub fn other_writer(&self) -> Option<String> {
        if self.other_writers_now() == 0 {
            return None;
        }
        lock(&self.shared.other_writer).clone()
    }

    /// How many other participants' writers on our write topic discovery knows now (allocation-free).
    pub fn other_writers_now(&self) -> u64 {
        self.shared.other_writers_now.load(Ordering::Relaxed)
    }

    pub fn counters(&self) -> LinkCounters {
        let s = &self.shared;
        LinkCounters {
            samples_in: s.samples_in.load(Ordering::Relaxed),
            samples_out: s.samples_out.load(Ordering::Relaxed),
            coalesced: s.coalesced.load(Ordering::Relaxed),
            write_errors: s.write_errors.load(Ordering::Relaxed),
            read_errors: s.read_errors.load(Ordering::Relaxed),
            other_writers: s.other_writers_max.load(Ordering::Relaxed),
        }
    }

    fn failed(&self) -> Option<String> {
        lock(&self.shared.thread_failed).clone()
    }
}

impl Drop for DdsLink {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        let _ = self.waker.wake();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn reader_qos() -> QosPolicies {
    // Matches any writer (a BEST_EFFORT reader accepts RELIABLE and BEST_EFFORT writers).
    QosPolicyBuilder::new()
        .reliability(Reliability::BestEffort)
        .history(History::KeepLast { depth: 1 })
        .build()
}

fn writer_qos() -> QosPolicies {
    // Matches any reader (RELIABLE offers what BEST_EFFORT and RELIABLE readers ask).
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        })
        .history(History::KeepLast { depth: 1 })
        .build()
}

type Reader = DataReader<CdrSample, RawCdr>;
type Writer = DataWriter<CdrSample, RawCdr>;

fn setup(
    endpoint: &Endpoint,
    topics: &Topics,
    ip: IpAddr,
) -> Result<(rustdds::DomainParticipant, Reader, Writer, Poll, Arc<Waker>), DdsError> {
    let dds = |what: &str, e: &dyn std::fmt::Display| DdsError::Setup(format!("{what} on {endpoint}: {e}"));
    let participant = DomainParticipantBuilder::new(endpoint.domain)
        .with_only_networks([ip])
        .build()
        .map_err(|e| dds("creating the DDS participant", &e))?;
    let rq = reader_qos();
    let wq = writer_qos();
    let read_topic = participant
        .create_topic(topics.read_topic.into(), topics.read_type.into(), &rq, TopicKind::NoKey)
        .map_err(|e| dds("creating the topic", &e))?;
    let write_topic = participant
        .create_topic(
            topics.write_topic.into(),
            topics.write_type.into(),
            &wq,
            TopicKind::NoKey,
        )
        .map_err(|e| dds("creating the topic", &e))?;
    let subscriber = participant
        .create_subscriber(&rq)
        .map_err(|e| dds("creating a subscriber", &e))?;
    let publisher = participant
        .create_publisher(&wq)
        .map_err(|e| dds("creating a publisher", &e))?;
    let mut reader = subscriber
        .create_datareader_no_key::<CdrSample, RawCdr>(&read_topic, Some(rq))
        .map_err(|e| dds("creating the reader", &e))?;
    let writer = publisher
        .create_datawriter_no_key::<CdrSample, RawCdr>(&write_topic, Some(wq))
        .map_err(|e| dds("creating the writer", &e))?;
    let poll = Poll::new().map_err(|e| dds("creating a poller", &e))?;
    let waker = Arc::new(Waker::new(poll.registry(), WAKE).map_err(|e| dds("creating a waker", &e))?);
    poll.registry()
        .register(&mut reader, READ, Interest::READABLE)
        .map_err(|e| dds("registering the reader", &e))?;
    Ok((participant, reader, writer, poll, waker))
}

fn transport(
    shared: Arc<Shared>,
    endpoint: Endpoint,
    topics: Topics,
    ip: IpAddr,
    ready: std::sync::mpsc::Sender<Result<Arc<Waker>, DdsError>>,
) {
    let (participant, mut reader, writer, mut poll, waker) = match setup(&endpoint, &topics, ip) {
        Ok(s) => s,
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    let _ = ready.send(Ok(waker));
    let own_prefix = participant.guid().prefix;
    let mut events = Events::with_capacity(16);
    let mut sent_seq = 0u64;
    let mut next_discovery_check = Instant::now();
    let fail = |why: String| {
        *lock(&shared.thread_failed) = Some(why);
        shared.arrived.notify_all();
    };
    while !shared.stop.load(Ordering::Relaxed) {
        if let Err(e) = poll.poll(&mut events, Some(Duration::from_millis(50))) {
            if e.kind() != std::io::ErrorKind::Interrupted {
                fail(format!("polling DDS: {e}"));
                return;
            }
        }
        loop {
            match reader.take_next_sample() {
                Ok(Some(s)) => {
                    let v = s.into_value();
                    let mut inbox = lock(&shared.inbox);
                    let n = v.0.len().min(inbox.bytes.len());
                    inbox.bytes[..n].copy_from_slice(&v.0[..n]);
                    inbox.len = v.0.len();
                    inbox.seq += 1;
                    drop(inbox);
                    shared.samples_in.fetch_add(1, Ordering::Relaxed);
                    shared.arrived.notify_all();
                }
                Ok(None) => break,
                Err(_) => {
                    shared.read_errors.fetch_add(1, Ordering::Relaxed);
                    break;
                }
            }
        }
        let pending = {
            let out = lock(&shared.outbox);
            (out.seq != sent_seq).then(|| {
                shared.coalesced.fetch_add(out.seq - sent_seq - 1, Ordering::Relaxed);
                sent_seq = out.seq;
                CdrSample(out.bytes[..out.len].to_vec())
            })
        };
        if let Some(sample) = pending {
            match writer.write(sample, None) {
                Ok(()) => shared.samples_out.fetch_add(1, Ordering::Relaxed),
                Err(_) => shared.write_errors.fetch_add(1, Ordering::Relaxed),
            };
        }
        if Instant::now() >= next_discovery_check {
            next_discovery_check = Instant::now() + DISCOVERY_CHECK;
            let others: Vec<String> = participant
                .discovered_writers()
                .iter()
                .filter(|w| {
                    w.publication_topic_data.topic_name == topics.write_topic
                        && w.writer_proxy.remote_writer_guid.prefix != own_prefix
                })
                .map(|w| format!("{:?}", w.writer_proxy.remote_writer_guid))
                .collect();
            shared.other_writers_now.store(others.len() as u64, Ordering::Relaxed);
            shared
                .other_writers_max
                .fetch_max(others.len() as u64, Ordering::Relaxed);
            if let Some(first) = others.first() {
                let mut slot = lock(&shared.other_writer);
                if slot.is_none() {
                    *slot = Some(first.clone());
                }
            }
        }
    }
}
