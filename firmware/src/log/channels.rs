//! Channel names, schemas and message encodings of a g1fw MCAP log.
//!
//! HAL frames travel as ROS 2 CDR with `ros2msg` schemas: raw bytes stay raw (replay decodes them
//! with the same codec as the HAL did, fast), and Foxglove and `mcap-ros2-support` decode them.
//! Derived products are JSON with JSON Schemas, which Foxglove plots directly.

pub const LOW_STATE: &str = "/hal/low_state";
pub const LOW_CMD: &str = "/hal/low_cmd";
pub const HAL_EVENT: &str = "/hal/event";
pub const OPERATOR: &str = "/operator/command";
pub const OBSERVATION: &str = "/policy/observation";
pub const ACTION: &str = "/policy/action";
pub const ESTIMATOR: &str = "/estimator/state";
pub const SAFETY_STATE: &str = "/safety/state";
pub const SAFETY_EVENT: &str = "/safety/event";
pub const TIMING: &str = "/timing/tick";
pub const TRUTH: &str = "/sim/truth";
pub const LIDAR_POINTS: &str = "/lidar/points";
pub const PERCEPTION_BEV: &str = "/perception/bev";
pub const PERCEPTION_TERRAIN: &str = "/perception/terrain";
pub const TRUTH_TERRAIN: &str = "/truth/terrain";
/// Frame id of the gravity-aligned robot frame the cloud and the grid are drawn in.
pub const ROBOT_FRAME_ID: &str = "g1_gravity_aligned";

/// Name of the MCAP metadata record that pins the run (spec, weights, options).
pub const RUN_METADATA: &str = "g1fw.run";

pub const LOW_STATE_MSG: &str = "\
# One tick's LowState as the HAL received it.
uint64 tick        # control tick index
uint64 time_ns     # tick time (simulation time in sim), ns
uint8 status       # 0 fresh, 1 no frame, 2 disconnected, 3 timeout, 4 malformed, 5 crc, 6 non-finite, 7 other
bool received      # a frame arrived (possibly bad); false: nothing arrived this tick
uint8[] data       # unitree_hg LowState_ wire bytes (2092), empty when nothing arrived
";

pub const LOW_CMD_MSG: &str = "\
# One tick's LowCmd as the firmware produced it.
uint64 tick
uint64 time_ns
bool sent          # handed to the HAL (false on the final tick of a run)
uint8[] data       # unitree_hg LowCmd_ wire bytes (1004)
";

const FOXGLOVE_COMMON: &str = r#""timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"},"pose":{"type":"object","properties":{"position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"orientation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}},"fields":{"type":"array","items":{"type":"object","properties":{"name":{"type":"string"},"offset":{"type":"integer"},"type":{"type":"integer"}}}},"data":{"type":"string","contentEncoding":"base64"}"#;

/// Foxglove's `foxglove.PointCloud` (x, y, z, intensity as float32) in JSON.
pub fn point_cloud_schema() -> String {
    format!(r#"{{"type":"object","properties":{{{FOXGLOVE_COMMON},"point_stride":{{"type":"integer"}}}}}}"#)
}

/// Foxglove's `foxglove.Grid` (the six BEV channels as float32 fields) in JSON.
pub fn grid_schema() -> String {
    format!(
        r#"{{"type":"object","properties":{{{FOXGLOVE_COMMON},"column_count":{{"type":"integer"}},"cell_size":{{"type":"object","properties":{{"x":{{"type":"number"}},"y":{{"type":"number"}}}}}},"row_stride":{{"type":"integer"}},"cell_stride":{{"type":"integer"}}}}}}"#
    )
}

/// `(topic, schema name, JSON Schema)` of every JSON channel.
pub const JSON_CHANNELS: &[(&str, &str, &str)] = &[
    (
        PERCEPTION_TERRAIN,
        "g1fw.TerrainEstimate",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"class":{"type":"string"},"step_height_m":{"type":"number"},"step_depth_m":{"type":"number"},"yaw_deg":{"type":"number"},"source":{"type":"string"},"held":{"type":"boolean"},"geometric":{"type":"object"},"points":{"type":"integer"},"bev":{"type":"object"},"base_height_m":{"type":"number"},"roll":{"type":"number"},"pitch":{"type":"number"}}}"#,
    ),
    (
        TRUTH_TERRAIN,
        "g1fw.TerrainTruth",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"class":{"type":"string"},"step_height_m":{"type":"number"},"step_depth_m":{"type":"number"},"yaw_deg":{"type":"number"}}}"#,
    ),
    (
        HAL_EVENT,
        "g1fw.HalEvent",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"kind":{"type":"string"},"phase":{"type":"string"}}}"#,
    ),
    (
        OPERATOR,
        "g1fw.OperatorCommand",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"vx":{"type":"number"},"vy":{"type":"number"},"wz":{"type":"number"},"estop":{"type":"boolean"},"reset":{"type":"boolean"}}}"#,
    ),
    (
        OBSERVATION,
        "g1fw.Observation",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"values":{"type":"array","items":{"type":["number","null"]}}}}"#,
    ),
    (
        ACTION,
        "g1fw.Action",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"values":{"type":"array","items":{"type":["number","null"]}},"target_q":{"type":"array","items":{"type":"number"}}}}"#,
    ),
    (
        ESTIMATOR,
        "g1fw.EstimatorState",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"valid":{"type":"boolean"},"attitude_source":{"type":"string"},"projected_gravity":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"rpy":{"type":"object","properties":{"roll":{"type":"number"},"pitch":{"type":"number"},"yaw":{"type":"number"}}},"lin_vel_body":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"lin_vel_world":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"ang_vel_body":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"lin_vel_std":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"height":{"type":"number"},"height_std":{"type":"number"},"foot_left":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"foot_right":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"contact":{"type":"array","items":{"type":"boolean"}},"contact_force_n":{"type":"array","items":{"type":"number"}},"sole_height":{"type":"array","items":{"type":"number"}}}}"#,
    ),
    (
        SAFETY_STATE,
        "g1fw.SafetyState",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"mode":{"type":"string"},"reason":{"type":"string"},"frame":{"type":"integer"},"crc_failures":{"type":"integer"},"crc_streak":{"type":"integer"},"missing_frames":{"type":"integer"},"stale_frames":{"type":"integer"},"state_age_ticks":{"type":"integer"},"clamped_targets":{"type":"integer"},"dropped_log_records":{"type":"integer"}}}"#,
    ),
    (
        SAFETY_EVENT,
        "g1fw.SafetyEvent",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"time_s":{"type":"number"},"event":{"type":"string"},"reason":{"type":"string"},"joint":{"type":"string"}}}"#,
    ),
    (
        TIMING,
        "g1fw.TickTiming",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"fast_ns":{"type":"integer"},"perception_ns":{"type":"integer"},"policy_ns":{"type":"integer"},"overruns":{"type":"integer"}}}"#,
    ),
    (
        TRUTH,
        "g1fw.SimTruth",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"base_pos":{"type":"object"},"base_quat":{"type":"object"},"lin_vel_body":{"type":"object"},"ang_vel_body":{"type":"object"},"foot_contact":{"type":"array","items":{"type":"boolean"}}}}"#,
    ),
];

/// CDR (XCDR1, little endian) header.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Encodes a LowStateFrame message into `out` (cleared first).
pub fn encode_low_state_frame(out: &mut Vec<u8>, tick: u64, time_ns: u64, status: u8, received: bool, data: &[u8]) {
    out.clear();
    out.extend_from_slice(&CDR_LE);
    out.extend_from_slice(&tick.to_le_bytes());
    out.extend_from_slice(&time_ns.to_le_bytes());
    out.push(status);
    out.push(received as u8);
    out.extend_from_slice(&[0, 0]); // align the sequence length to 4
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(data);
}

/// Encodes a LowCmdFrame message into `out` (cleared first).
pub fn encode_low_cmd_frame(out: &mut Vec<u8>, tick: u64, time_ns: u64, sent: bool, data: &[u8]) {
    out.clear();
    out.extend_from_slice(&CDR_LE);
    out.extend_from_slice(&tick.to_le_bytes());
    out.extend_from_slice(&time_ns.to_le_bytes());
    out.push(sent as u8);
    out.extend_from_slice(&[0, 0, 0]);
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(data);
}

/// A decoded LowStateFrame (borrows the message bytes).
#[derive(Debug, PartialEq)]
pub struct LowStateFrame<'a> {
    pub tick: u64,
    pub time_ns: u64,
    pub status: u8,
    pub received: bool,
    pub data: &'a [u8],
}

/// A decoded LowCmdFrame.
#[derive(Debug, PartialEq)]
pub struct LowCmdFrame<'a> {
    pub tick: u64,
    pub time_ns: u64,
    pub sent: bool,
    pub data: &'a [u8],
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

fn seq_at(b: &[u8], at: usize) -> Option<&[u8]> {
    let n = u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?) as usize;
    b.get(at + 4..at + 4 + n)
}

pub fn decode_low_state_frame(msg: &[u8]) -> Option<LowStateFrame<'_>> {
    let b = msg.strip_prefix(&CDR_LE)?;
    if b.len() < 20 {
        return None;
    }
    Some(LowStateFrame {
        tick: u64_at(b, 0),
        time_ns: u64_at(b, 8),
        status: b[16],
        received: b[17] != 0,
        data: seq_at(b, 20)?,
    })
}

pub fn decode_low_cmd_frame(msg: &[u8]) -> Option<LowCmdFrame<'_>> {
    let b = msg.strip_prefix(&CDR_LE)?;
    if b.len() < 20 {
        return None;
    }
    Some(LowCmdFrame {
        tick: u64_at(b, 0),
        time_ns: u64_at(b, 8),
        sent: b[16] != 0,
        data: seq_at(b, 20)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cdr_frames_round_trip() {
        let mut v = Vec::new();
        encode_low_state_frame(&mut v, 7, 14_000_000, 5, true, &[1, 2, 3]);
        assert_eq!(v.len(), 4 + 24 + 3);
        let f = decode_low_state_frame(&v).unwrap();
        assert_eq!(
            (f.tick, f.time_ns, f.status, f.received, f.data),
            (7, 14_000_000, 5, true, &[1u8, 2, 3][..])
        );
        encode_low_cmd_frame(&mut v, 9, 18, false, &[4; 10]);
        let c = decode_low_cmd_frame(&v).unwrap();
        assert_eq!((c.tick, c.time_ns, c.sent, c.data.len()), (9, 18, false, 10));
        assert!(decode_low_cmd_frame(&v[..10]).is_none());
        v.truncate(v.len() - 1);
        assert!(decode_low_cmd_frame(&v).is_none(), "short sequence");
    }
}
