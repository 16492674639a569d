//! Assisted climbs (`g1-train ppo --assist-share`): a helping hand on the base that lets the
//! policy explore climbs it cannot yet do alone, decayed to nothing as training goes on.
//!
//! Why: every fine-tune from the committed actor plateaued at about 15.5 cm
//! (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-11-29 to 12-02). Training every
//! environment at 18 cm or more taught nothing (run 45: success 8–12 % with no trend), and more
//! action noise found nothing at all (run 46): at 18–22 cm the rollouts never contain the climb PPO
//! would need to reinforce. The climbs that get a foot onto the first tread end with the body
//! falling back over the trailing foot. A virtual assistant (Yu, Turk and Liu, "Learning Symmetric
//! and Low-Energy Locomotion", SIGGRAPH 2018) carries part of the weight, holds the torso upright,
//! damps its spin, lifts a base that sinks and pulls it along the staircase, so more such climbs
//! succeed while the legs learn the motion; its strength then decays linearly to zero over
//! `decay_steps` env steps, and the policy must carry itself.
//!
//! How strong: the committed actor at 17.6 / 21.8 cm up (`g1-train ppo-eval --randomization`, 16
//! episodes each) succeeds 1 / 0 times alone; at full strength with the weight share, the upright
//! torque and the pull only, 2 / 3 (falls on a sinking base and base spin); with the height spring
//! and yaw damping as well, 7 / 7 (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-12-02).
//!
//! The robot never has this: only training's simulator applies it ([`g1_sim::Simulator::
//! set_base_wrench`]), the policy does not observe it, and the export is the same network. An
//! assisted episode climbs a staircase drawn from `levels`, moves no curriculum level and is
//! left out of the success rates (it has its own, `success_assisted`).

/// Share of the robot's weight the assistant carries at full strength, upward on the base.
pub const SUPPORT_SHARE: f64 = 0.25;
/// Torque per unit of tilt (sin of the angle from upright) at full strength, N·m: at 30° it
/// matches about the torque of the weight over a 0.7 m lever.
pub const UPRIGHT_STIFFNESS: f64 = 400.0;
/// Torque per rad/s of roll, pitch and yaw rate at full strength, N·m·s (yaw only damped: a foot
/// meeting a riser spins the base, the commonest trip left once the torso is held up).
pub const UPRIGHT_DAMPING: f64 = 40.0;
/// Pull along the target heading per m/s the base is slower than commanded, N s/m.
pub const PULL_GAIN: f64 = 150.0;
/// The pull's cap, as a share of the robot's weight. It only pulls forward, never holds back.
pub const PULL_MAX_SHARE: f64 = 0.25;

/// Assisted climbs: how many, where, and for how long.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Assist {
    /// Share of the climbing columns' episodes (not stands) that are assisted. 0: none.
    pub share: f64,
    /// Curriculum levels an assisted episode's staircase is drawn from, inclusive.
    pub levels: (usize, usize),
    /// Env steps of the run over which the strength decays linearly from 1 to 0.
    pub decay_steps: u64,
}

impl Assist {
    /// No assisted episodes (the default).
    pub const OFF: Self = Self {
        share: 0.0,
        levels: (6, 8),
        decay_steps: 15_000_000,
    };

    /// The assistant's strength after `env_steps` of the run: 1 at the start, 0 from
    /// `decay_steps` on, and always 0 in a run without assisted episodes (as its log says).
    pub fn strength(&self, env_steps: u64) -> f64 {
        if self.decay_steps == 0 || self.share <= 0.0 {
            return 0.0;
        }
        (1.0 - env_steps as f64 / self.decay_steps as f64).clamp(0.0, 1.0)
    }
}

impl Default for Assist {
    fn default() -> Self {
        Self::OFF
    }
}

/// The base as the assistant sees it (world frame).
#[derive(Clone, Copy, Debug)]
pub struct BaseState {
    /// Orientation, (w, x, y, z).
    pub quat: [f64; 4],
    /// Angular velocity in the base's own frame, rad/s.
    pub ang_vel_body: [f64; 3],
    /// Linear velocity, m/s.
    pub lin_vel_world: [f64; 3],
    /// Height of the base over the ground under it, m.
    pub height: f64,
}

/// Where the height spring starts pushing: a base lower than this over the ground under it, m
/// (the G1 walks with its base about 0.75 m up).
pub const HEIGHT_TARGET_M: f64 = 0.72;
/// Upward force per metre the base sinks below [`HEIGHT_TARGET_M`] at full strength, N/m, and per
/// m/s it is still sinking there, N s/m.
pub const HEIGHT_STIFFNESS: f64 = 2000.0;
pub const HEIGHT_DAMPING: f64 = 200.0;

/// The assistant's force and torque on the base (world frame, N and N·m) at `strength` (0–1), for
/// a robot of `mass` kg asked to walk at `vx_cmd` m/s along `heading` (rad, world yaw).
pub fn wrench(strength: f64, mass: f64, base: &BaseState, heading: f64, vx_cmd: f64) -> ([f64; 3], [f64; 3]) {
    if strength <= 0.0 {
        return ([0.0; 3], [0.0; 3]);
    }
    let weight = mass * 9.81;
    let r = g1_sim::quat_to_mat(base.quat);
    // The base's up axis and its angular velocity, in the world.
    let up = [r[2], r[5], r[8]];
    let w = base.ang_vel_body;
    let w_world: [f64; 3] = std::array::from_fn(|i| r[3 * i] * w[0] + r[3 * i + 1] * w[1] + r[3 * i + 2] * w[2]);
    // up × e_z turns the up axis back to vertical, |·| = sin(tilt); yaw is only damped.
    let torque = [
        strength * (UPRIGHT_STIFFNESS * up[1] - UPRIGHT_DAMPING * w_world[0]),
        strength * (-UPRIGHT_STIFFNESS * up[0] - UPRIGHT_DAMPING * w_world[1]),
        -strength * UPRIGHT_DAMPING * w_world[2],
    ];
    let (c, s) = (heading.cos(), heading.sin());
    let along = base.lin_vel_world[0] * c + base.lin_vel_world[1] * s;
    let pull = (PULL_GAIN * (vx_cmd - along)).clamp(0.0, PULL_MAX_SHARE * weight);
    // Below the target height a spring lifts the base, damped only while it still sinks.
    let sink = HEIGHT_TARGET_M - base.height;
    let lift = if sink > 0.0 {
        HEIGHT_STIFFNESS * sink - HEIGHT_DAMPING * base.lin_vel_world[2].min(0.0)
    } else {
        0.0
    };
    let force = [
        strength * pull * c,
        strength * pull * s,
        strength * (SUPPORT_SHARE * weight + lift),
    ];
    (force, torque)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn upright(v: [f64; 3]) -> BaseState {
        BaseState {
            quat: [1.0, 0.0, 0.0, 0.0],
            ang_vel_body: [0.0; 3],
            lin_vel_world: v,
            height: 0.75,
        }
    }

    #[test]
    fn strength_decays_linearly_to_zero_and_stays_there() {
        let a = Assist {
            share: 0.5,
            levels: (6, 8),
            decay_steps: 1000,
        };
        assert_eq!(a.strength(0), 1.0);
        assert!((a.strength(250) - 0.75).abs() < 1e-12);
        assert_eq!(a.strength(1000), 0.0);
        assert_eq!(a.strength(5000), 0.0);
        assert_eq!(Assist { decay_steps: 0, ..a }.strength(0), 0.0);
        assert_eq!(Assist::OFF.strength(0), 0.0);
    }

    #[test]
    fn an_upright_robot_at_the_commanded_speed_gets_support_only() {
        let (f, t) = wrench(1.0, 30.0, &upright([0.5, 0.0, 0.0]), 0.0, 0.5);
        assert_eq!(t, [0.0; 3]);
        assert_eq!([f[0], f[1]], [0.0, 0.0]);
        assert!((f[2] - SUPPORT_SHARE * 30.0 * 9.81).abs() < 1e-9);
        // Faster than asked: no pull back.
        let (f, _) = wrench(1.0, 30.0, &upright([1.0, 0.0, 0.0]), 0.0, 0.5);
        assert_eq!([f[0], f[1]], [0.0, 0.0]);
        // Nothing at strength 0.
        assert_eq!(wrench(0.0, 30.0, &upright([0.0; 3]), 0.0, 0.5), ([0.0; 3], [0.0; 3]));
    }

    #[test]
    fn a_stalled_robot_is_pulled_along_the_heading_and_the_pull_is_capped() {
        let heading = 0.7f64;
        // 40 kg: the pull's cap (98 N) is above the 75 N asked.
        let (f, _) = wrench(0.5, 40.0, &upright([0.0; 3]), heading, 0.5);
        let pull = 0.5 * PULL_GAIN * 0.5;
        assert!((f[0] - pull * heading.cos()).abs() < 1e-9 && (f[1] - pull * heading.sin()).abs() < 1e-9);
        // Pushed back hard: the pull stops at its cap.
        let (f, _) = wrench(1.0, 30.0, &upright([-5.0, 0.0, 0.0]), 0.0, 0.5);
        assert!((f[0] - PULL_MAX_SHARE * 30.0 * 9.81).abs() < 1e-9);
    }

    #[test]
    fn a_sinking_base_is_lifted_and_a_spin_is_damped() {
        let mut b = upright([0.5, 0.0, -0.2]);
        b.height = HEIGHT_TARGET_M - 0.1;
        b.ang_vel_body = [0.0, 0.0, 2.0];
        let (f, t) = wrench(0.5, 30.0, &b, 0.0, 0.5);
        let want = 0.5 * (SUPPORT_SHARE * 30.0 * 9.81 + HEIGHT_STIFFNESS * 0.1 + HEIGHT_DAMPING * 0.2);
        assert!((f[2] - want).abs() < 1e-9, "{} vs {want}", f[2]);
        assert!((t[2] + 0.5 * UPRIGHT_DAMPING * 2.0).abs() < 1e-9, "{t:?}");
        // Rising back up: the spring only, no damping against the rise.
        b.lin_vel_world[2] = 0.3;
        let (f, _) = wrench(1.0, 30.0, &b, 0.0, 0.5);
        assert!((f[2] - (SUPPORT_SHARE * 30.0 * 9.81 + HEIGHT_STIFFNESS * 0.1)).abs() < 1e-9);
    }

    #[test]
    fn a_tilt_back_is_met_by_a_torque_that_pitches_the_base_forward() {
        // Pitched back (nose up) by 0.3 rad about the world's y axis: a rotation of -0.3 about y.
        let a = -0.3f64;
        let tilted = BaseState {
            quat: [(a / 2.0).cos(), 0.0, (a / 2.0).sin(), 0.0],
            ang_vel_body: [0.0, -1.0, 0.0],
            lin_vel_world: [0.5, 0.0, 0.0],
            height: 0.75,
        };
        let (_, t) = wrench(1.0, 30.0, &tilted, 0.0, 0.5);
        // Forward pitch is positive about y; both the stiffness and the damping push that way.
        let expect = UPRIGHT_STIFFNESS * 0.3f64.sin() + UPRIGHT_DAMPING;
        assert!((t[1] - expect).abs() < 1e-9, "{t:?} vs {expect}");
        assert!(t[0].abs() < 1e-9 && t[2] == 0.0);
        // A roll to the left (about +x) is met by a torque about -x.
        let b = 0.2f64;
        let rolled = BaseState {
            quat: [(b / 2.0).cos(), (b / 2.0).sin(), 0.0, 0.0],
            ..upright([0.5, 0.0, 0.0])
        };
        let (_, t) = wrench(1.0, 30.0, &rolled, 0.0, 0.5);
        assert!((t[0] + UPRIGHT_STIFFNESS * b.sin()).abs() < 1e-9 && t[1].abs() < 1e-9);
    }
}
