//! Channel names, schemas and message encodings of a g1fw MCAP log.
//!
//! HAL frames travel as ROS 2 CDR with `ros2msg` schemas: raw bytes stay raw (replay decodes them
//! with the same codec as the HAL did, fast), and Foxglove and `mcap-ros2-support` decode them. The
//! raw lidar frames the perception group consumed (`/lidar/frame`) travel the same way, as plain
//! little-endian columns, so replay feeds back bit-identical points.
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
/// The raw lidar frame each perception step with a fresh frame consumed (sensor frame, exact bits;
/// [`LIDAR_FRAME_MSG`]). Replay feeds it back on the same tick.
pub const LIDAR_FRAME: &str = "/lidar/frame";
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

/// Schema name of [`LIDAR_FRAME`] (`ros2msg`, message encoding `cdr`).
pub const LIDAR_FRAME_SCHEMA: &str = "g1fw/msg/LidarFrame";

/// [`LIDAR_FRAME`]'s message definition. The CDR bytes (XCDR1, little endian, after the 4-byte
/// encapsulation header `00 01 00 00`; offsets from the end of that header):
///
/// | offset | bytes | field |
/// |---|---|---|
/// | 0 | 8 | `tick`: u64, the control tick whose perception step consumed the frame |
/// | 8 | 8 | `timestamp_ns`: u64, frame start on the HAL's time base |
/// | 16 | 4 | `overflow`: u32, returns that did not fit the frame buffer (not stored) |
/// | 20 | 4 + 4n | `x`: u32 count n, then n f32 (sensor frame, m, exact bit patterns) |
/// | … | 4 + 4n | `y`, then `z`: the same |
/// | … | 4 + 4n | `offset_ns`: u32 count n, then n u32 (firing time after `timestamp_ns`) |
/// | … | 4 + n | `reflectivity`: u32 count n, then n u8 |
/// | … | pad + 4 + n | `tag`: zero padding to a multiple of 4, u32 count n, then n u8 |
///
/// Every column has the same count n (the frame's point count, at most the frame capacity); the
/// message is `4 + 20 + 4·(4 + 4n) + 2·(4 + n) + pad` bytes, about 18 bytes per point.
pub const LIDAR_FRAME_MSG: &str = "\
# One lidar frame exactly as the perception group consumed it (g1fw replay feeds it back).
uint64 tick            # control tick of the perception step that consumed the frame
uint64 timestamp_ns    # frame start on the HAL's time base, ns
uint32 overflow        # returns that did not fit the frame buffer (not stored)
float32[] x            # sensor frame, m; all six columns hold one entry per point
float32[] y
float32[] z
uint32[] offset_ns     # firing time after timestamp_ns, ns
uint8[] reflectivity
uint8[] tag
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
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"back_tick":{"type":"integer"},"late":{"type":"boolean"},"class":{"type":"string"},"step_height_m":{"type":"number"},"step_depth_m":{"type":"number"},"yaw_deg":{"type":"number"},"source":{"type":"string"},"held":{"type":"boolean"},"geometric":{"type":"object"},"points":{"type":"integer"},"bev":{"type":"object"},"base_height_m":{"type":"number"},"roll":{"type":"number"},"pitch":{"type":"number"}}}"#,
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
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"vx":{"type":"number"},"vy":{"type":"number"},"wz":{"type":"number"},"received":{"type":"array","items":{"type":"number"}},"estop":{"type":"boolean"},"reset":{"type":"boolean"},"request":{"type":"string"}}}"#,
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
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"mode":{"type":"string"},"reason":{"type":"string"},"frame":{"type":"integer"},"crc_failures":{"type":"integer"},"crc_streak":{"type":"integer"},"missing_frames":{"type":"integer"},"stale_frames":{"type":"integer"},"state_age_ticks":{"type":"integer"},"clamped_targets":{"type":"integer"},"envelope_range_clamps":{"type":"integer"},"envelope_violations":{"type":"integer"},"dropped_log_records":{"type":"integer"}}}"#,
    ),
    (
        SAFETY_EVENT,
        "g1fw.SafetyEvent",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"time_s":{"type":"number"},"event":{"type":"string"},"reason":{"type":"string"},"joint":{"type":"string"},"detail":{"type":"string"}}}"#,
    ),
    (
        TIMING,
        "g1fw.TickTiming",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"fast_ns":{"type":"integer"},"perception_ns":{"type":"integer"},"policy_ns":{"type":"integer"},"overruns":{"type":"integer"}}}"#,
    ),
    (
        TRUTH,
        "g1fw.SimTruth",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"base_pos":{"type":"object"},"base_quat":{"type":"object"},"lin_vel_body":{"type":"object"},"ang_vel_body":{"type":"object"},"foot_contact":{"type":"array","items":{"type":"boolean"}},"stairs":{"type":"object","properties":{"axis_s":{"type":"number"},"risers":{"type":"integer"},"risers_passed":{"type":"integer"},"on_end_landing":{"type":"boolean"}}}}}"#,
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

/// Encodes a [`LIDAR_FRAME`] message (layout at [`LIDAR_FRAME_MSG`]) into `out` (cleared first;
/// reused across frames, it stops growing after the largest one).
pub fn encode_lidar_frame<const CAP: usize>(out: &mut Vec<u8>, tick: u64, frame: &hal::PointFrame<CAP>) {
    let pts = frame.as_slice();
    let n = pts.len() as u32;
    out.clear();
    out.extend_from_slice(&CDR_LE);
    out.extend_from_slice(&tick.to_le_bytes());
    out.extend_from_slice(&frame.timestamp_ns.to_le_bytes());
    out.extend_from_slice(&(frame.overflow.min(u32::MAX as usize) as u32).to_le_bytes());
    for axis in 0..3 {
        out.extend_from_slice(&n.to_le_bytes());
        for p in pts {
            out.extend_from_slice(&p.xyz[axis].to_bits().to_le_bytes());
        }
    }
    out.extend_from_slice(&n.to_le_bytes());
    for p in pts {
        out.extend_from_slice(&p.offset_ns.to_le_bytes());
    }
    out.extend_from_slice(&n.to_le_bytes());
    out.extend(pts.iter().map(|p| p.reflectivity));
    // CDR aligns the next sequence length to 4 (relative to the end of the encapsulation header).
    while !(out.len() - CDR_LE.len()).is_multiple_of(4) {
        out.push(0);
    }
    out.extend_from_slice(&n.to_le_bytes());
    out.extend(pts.iter().map(|p| p.tag));
}

/// Why a [`LIDAR_FRAME`] message does not decode.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LidarFrameError {
    #[error("shorter than its header or its columns say ({len} bytes)")]
    Short { len: usize },
    #[error("not little-endian CDR")]
    Encapsulation,
    #[error("column {column} holds {got} points, column x {expected}")]
    Columns {
        column: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{n} points, more than the frame buffer holds ({cap})")]
    TooMany { n: usize, cap: usize },
    #[error("{extra} bytes after the last column")]
    Trailing { extra: usize },
}

/// The fixed part of a [`LIDAR_FRAME`] message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LidarFrameHeader {
    pub tick: u64,
    pub timestamp_ns: u64,
    pub overflow: u32,
    pub points: usize,
}

/// Decodes a [`LIDAR_FRAME`] message into `out` (points beyond the count are left as they were, as
/// a HAL leaves them). Checks every length before writing; on error `out` is unchanged.
pub fn decode_lidar_frame<const CAP: usize>(
    msg: &[u8],
    out: &mut hal::PointFrame<CAP>,
) -> Result<LidarFrameHeader, LidarFrameError> {
    let b = msg.strip_prefix(&CDR_LE).ok_or(if msg.len() < 4 {
        LidarFrameError::Short { len: msg.len() }
    } else {
        LidarFrameError::Encapsulation
    })?;
    let short = LidarFrameError::Short { len: msg.len() };
    if b.len() < 24 {
        return Err(short);
    }
    let h = LidarFrameHeader {
        tick: u64_at(b, 0),
        timestamp_ns: u64_at(b, 8),
        overflow: u32::from_le_bytes(b[16..20].try_into().expect("4 bytes")),
        points: u32::from_le_bytes(b[20..24].try_into().expect("4 bytes")) as usize,
    };
    let n = h.points;
    if n > CAP {
        return Err(LidarFrameError::TooMany { n, cap: CAP });
    }
    // Column offsets, each checked before anything is written.
    let col = |at: usize, name: &'static str, elem: usize| -> Result<usize, LidarFrameError> {
        let got = u32::from_le_bytes(b.get(at..at + 4).ok_or(short.clone())?.try_into().expect("4 bytes")) as usize;
        if got != n {
            return Err(LidarFrameError::Columns {
                column: name,
                expected: n,
                got,
            });
        }
        if b.len() < at + 4 + n * elem {
            return Err(short.clone());
        }
        Ok(at + 4)
    };
    let x = col(20, "x", 4)?;
    let y = col(x + 4 * n, "y", 4)?;
    let z = col(y + 4 * n, "z", 4)?;
    let off = col(z + 4 * n, "offset_ns", 4)?;
    let refl = col(off + 4 * n, "reflectivity", 1)?;
    let tag = col((refl + n).next_multiple_of(4), "tag", 1)?;
    if b.len() != tag + n {
        return Err(LidarFrameError::Trailing {
            extra: b.len() - (tag + n),
        });
    }
    let f = |at: usize, i: usize| {
        f32::from_bits(u32::from_le_bytes(
            b[at + 4 * i..at + 4 * i + 4].try_into().expect("4 bytes"),
        ))
    };
    for (i, p) in out.points[..n].iter_mut().enumerate() {
        *p = hal::LidarPoint {
            xyz: [f(x, i), f(y, i), f(z, i)],
            reflectivity: b[refl + i],
            tag: b[tag + i],
            offset_ns: u32::from_le_bytes(b[off + 4 * i..off + 4 * i + 4].try_into().expect("4 bytes")),
        };
    }
    out.len = n;
    out.timestamp_ns = h.timestamp_ns;
    out.overflow = h.overflow as usize;
    Ok(h)
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

    fn test_frame() -> Box<hal::PointFrame<64>> {
        let mut f = Box::new(hal::PointFrame::<64>::new());
        f.clear(123_456_789_012);
        f.overflow = 3;
        // Bit patterns a decimal round trip would lose: NaN payloads, -0, subnormals, infinities.
        let specials = [
            f32::from_bits(0x7fc0_1234),
            -0.0,
            f32::from_bits(1),
            f32::NEG_INFINITY,
            0.1,
            -1.5e30,
        ];
        for i in 0..(7 + specials.len()) {
            let v = |k: usize| specials.get((i + k) % 11).copied().unwrap_or(i as f32 * 0.37 - 1.0);
            f.push(hal::LidarPoint {
                xyz: [v(0), v(1), v(2)],
                reflectivity: (i * 17) as u8,
                tag: (i * 3) as u8,
                offset_ns: (i as u32) * 97_000 + 5,
            });
        }
        f
    }

    #[test]
    fn lidar_frames_round_trip_bit_exact() {
        let f = test_frame();
        let mut v = Vec::new();
        encode_lidar_frame(&mut v, 4200, &f);
        let n = f.len;
        assert_eq!(
            v.len(),
            4 + 20 + 4 * (4 + 4 * n) + 4 + n + (4 - (4 + n) % 4) % 4 + 4 + n
        );
        let mut g = Box::new(hal::PointFrame::<64>::new());
        let h = decode_lidar_frame(&v, &mut g).unwrap();
        assert_eq!(
            h,
            LidarFrameHeader {
                tick: 4200,
                timestamp_ns: 123_456_789_012,
                overflow: 3,
                points: n
            }
        );
        assert_eq!((g.len, g.timestamp_ns, g.overflow), (f.len, f.timestamp_ns, f.overflow));
        assert_same_bits(f.as_slice(), g.as_slice());
        // Every length of the padding before `tag` round-trips, an empty frame included.
        for len in 0..5 {
            let mut e = test_frame();
            e.len = len;
            encode_lidar_frame(&mut v, 1, &e);
            assert_eq!(decode_lidar_frame(&v, &mut g).unwrap().points, len);
            assert_same_bits(e.as_slice(), g.as_slice());
        }
    }

    fn assert_same_bits(a: &[hal::LidarPoint], b: &[hal::LidarPoint]) {
        assert_eq!(a.len(), b.len());
        for (p, q) in a.iter().zip(b) {
            assert_eq!(p.xyz.map(f32::to_bits), q.xyz.map(f32::to_bits));
            assert_eq!(
                (p.reflectivity, p.tag, p.offset_ns),
                (q.reflectivity, q.tag, q.offset_ns)
            );
        }
    }

    #[test]
    fn bad_lidar_frames_are_refused_and_leave_the_frame_alone() {
        let f = test_frame();
        let mut v = Vec::new();
        encode_lidar_frame(&mut v, 7, &f);
        let mut g = Box::new(hal::PointFrame::<64>::new());
        g.clear(99);
        let untouched = |g: &hal::PointFrame<64>| g.len == 0 && g.timestamp_ns == 99;
        // Too many points for a smaller buffer.
        let mut small = Box::new(hal::PointFrame::<4>::new());
        assert_eq!(
            decode_lidar_frame(&v, &mut small),
            Err(LidarFrameError::TooMany { n: f.len, cap: 4 })
        );
        // Cut anywhere: short, never a panic.
        for cut in [0, 3, 10, 27, v.len() / 2, v.len() - 1] {
            assert!(decode_lidar_frame(&v[..cut], &mut g).is_err(), "cut at {cut}");
            assert!(untouched(&g));
        }
        let mut extra = v.clone();
        extra.push(0);
        assert_eq!(
            decode_lidar_frame(&extra, &mut g),
            Err(LidarFrameError::Trailing { extra: 1 })
        );
        let mut big_endian = v.clone();
        big_endian[1] = 0;
        assert_eq!(
            decode_lidar_frame(&big_endian, &mut g),
            Err(LidarFrameError::Encapsulation)
        );
        // A column whose count disagrees with x's.
        let mut cols = v.clone();
        let y_count = 4 + 24 + 4 * f.len;
        cols[y_count] ^= 1;
        assert!(matches!(
            decode_lidar_frame(&cols, &mut g),
            Err(LidarFrameError::Columns { column: "y", .. })
        ));
        assert!(untouched(&g));
    }
}
