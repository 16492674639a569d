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
        let fx = ((x + BEV_HALF_EXTENT_M) / BEV_CELL_M).floor();
        let fy = ((y + BEV_HALF_EXTENT_M) / BEV_CELL_M).floor();
        // Comparisons are false for NaN, so NaN coordinates fall outside.
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
