//! The paper's explicit terrain token z = (class, step height, step depth, yaw).

/// Terrain class s_t (the paper's three classes). The discriminant is the class index the networks use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum TerrainClass {
    #[default]
    Flat = 0,
    StairsUp = 1,
    StairsDown = 2,
}

impl TerrainClass {
    pub const ALL: [TerrainClass; 3] = [TerrainClass::Flat, TerrainClass::StairsUp, TerrainClass::StairsDown];

    pub const fn index(self) -> usize {
        self as usize
    }

    pub const fn from_index(i: usize) -> Option<Self> {
        match i {
            0 => Some(Self::Flat),
            1 => Some(Self::StairsUp),
            2 => Some(Self::StairsDown),
            _ => None,
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Flat => "flat",
            Self::StairsUp => "stairs-up",
            Self::StairsDown => "stairs-down",
        }
    }
}

/// Terrain token z_t.
///
/// Conventions (shared by ground truth, the geometric estimator and the CNN):
/// - `step_height_m`, `step_depth_m`: the step the robot is about to take (or is on), both ≥ 0;
///   0 on flat terrain.
/// - `yaw_rad`: θ = robot heading − direction of travel over the stairs (uphill for `StairsUp`,
///   downhill for `StairsDown`), wrapped to (−π, π]. Positive: the robot is turned left
///   (counter-clockwise, seen from above) of the stair direction, so in the robot's frame the stairs
///   run at angle −θ.
///   On flat terrain it is the robot's heading relative to the world's reference direction.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TerrainToken {
    pub class: TerrainClass,
    pub step_height_m: f32,
    pub step_depth_m: f32,
    pub yaw_rad: f32,
}

impl TerrainToken {
    pub const FLAT: TerrainToken = TerrainToken {
        class: TerrainClass::Flat,
        step_height_m: 0.0,
        step_depth_m: 0.0,
        yaw_rad: 0.0,
    };

    pub fn is_finite(&self) -> bool {
        self.step_height_m.is_finite() && self.step_depth_m.is_finite() && self.yaw_rad.is_finite()
    }
}

/// Wraps an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = 2.0 * core::f64::consts::PI;
    let mut r = a % two_pi;
    if r <= -core::f64::consts::PI {
        r += two_pi;
    } else if r > core::f64::consts::PI {
        r -= two_pi;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::PI;

    #[test]
    fn class_index_round_trips() {
        for c in TerrainClass::ALL {
            assert_eq!(TerrainClass::from_index(c.index()), Some(c));
        }
        assert_eq!(TerrainClass::from_index(3), None);
    }

    #[test]
    fn wrap_angle_lands_in_half_open_interval() {
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5 - 4.0 * PI) - 0.5).abs() < 1e-12);
        assert!((wrap_angle(-0.25) + 0.25).abs() < 1e-15);
    }
}
