//! A simulated Livox MID-360 by MuJoCo ray casting.
//!
//! The sensor streams: every control tick casts the rays whose firing times fall in that tick, from
//! the sensor's pose at that tick (so motion during a frame skews the cloud as on the real sensor),
//! in one batched `mj_multiRay` call. Pattern: four lines, each sweeping the full circle once per
//! 0.1 s while its elevation runs a triangle wave over the field of view; the sweep and the wave
//! frequencies are not commensurate with the frame rate, so successive frames interleave
//! (non-repetitive, rosette-like coverage). Returns carry Gaussian range noise; dropouts and rays
//! with no hit come out as zero points, and returns closer than the minimum range are left in, as
//! the sensor's driver does (consumers drop both). Hits on the robot's own body are included,
//! except on the body the sensor is bolted to.
use hal::LidarPoint;
use mujoco_rs::mujoco_c::{mjData, mjModel, mj_multiRay};
use mujoco_rs::prelude::*;

use sensor_io::livox::{encode_cartesian_high, PacketMeta, MID360_POINTS_PER_PACKET, MID360_POINT_PERIOD_NS};

use crate::SimError;
use labkit::rng::Rng;

/// Torso origin in the pelvis frame on the G1 (used when the model has no `torso_link` body).
pub const G1_TORSO_IN_PELVIS: [f64; 3] = [-0.0039635, 0.0, 0.044];

/// Sensor settings; the defaults follow `../shared/facts/mid360_lidar.md`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LidarConfig {
    /// Sensor pose on the torso: position (m) and roll, pitch, yaw (rad, R = Rz·Ry·Rx). Default:
    /// the latest unitree_ros URDF (`mid360_link` upside down on `torso_link`).
    pub mount_xyz: [f64; 3],
    pub mount_rpy: [f64; 3],
    pub points_per_second: f64,
    pub frame_hz: f64,
    /// Elevation field of view in the sensor frame, degrees.
    pub fov_min_deg: f64,
    pub fov_max_deg: f64,
    pub lines: usize,
    /// Gaussian range noise, m (1 σ).
    pub range_noise_std: f64,
    /// Probability that a return is lost.
    pub dropout: f64,
    /// Largest range that returns, m.
    pub max_range: f64,
    pub seed: u64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            mount_xyz: [0.0002835, 0.00003, 0.428434],
            mount_rpy: [std::f64::consts::PI, 0.0511, 0.0],
            points_per_second: 200_000.0,
            frame_hz: 10.0,
            fov_min_deg: -7.0,
            fov_max_deg: 52.0,
            lines: 4,
            range_noise_std: 0.02,
            dropout: 0.01,
            max_range: 40.0,
            seed: 1,
        }
    }
}

impl LidarConfig {
    pub fn validate(&self) -> Result<(), SimError> {
        let ok = self.points_per_second.is_finite()
            && self.points_per_second > 0.0
            && self.points_per_second <= 2.0e6
            && self.frame_hz.is_finite()
            && self.frame_hz > 0.0
            && self.fov_min_deg < self.fov_max_deg
            && self.fov_min_deg >= -90.0
            && self.fov_max_deg <= 90.0
            && (1..=16).contains(&self.lines)
            && self.range_noise_std >= 0.0
            && (0.0..=1.0).contains(&self.dropout)
            && self.max_range > 0.1
            && self.mount_xyz.iter().chain(&self.mount_rpy).all(|v| v.is_finite());
        if ok {
            Ok(())
        } else {
            Err(SimError::Config(format!(
                "lidar config {self:?}: rates and ranges must be positive and finite, 1..16 lines, dropout in [0, 1]"
            )))
        }
    }

    /// Sensor pose in the pelvis frame with the waist at zero (what the firmware's BEV uses).
    pub fn mount_in_pelvis(&self) -> ([f64; 3], [f64; 3]) {
        let p = self.mount_xyz;
        let t = G1_TORSO_IN_PELVIS;
        ([p[0] + t[0], p[1] + t[1], p[2] + t[2]], self.mount_rpy)
    }

    /// Points per frame.
    pub fn points_per_frame(&self) -> usize {
        (self.points_per_second / self.frame_hz).round() as usize
    }
}

/// Rotation matrix (row-major) from roll, pitch, yaw: Rz(yaw)·Ry(pitch)·Rx(roll).
pub fn rpy_matrix(rpy: [f64; 3]) -> [f64; 9] {
    let r = sensor_io::bev::rpy_rotation(rpy);
    [
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    ]
}

fn mat_mul(a: &[f64; 9], b: &[f64; 9]) -> [f64; 9] {
    let mut r = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            r[3 * i + j] = (0..3).map(|k| a[3 * i + k] * b[3 * k + j]).sum();
        }
    }
    r
}

fn mat_vec(a: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    [
        a[0] * v[0] + a[1] * v[1] + a[2] * v[2],
        a[3] * v[0] + a[4] * v[1] + a[5] * v[2],
        a[6] * v[0] + a[7] * v[1] + a[8] * v[2],
    ]
}

/// One simulated return, before packetising.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Return {
    /// Sensor frame, m; all zero for "no return".
    pub xyz: [f32; 3],
    pub reflectivity: u8,
    /// Firing time since the start of the run, ns.
    pub time_ns: u64,
    /// MuJoCo geom hit (−1: none).
    pub geom: i32,
}

impl Return {
    pub fn point(&self, frame_start_ns: u64) -> LidarPoint {
        LidarPoint {
            xyz: self.xyz,
            reflectivity: self.reflectivity,
            tag: 0,
            offset_ns: self.time_ns.saturating_sub(frame_start_ns) as u32,
        }
    }
}

/// The sensor, attached to a model. Buffers are sized at construction; [`LidarSim::scan`] does not
/// allocate.
pub struct LidarSim {
    cfg: LidarConfig,
    body: usize,
    /// Mount in the body's frame.
    mount_pos: [f64; 3],
    mount_rot: [f64; 9],
    /// Next point index to fire (global).
    next_point: u64,
    rng: Rng,
    dirs_sensor: Vec<[f64; 3]>,
    dirs_world: Vec<[f64; 3]>,
    geom: Vec<i32>,
    dist: Vec<f64>,
}

impl LidarSim {
    /// Attaches the sensor to `torso_link` (or the pelvis plus the G1 torso offset when the model
    /// has no torso body). `max_points_per_call` bounds one [`LidarSim::scan`].
    pub fn new(model: &MjModel, cfg: LidarConfig, max_points_per_call: usize) -> Result<Self, SimError> {
        cfg.validate()?;
        let (body, offset) = match model.name_to_id(MjtObjBase::mjOBJ_BODY, "torso_link") {
            Some(b) => (b, [0.0; 3]),
            None => (
                model
                    .name_to_id(MjtObjBase::mjOBJ_BODY, "pelvis")
                    .ok_or_else(|| SimError::Model("lidar: the model has neither torso_link nor pelvis".into()))?,
                G1_TORSO_IN_PELVIS,
            ),
        };
        let p = cfg.mount_xyz;
        Ok(Self {
            cfg,
            body,
            mount_pos: [p[0] + offset[0], p[1] + offset[1], p[2] + offset[2]],
            mount_rot: rpy_matrix(cfg.mount_rpy),
            next_point: 0,
            rng: Rng(cfg.seed ^ 0x11DA_5EED),
            dirs_sensor: vec![[0.0; 3]; max_points_per_call],
            dirs_world: vec![[0.0; 3]; max_points_per_call],
            geom: vec![-1; max_points_per_call],
            dist: vec![0.0; max_points_per_call],
        })
    }

    pub fn config(&self) -> &LidarConfig {
        &self.cfg
    }

    /// Start of the frame containing time `t_ns`, and its index.
    pub fn frame_of(&self, t_ns: u64) -> (u64, u64) {
        let period_ns = (1e9 / self.cfg.frame_hz).round() as u64;
        let idx = t_ns / period_ns;
        (idx, idx * period_ns)
    }

    /// Sensor-frame direction of point `k` (unit vector).
    pub fn direction(&self, k: u64) -> [f64; 3] {
        let c = &self.cfg;
        let lines = c.lines as u64;
        let line = (k % lines) as f64;
        let t = (k / lines) as f64 * lines as f64 / c.points_per_second;
        // Sweep slightly faster than the frame rate and run the elevation wave at a non-integer
        // multiple of it, so consecutive frames fill in each other's gaps.
        let az = std::f64::consts::TAU * (c.frame_hz * 1.0037 * t + line / c.lines as f64);
        let phase = (437.3 * t + line * 0.618_034).fract();
        let tri = if phase < 0.5 { 2.0 * phase } else { 2.0 - 2.0 * phase };
        let el = (c.fov_min_deg + tri * (c.fov_max_deg - c.fov_min_deg)).to_radians();
        [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()]
    }

    /// Fires every point due in [`t0_ns`, `t1_ns`) from the model's current pose, appending the
    /// returns to `out` (capacity reserved by the caller; never grows past `max_points_per_call`).
    pub fn scan(&mut self, data: &mut MjData<Box<MjModel>>, t0_ns: u64, t1_ns: u64, out: &mut Vec<Return>) {
        let rate = self.cfg.points_per_second;
        let first = self.next_point.max((t0_ns as f64 * 1e-9 * rate).ceil() as u64);
        let end = (t1_ns as f64 * 1e-9 * rate).ceil() as u64;
        let n = (end.saturating_sub(first) as usize).min(self.dirs_sensor.len());
        self.next_point = first + n as u64;
        if n == 0 {
            return;
        }
        let xpos = data.xpos()[self.body];
        let xmat = data.xmat()[self.body];
        let rot = mat_mul(&xmat, &self.mount_rot);
        let origin = {
            let o = mat_vec(&xmat, self.mount_pos);
            [xpos[0] + o[0], xpos[1] + o[1], xpos[2] + o[2]]
        };
        for i in 0..n {
            let d = self.direction(first + i as u64);
            self.dirs_sensor[i] = d;
            self.dirs_world[i] = mat_vec(&rot, d);
        }
        let m: *const mjModel = data.model().ffi();
        // SAFETY: `m` and the data pointer come from the same live MjData; the direction, id and
        // distance buffers hold at least `n` rays (n ≤ their common length); normals are not
        // requested (null), and a null geomgroup means "all groups".
        unsafe {
            let d: *mut mjData = data.ffi_mut();
            mj_multiRay(
                m,
                d,
                &origin,
                self.dirs_world.as_ptr() as *const f64,
                std::ptr::null(),
                true,
                self.body as i32,
                self.geom.as_mut_ptr(),
                self.dist.as_mut_ptr(),
                std::ptr::null_mut(),
                n as i32,
                self.cfg.max_range,
            );
        }
        for i in 0..n {
            let k = first + i as u64;
            let time_ns = (k as f64 / rate * 1e9) as u64;
            let (g, dist) = (self.geom[i], self.dist[i]);
            let lost = self.rng.chance(self.cfg.dropout);
            let noise = self.rng.gaussian() * self.cfg.range_noise_std;
            if g < 0 || dist.is_nan() || dist < 0.0 || dist > self.cfg.max_range || lost {
                out.push(Return {
                    xyz: [0.0; 3],
                    reflectivity: 0,
                    time_ns,
                    geom: -1,
                });
                continue;
            }
            let r = (dist + noise).max(0.0);
            let d = self.dirs_sensor[i];
            out.push(Return {
                xyz: [(d[0] * r) as f32, (d[1] * r) as f32, (d[2] * r) as f32],
                reflectivity: 60,
                time_ns,
                geom: g,
            });
        }
    }
}

/// Streams returns as Livox Cartesian-high packets the way the sensor does: a packet leaves when it
/// holds [`MID360_POINTS_PER_PACKET`] points or when the frame ends; `udp_cnt` counts packets and
/// `frame_cnt` frames. Output datagrams are appended to a byte buffer, each prefixed by its length
/// (u16 LE), which is how the bridge carries UDP datagrams. No allocation after construction.
pub struct LivoxStream {
    pending: Vec<LidarPoint>,
    pending_t0_ns: u64,
    pending_frame: u64,
    udp_cnt: u16,
    packet: Vec<u8>,
    period_ns: u64,
}

impl LivoxStream {
    pub fn new(frame_hz: f64) -> Self {
        Self {
            pending: Vec::with_capacity(MID360_POINTS_PER_PACKET),
            pending_t0_ns: 0,
            pending_frame: 0,
            udp_cnt: 0,
            packet: vec![0; sensor_io::livox::cartesian_high_len(MID360_POINTS_PER_PACKET)],
            period_ns: (1e9 / frame_hz).round() as u64,
        }
    }

    /// Adds returns (in firing order) and appends every packet that completes to `out`.
    pub fn push(&mut self, returns: &[Return], out: &mut Vec<u8>) {
        for r in returns {
            let frame = r.time_ns / self.period_ns;
            if !self.pending.is_empty() && frame != self.pending_frame {
                self.flush(out);
            }
            if self.pending.is_empty() {
                self.pending_t0_ns = r.time_ns;
                self.pending_frame = frame;
            }
            self.pending.push(r.point(self.pending_t0_ns));
            if self.pending.len() == MID360_POINTS_PER_PACKET {
                self.flush(out);
            }
        }
    }

    fn flush(&mut self, out: &mut Vec<u8>) {
        let meta = PacketMeta {
            udp_cnt: self.udp_cnt,
            frame_cnt: self.pending_frame as u8,
            timestamp_ns: self.pending_t0_ns,
            time_interval: (self.pending.len() as u64 * MID360_POINT_PERIOD_NS as u64 / 100) as u16,
            time_type: 0,
        };
        // Cannot fail: the buffer holds a full packet and `pending` never exceeds one.
        if let Ok(n) = encode_cartesian_high(&meta, &self.pending, &mut self.packet) {
            sim_hal::bridge::append_datagram(out, &self.packet[..n]);
        }
        self.udp_cnt = self.udp_cnt.wrapping_add(1);
        self.pending.clear();
    }
}
