//! Keyframe memory for the BEV grid.
//!
//! Why: the G1's MID-360 hangs upside down on the torso and sees nothing within ~0.8 m of the robot,
//! yet the terrain token describes the nearest riser ahead, which on a staircase is usually the one
//! at the robot's feet. A single frame cannot show it; the frames taken while the robot walked up to
//! it can. So the grid is built from the current frame plus a few remembered frames, mapped through
//! the state estimator's odometry into the current robot frame.
//!
//! Rules (shared by the firmware and the dataset renderer, so the network sees the same grids):
//! - a frame becomes a keyframe when the robot has moved [`MemoryConfig::spacing_m`] or turned
//!   [`MemoryConfig::turn_rad`] since the newest keyframe (or there is none); the oldest is dropped
//!   beyond [`MemoryConfig::keyframes`]. A robot that stops keeps the memory of its approach;
//! - a keyframe stores its points within [`MemoryConfig::keep_half_extent_m`] of the robot (more than
//!   the grid's 1.5 m: a frame taken 1 m back must cover the ground just ahead of the robot now), in
//!   the odometry frame, thinned with a fixed stride to at most `points_per_keyframe`;
//! - newest wins per cell: cells the current frame hits hold only current points; a cell it misses
//!   takes the points of the newest keyframe that hits it, and only those. Fresh data is never mixed
//!   with stale data, so odometry drift cannot smear a riser that is in view.
//!
//! Frames: robot points are in the grid's gravity-aligned robot frame (see [`crate::bev`]); an
//! [`OdomPose`] places that frame in the estimator's odometry frame.
//! Everything is allocated in [`BevMemory::new`]; stepping does not allocate.
use crate::bev::{BevBuilder, BevGrid, BevStats, BEV_CELLS};

/// Where the robot frame of one grid lies in the odometry frame: `p_odom = Rz(yaw)·(x, y, z −
/// height) + pos`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OdomPose {
    /// Base position in the odometry frame, m.
    pub pos: [f32; 3],
    /// Heading, rad.
    pub yaw: f32,
    /// The grid's base height (base above the ground under the robot), m.
    pub height: f32,
}

impl OdomPose {
    fn is_finite(&self) -> bool {
        self.pos.iter().all(|v| v.is_finite()) && self.yaw.is_finite() && self.height.is_finite()
    }
}

/// Memory settings: [`MemoryConfig::DEFAULT`] when the memory is on; [`BUILTIN_NETWORK_KEYFRAMES`]
/// says whether the firmware's built-in terrain network was trained with it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MemoryConfig {
    /// Keyframes kept (0: no memory, single-frame grids).
    pub keyframes: usize,
    /// Distance moved that makes a new keyframe, m.
    pub spacing_m: f32,
    /// Heading change that makes a new keyframe, rad.
    pub turn_rad: f32,
    /// Half side of the square (robot frame, at capture) whose points a keyframe keeps, m.
    pub keep_half_extent_m: f32,
    /// Most points one keyframe keeps.
    pub points_per_keyframe: usize,
}

impl MemoryConfig {
    pub const DEFAULT: MemoryConfig = MemoryConfig {
        keyframes: 4,
        spacing_m: 0.3,
        turn_rad: 0.35,
        keep_half_extent_m: 2.7,
        points_per_keyframe: 8192,
    };
    /// Single-frame grids.
    pub const OFF: MemoryConfig = Self::with_keyframes(0);
    /// What the built-in network was trained with.
    pub const BUILTIN: MemoryConfig = Self::with_keyframes(BUILTIN_NETWORK_KEYFRAMES);

    /// [`MemoryConfig::DEFAULT`] with `keyframes` keyframes.
    pub const fn with_keyframes(keyframes: usize) -> Self {
        MemoryConfig {
            keyframes,
            ..Self::DEFAULT
        }
    }
}

/// Most keyframes a memory may keep: each holds up to 8192 points and is merged into every grid.
/// The one bound of the firmware's `[perception] bev_memory_keyframes` and of every tool's
/// `--memory-keyframes` (a huge count once tried to allocate 446 GB).
pub const MAX_KEYFRAMES: usize = 16;

/// Parses a `--memory-keyframes` value, refusing counts above [`MAX_KEYFRAMES`].
pub fn parse_keyframes(s: &str) -> Result<usize, String> {
    let n: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number of keyframes"))?;
    if n > MAX_KEYFRAMES {
        return Err(format!(
            "{n} keyframes: at most {MAX_KEYFRAMES} (0: single-frame grids)"
        ));
    }
    Ok(n)
}

/// Keyframes of the grids the firmware's built-in terrain network was trained on: the default of
/// `[perception] bev_memory_keyframes`, of `g1-dataset export` and of `g1-train eval-terrain`, so
/// all three agree with the committed weights. 0: the committed weights are single-frame (trained on
/// 172 000 single-frame samples); a network trained on memory grids (4) is not yet better — see
/// docs/results.md.
pub const BUILTIN_NETWORK_KEYFRAMES: usize = 0;

impl Default for MemoryConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What one [`BevMemory::build`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MemoryStats {
    /// Keyframes held when the grid was built.
    pub keyframes: usize,
    /// Remembered points that went into the grid (in cells the current frame missed).
    pub points_used: usize,
    /// This frame became a keyframe.
    pub stored: bool,
}

const CELLS: usize = BEV_CELLS * BEV_CELLS;

/// The keyframe ring and the buffers to merge it (see the module documentation).
pub struct BevMemory {
    cfg: MemoryConfig,
    /// `keyframes × points_per_keyframe` odometry-frame points.
    points: Box<[[f32; 3]]>,
    counts: Box<[usize]>,
    poses: Box<[OdomPose]>,
    /// Slot of the newest keyframe, and how many are held.
    newest: usize,
    len: usize,
    /// Per cell: 0 free, 1 current frame, 2 + k the k-th newest keyframe.
    owner: Box<[u8; CELLS]>,
    /// Current points followed by the accepted remembered ones, robot frame.
    merged: Box<[[f32; 3]]>,
}

impl BevMemory {
    /// `current_cap`: most points a current frame brings. At most 250 keyframes are kept.
    pub fn new(cfg: MemoryConfig, current_cap: usize) -> Self {
        let cfg = MemoryConfig {
            keyframes: cfg.keyframes.min(250),
            ..cfg
        };
        let k = cfg.keyframes;
        Self {
            cfg,
            points: vec![[0.0; 3]; k * cfg.points_per_keyframe].into_boxed_slice(),
            counts: vec![0; k].into_boxed_slice(),
            poses: vec![OdomPose::default(); k].into_boxed_slice(),
            newest: 0,
            len: 0,
            owner: Box::new([0; CELLS]),
            merged: vec![[0.0; 3]; current_cap + k * cfg.points_per_keyframe].into_boxed_slice(),
        }
    }

    pub fn config(&self) -> &MemoryConfig {
        &self.cfg
    }

    /// Keyframes held.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Forgets every keyframe (e.g. when odometry is lost or reset).
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Slot of the `age`-th newest keyframe (0: newest).
    fn slot(&self, age: usize) -> usize {
        (self.newest + self.cfg.keyframes - age) % self.cfg.keyframes
    }

    /// A frame at `pose` would become a keyframe.
    pub fn due(&self, pose: &OdomPose) -> bool {
        if self.cfg.keyframes == 0 || !pose.is_finite() {
            return false;
        }
        if self.len == 0 {
            return true;
        }
        let last = &self.poses[self.newest];
        let (dx, dy) = (pose.pos[0] - last.pos[0], pose.pos[1] - last.pos[1]);
        let turned = hal::wrap_angle(f64::from(pose.yaw) - f64::from(last.yaw)).abs() as f32;
        dx * dx + dy * dy >= self.cfg.spacing_m * self.cfg.spacing_m || turned >= self.cfg.turn_rad
    }

    /// Stores robot-frame `points` seen at `pose` as the newest keyframe (dropping the oldest when
    /// full). Non-finite points are skipped.
    pub fn remember(&mut self, points: &[[f32; 3]], pose: &OdomPose) {
        if self.cfg.keyframes == 0 || !pose.is_finite() {
            return;
        }
        let slot = if self.len == 0 {
            0
        } else {
            (self.newest + 1) % self.cfg.keyframes
        };
        let cap = self.cfg.points_per_keyframe;
        let keep = self.cfg.keep_half_extent_m;
        let inside = |q: &[f32; 3]| q.iter().all(|v| v.is_finite()) && q[0].abs() <= keep && q[1].abs() <= keep;
        let candidates = points.iter().filter(|q| inside(q)).count();
        // A fixed stride (not random) keeps the memory a pure function of its inputs.
        let stride = candidates.div_ceil(cap).max(1);
        let (s, c) = libm::sincosf(pose.yaw);
        let dst = &mut self.points[slot * cap..(slot + 1) * cap];
        let mut n = 0;
        for q in points.iter().filter(|q| inside(q)).step_by(stride) {
            let z = q[2] - pose.height;
            dst[n] = [
                c * q[0] - s * q[1] + pose.pos[0],
                s * q[0] + c * q[1] + pose.pos[1],
                z + pose.pos[2],
            ];
            n += 1;
        }
        self.counts[slot] = n;
        self.poses[slot] = *pose;
        self.newest = slot;
        self.len = (self.len + 1).min(self.cfg.keyframes);
    }

    /// Grids the current frame's robot-frame `current` points at `pose` together with the
    /// remembered keyframes (newest wins per cell), then stores the frame as a keyframe if
    /// [`due`](Self::due). Points beyond the merge buffer (more than `current_cap`) are dropped.
    pub fn build(
        &mut self,
        current: &[[f32; 3]],
        pose: &OdomPose,
        builder: &mut BevBuilder,
        out: &mut BevGrid,
    ) -> (BevStats, MemoryStats) {
        let mut mem = MemoryStats {
            keyframes: self.len,
            ..MemoryStats::default()
        };
        let n_cur = current.len().min(self.merged.len() - self.points.len());
        let stats = if self.len == 0 || !pose.is_finite() {
            // Nothing to merge (always so with the memory off): grid the frame in place, no copy.
            builder.build_robot_points(&current[..n_cur], out)
        } else {
            let n = self.merge(&current[..n_cur], pose);
            mem.points_used = n - n_cur;
            builder.build_robot_points(&self.merged[..n], out)
        };
        if self.due(pose) {
            self.remember(current, pose);
            mem.stored = true;
        }
        (stats, mem)
    }

    /// Copies `current` into the merge buffer followed by the remembered points, mapped into the
    /// robot frame at `pose`, that land in cells `current` misses (newest keyframe wins per cell);
    /// returns how many points the buffer holds.
    fn merge(&mut self, current: &[[f32; 3]], pose: &OdomPose) -> usize {
        self.merged[..current.len()].copy_from_slice(current);
        let mut n = current.len();
        self.owner.fill(0);
        for q in current {
            if let Some((ix, iy)) = BevGrid::cell_of(q[0], q[1]) {
                self.owner[ix * BEV_CELLS + iy] = 1;
            }
        }
        let (s, c) = libm::sincosf(pose.yaw);
        let cap = self.cfg.points_per_keyframe;
        for age in 0..self.len {
            let slot = self.slot(age);
            let tag = 2 + age as u8;
            for p in &self.points[slot * cap..slot * cap + self.counts[slot]] {
                let (dx, dy) = (p[0] - pose.pos[0], p[1] - pose.pos[1]);
                let q = [c * dx + s * dy, -s * dx + c * dy, p[2] - pose.pos[2] + pose.height];
                let Some((ix, iy)) = BevGrid::cell_of(q[0], q[1]) else {
                    continue;
                };
                let o = &mut self.owner[ix * BEV_CELLS + iy];
                if *o == 0 || *o == tag {
                    *o = tag;
                    self.merged[n] = q;
                    n += 1;
                }
            }
        }
        n
    }
}

snapshot::snapshot_fields!(OdomPose { pos, yaw, height });

/// The keyframes held (each slot's points up to its count), not the merge buffers.
impl snapshot::Snapshot for BevMemory {
    fn save(&self, out: &mut Vec<u8>) {
        self.counts.save(out);
        self.poses.save(out);
        self.newest.save(out);
        self.len.save(out);
        let per = self.cfg.points_per_keyframe;
        for (slot, &n) in self.counts.iter().enumerate() {
            for p in &self.points[slot * per..slot * per + n] {
                p.save(out);
            }
        }
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        use snapshot::SnapshotError;
        self.counts.restore(input)?;
        self.poses.restore(input)?;
        self.newest.restore(input)?;
        self.len.restore(input)?;
        let (per, k) = (self.cfg.points_per_keyframe, self.cfg.keyframes);
        if self.len > k || (k > 0 && self.newest >= k) {
            return Err(SnapshotError::Invalid {
                what: "keyframe ring",
                value: self.len as u64,
            });
        }
        for slot in 0..self.counts.len() {
            let n = self.counts[slot];
            if n > per {
                return Err(SnapshotError::Length {
                    what: "keyframe points",
                    expected: per,
                    found: n as u64,
                });
            }
            for p in &mut self.points[slot * per..slot * per + n] {
                p.restore(input)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn memory_keyframes_are_bounded_before_anything_is_allocated() {
        assert_eq!(super::parse_keyframes("4"), Ok(4));
        assert_eq!(super::parse_keyframes("16"), Ok(16));
        let e = super::parse_keyframes("4294967295").unwrap_err();
        assert!(e.contains("at most 16"), "{e}");
        assert!(super::parse_keyframes("-1").unwrap_err().contains("whole number"));
    }

    use super::*;
    use crate::bev::{CH_DENSITY, CH_MAX};

    fn pose(x: f32, yaw: f32) -> OdomPose {
        OdomPose {
            pos: [x, 0.0, 0.8],
            yaw,
            height: 0.8,
        }
    }

    /// A patch of points at height `z` around robot-frame (x, y).
    fn patch(x: f32, y: f32, z: f32) -> Vec<[f32; 3]> {
        (0..4)
            .flat_map(|i| (0..4).map(move |j| [x + 0.01 * i as f32, y + 0.01 * j as f32, z]))
            .collect()
    }

    #[test]
    fn a_remembered_patch_lands_where_the_robot_has_moved_it() {
        let mut m = BevMemory::new(MemoryConfig::DEFAULT, 1000);
        let (mut b, mut g) = (BevBuilder::new_boxed(), Box::new(BevGrid::zeroed()));
        // Seen 1.0 m ahead from x = 0, then the robot walks to x = 0.6 (that patch is now 0.4 m
        // ahead, inside the blind disc) with nothing in view.
        let (_, s0) = m.build(&patch(1.0, 0.2, 0.15), &pose(0.0, 0.0), &mut b, &mut g);
        assert!(s0.stored && m.len() == 1);
        let (stats, s1) = m.build(&[], &pose(0.6, 0.0), &mut b, &mut g);
        assert_eq!((s1.keyframes, s1.points_used, stats.used), (1, 16, 16));
        let (ix, iy) = BevGrid::cell_of(0.415, 0.215).unwrap();
        assert!(g.occupied(ix, iy));
        assert!((g.get(CH_MAX, ix, iy) - 0.15).abs() < 1e-5);
        // Turned by 90° left in place: "ahead" is now the robot's right.
        let (_, s2) = m.build(&[], &pose(0.6, core::f32::consts::FRAC_PI_2), &mut b, &mut g);
        assert!(s2.stored, "a 90° turn makes a keyframe");
        let (ix, iy) = BevGrid::cell_of(0.215, -0.415).unwrap();
        assert!(g.occupied(ix, iy), "rotated into the right half");
    }

    #[test]
    fn the_current_frame_owns_its_cells_and_the_newest_keyframe_wins() {
        let mut m = BevMemory::new(MemoryConfig::DEFAULT, 1000);
        let (mut b, mut g) = (BevBuilder::new_boxed(), Box::new(BevGrid::zeroed()));
        m.build(&patch(1.0, 0.0, 0.10), &pose(0.0, 0.0), &mut b, &mut g); // old: z 0.10
        m.build(&patch(0.6, 0.0, 0.20), &pose(0.4, 0.0), &mut b, &mut g); // newer: z 0.20, same spot
        assert_eq!(m.len(), 2);
        let (ix, iy) = BevGrid::cell_of(0.615, 0.015).unwrap();
        // Nothing current there: the newer keyframe alone fills it.
        m.build(&[], &pose(0.4, 0.0), &mut b, &mut g);
        assert!((g.get(CH_MAX, ix, iy) - 0.20).abs() < 1e-5);
        // The current frame hits the cell: only its points count.
        m.build(&patch(0.6, 0.0, 0.30), &pose(0.4, 0.0), &mut b, &mut g);
        assert!((g.get(CH_MAX, ix, iy) - 0.30).abs() < 1e-5);
        assert!((g.get(crate::bev::CH_MIN, ix, iy) - 0.30).abs() < 1e-5);
        assert!(g.get(CH_DENSITY, ix, iy) > 0.0);
    }

    #[test]
    fn keyframes_come_with_distance_and_the_oldest_is_dropped() {
        let cfg = MemoryConfig {
            keyframes: 2,
            ..MemoryConfig::DEFAULT
        };
        let mut m = BevMemory::new(cfg, 100);
        let (mut b, mut g) = (BevBuilder::new_boxed(), Box::new(BevGrid::zeroed()));
        let mut stored = 0;
        for k in 0..10 {
            let (_, s) = m.build(&patch(1.0, 0.0, 0.1), &pose(0.1 * k as f32, 0.0), &mut b, &mut g);
            stored += s.stored as usize;
        }
        // x = 0, 0.3, 0.6, 0.9 (float sums may put one at the next 0.1).
        assert!((3..=4).contains(&stored), "{stored}");
        assert_eq!(m.len(), 2);
        // Standing still never adds one.
        let (_, s) = m.build(&[], &pose(0.9, 0.0), &mut b, &mut g);
        assert!(!s.stored);
        m.clear();
        assert!(m.is_empty());
    }

    #[test]
    fn a_keyframe_is_thinned_to_its_capacity_and_bad_poses_are_ignored() {
        let cfg = MemoryConfig {
            points_per_keyframe: 10,
            ..MemoryConfig::DEFAULT
        };
        let mut m = BevMemory::new(cfg, 100);
        let pts: Vec<[f32; 3]> = (0..95).map(|i| [0.01 * i as f32, 0.0, 0.0]).collect();
        m.remember(&pts, &pose(0.0, 0.0));
        assert!(m.counts[m.newest] <= 10 && m.counts[m.newest] >= 9);
        let before = m.len();
        m.remember(&pts, &pose(f32::NAN, 0.0));
        assert_eq!(m.len(), before);
        let (mut b, mut g) = (BevBuilder::new_boxed(), Box::new(BevGrid::zeroed()));
        let (_, s) = m.build(&pts, &pose(f32::NAN, 0.0), &mut b, &mut g);
        assert_eq!((s.points_used, s.stored), (0, false));
    }

    #[test]
    fn off_is_the_single_frame_grid() {
        let mut m = BevMemory::new(MemoryConfig::OFF, 100);
        let (mut b, mut g1, mut g2) = (
            BevBuilder::new_boxed(),
            Box::new(BevGrid::zeroed()),
            Box::new(BevGrid::zeroed()),
        );
        let pts = patch(1.0, 0.0, 0.1);
        m.build(&pts, &pose(0.0, 0.0), &mut b, &mut g1);
        m.build(&pts, &pose(1.0, 0.0), &mut b, &mut g1);
        b.build_robot_points(&pts, &mut g2);
        assert_eq!(g1.data, g2.data);
        assert!(m.is_empty());
    }
}
