//! Commanded turns on staircases (`g1-train ppo --stair-turns SHARE`).
//!
//! Why: through `g1fw` the policy turns on its own on a flight, at 0.4–0.8 rad/s against heading
//! hold's −0.24 … +0.07 rad/s, while on flat ground it follows the turn rate within 0.08 rad/s
//! RMSE; a quarter of the failed climbs end off the side of the staircase and the yawed presets
//! trip. In training a staircase episode only ever asks to hold the staircase's axis, so the turn
//! rate is rarely commanded where the robot climbs. IsaacLab's rough-terrain G1 draws random
//! headings on every terrain. Here the target heading leaves the axis for a moment and comes back,
//! so the policy hears turn-rate commands of either sign (heading hold's, up to its limit) while it
//! is on the approach or the flight, and is paid by the same `track_ang_vel_z` kernel to follow them.
//! `progress` and `drift` keep measuring along the axis.

use labkit::rng::Rng;

/// When the turn starts, s after the episode's start: the approach and the flight (the first riser
/// is ~1–2 s away at the commanded speeds, and a flight takes 3–8 s).
pub const START_S: (f64, f64) = (1.0, 7.0);
/// How long the target heading stays off the axis, s.
pub const HOLD_S: (f64, f64) = (1.0, 2.5);
/// How far the target heading leaves the axis, rad (either side): heading hold's 0.5 rad/s
/// limit is reached from ~0.5 rad, and 0.45 rad for 2.5 s at 0.8 m/s moves the base ~0.6 m
/// across, inside the narrowest staircase's half width with the robot's own drift.
pub const OFFSET_RAD: (f64, f64) = (0.15, 0.45);

/// One episode's commanded turn: the target heading sits `offset_rad` off the staircase's axis
/// from `start_s` until `end_s`, and on the axis before and after.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StairTurn {
    pub start_s: f64,
    pub end_s: f64,
    pub offset_rad: f64,
}

impl StairTurn {
    /// Draws a turn: start, length and size uniform in [`START_S`], [`HOLD_S`] and
    /// [`OFFSET_RAD`], left or right with equal chance.
    pub fn draw(rng: &mut Rng) -> Self {
        let start_s = rng.range(START_S.0, START_S.1);
        let end_s = start_s + rng.range(HOLD_S.0, HOLD_S.1);
        let size = rng.range(OFFSET_RAD.0, OFFSET_RAD.1);
        let offset_rad = if rng.chance(0.5) { size } else { -size };
        Self {
            start_s,
            end_s,
            offset_rad,
        }
    }

    /// The target heading's offset from the axis at `t_s`, rad.
    pub fn offset_at(&self, t_s: f64) -> f64 {
        if (self.start_s..self.end_s).contains(&t_s) {
            self.offset_rad
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turns_stay_in_their_ranges_go_both_ways_and_return_to_the_axis() {
        let mut rng = Rng(7);
        let turns: Vec<StairTurn> = (0..2000).map(|_| StairTurn::draw(&mut rng)).collect();
        for t in &turns {
            assert!((START_S.0..START_S.1).contains(&t.start_s), "{t:?}");
            let hold = t.end_s - t.start_s;
            assert!((HOLD_S.0..HOLD_S.1).contains(&hold), "{t:?}");
            assert!((OFFSET_RAD.0..OFFSET_RAD.1).contains(&t.offset_rad.abs()), "{t:?}");
            assert_eq!(t.offset_at(t.start_s - 1e-9), 0.0);
            assert_eq!(t.offset_at(t.start_s), t.offset_rad);
            assert_eq!(t.offset_at(0.5 * (t.start_s + t.end_s)), t.offset_rad);
            assert_eq!(t.offset_at(t.end_s), 0.0, "back on the axis after the turn");
        }
        let left = turns.iter().filter(|t| t.offset_rad > 0.0).count();
        assert!((900..1100).contains(&left), "left turns {left} of 2000");
    }

    #[test]
    fn no_turn_keeps_the_axis() {
        let t = StairTurn::default();
        assert!((0..1000).all(|i| t.offset_at(i as f64 * 0.02) == 0.0));
    }
}
