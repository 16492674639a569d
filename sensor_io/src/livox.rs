//! Livox MID-360 point packets (Livox SDK2 `LivoxLidarEthernetPacket`, `#pragma pack(1)`,
//! little-endian) and a frame assembler that turns a stream of them into [`hal::PointFrame`]s.
//!
//! Header, 36 bytes:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | version, always [`VERSION`] (0) in SDK2; other values are rejected |
//! | 1 | u16 | length of the whole packet, header included |
//! | 3 | u16 | time_interval: time spanned by the packet, units of 0.1 µs |
//! | 5 | u16 | dot_num: points in the payload |
//! | 7 | u16 | udp_cnt: packet counter (gaps are lost packets) |
//! | 9 | u8 | frame_cnt |
//! | 10 | u8 | data_type: 0x00 IMU, 0x01 Cartesian high, 0x02 Cartesian low |
//! | 11 | u8 | time_type |
//! | 12 | u8\[12\] | reserved (written as zero, ignored on decode) |
//! | 24 | u32 | crc32: CRC-32/ISO-HDLC over bytes 28..length (timestamp + payload) |
//! | 28 | u64 | timestamp, ns |
//!
//! Payloads: Cartesian high `i32 x, y, z` (mm) + `u8 reflectivity` + `u8 tag` (14 bytes per point);
//! Cartesian low `i16 x, y, z` (cm) + reflectivity + tag (8 bytes); IMU `6 × f32` (gyro rad/s,
//! accelerometer g). Point `i` lies `i * time_interval * 100 / dot_num` ns after the packet's
//! timestamp.
//!
//! Decoding checks, in order: length (at least a header, and exactly the header's `length`), header
//! consistency (version, data type, `dot_num` against the payload size), CRC, payload (IMU values
//! finite). No input panics; every rejection is a [`LivoxError`].
//!
//! Returns closer than [`MIN_RANGE_M`] (the MID-360's minimum range; the sensor reports "no return"
//! as a zero point at the origin) are not valid measurements: [`Packet::points`] yields them as they
//! are on the wire, [`in_range`] tells them apart, and [`FrameAssembler`] drops and counts them.
use hal::{LidarPoint, PointFrame};

/// Header size, bytes.
pub const HEADER_LEN: usize = 36;
/// The only header version SDK2 sends.
pub const VERSION: u8 = 0;
pub const DATA_TYPE_IMU: u8 = 0x00;
pub const DATA_TYPE_CARTESIAN_HIGH: u8 = 0x01;
pub const DATA_TYPE_CARTESIAN_LOW: u8 = 0x02;
/// Payload bytes per Cartesian-high point.
pub const POINT_HIGH_LEN: usize = 14;
/// Payload bytes per Cartesian-low point.
pub const POINT_LOW_LEN: usize = 8;
/// Payload bytes per IMU sample.
pub const IMU_SAMPLE_LEN: usize = 24;
/// Points per Cartesian-high packet as the MID-360 sends them.
pub const MID360_POINTS_PER_PACKET: usize = 96;
/// Largest Cartesian-high point count that fits the u16 `length` field.
pub const MAX_POINTS_HIGH: usize = (u16::MAX as usize - HEADER_LEN) / POINT_HIGH_LEN;
/// Minimum valid range, m; closer returns (zero points included) are dropped by the assembler.
pub const MIN_RANGE_M: f32 = 0.1;
/// Nominal MID-360 point period, ns (about 200,000 points/s; [unverified], a parameter of
/// [`PacketWriter`]).
pub const MID360_POINT_PERIOD_NS: u32 = 5_000;

const OFF_LENGTH: usize = 1;
const OFF_TIME_INTERVAL: usize = 3;
const OFF_DOT_NUM: usize = 5;
const OFF_UDP_CNT: usize = 7;
const OFF_FRAME_CNT: usize = 9;
const OFF_DATA_TYPE: usize = 10;
const OFF_TIME_TYPE: usize = 11;
const OFF_CRC: usize = 24;
const OFF_TIMESTAMP: usize = 28;

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LivoxError {
    #[error("livox packet too short: {got} bytes, a header alone is {HEADER_LEN}")]
    TooShort { got: usize },
    #[error("livox packet length mismatch: header says {header} bytes, datagram has {got}")]
    LengthMismatch { header: u16, got: usize },
    #[error("livox packet version {0} unsupported (SDK2 sends {VERSION})")]
    Version(u8),
    #[error("livox packet data type {0:#04x} unknown (0x00 IMU, 0x01 Cartesian high, 0x02 Cartesian low)")]
    UnknownDataType(u8),
    #[error(
        "livox packet dot_num {dot_num} does not match the payload: {payload_len} bytes for data type {data_type:#04x}"
    )]
    DotCountMismatch {
        dot_num: u16,
        data_type: u8,
        payload_len: usize,
    },
    #[error("livox packet CRC mismatch: header says {expected:#010x}, contents give {got:#010x}")]
    Crc { expected: u32, got: u32 },
    #[error("livox IMU packet: non-finite value in sample {sample}, component {component}")]
    NonFinite { sample: usize, component: usize },
    #[error("livox encode: output buffer holds {got} bytes, the packet needs {need}")]
    BufferTooSmall { need: usize, got: usize },
    #[error("livox encode: {count} points per packet, at most {max} fit (and at least 1)")]
    PointCount { count: usize, max: usize },
}

impl hal::Error for LivoxError {
    fn kind(&self) -> hal::ErrorKind {
        match self {
            LivoxError::Crc { .. } => hal::ErrorKind::Checksum,
            LivoxError::NonFinite { .. } => hal::ErrorKind::NonFinite,
            LivoxError::BufferTooSmall { .. } | LivoxError::PointCount { .. } => hal::ErrorKind::Other,
            _ => hal::ErrorKind::Malformed,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// CRC-32/ISO-HDLC (zlib): reflected, poly 0x04C11DB7 (0xEDB88320 reflected), init and xorout
// 0xFFFFFFFF. Tables built at compile time.

const CRC_POLY_REFLECTED: u32 = 0xEDB8_8320;

const CRC_TABLES: [[u32; 256]; 16] = {
    let mut t = [[0u32; 256]; 16];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut b = 0;
        while b < 8 {
            c = if c & 1 != 0 {
                (c >> 1) ^ CRC_POLY_REFLECTED
            } else {
                c >> 1
            };
            b += 1;
        }
        t[0][i] = c;
        i += 1;
    }
    let mut k = 1;
    while k < 16 {
        let mut i = 0;
        while i < 256 {
            let prev = t[k - 1][i];
            t[k][i] = (prev >> 8) ^ t[0][(prev & 0xFF) as usize];
            i += 1;
        }
        k += 1;
    }
    t
};

/// Standard CRC-32 (ISO-HDLC / zlib / Ethernet) of `bytes`, as every Livox packet carries it.
/// `crc32fast` folds with the CPU's carry-less multiply (x86-64, detected at run time) or its CRC
/// instructions (aarch64), several times faster than [`crc32_table`] over a frame's ~290 KB; a CRC
/// is exact, so the result does not depend on which path runs.
pub fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

/// The same CRC-32 in portable code, slicing-by-16: `CRC_TABLES[k][b]` is byte `b` followed by `k`
/// zero bytes, so sixteen independent lookups replace a serial chain (about 1 byte/cycle). Kept as
/// the reference [`crc32`] is tested and benchmarked against.
pub fn crc32_table(bytes: &[u8]) -> u32 {
    let t = &CRC_TABLES;
    let mut crc = 0xFFFF_FFFFu32;
    let mut chunks = bytes.chunks_exact(16);
    for c in &mut chunks {
        let x = crc ^ u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        crc = t[15][(x & 0xFF) as usize]
            ^ t[14][((x >> 8) & 0xFF) as usize]
            ^ t[13][((x >> 16) & 0xFF) as usize]
            ^ t[12][(x >> 24) as usize]
            ^ t[11][c[4] as usize]
            ^ t[10][c[5] as usize]
            ^ t[9][c[6] as usize]
            ^ t[8][c[7] as usize]
            ^ t[7][c[8] as usize]
            ^ t[6][c[9] as usize]
            ^ t[5][c[10] as usize]
            ^ t[4][c[11] as usize]
            ^ t[3][c[12] as usize]
            ^ t[2][c[13] as usize]
            ^ t[1][c[14] as usize]
            ^ t[0][c[15] as usize];
    }
    for &b in chunks.remainder() {
        crc = (crc >> 8) ^ t[0][((crc ^ b as u32) & 0xFF) as usize];
    }
    !crc
}

// ---------------------------------------------------------------------------------------------
// Decoding

#[inline]
fn rd_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
#[inline]
fn rd_i16(b: &[u8], at: usize) -> i16 {
    i16::from_le_bytes([b[at], b[at + 1]])
}
#[inline]
fn rd_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}
#[inline]
fn rd_i32(b: &[u8], at: usize) -> i32 {
    rd_u32(b, at) as i32
}
#[inline]
fn rd_u64(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

/// The 36-byte header, as on the wire (reserved bytes dropped).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PacketHeader {
    pub version: u8,
    /// Whole packet, header included, bytes.
    pub length: u16,
    /// Time spanned by the packet, units of 0.1 µs.
    pub time_interval: u16,
    pub dot_num: u16,
    pub udp_cnt: u16,
    pub frame_cnt: u8,
    pub data_type: u8,
    pub time_type: u8,
    pub crc32: u32,
    pub timestamp_ns: u64,
}

impl PacketHeader {
    /// Payload bytes per point for this data type, `None` for an unknown type.
    pub fn point_size(&self) -> Option<usize> {
        point_size(self.data_type)
    }

    /// Offset of point `i` from the packet timestamp, ns: `i * time_interval * 100 / dot_num`.
    #[inline]
    pub fn point_offset_ns(&self, i: usize) -> u32 {
        if self.dot_num == 0 {
            return 0;
        }
        let ns = i as u64 * self.time_interval as u64 * 100 / self.dot_num as u64;
        ns.min(u32::MAX as u64) as u32
    }
}

fn point_size(data_type: u8) -> Option<usize> {
    match data_type {
        DATA_TYPE_IMU => Some(IMU_SAMPLE_LEN),
        DATA_TYPE_CARTESIAN_HIGH => Some(POINT_HIGH_LEN),
        DATA_TYPE_CARTESIAN_LOW => Some(POINT_LOW_LEN),
        _ => None,
    }
}

/// Parses the header fields without checking them against each other or the payload (only that
/// `buf` holds a header).
pub fn decode_header(buf: &[u8]) -> Result<PacketHeader, LivoxError> {
    if buf.len() < HEADER_LEN {
        return Err(LivoxError::TooShort { got: buf.len() });
    }
    Ok(PacketHeader {
        version: buf[0],
        length: rd_u16(buf, OFF_LENGTH),
        time_interval: rd_u16(buf, OFF_TIME_INTERVAL),
        dot_num: rd_u16(buf, OFF_DOT_NUM),
        udp_cnt: rd_u16(buf, OFF_UDP_CNT),
        frame_cnt: buf[OFF_FRAME_CNT],
        data_type: buf[OFF_DATA_TYPE],
        time_type: buf[OFF_TIME_TYPE],
        crc32: rd_u32(buf, OFF_CRC),
        timestamp_ns: rd_u64(buf, OFF_TIMESTAMP),
    })
}

/// One IMU sample from an IMU packet.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuSample {
    /// rad/s.
    pub gyro: [f32; 3],
    /// g.
    pub acc: [f32; 3],
}

/// A validated packet: the header and a view of its payload (no copy).
#[derive(Debug, Clone, Copy)]
pub struct Packet<'a> {
    pub header: PacketHeader,
    payload: &'a [u8],
}

impl<'a> Packet<'a> {
    /// The payload bytes (`dot_num` records of the header's data type).
    pub fn payload(&self) -> &'a [u8] {
        self.payload
    }

    pub fn is_points(&self) -> bool {
        matches!(
            self.header.data_type,
            DATA_TYPE_CARTESIAN_HIGH | DATA_TYPE_CARTESIAN_LOW
        )
    }

    /// Every point on the wire, in metres, `offset_ns` relative to the packet timestamp; near and
    /// zero returns included (see [`in_range`]). Empty for an IMU packet.
    pub fn points(&self) -> Points<'a> {
        let (size, n) = match self.header.data_type {
            DATA_TYPE_CARTESIAN_HIGH => (POINT_HIGH_LEN, self.header.dot_num as usize),
            DATA_TYPE_CARTESIAN_LOW => (POINT_LOW_LEN, self.header.dot_num as usize),
            _ => (POINT_HIGH_LEN, 0),
        };
        let span_ns = self.header.time_interval as u64 * 100;
        let d = (n as u64).max(1);
        Points {
            payload: self.payload,
            size,
            i: 0,
            n,
            off_q: 0,
            off_r: 0,
            step_q: span_ns / d,
            step_r: span_ns % d,
        }
    }

    /// IMU samples (empty for a point packet).
    pub fn imu_samples(&self) -> impl Iterator<Item = ImuSample> + 'a {
        let data = if self.header.data_type == DATA_TYPE_IMU {
            self.payload
        } else {
            &[]
        };
        data.chunks_exact(IMU_SAMPLE_LEN).map(imu_sample)
    }
}

fn imu_sample(c: &[u8]) -> ImuSample {
    let f = |k: usize| f32::from_bits(rd_u32(c, 4 * k));
    ImuSample {
        gyro: [f(0), f(1), f(2)],
        acc: [f(3), f(4), f(5)],
    }
}

/// Iterator over a packet's points.
#[derive(Debug, Clone)]
pub struct Points<'a> {
    payload: &'a [u8],
    size: usize,
    i: usize,
    n: usize,
    // Offset of point i is floor(i·span / n): kept as quotient and remainder, advanced by the
    // quotient and remainder of span / n (no division per point).
    off_q: u64,
    off_r: u64,
    step_q: u64,
    step_r: u64,
}

impl Iterator for Points<'_> {
    type Item = LidarPoint;

    #[inline]
    fn next(&mut self) -> Option<LidarPoint> {
        if self.i >= self.n {
            return None;
        }
        let at = self.i * self.size;
        let c = self.payload.get(at..at + self.size)?;
        let offset_ns = self.off_q.min(u32::MAX as u64) as u32;
        self.i += 1;
        self.off_q += self.step_q;
        self.off_r += self.step_r;
        if self.off_r >= self.n as u64 {
            self.off_q += 1;
            self.off_r -= self.n as u64;
        }
        Some(if self.size == POINT_HIGH_LEN {
            LidarPoint {
                xyz: [
                    (rd_i32(c, 0) as f64 * 0.001) as f32,
                    (rd_i32(c, 4) as f64 * 0.001) as f32,
                    (rd_i32(c, 8) as f64 * 0.001) as f32,
                ],
                reflectivity: c[12],
                tag: c[13],
                offset_ns,
            }
        } else {
            LidarPoint {
                xyz: [
                    (rd_i16(c, 0) as f64 * 0.01) as f32,
                    (rd_i16(c, 2) as f64 * 0.01) as f32,
                    (rd_i16(c, 4) as f64 * 0.01) as f32,
                ],
                reflectivity: c[6],
                tag: c[7],
                offset_ns,
            }
        })
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.n.saturating_sub(self.i);
        (left, Some(left))
    }
}

impl ExactSizeIterator for Points<'_> {}

/// At least [`MIN_RANGE_M`] from the sensor (false for zero "no return" points).
#[inline]
pub fn in_range(p: &LidarPoint) -> bool {
    let [x, y, z] = p.xyz;
    x * x + y * y + z * z >= MIN_RANGE_M * MIN_RANGE_M
}

/// Validates `buf` as one packet and returns a view of it. Checks length → header consistency →
/// CRC → payload; never panics.
pub fn decode_packet(buf: &[u8]) -> Result<Packet<'_>, LivoxError> {
    let header = decode_header(buf)?;
    if header.length as usize != buf.len() {
        return Err(LivoxError::LengthMismatch {
            header: header.length,
            got: buf.len(),
        });
    }
    if header.version != VERSION {
        return Err(LivoxError::Version(header.version));
    }
    let size = point_size(header.data_type).ok_or(LivoxError::UnknownDataType(header.data_type))?;
    let payload = &buf[HEADER_LEN..];
    if header.dot_num as usize * size != payload.len() {
        return Err(LivoxError::DotCountMismatch {
            dot_num: header.dot_num,
            data_type: header.data_type,
            payload_len: payload.len(),
        });
    }
    let got = crc32(&buf[OFF_TIMESTAMP..]);
    if got != header.crc32 {
        return Err(LivoxError::Crc {
            expected: header.crc32,
            got,
        });
    }
    if header.data_type == DATA_TYPE_IMU {
        for (sample, c) in payload.chunks_exact(IMU_SAMPLE_LEN).enumerate() {
            let s = imu_sample(c);
            let all = [s.gyro[0], s.gyro[1], s.gyro[2], s.acc[0], s.acc[1], s.acc[2]];
            if let Some(component) = all.iter().position(|v| !v.is_finite()) {
                return Err(LivoxError::NonFinite { sample, component });
            }
        }
    }
    Ok(Packet { header, payload })
}

// ---------------------------------------------------------------------------------------------
// Encoding

/// The header fields an encoder chooses (the rest follow from the points).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PacketMeta {
    pub udp_cnt: u16,
    pub frame_cnt: u8,
    /// Packet timestamp, ns.
    pub timestamp_ns: u64,
    /// Time spanned by the packet, units of 0.1 µs.
    pub time_interval: u16,
    pub time_type: u8,
}

/// Packet size for `n` Cartesian-high points.
pub const fn cartesian_high_len(n: usize) -> usize {
    HEADER_LEN + n * POINT_HIGH_LEN
}

#[inline]
fn metres_to_mm(v: f32) -> i32 {
    // `as` saturates at the i32 range and maps NaN to 0 (a zero point, dropped as out of range).
    (v as f64 * 1000.0).round() as i32
}

/// Encodes `points` as one Cartesian-high packet into `out[..len]` and returns `len`. Coordinates
/// are rounded to whole millimetres and saturate at the i32 range; NaN becomes 0. The points'
/// `offset_ns` are not encoded (the wire spaces points evenly over `time_interval`). No allocation.
pub fn encode_cartesian_high(meta: &PacketMeta, points: &[LidarPoint], out: &mut [u8]) -> Result<usize, LivoxError> {
    if points.len() > MAX_POINTS_HIGH {
        return Err(LivoxError::PointCount {
            count: points.len(),
            max: MAX_POINTS_HIGH,
        });
    }
    let len = cartesian_high_len(points.len());
    if out.len() < len {
        return Err(LivoxError::BufferTooSmall {
            need: len,
            got: out.len(),
        });
    }
    let out = &mut out[..len];
    out[..HEADER_LEN].fill(0);
    out[0] = VERSION;
    out[OFF_LENGTH..OFF_LENGTH + 2].copy_from_slice(&(len as u16).to_le_bytes());
    out[OFF_TIME_INTERVAL..OFF_TIME_INTERVAL + 2].copy_from_slice(&meta.time_interval.to_le_bytes());
    out[OFF_DOT_NUM..OFF_DOT_NUM + 2].copy_from_slice(&(points.len() as u16).to_le_bytes());
    out[OFF_UDP_CNT..OFF_UDP_CNT + 2].copy_from_slice(&meta.udp_cnt.to_le_bytes());
    out[OFF_FRAME_CNT] = meta.frame_cnt;
    out[OFF_DATA_TYPE] = DATA_TYPE_CARTESIAN_HIGH;
    out[OFF_TIME_TYPE] = meta.time_type;
    out[OFF_TIMESTAMP..HEADER_LEN].copy_from_slice(&meta.timestamp_ns.to_le_bytes());
    for (p, c) in points.iter().zip(out[HEADER_LEN..].chunks_exact_mut(POINT_HIGH_LEN)) {
        for k in 0..3 {
            c[4 * k..4 * k + 4].copy_from_slice(&metres_to_mm(p.xyz[k]).to_le_bytes());
        }
        c[12] = p.reflectivity;
        c[13] = p.tag;
    }
    let crc = crc32(&out[OFF_TIMESTAMP..]);
    out[OFF_CRC..OFF_CRC + 4].copy_from_slice(&crc.to_le_bytes());
    Ok(len)
}

/// Splits frames of points into Cartesian-high packets of `points_per_packet` points (the last may
/// be shorter), the way the sensor streams them: `udp_cnt` counts packets (wrapping) across frames,
/// `frame_cnt` counts frames, packet timestamps advance by `point_period_ns` per point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PacketWriter {
    points_per_packet: usize,
    /// Time between consecutive points, ns.
    pub point_period_ns: u32,
    /// Counter of the next packet.
    pub udp_cnt: u16,
    /// Counter of the next frame.
    pub frame_cnt: u8,
}

impl Default for PacketWriter {
    fn default() -> Self {
        Self {
            points_per_packet: MID360_POINTS_PER_PACKET,
            point_period_ns: MID360_POINT_PERIOD_NS,
            udp_cnt: 0,
            frame_cnt: 0,
        }
    }
}

impl PacketWriter {
    /// [`MID360_POINTS_PER_PACKET`] points per packet, [`MID360_POINT_PERIOD_NS`] apart.
    pub fn new() -> Self {
        Self::default()
    }

    /// `n` points per packet (1..=[`MAX_POINTS_HIGH`]).
    pub fn with_points_per_packet(n: usize) -> Result<Self, LivoxError> {
        if n == 0 || n > MAX_POINTS_HIGH {
            return Err(LivoxError::PointCount {
                count: n,
                max: MAX_POINTS_HIGH,
            });
        }
        Ok(Self {
            points_per_packet: n,
            ..Self::default()
        })
    }

    pub fn points_per_packet(&self) -> usize {
        self.points_per_packet
    }

    /// Bytes a buffer needs to hold any packet this writer makes.
    pub fn max_packet_len(&self) -> usize {
        cartesian_high_len(self.points_per_packet)
    }

    /// Encodes one frame starting at `timestamp_ns`: each packet is built in `buf` and handed to
    /// `emit`. Returns the number of packets; advances `udp_cnt` per packet and `frame_cnt` once.
    /// An empty frame emits nothing (and does not advance `frame_cnt`).
    pub fn write_frame(
        &mut self,
        points: &[LidarPoint],
        timestamp_ns: u64,
        buf: &mut [u8],
        mut emit: impl FnMut(&[u8]),
    ) -> Result<usize, LivoxError> {
        if points.is_empty() {
            return Ok(0);
        }
        let need = cartesian_high_len(self.points_per_packet.min(points.len()));
        if buf.len() < need {
            return Err(LivoxError::BufferTooSmall { need, got: buf.len() });
        }
        let mut packets = 0;
        for (k, chunk) in points.chunks(self.points_per_packet).enumerate() {
            let span_ns = chunk.len() as u64 * self.point_period_ns as u64;
            let meta = PacketMeta {
                udp_cnt: self.udp_cnt,
                frame_cnt: self.frame_cnt,
                timestamp_ns: timestamp_ns
                    .wrapping_add(k as u64 * self.points_per_packet as u64 * self.point_period_ns as u64),
                time_interval: (span_ns / 100).min(u16::MAX as u64) as u16,
                time_type: 0,
            };
            let n = encode_cartesian_high(&meta, chunk, buf)?;
            emit(&buf[..n]);
            self.udp_cnt = self.udp_cnt.wrapping_add(1);
            packets += 1;
        }
        self.frame_cnt = self.frame_cnt.wrapping_add(1);
        Ok(packets)
    }
}

// ---------------------------------------------------------------------------------------------
// Frame assembly

/// Rejected packets by error kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MalformedCounts {
    pub too_short: u64,
    pub length_mismatch: u64,
    pub version: u64,
    pub unknown_data_type: u64,
    pub dot_count: u64,
    pub crc: u64,
    pub non_finite: u64,
}

impl MalformedCounts {
    pub fn record(&mut self, e: &LivoxError) {
        let c = match e {
            LivoxError::TooShort { .. } => &mut self.too_short,
            LivoxError::LengthMismatch { .. } => &mut self.length_mismatch,
            LivoxError::Version(_) => &mut self.version,
            LivoxError::UnknownDataType(_) => &mut self.unknown_data_type,
            LivoxError::DotCountMismatch { .. } => &mut self.dot_count,
            LivoxError::Crc { .. } => &mut self.crc,
            LivoxError::NonFinite { .. } => &mut self.non_finite,
            // Encoder-side errors never come out of decoding.
            LivoxError::BufferTooSmall { .. } | LivoxError::PointCount { .. } => return,
        };
        *c += 1;
    }

    pub fn total(&self) -> u64 {
        self.too_short
            + self.length_mismatch
            + self.version
            + self.unknown_data_type
            + self.dot_count
            + self.crc
            + self.non_finite
    }
}

/// What a [`FrameAssembler`] has seen since construction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AssemblerStats {
    /// Valid point packets taken in.
    pub packets: u64,
    /// Valid IMU packets (ignored: IMU data has its own path).
    pub imu_packets: u64,
    /// Rejected packets, by kind.
    pub malformed: MalformedCounts,
    /// Packets missing according to `udp_cnt` gaps.
    pub lost_packets: u64,
    /// Packets whose `udp_cnt` repeated or went backwards (taken in all the same).
    pub reordered: u64,
    /// Points stored in frames.
    pub points: u64,
    /// Points closer than [`MIN_RANGE_M`], dropped.
    pub near_dropped: u64,
    /// Points that did not fit a frame.
    pub overflow: u64,
    /// Frames completed.
    pub frames: u64,
}

/// Collects point packets into frames of at most `CAP` points. A frame completes when a valid
/// packet with another `frame_cnt` arrives, or on [`flush`](Self::flush). Point `offset_ns` is
/// relative to the frame's first packet's timestamp (`PointFrame::timestamp_ns`). Malformed packets
/// are counted and returned as errors without touching the frame being built. Both frames are
/// allocated once, at construction; `push` never allocates.
pub struct FrameAssembler<const CAP: usize> {
    building: Box<PointFrame<CAP>>,
    done: Box<PointFrame<CAP>>,
    frame_cnt: Option<u8>,
    last_udp_cnt: Option<u16>,
    stats: AssemblerStats,
}

/// A zeroed point frame built in place on the heap (for buffers that must not allocate later).
pub fn boxed_point_frame<const CAP: usize>() -> Box<PointFrame<CAP>> {
    // Built in place on the heap: a large frame (CAP × 24 bytes) would not fit a thread's stack.
    let b = Box::<PointFrame<CAP>>::new_zeroed();
    // SAFETY: every field of PointFrame (and of LidarPoint) is an integer or an f32 (arrays of
    // them), for which all-zero bytes are a valid value; zero is also what PointFrame::new() holds.
    unsafe { b.assume_init() }
}

impl<const CAP: usize> FrameAssembler<CAP> {
    /// Allocates the two frames (being built, last completed) on the heap.
    pub fn new_boxed() -> Self {
        Self {
            building: boxed_point_frame(),
            done: boxed_point_frame(),
            frame_cnt: None,
            last_udp_cnt: None,
            stats: AssemblerStats::default(),
        }
    }

    pub fn stats(&self) -> &AssemblerStats {
        &self.stats
    }

    /// The frame being built (empty when none is in progress).
    pub fn current(&self) -> &PointFrame<CAP> {
        &self.building
    }

    /// `frame_cnt` of the frame in progress.
    pub fn current_frame_cnt(&self) -> Option<u8> {
        self.frame_cnt
    }

    /// Takes in one datagram. Returns the completed previous frame when this packet starts a new
    /// one, `None` otherwise, or the decode error (counted; the frame in progress is unchanged).
    pub fn push(&mut self, datagram: &[u8]) -> Result<Option<&PointFrame<CAP>>, LivoxError> {
        let packet = match decode_packet(datagram) {
            Ok(p) => p,
            Err(e) => {
                self.stats.malformed.record(&e);
                return Err(e);
            }
        };
        let h = packet.header;
        if !packet.is_points() {
            self.stats.imu_packets += 1;
            return Ok(None);
        }
        self.stats.packets += 1;
        if let Some(last) = self.last_udp_cnt {
            let d = h.udp_cnt.wrapping_sub(last);
            if d == 0 || d > 0x8000 {
                self.stats.reordered += 1;
            } else {
                self.stats.lost_packets += (d - 1) as u64;
            }
        }
        self.last_udp_cnt = Some(h.udp_cnt);

        let completed = match self.frame_cnt {
            Some(f) if f != h.frame_cnt => {
                self.finish();
                true
            }
            _ => false,
        };
        if self.frame_cnt.is_none() {
            self.building.clear(h.timestamp_ns);
            self.frame_cnt = Some(h.frame_cnt);
        }
        // Packets stamped before the frame's first one (reordering) get offset 0.
        let base = h.timestamp_ns.saturating_sub(self.building.timestamp_ns);
        for mut p in packet.points() {
            if !in_range(&p) {
                self.stats.near_dropped += 1;
                continue;
            }
            p.offset_ns = (base + p.offset_ns as u64).min(u32::MAX as u64) as u32;
            if self.building.push(p) {
                self.stats.points += 1;
            } else {
                self.stats.overflow += 1;
            }
        }
        Ok(if completed { Some(&*self.done) } else { None })
    }

    /// Completes the frame in progress, if any (end of stream, or a timeout between frames).
    pub fn flush(&mut self) -> Option<&PointFrame<CAP>> {
        if self.frame_cnt.is_some() {
            self.finish();
            Some(&*self.done)
        } else {
            None
        }
    }

    /// The last completed frame (empty before the first).
    pub fn last_frame(&self) -> &PointFrame<CAP> {
        &self.done
    }

    fn finish(&mut self) {
        core::mem::swap(&mut self.building, &mut self.done);
        self.building.clear(0);
        self.frame_cnt = None;
        self.stats.frames += 1;
    }
}

impl<const CAP: usize> Default for FrameAssembler<CAP> {
    fn default() -> Self {
        Self::new_boxed()
    }
}

// ---------------------------------------------------------------------------------------------
// Fuzzing entry point

/// Fuzz harness shared by `fuzz/` (cargo-fuzz target `livox_packet`) and the `livox_fuzz_smoke` test: decodes
/// `data` as one packet, then as a stream of packets cut by their own `length` fields (as a capture
/// file would be read), and feeds both to a small [`FrameAssembler`], asserting invariants.
#[doc(hidden)]
pub fn fuzz_livox(data: &[u8]) {
    const CAP: usize = 64;
    if let Ok(p) = decode_packet(data) {
        check_packet(data, &p);
    }
    let mut asm = FrameAssembler::<CAP>::new_boxed();
    let mut expect = Expect::default();
    push_checked(&mut asm, data, &mut expect);
    // The same bytes as a stream of packets.
    let mut rest = data;
    let mut pieces = 0;
    while !rest.is_empty() && pieces < 1024 {
        let n = if rest.len() >= 3 {
            rd_u16(rest, OFF_LENGTH) as usize
        } else {
            rest.len()
        };
        let n = if n == 0 || n > rest.len() { rest.len() } else { n };
        push_checked(&mut asm, &rest[..n], &mut expect);
        rest = &rest[n..];
        pieces += 1;
    }
    let before = asm.current().len + asm.current().overflow;
    if let Some(f) = asm.flush() {
        assert!(f.len <= CAP);
        assert_eq!(f.len + f.overflow, before);
    }
    assert!(asm.flush().is_none());
    let s = asm.stats();
    assert_eq!(s.packets + s.imu_packets + s.malformed.total(), expect.pushes);
    assert_eq!(s.malformed.total(), expect.errors);
    assert_eq!(s.points + s.near_dropped + s.overflow, expect.points_in);
}

#[derive(Default)]
struct Expect {
    pushes: u64,
    errors: u64,
    points_in: u64,
}

fn check_packet(data: &[u8], p: &Packet<'_>) {
    let h = p.header;
    assert_eq!(h.length as usize, data.len());
    assert_eq!(decode_header(data), Ok(h));
    assert_eq!(HEADER_LEN + p.payload().len(), data.len());
    let mut last = 0;
    let mut n = 0;
    for (i, q) in p.points().enumerate() {
        assert!(q.xyz.iter().all(|v| v.is_finite()));
        assert!(q.offset_ns >= last && q.offset_ns as u64 <= h.time_interval as u64 * 100);
        assert_eq!(q.offset_ns, h.point_offset_ns(i));
        last = q.offset_ns;
        n += 1;
    }
    if p.is_points() {
        assert_eq!(n, h.dot_num as usize);
        assert_eq!(p.imu_samples().count(), 0);
    } else {
        assert_eq!(n, 0);
        assert_eq!(p.imu_samples().count(), h.dot_num as usize);
    }
    if h.data_type == DATA_TYPE_CARTESIAN_HIGH && n <= 128 {
        // Re-encoding reproduces the packet whenever millimetres survive the trip through f32.
        let mut pts = [LidarPoint::default(); 128];
        for (d, s) in pts.iter_mut().zip(p.points()) {
            *d = s;
        }
        let mut buf = [0u8; cartesian_high_len(128)];
        let meta = PacketMeta {
            udp_cnt: h.udp_cnt,
            frame_cnt: h.frame_cnt,
            timestamp_ns: h.timestamp_ns,
            time_interval: h.time_interval,
            time_type: h.time_type,
        };
        let len = encode_cartesian_high(&meta, &pts[..n], &mut buf).expect("re-encode");
        assert_eq!(len, data.len());
        let exact = p
            .payload()
            .chunks_exact(POINT_HIGH_LEN)
            .all(|c| (0..3).all(|k| rd_i32(c, 4 * k).unsigned_abs() < 1 << 23));
        let reserved_zero = data[12..24].iter().all(|&b| b == 0);
        if exact && reserved_zero {
            assert_eq!(&buf[..len], data);
        }
        let q = decode_packet(&buf[..len]).expect("re-encoded packet decodes");
        assert_eq!(q.header.dot_num, h.dot_num);
    }
}

fn push_checked<const CAP: usize>(asm: &mut FrameAssembler<CAP>, bytes: &[u8], e: &mut Expect) {
    let in_progress = (asm.current().len, asm.current().overflow, asm.current_frame_cnt());
    let decoded = decode_packet(bytes);
    let frames_before = asm.stats().frames;
    e.pushes += 1;
    match asm.push(bytes) {
        Err(err) => {
            assert_eq!(decoded.err(), Some(err));
            e.errors += 1;
            // A rejected packet leaves the frame in progress as it was.
            let now = (asm.current().len, asm.current().overflow, asm.current_frame_cnt());
            assert_eq!(now, in_progress);
        }
        Ok(done) => {
            let p = decoded.expect("assembler accepted what decode_packet rejects");
            let completed = done.map(|f| (f.len, f.overflow, f.as_slice().iter().all(in_range)));
            if let Some((len, overflow, all_in_range)) = completed {
                assert!(len <= CAP);
                assert_eq!(len + overflow, in_progress.0 + in_progress.1);
                assert!(all_in_range);
            }
            assert_eq!(asm.stats().frames, frames_before + completed.is_some() as u64);
            if p.is_points() {
                e.points_in += p.header.dot_num as u64;
                assert_eq!(asm.current_frame_cnt(), Some(p.header.frame_cnt));
                assert!(asm.current().len <= CAP);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(x: f32, y: f32, z: f32) -> LidarPoint {
        LidarPoint {
            xyz: [x, y, z],
            reflectivity: 7,
            tag: 1,
            offset_ns: 0,
        }
    }

    fn meta(udp_cnt: u16, frame_cnt: u8, timestamp_ns: u64) -> PacketMeta {
        PacketMeta {
            udp_cnt,
            frame_cnt,
            timestamp_ns,
            time_interval: 4800,
            time_type: 0,
        }
    }

    fn packet(m: &PacketMeta, points: &[LidarPoint]) -> Vec<u8> {
        let mut buf = vec![0u8; cartesian_high_len(points.len())];
        let n = encode_cartesian_high(m, points, &mut buf).unwrap();
        assert_eq!(n, buf.len());
        buf
    }

    /// Rewrites the CRC after tampering with a packet.
    fn reseal(buf: &mut [u8]) {
        let crc = crc32(&buf[OFF_TIMESTAMP..]);
        buf[OFF_CRC..OFF_CRC + 4].copy_from_slice(&crc.to_le_bytes());
    }

    fn imu_packet(values: [f32; 6]) -> Vec<u8> {
        let mut buf = vec![0u8; HEADER_LEN + IMU_SAMPLE_LEN];
        let len = buf.len() as u16;
        buf[OFF_LENGTH..OFF_LENGTH + 2].copy_from_slice(&len.to_le_bytes());
        buf[OFF_DOT_NUM..OFF_DOT_NUM + 2].copy_from_slice(&1u16.to_le_bytes());
        buf[OFF_DATA_TYPE] = DATA_TYPE_IMU;
        for (k, v) in values.iter().enumerate() {
            buf[HEADER_LEN + 4 * k..HEADER_LEN + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
        reseal(&mut buf);
        buf
    }

    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> u32 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 33) as u32
        }
        fn unit(&mut self) -> f32 {
            self.next() as f32 / (1u64 << 31) as f32
        }
    }

    #[test]
    fn crc_matches_the_crc_crate() {
        let reference = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), reference.checksum(b""));
        let mut rng = Lcg(3);
        let data: Vec<u8> = (0..4096).map(|_| rng.next() as u8).collect();
        for len in (0..64).chain([1343, 1352, 4095, 4096]) {
            for start in 0..3 {
                let s = &data[start..start + len.min(4093)];
                assert_eq!(crc32(s), reference.checksum(s), "len {len} start {start}");
                assert_eq!(crc32_table(s), reference.checksum(s), "table, len {len} start {start}");
            }
        }
    }

    #[test]
    fn round_trip_within_a_millimetre() {
        let mut rng = Lcg(1);
        let points: Vec<LidarPoint> = (0..MID360_POINTS_PER_PACKET)
            .map(|_| {
                let mut p = pt(
                    rng.unit() * 80.0 - 40.0,
                    rng.unit() * 80.0 - 40.0,
                    rng.unit() * 10.0 - 5.0,
                );
                p.reflectivity = rng.next() as u8;
                p.tag = rng.next() as u8;
                p
            })
            .collect();
        let m = meta(77, 3, 1_234_567_890_123);
        let buf = packet(&m, &points);
        assert_eq!(buf.len(), 36 + 96 * 14);
        let p = decode_packet(&buf).unwrap();
        let h = p.header;
        assert_eq!(
            (
                h.version,
                h.length as usize,
                h.dot_num,
                h.udp_cnt,
                h.frame_cnt,
                h.data_type
            ),
            (0, buf.len(), 96, 77, 3, DATA_TYPE_CARTESIAN_HIGH)
        );
        assert_eq!((h.timestamp_ns, h.time_interval), (1_234_567_890_123, 4800));
        assert_eq!(p.points().len(), 96);
        for (i, (a, b)) in points.iter().zip(p.points()).enumerate() {
            for k in 0..3 {
                assert!((a.xyz[k] - b.xyz[k]).abs() <= 0.0005 + 1e-6, "{a:?} {b:?}");
            }
            assert_eq!((a.reflectivity, a.tag), (b.reflectivity, b.tag));
            // 4800 × 0.1 µs over 96 points: 5 µs apart.
            assert_eq!(b.offset_ns, i as u32 * 5000);
        }
        // Rounding and saturation.
        let buf = packet(&m, &[pt(0.0015, -0.0015, 1e12), pt(f32::NAN, -1e12, 0.0)]);
        let q: Vec<_> = decode_packet(&buf).unwrap().points().collect();
        assert_eq!(q[0].xyz, [0.002, -0.002, i32::MAX as f32 / 1000.0]);
        assert_eq!(q[1].xyz, [0.0, i32::MIN as f32 / 1000.0, 0.0]);
    }

    #[test]
    fn cartesian_low_and_imu_decode() {
        let mut buf = vec![0u8; HEADER_LEN + 2 * POINT_LOW_LEN];
        let len = buf.len() as u16;
        buf[OFF_LENGTH..OFF_LENGTH + 2].copy_from_slice(&len.to_le_bytes());
        buf[OFF_DOT_NUM..OFF_DOT_NUM + 2].copy_from_slice(&2u16.to_le_bytes());
        buf[OFF_TIME_INTERVAL..OFF_TIME_INTERVAL + 2].copy_from_slice(&10u16.to_le_bytes());
        buf[OFF_DATA_TYPE] = DATA_TYPE_CARTESIAN_LOW;
        for (k, v) in [150i16, -20, 3].iter().enumerate() {
            buf[HEADER_LEN + 8 + 2 * k..HEADER_LEN + 10 + 2 * k].copy_from_slice(&v.to_le_bytes());
        }
        buf[HEADER_LEN + 8 + 6] = 9;
        reseal(&mut buf);
        let p = decode_packet(&buf).unwrap();
        let pts: Vec<_> = p.points().collect();
        assert_eq!(pts.len(), 2);
        assert_eq!(pts[1].xyz, [1.5, -0.2, 0.03]);
        assert_eq!((pts[1].reflectivity, pts[1].offset_ns), (9, 500));
        assert!(!in_range(&pts[0]) && in_range(&pts[1]));

        let buf = imu_packet([0.1, 0.2, 0.3, 0.0, 0.0, -1.0]);
        let p = decode_packet(&buf).unwrap();
        assert!(!p.is_points());
        assert_eq!(p.points().count(), 0);
        let s: Vec<_> = p.imu_samples().collect();
        assert_eq!(
            s,
            vec![ImuSample {
                gyro: [0.1, 0.2, 0.3],
                acc: [0.0, 0.0, -1.0]
            }]
        );
    }

    #[test]
    fn every_error_is_reachable() {
        let good = packet(&meta(1, 1, 5), &[pt(1.0, 2.0, 3.0), pt(-1.0, 0.5, 0.2)]);
        assert!(decode_packet(&good).is_ok());

        assert_eq!(
            decode_packet(&good[..35]).unwrap_err(),
            LivoxError::TooShort { got: 35 }
        );
        assert_eq!(decode_packet(&[]).unwrap_err(), LivoxError::TooShort { got: 0 });
        assert_eq!(
            decode_packet(&good[..good.len() - 1]).unwrap_err(),
            LivoxError::LengthMismatch { header: 64, got: 63 }
        );
        let mut b = good.clone();
        b[0] = 5;
        assert_eq!(decode_packet(&b).unwrap_err(), LivoxError::Version(5));
        let mut b = good.clone();
        b[OFF_DATA_TYPE] = 0x03;
        assert_eq!(decode_packet(&b).unwrap_err(), LivoxError::UnknownDataType(3));
        let mut b = good.clone();
        b[OFF_DOT_NUM] = 3;
        assert_eq!(
            decode_packet(&b).unwrap_err(),
            LivoxError::DotCountMismatch {
                dot_num: 3,
                data_type: 1,
                payload_len: 28
            }
        );
        let mut b = good.clone();
        b[40] ^= 1;
        let e = decode_packet(&b).unwrap_err();
        assert!(matches!(e, LivoxError::Crc { expected, got } if expected == rd_u32(&good, 24) && got != expected));
        // The CRC covers the timestamp, not the header before it.
        let mut b = good.clone();
        b[OFF_TIMESTAMP] ^= 0x80;
        assert!(matches!(decode_packet(&b), Err(LivoxError::Crc { .. })));
        let e = decode_packet(&imu_packet([0.0, f32::NAN, 0.0, 0.0, 0.0, 1.0])).unwrap_err();
        assert_eq!(
            e,
            LivoxError::NonFinite {
                sample: 0,
                component: 1
            }
        );

        let mut small = [0u8; 40];
        assert_eq!(
            encode_cartesian_high(&meta(0, 0, 0), &[pt(1.0, 0.0, 0.0)], &mut small).unwrap_err(),
            LivoxError::BufferTooSmall { need: 50, got: 40 }
        );
        let many = vec![pt(1.0, 0.0, 0.0); MAX_POINTS_HIGH + 1];
        let mut big = vec![0u8; 70_000];
        assert!(matches!(
            encode_cartesian_high(&meta(0, 0, 0), &many, &mut big),
            Err(LivoxError::PointCount { .. })
        ));
        assert!(encode_cartesian_high(&meta(0, 0, 0), &many[1..], &mut big).is_ok());
        assert!(PacketWriter::with_points_per_packet(0).is_err());

        // Order of checks: a bad length hides a bad CRC, a bad header hides a bad CRC.
        let mut b = good.clone();
        b[40] ^= 1;
        b[OFF_DATA_TYPE] = 9;
        assert_eq!(decode_packet(&b).unwrap_err(), LivoxError::UnknownDataType(9));
        b.push(0);
        assert!(matches!(decode_packet(&b), Err(LivoxError::LengthMismatch { .. })));

        // Every message names the packet and reads as a sentence.
        for e in [LivoxError::TooShort { got: 3 }, LivoxError::Crc { expected: 1, got: 2 }] {
            assert!(e.to_string().starts_with("livox"));
        }
        use hal::Error as _;
        assert_eq!(LivoxError::Crc { expected: 1, got: 2 }.kind(), hal::ErrorKind::Checksum);
        assert_eq!(LivoxError::Version(1).kind(), hal::ErrorKind::Malformed);
    }

    #[test]
    fn writer_splits_frames_into_packets() {
        let points: Vec<_> = (0..200).map(|i| pt(1.0 + i as f32 * 0.01, 0.0, 0.0)).collect();
        let mut w = PacketWriter::new();
        w.udp_cnt = u16::MAX;
        let mut buf = [0u8; cartesian_high_len(MID360_POINTS_PER_PACKET)];
        let mut got = Vec::new();
        let n = w
            .write_frame(&points, 1_000_000, &mut buf, |b| got.push(b.to_vec()))
            .unwrap();
        assert_eq!((n, got.len(), w.udp_cnt, w.frame_cnt), (3, 3, 2, 1));
        let headers: Vec<_> = got.iter().map(|b| decode_packet(b).unwrap().header).collect();
        assert_eq!(headers.iter().map(|h| h.dot_num).collect::<Vec<_>>(), [96, 96, 8]);
        assert_eq!(headers.iter().map(|h| h.udp_cnt).collect::<Vec<_>>(), [u16::MAX, 0, 1]);
        assert_eq!(
            headers.iter().map(|h| h.timestamp_ns).collect::<Vec<_>>(),
            [1_000_000, 1_480_000, 1_960_000]
        );
        assert_eq!(headers[2].time_interval, 400);
        assert!(headers.iter().all(|h| h.frame_cnt == 0));

        // Through the assembler: the same points, times 5 µs apart from the frame start.
        let mut asm = FrameAssembler::<256>::new_boxed();
        for b in &got {
            assert!(asm.push(b).unwrap().is_none());
        }
        let f = asm.flush().unwrap();
        assert_eq!((f.len, f.timestamp_ns), (200, 1_000_000));
        for (i, (a, b)) in points.iter().zip(f.as_slice()).enumerate() {
            assert!((a.xyz[0] - b.xyz[0]).abs() < 0.0006);
            assert_eq!(b.offset_ns, i as u32 * 5000);
        }
        let small = PacketWriter::with_points_per_packet(10).unwrap();
        assert_eq!((small.points_per_packet(), small.max_packet_len()), (10, 176));
        assert!(matches!(
            w.write_frame(&points, 0, &mut buf[..100], |_| ()),
            Err(LivoxError::BufferTooSmall { .. })
        ));
    }

    #[test]
    fn assembler_frame_boundaries_and_offsets() {
        let mut asm = FrameAssembler::<1000>::new_boxed();
        let a0 = packet(&meta(0, 7, 1_000), &[pt(1.0, 0.0, 0.0), pt(2.0, 0.0, 0.0)]);
        let a1 = packet(&meta(1, 7, 2_000), &[pt(3.0, 0.0, 0.0)]);
        let b0 = packet(&meta(2, 8, 9_000), &[pt(4.0, 0.0, 0.0)]);
        assert!(asm.push(&a0).unwrap().is_none());
        assert!(asm.push(&a1).unwrap().is_none());
        assert_eq!(asm.current().len, 3);
        let f = asm.push(&b0).unwrap().unwrap();
        assert_eq!((f.len, f.timestamp_ns, f.overflow), (3, 1_000, 0));
        let offs: Vec<_> = f.as_slice().iter().map(|p| p.offset_ns).collect();
        // time_interval 4800 (480 µs) over 2 points: 240 µs apart; second packet 1 µs later.
        assert_eq!(offs, [0, 240_000, 1_000]);
        assert_eq!(f.as_slice()[2].xyz[0], 3.0);
        assert_eq!(asm.current_frame_cnt(), Some(8));
        let f = asm.flush().unwrap();
        assert_eq!((f.len, f.timestamp_ns, f.as_slice()[0].xyz[0]), (1, 9_000, 4.0));
        assert!(asm.flush().is_none());
        assert_eq!(asm.last_frame().len, 1);
        let s = asm.stats();
        assert_eq!(
            (s.frames, s.packets, s.points, s.lost_packets, s.reordered),
            (2, 3, 4, 0, 0)
        );
        // An IMU packet is counted and ignored.
        assert!(asm.push(&imu_packet([0.0; 6])).unwrap().is_none());
        assert_eq!((asm.stats().imu_packets, asm.current_frame_cnt()), (1, None));
    }

    #[test]
    fn assembler_counts_udp_gaps() {
        let mut asm = FrameAssembler::<100>::new_boxed();
        for (udp, expect_lost, expect_reordered) in [
            (65534u16, 0, 0),
            (65535, 0, 0),
            (2, 2, 0),
            (2, 2, 1),
            (1, 2, 2),
            (10, 10, 2),
        ] {
            asm.push(&packet(&meta(udp, 0, 0), &[pt(1.0, 0.0, 0.0)])).unwrap();
            let s = asm.stats();
            assert_eq!(
                (s.lost_packets, s.reordered),
                (expect_lost, expect_reordered),
                "udp {udp}"
            );
        }
    }

    #[test]
    fn assembler_drops_near_points_and_counts_overflow() {
        let mut asm = FrameAssembler::<3>::new_boxed();
        let pts = [
            pt(0.0, 0.0, 0.0),
            pt(0.05, 0.05, 0.05),
            pt(0.1, 0.0, 0.0),
            pt(0.0, -0.2, 0.0),
            pt(5.0, 5.0, 5.0),
            pt(6.0, 0.0, 0.0),
        ];
        asm.push(&packet(&meta(0, 0, 0), &pts)).unwrap();
        let f = asm.flush().unwrap();
        assert_eq!((f.len, f.overflow), (3, 1));
        assert_eq!(f.as_slice()[0].xyz, [0.1, 0.0, 0.0]);
        let s = *asm.stats();
        assert_eq!((s.near_dropped, s.points, s.overflow), (2, 3, 1));
        // The next frame starts empty with fresh overflow.
        asm.push(&packet(&meta(1, 1, 0), &pts[4..])).unwrap();
        let f = asm.flush().unwrap();
        assert_eq!((f.len, f.overflow), (2, 0));
    }

    #[test]
    fn malformed_packets_leave_the_frame_alone() {
        let mut asm = FrameAssembler::<100>::new_boxed();
        let good = packet(&meta(0, 4, 100), &[pt(1.0, 1.0, 1.0), pt(2.0, 2.0, 2.0)]);
        asm.push(&good).unwrap();
        // A corrupted packet of another frame must neither end this frame nor add points.
        let mut bad = packet(&meta(1, 5, 200), &[pt(9.0, 9.0, 9.0)]);
        bad[HEADER_LEN] ^= 0xFF;
        assert!(matches!(asm.push(&bad), Err(LivoxError::Crc { .. })));
        assert!(matches!(asm.push(&bad[..20]), Err(LivoxError::TooShort { .. })));
        assert!(matches!(asm.push(&bad[..40]), Err(LivoxError::LengthMismatch { .. })));
        assert_eq!((asm.current().len, asm.current_frame_cnt()), (2, Some(4)));
        asm.push(&packet(&meta(2, 4, 300), &[pt(3.0, 3.0, 3.0)])).unwrap();
        let f = asm.flush().unwrap();
        assert_eq!(f.len, 3);
        let s = asm.stats();
        assert_eq!(
            (
                s.malformed.crc,
                s.malformed.too_short,
                s.malformed.length_mismatch,
                s.malformed.total()
            ),
            (1, 1, 1, 3)
        );
        assert_eq!(s.lost_packets, 1);
    }

    #[test]
    fn fuzz_entry_accepts_valid_and_garbage_input() {
        let a = packet(&meta(0, 0, 0), &[pt(1.0, 2.0, 3.0), pt(0.0, 0.0, 0.0)]);
        let b = packet(&meta(1, 1, 10), &[pt(-1.0, 2.0, 3.0)]);
        fuzz_livox(&a);
        fuzz_livox(&[a.clone(), b.clone(), a.clone(), imu_packet([1.0; 6])].concat());
        fuzz_livox(&[]);
        fuzz_livox(&[0xFF; 100]);
        fuzz_livox(&a[..40]);
    }
}
