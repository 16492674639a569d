//! The policy's two interfaces with the robot, defined once: state → observation, and action → PD
//! targets. The controller runs them on the robot and in `g1fw sim`; the PPO trainer (`g1-train
//! ppo`) runs the very same code on its simulated states, so trainer and firmware observe and act
//! identically by construction (`train/tests/` checks it on recorded states).
//!
//! Fixed allocation: every buffer is sized in [`PolicyIo::new`]; the per-step calls allocate nothing.
use hal::{LowState, TerrainToken, NUM_MOTORS};

use crate::obs::{ObsInputs, ObservationBuilder};
use crate::spec::{DeploySpec, PhaseRate};

pub struct PolicyIo {
    obs: ObservationBuilder,
    obs_buf: Vec<f32>,
    last_action: Vec<f32>,
    joint_pos_rel: Vec<f32>,
    joint_vel: Vec<f32>,
    action_scale: Vec<f32>,
    default_pose: Vec<f32>,
    joint_ids_map: Vec<usize>,
    cmd_min: Option<[f32; 3]>,
    cmd_max: Option<[f32; 3]>,
    /// Gait clock: (first step time, period) in seconds, if the spec has one.
    phase: Option<(f64, f64)>,
    /// A clock the policy sets (`[phase] rate`): its range, where in the period the newest
    /// observation is, and the rate the last action asked for.
    rate: Option<PhaseRate>,
    rate_phase: f64,
    next_rate: f64,
    /// The gait phase of the newest observation, in [0, 1).
    phase_now: f32,
    policy_hz: f64,
    action_clip: Option<f32>,
    /// Target limits per slot (robot joint range shrunk by the spec's margin).
    q_min: [f32; NUM_MOTORS],
    q_max: [f32; NUM_MOTORS],
    /// Policy steps since the last [`PolicyIo::reset`] (drives the gait phase clock).
    steps_since_reset: u64,
}

impl PolicyIo {
    pub fn new(spec: &DeploySpec) -> Self {
        let n = spec.num_joints();
        let p = &spec.policy;
        let (q_min, q_max) = crate::envelope::target_limits(spec.safety.joint_range_margin_rad);
        let phase = spec.phase.as_ref().map(|ph| (ph.first_step_time_s, ph.period_s));
        Self {
            obs: ObservationBuilder::new(spec),
            obs_buf: vec![0.0; spec.observation_dim()],
            last_action: vec![0.0; n],
            joint_pos_rel: vec![0.0; n],
            joint_vel: vec![0.0; n],
            action_scale: p.action_scale.expand(n).expect("validated by DeploySpec"),
            default_pose: p.default_pose.clone(),
            joint_ids_map: p.joint_ids_map.clone(),
            cmd_min: spec.commands.min,
            cmd_max: spec.commands.max,
            phase,
            rate: spec.phase.as_ref().and_then(|ph| ph.rate),
            rate_phase: clock_start(phase),
            next_rate: 1.0,
            phase_now: 0.0,
            policy_hz: spec.rates.policy_hz as f64,
            action_clip: p.action_clip,
            q_min,
            q_max,
            steps_since_reset: 0,
        }
    }

    /// A fresh episode: no history, last action zero, gait clock at its start.
    pub fn reset(&mut self) {
        self.last_action.iter_mut().for_each(|a| *a = 0.0);
        self.steps_since_reset = 0;
        self.rate_phase = clock_start(self.phase);
        self.next_rate = 1.0;
        self.obs.reset();
    }

    pub fn dim(&self) -> usize {
        self.obs_buf.len()
    }

    /// The operator command clamped to the spec's `[commands]` limits.
    pub fn clamp_command(&self, command: [f32; 3]) -> [f32; 3] {
        let mut cmd = command;
        if let Some(lo) = self.cmd_min {
            (0..3).for_each(|i| cmd[i] = cmd[i].max(lo[i]));
        }
        if let Some(hi) = self.cmd_max {
            (0..3).for_each(|i| cmd[i] = cmd[i].min(hi[i]));
        }
        cmd
    }

    /// Builds this policy step's observation from the robot's state, the operator command and
    /// the terrain token, and advances the gait clock. Returns the observation (length
    /// [`PolicyIo::dim`]); it may hold NaN if the state did (the caller decides what that means).
    pub fn observe(&mut self, state: &LowState, command: [f32; 3], terrain: TerrainToken) -> &[f32] {
        for (i, &slot) in self.joint_ids_map.iter().enumerate() {
            self.joint_pos_rel[i] = state.motors[slot].q - self.default_pose[i];
            self.joint_vel[i] = state.motors[slot].dq;
        }
        let phase = match (self.phase, self.rate) {
            // A fixed clock, from the step count (bit for bit as it has always been).
            (Some((first, period)), None) => {
                let t = first + self.steps_since_reset as f64 / self.policy_hz;
                (t.rem_euclid(period) / period) as f32
            }
            // A policy-set clock advances by the rate the last action chose.
            (Some((_, period)), Some(_)) => {
                if self.steps_since_reset > 0 {
                    self.rate_phase = (self.rate_phase + self.next_rate / (period * self.policy_hz)).rem_euclid(1.0);
                }
                self.rate_phase as f32
            }
            (None, _) => 0.0,
        };
        self.phase_now = phase;
        let inputs = ObsInputs {
            gyro: state.imu.gyroscope,
            quat: state.imu.quaternion,
            command: self.clamp_command(command),
            joint_pos_rel: &self.joint_pos_rel,
            joint_vel: &self.joint_vel,
            last_action: &self.last_action,
            phase,
            terrain,
        };
        self.obs.build(&inputs, &mut self.obs_buf);
        self.steps_since_reset += 1;
        &self.obs_buf
    }

    /// The newest observation.
    pub fn observation(&self) -> &[f32] {
        &self.obs_buf
    }

    /// The newest (clipped) action, as the next observation's `last_action` will see it.
    pub fn last_action(&self) -> &[f32] {
        &self.last_action
    }

    /// The gait phase the newest observation holds, in [0, 1) (0 without a clock).
    pub fn phase(&self) -> f32 {
        self.phase_now
    }

    /// The rate the gait clock runs at from the next observation on (1: nominal; always 1 for a
    /// fixed clock).
    pub fn clock_rate(&self) -> f64 {
        self.next_rate
    }

    /// Turns a raw network output into PD position targets: clip (spec `action_clip`), remember
    /// as the last action, `q = default + scale · action`, clamped to the joint range. Writes the
    /// policy's slots of `target_q` and returns how many targets were clamped. With a policy-set
    /// clock (`[phase] rate`) the output after the joints sets the clock's rate, clamped to its
    /// range; it reaches no motor and is not part of the next observation's last action.
    pub fn apply_action(&mut self, action: &[f32], target_q: &mut [f32; NUM_MOTORS]) -> u64 {
        if let (Some(r), Some(&raw)) = (self.rate, action.get(self.last_action.len())) {
            // max/min, not clamp: never panics; a NaN (the controller rejects one before this)
            // gives the slowest rate.
            self.next_rate = (1.0 + raw as f64).max(r.min).min(r.max);
        }
        for (a, &raw) in self.last_action.iter_mut().zip(action) {
            *a = match self.action_clip {
                // max/min, not clamp: never panics, whatever the spec held (validated c > 0).
                Some(c) => raw.max(-c).min(c),
                None => raw,
            };
        }
        let mut clamped = 0;
        for (i, &slot) in self.joint_ids_map.iter().enumerate() {
            let q = self.default_pose[i] + self.action_scale[i] * self.last_action[i];
            let c = q.max(self.q_min[slot]).min(self.q_max[slot]);
            clamped += (c != q) as u64;
            target_q[slot] = c;
        }
        clamped
    }
}

/// Where a policy-set clock starts, as a fraction of its period (the fixed clock's first step).
fn clock_start(phase: Option<(f64, f64)>) -> f64 {
    phase.map_or(0.0, |(first, period)| (first / period).rem_euclid(1.0))
}

snapshot::snapshot_fields!(PolicyIo {
    obs,
    obs_buf,
    last_action,
    joint_pos_rel,
    joint_vel,
    rate_phase,
    next_rate,
    phase_now,
    steps_since_reset,
});
