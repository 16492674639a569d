//! The paper's bird's-eye-view grid: 6 × 60 × 60 over 3 m × 3 m around the robot, 0.05 m cells.
//!
//! Frame: the gravity-aligned robot frame. Origin below the base (pelvis) on the ground the robot
//! stands on (z = 0 there), x forward along the robot's heading, y left, z up; roll and pitch are
//! removed, yaw is not (the grid turns with the robot).
//!
//! Layout: channel-major `data[c * 3600 + ix * 60 + iy]`, `ix = floor((x + 1.5) / 0.05)` (row 0 is
//! 1.5 m behind the robot), `iy = floor((y + 1.5) / 0.05)` (column 0 is 1.5 m to the right).
//! Channels: 0 max z, 1 min z, 2 mean z, 3 max − min, 4 std z (population), 5 density = points in the
//! cell / points in the fullest cell (so 1.0 somewhere whenever any cell is occupied). Empty cells
//! are 0 in every channel.

/// Cells per side.
pub const BEV_CELLS: usize = 60;
/// Channels per cell.
pub const BEV_CHANNELS: usize = 6;
/// Cell edge, m.
pub const BEV_CELL_M: f32 = 0.05;
/// Half the window's side, m.
pub const BEV_HALF_EXTENT_M: f32 = 1.5;
/// Values in one grid.
pub const BEV_LEN: usize = BEV_CHANNELS * BEV_CELLS * BEV_CELLS;

/// Channel indices.
pub const CH_MAX: usize = 0;
pub const CH_MIN: usize = 1;
pub const CH_MEAN: usize = 2;
pub const CH_RANGE: usize = 3;
pub const CH_STD: usize = 4;
pub const CH_DENSITY: usize = 5;
pub const CHANNEL_NAMES: [&str; BEV_CHANNELS] = ["max_z", "min_z", "mean_z", "range_z", "std_z", "density"];

/// One BEV grid (86 KB; box it once).
#[derive(Clone, Debug, PartialEq)]
pub struct BevGrid {
    pub data: [f32; BEV_LEN],
}

impl BevGrid {
    pub const fn zeroed() -> Self {
        Self { data: [0.0; BEV_LEN] }
    }

    #[inline]
    pub const fn index(channel: usize, ix: usize, iy: usize) -> usize {
        channel * BEV_CELLS * BEV_CELLS + ix * BEV_CELLS + iy
    }

    #[inline]
    pub fn get(&self, channel: usize, ix: usize, iy: usize) -> f32 {
        self.data[Self::index(channel, ix, iy)]
    }

    /// Cell containing (x, y), if inside the window.
    #[inline]
    pub fn cell_of(x: f32, y: f32) -> Option<(usize, usize)> {
        let fx = (x + BEV_HALF_EXTENT_M) / BEV_CELL_M;
        let fy = (y + BEV_HALF_EXTENT_M) / BEV_CELL_M;
        // `floor(f)` lies in [0, 60) exactly when `f` does, and there `floor(f) as usize` equals
        // `f as usize` (truncation), so no `floor` call is needed (it is a libm call on baseline
        // x86-64 and was a fifth of the BEV build time). Comparisons are false for NaN, so NaN
        // coordinates fall outside.
        if fx >= 0.0 && fx < BEV_CELLS as f32 && fy >= 0.0 && fy < BEV_CELLS as f32 {
            Some((fx as usize, fy as usize))
        } else {
            None
        }
    }

    /// Centre of cell (ix, iy) in the robot frame, m.
    #[inline]
    pub fn cell_center(ix: usize, iy: usize) -> (f32, f32) {
        (
            -BEV_HALF_EXTENT_M + (ix as f32 + 0.5) * BEV_CELL_M,
            -BEV_HALF_EXTENT_M + (iy as f32 + 0.5) * BEV_CELL_M,
        )
    }

    /// A cell holds points (density > 0).
    #[inline]
    pub fn occupied(&self, ix: usize, iy: usize) -> bool {
        self.get(CH_DENSITY, ix, iy) > 0.0
    }
}

impl Default for BevGrid {
    fn default() -> Self {
        Self::zeroed()
    }
}

// ---------------------------------------------------------------------------------------------
// Sensor mount and the robot frame

/// Why a BEV configuration was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum BevError {
    #[error("self-filter: {count} boxes given, at most {MAX_SELF_BOXES} supported")]
    TooManyBoxes { count: usize },
    #[error("self-filter: box {index} is inverted or not finite (need min <= max on every axis)")]
    InvalidBox { index: usize },
}

/// The lidar's pose in the base (pelvis) frame: `p_base = R_mount · p_sensor + xyz`, with
/// `R_mount = Rz(yaw) · Ry(pitch) · Rx(roll)` and `rpy = [roll, pitch, yaw]` (URDF convention).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MountPose {
    /// m, base frame.
    pub xyz: [f32; 3],
    /// rad.
    pub rpy: [f32; 3],
}

impl MountPose {
    /// MID-360 on the G1 per the latest unitree_ros URDF: `torso_link` at (-0.0039635, 0, 0.044)
    /// from the pelvis (waist joints at zero), `mid360_link` at (0.0002835, 0.00003, 0.428434) from
    /// the torso with rpy (π, 0.0511, 0), i.e. mounted upside down. Sources disagree (older URDF:
    /// z 0.41618, rpy (0, 0.0401, 0)): treat it as a calibrated parameter.
    pub const G1_MID360_DEFAULT: MountPose = MountPose {
        xyz: [-0.00368, 0.00003, 0.472434],
        rpy: [core::f32::consts::PI, 0.0511, 0.0],
    };

    /// Identity rotation, no offset.
    pub const IDENTITY: MountPose = MountPose {
        xyz: [0.0; 3],
        rpy: [0.0; 3],
    };
}

type M3 = [[f64; 3]; 3];

fn rot_x(a: f64) -> M3 {
    let (s, c) = libm::sincos(a);
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}
fn rot_y(a: f64) -> M3 {
    let (s, c) = libm::sincos(a);
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}
fn rot_z(a: f64) -> M3 {
    let (s, c) = libm::sincos(a);
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}
/// Rotation matrix (rows) of roll, pitch, yaw: `Rz(yaw) · Ry(pitch) · Rx(roll)` (URDF / ZYX Euler).
pub fn rpy_rotation(rpy: [f64; 3]) -> [[f64; 3]; 3] {
    mat_mul(&rot_z(rpy[2]), &mat_mul(&rot_y(rpy[1]), &rot_x(rpy[0])))
}

fn mat_mul(a: &M3, b: &M3) -> M3 {
    core::array::from_fn(|i| core::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}
fn mat_vec(a: &M3, v: [f64; 3]) -> [f64; 3] {
    core::array::from_fn(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

/// Maps sensor-frame points into the gravity-aligned robot frame of the grid:
/// `p_robot = Ry(pitch) · Rx(roll) · (R_mount · p_s + t_mount) + [0, 0, base_height]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotFrame {
    pub rot: [[f32; 3]; 3],
    pub trans: [f32; 3],
}

/// A torso-mounted sensor's chain on the G1: waist yaw about z at the pelvis origin, then waist
/// roll about x and pitch about y at `roll_pitch_origin` (Unitree's g1_29dof_rev_1_0 MJCF and URDF:
/// `waist_roll_link` at (-0.0039635, 0, 0.044) on `waist_yaw_link`, `torso_link` at its origin).
/// A [`MountPose`] is given with the waist at zero; the waist's PD holds it there only up to its
/// compliance (±0.035 rad of roll with the gait on the 29-dof G1), which tilts the whole cloud.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WaistChain {
    /// m, waist-yaw frame.
    pub roll_pitch_origin: [f32; 3],
}

impl WaistChain {
    pub const G1: WaistChain = WaistChain {
        roll_pitch_origin: [-0.0039635, 0.0, 0.044],
    };

    /// The sensor's rotation and position on the pelvis with the waist at `[yaw, roll, pitch]`
    /// (rad), for a `mount` given with the waist at zero.
    fn mount_at(&self, mount: &MountPose, waist: [f32; 3]) -> (M3, [f64; 3]) {
        let [yaw, roll, pitch] = waist.map(f64::from);
        let r_yaw = rot_z(yaw);
        let r_waist = mat_mul(&mat_mul(&r_yaw, &rot_x(roll)), &rot_y(pitch));
        let origin = self.roll_pitch_origin.map(f64::from);
        let xyz = mount.xyz.map(f64::from);
        let on_torso = [xyz[0] - origin[0], xyz[1] - origin[1], xyz[2] - origin[2]];
        let a = mat_vec(&r_yaw, origin);
        let b = mat_vec(&r_waist, on_torso);
        let rot = mat_mul(&r_waist, &rpy_rotation(mount.rpy.map(f64::from)));
        (rot, [a[0] + b[0], a[1] + b[1], a[2] + b[2]])
    }
}

impl RobotFrame {
    /// `roll`, `pitch`: the base's attitude (rad, ZYX Euler angles, yaw left out); `base_height`:
    /// height of the base origin above the ground under the robot, m. Composed in f64.
    pub fn new(mount: &MountPose, roll: f32, pitch: f32, base_height: f32) -> Self {
        Self::compose(
            rpy_rotation(mount.rpy.map(f64::from)),
            mount.xyz.map(f64::from),
            roll,
            pitch,
            base_height,
        )
    }

    /// As [`RobotFrame::new`] for a sensor on the torso: `mount` holds with the waist at zero, and
    /// `waist` (yaw, roll, pitch, rad, as measured) moves it along `chain`.
    pub fn on_waist(
        mount: &MountPose,
        chain: &WaistChain,
        waist: [f32; 3],
        roll: f32,
        pitch: f32,
        base_height: f32,
    ) -> Self {
        if waist == [0.0; 3] {
            // Exactly `new`'s bits (the chain's round trip through the waist origin is not).
            return Self::new(mount, roll, pitch, base_height);
        }
        let (rot, xyz) = chain.mount_at(mount, waist);
        Self::compose(rot, xyz, roll, pitch, base_height)
    }

    fn compose(r_mount: M3, xyz: [f64; 3], roll: f32, pitch: f32, base_height: f32) -> Self {
        let r_level = mat_mul(&rot_y(pitch as f64), &rot_x(roll as f64));
        let rot = mat_mul(&r_level, &r_mount);
        let mut trans = mat_vec(&r_level, xyz);
        trans[2] += base_height as f64;
        Self {
            rot: rot.map(|row| row.map(|v| v as f32)),
            trans: trans.map(|v| v as f32),
        }
    }

    /// `rot · p + trans`.
    #[inline]
    pub fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.rot;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + self.trans[0],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + self.trans[1],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + self.trans[2],
        ]
    }
}

// ---------------------------------------------------------------------------------------------
// Self filter

/// Axis-aligned box in the robot frame, m, bounds inclusive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Aabb {
    #[inline]
    pub fn contains(&self, p: [f32; 3]) -> bool {
        (0..3).all(|k| p[k] >= self.min[k] && p[k] <= self.max[k])
    }

    fn is_valid(&self) -> bool {
        (0..3).all(|k| self.min[k].is_finite() && self.max[k].is_finite() && self.min[k] <= self.max[k])
    }
}

/// Most boxes a [`SelfFilter`] holds.
pub const MAX_SELF_BOXES: usize = 8;

/// Drops returns off the robot's own body: points inside any of up to [`MAX_SELF_BOXES`] boxes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelfFilter {
    boxes: [Aabb; MAX_SELF_BOXES],
    count: usize,
}

const EMPTY_BOX: Aabb = Aabb {
    min: [0.0; 3],
    max: [0.0; 3],
};

impl SelfFilter {
    /// The whole column around the G1's body: x ∈ [−0.35, 0.35], y ∈ [−0.40, 0.40],
    /// z ∈ [−1.0, 2.5] (robot frame).
    pub const G1_DEFAULT: SelfFilter = SelfFilter {
        boxes: [
            Aabb {
                min: [-0.35, -0.40, -1.0],
                max: [0.35, 0.40, 2.5],
            },
            EMPTY_BOX,
            EMPTY_BOX,
            EMPTY_BOX,
            EMPTY_BOX,
            EMPTY_BOX,
            EMPTY_BOX,
            EMPTY_BOX,
        ],
        count: 1,
    };

    /// Filters nothing.
    pub const NONE: SelfFilter = SelfFilter {
        boxes: [EMPTY_BOX; MAX_SELF_BOXES],
        count: 0,
    };

    /// Rejects more than [`MAX_SELF_BOXES`] boxes and inverted or non-finite ones.
    pub fn new(boxes: &[Aabb]) -> Result<Self, BevError> {
        if boxes.len() > MAX_SELF_BOXES {
            return Err(BevError::TooManyBoxes { count: boxes.len() });
        }
        if let Some(index) = boxes.iter().position(|b| !b.is_valid()) {
            return Err(BevError::InvalidBox { index });
        }
        let mut f = Self::NONE;
        f.boxes[..boxes.len()].copy_from_slice(boxes);
        f.count = boxes.len();
        Ok(f)
    }

    pub fn boxes(&self) -> &[Aabb] {
        &self.boxes[..self.count]
    }

    #[inline]
    pub fn contains(&self, p: [f32; 3]) -> bool {
        self.boxes[..self.count].iter().any(|b| b.contains(p))
    }

    /// Whether a robot-frame point is terrain to grid: the one rule every gridding path (the
    /// builder, the firmware's motion-compensated frame, the dataset renderer) applies.
    #[inline]
    pub fn classify(&self, q: [f32; 3]) -> PointClass {
        if !(q[0].is_finite() && q[1].is_finite() && q[2].is_finite()) {
            PointClass::NonFinite
        } else if self.contains(q) {
            PointClass::SelfHit
        } else {
            PointClass::Terrain
        }
    }
}

/// What [`SelfFilter::classify`] makes of a robot-frame point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointClass {
    /// A NaN or infinite coordinate.
    NonFinite,
    /// On the robot's own body.
    SelfHit,
    /// Goes to the grid.
    Terrain,
}

// ---------------------------------------------------------------------------------------------
// Grid builder

/// Cells in one grid.
const CELLS: usize = BEV_CELLS * BEV_CELLS;

/// What happened to a build's input points: `input = used + self_hits + outside + non_finite`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BevStats {
    pub input: usize,
    /// Points that landed in a cell.
    pub used: usize,
    /// Points inside the self filter.
    pub self_hits: usize,
    /// Points outside the window.
    pub outside: usize,
    /// Points with a NaN or infinite coordinate (after the transform).
    pub non_finite: usize,
}

/// One cell's accumulators (32 bytes: one point touches one half cache line).
#[derive(Debug, Clone, Copy)]
struct Acc {
    sum: f64,
    sum_sq: f64,
    count: u32,
    min: f32,
    max: f32,
}

const ACC_EMPTY: Acc = Acc {
    sum: 0.0,
    sum_sq: 0.0,
    count: 0,
    min: f32::INFINITY,
    max: f32::NEG_INFINITY,
};

/// Builds [`BevGrid`]s from point clouds with fixed per-cell accumulators (point count, sum and sum
/// of squares of z in f64, min and max z): one pass over the points, one over the cells, no
/// allocation. Allocate once with [`new_boxed`](Self::new_boxed) (about 115 KB).
pub struct BevBuilder {
    cells: [Acc; CELLS],
}

impl BevBuilder {
    pub fn new_boxed() -> Box<Self> {
        Box::new(Self {
            cells: [ACC_EMPTY; CELLS],
        })
    }

    /// Sensor-frame points (e.g. a lidar frame) → `frame` → drop those inside `filter` → grid.
    pub fn build(
        &mut self,
        points: &[hal::LidarPoint],
        frame: &RobotFrame,
        filter: &SelfFilter,
        out: &mut BevGrid,
    ) -> BevStats {
        self.reset();
        let mut stats = BevStats {
            input: points.len(),
            ..BevStats::default()
        };
        for p in points {
            let q = frame.apply(p.xyz);
            match filter.classify(q) {
                PointClass::NonFinite => stats.non_finite += 1,
                PointClass::SelfHit => stats.self_hits += 1,
                PointClass::Terrain if self.add(q) => stats.used += 1,
                PointClass::Terrain => stats.outside += 1,
            }
        }
        self.finish(out);
        stats
    }

    /// Points already in the robot frame, no self filter.
    pub fn build_robot_points(&mut self, points: &[[f32; 3]], out: &mut BevGrid) -> BevStats {
        self.reset();
        let mut stats = BevStats {
            input: points.len(),
            ..BevStats::default()
        };
        for &q in points {
            if !(q[0].is_finite() && q[1].is_finite() && q[2].is_finite()) {
                stats.non_finite += 1;
            } else if self.add(q) {
                stats.used += 1;
            } else {
                stats.outside += 1;
            }
        }
        self.finish(out);
        stats
    }

    fn reset(&mut self) {
        self.cells.fill(ACC_EMPTY);
    }

    /// Accumulates a finite robot-frame point; false when it is outside the window.
    #[inline]
    fn add(&mut self, q: [f32; 3]) -> bool {
        let Some((ix, iy)) = BevGrid::cell_of(q[0], q[1]) else {
            return false;
        };
        let a = &mut self.cells[ix * BEV_CELLS + iy];
        let z = q[2];
        let zd = z as f64;
        a.count += 1;
        a.sum += zd;
        a.sum_sq += zd * zd;
        a.min = a.min.min(z);
        a.max = a.max.max(z);
        true
    }

    fn finish(&self, out: &mut BevGrid) {
        let max_count = self.cells.iter().map(|a| a.count).max().unwrap_or(0);
        let inv_max = if max_count > 0 { 1.0 / max_count as f64 } else { 0.0 };
        let (max_ch, rest) = out.data.split_at_mut(CELLS);
        let (min_ch, rest) = rest.split_at_mut(CELLS);
        let (mean_ch, rest) = rest.split_at_mut(CELLS);
        let (range_ch, rest) = rest.split_at_mut(CELLS);
        let (std_ch, density_ch) = rest.split_at_mut(CELLS);
        for (c, a) in self.cells.iter().enumerate() {
            let n = a.count;
            if n == 0 {
                max_ch[c] = 0.0;
                min_ch[c] = 0.0;
                mean_ch[c] = 0.0;
                range_ch[c] = 0.0;
                std_ch[c] = 0.0;
                density_ch[c] = 0.0;
                continue;
            }
            let nf = n as f64;
            let mean = a.sum / nf;
            let var = (a.sum_sq / nf - mean * mean).max(0.0);
            max_ch[c] = a.max;
            min_ch[c] = a.min;
            mean_ch[c] = mean as f32;
            range_ch[c] = a.max - a.min;
            std_ch[c] = var.sqrt() as f32;
            density_ch[c] = (nf * inv_max) as f32;
        }
    }
}

snapshot::snapshot_fields!(BevStats {
    input,
    used,
    self_hits,
    outside,
    non_finite
});
