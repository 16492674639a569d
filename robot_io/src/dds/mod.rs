//! The G1's own low-level interface: unitree_hg `LowState_` on `rt/lowstate` (robot → us) and
//! `LowCmd_` on `rt/lowcmd` (us → robot), over DDS as unitree_sdk2 speaks it (CycloneDDS 0.10.2,
//! XCDR1, domain 0 on the robot's Ethernet port; unitree_mujoco uses domain 1 on `lo`).
//!
//! Library: `rustdds` (pure Rust). Chosen on evidence (`../shared/facts/g1_dds.md`): it exchanged
//! `rt/lowcmd` samples intact both ways with CycloneDDS 0.10.2, where `dust_dds` 0.16 delivered
//! nothing in either direction (it stalls on an XTypes type lookup); `cyclors` would build
//! CycloneDDS 11 from C behind an unsafe API. Here it is tested against Debian's CycloneDDS 0.10.2
//! (`tests/tests/dds_peer.rs`).
//!
//! QoS: our reader is BEST_EFFORT / KEEP_LAST 1 and our writer RELIABLE / KEEP_LAST 1, a pair that
//! matches any peer. The library runs on [`DdsLink`]'s thread; the control thread only copies
//! bytes in and out of fixed buffers ([`DdsHal`]), so the tick allocates nothing.
mod hal_impl;
mod link;
mod raw;

pub use hal_impl::{DdsHal, DdsHalConfig, DdsHalCounters, JitterSummary, Pace, PeriodJitter};
pub use link::{interface_address, DdsLink, Endpoint, LinkCounters, Topics, SAMPLE_CAP};
pub use raw::{CdrSample, RawCdr};

use sensor_io::unitree_hg::cdr::CdrError;
use sensor_io::unitree_hg::DecodeError;

pub const LOW_STATE_TOPIC: &str = "rt/lowstate";
pub const LOW_CMD_TOPIC: &str = "rt/lowcmd";
/// Type names as unitree_sdk2 registers them (keyless, @final).
pub const LOW_STATE_TYPE: &str = "unitree_hg::msg::dds_::LowState_";
pub const LOW_CMD_TYPE: &str = "unitree_hg::msg::dds_::LowCmd_";
/// The robot's domain; unitree_mujoco's default is 1 (on `lo`).
pub const ROBOT_DOMAIN: u16 = 0;

/// The controller's side: reads the state, writes commands.
pub const CONTROLLER: Topics = Topics {
    read_topic: LOW_STATE_TOPIC,
    read_type: LOW_STATE_TYPE,
    write_topic: LOW_CMD_TOPIC,
    write_type: LOW_CMD_TYPE,
};

/// The robot's side (the G1, unitree_mujoco, `g1-sim --dds`): reads commands, writes the state.
pub const ROBOT: Topics = Topics {
    read_topic: LOW_CMD_TOPIC,
    read_type: LOW_CMD_TYPE,
    write_topic: LOW_STATE_TOPIC,
    write_type: LOW_STATE_TYPE,
};

#[derive(Debug, thiserror::Error)]
pub enum DdsError {
    #[error("DDS: network interface '{interface}': {why}")]
    Interface { interface: String, why: String },
    #[error("DDS: {0}")]
    Setup(String),
    #[error("DDS: the transport thread stopped: {0}")]
    Thread(String),
    #[error(
        "DDS: another program publishes {topic} on {endpoint} (writer {writer}): two programs commanding \
         the same motors fight each other. Stop it first (on the robot: release the sport service with \
         MotionSwitcher ReleaseMode, and stop any other low-level controller)"
    )]
    OtherWriter {
        topic: &'static str,
        endpoint: Endpoint,
        writer: String,
    },
    #[error("DDS: no {topic} sample for {waited_ms} ms on {endpoint}; {hint}")]
    Timeout {
        topic: &'static str,
        waited_ms: u64,
        endpoint: Endpoint,
        hint: &'static str,
    },
    #[error("DDS: stopped by a signal while waiting for the first {topic} sample")]
    Stopped { topic: &'static str },
    #[error(transparent)]
    Cdr(#[from] CdrError),
    #[error(transparent)]
    Decode(#[from] DecodeError),
}

impl hal::Error for DdsError {
    fn kind(&self) -> hal::ErrorKind {
        match self {
            DdsError::Interface { .. }
            | DdsError::Setup(_)
            | DdsError::OtherWriter { .. }
            | DdsError::Stopped { .. } => hal::ErrorKind::Other,
            DdsError::Thread(_) => hal::ErrorKind::Disconnected,
            DdsError::Timeout { .. } => hal::ErrorKind::Timeout,
            DdsError::Cdr(e) => e.kind(),
            DdsError::Decode(e) => e.kind(),
        }
    }
}
