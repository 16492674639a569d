//! Rollouts: every environment of a worker's share steps the actor (the firmware's executor inside
//! the environment) with Gaussian exploration noise, filling its buffer for the update.
use labkit::rng::Rng;

use super::algo::{gaussian_logp, EnvRollout};
use super::env::StairEnv;

/// One environment with its rollout buffer, its action noise and the episodes it finished.
pub struct Slot {
    pub env: StairEnv,
    pub roll: EnvRollout,
    pub rng: Rng,
    pub ends: Vec<super::env::EpisodeEnd>,
    /// The held part of the action noise ([`NoiseHold`]): its unit draws and the steps left.
    pub held: Vec<f32>,
    pub held_left: usize,
}

/// Temporally correlated exploration for the outputs from `from` on (the gait clock's rate): their
/// unit noise is drawn once every `every` policy steps (and at each episode start) and held in
/// between. White noise on a rate averages out within one step of the gait, so PPO would never see
/// what a sustained slower clock does. The log-probability stays the per-step Gaussian's, as with
/// any correlated exploration (gSDE, pink noise). `every` ≤ 1: every output draws each step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NoiseHold {
    pub from: usize,
    pub every: usize,
}

/// One exploratory action: `mean` plus σ times unit Gaussian noise, where the last `held.len()`
/// outputs take `held`, redrawn when `held_left` runs out (then held `every` steps).
fn explore(
    act: &mut [f32],
    mean: &[f32],
    log_std: &[f32],
    rng: &mut Rng,
    held: &mut [f32],
    held_left: &mut usize,
    every: usize,
) {
    let held_from = act.len() - held.len();
    if *held_left == 0 {
        for h in held.iter_mut() {
            *h = rng.gaussian() as f32;
        }
        *held_left = every.max(1);
    }
    *held_left -= 1;
    for j in 0..act.len() {
        let unit = if j < held_from {
            rng.gaussian() as f32
        } else {
            held[j - held_from]
        };
        act[j] = mean[j] + (log_std[j] as f64).exp() as f32 * unit;
    }
}

/// Runs `steps` policy steps on every slot of `slots` (one worker's share).
pub fn rollout(
    slots: &mut [Slot],
    log_std: &[f32],
    hold: NoiseHold,
    steps: usize,
    obs_dim: usize,
    critic_dim: usize,
) -> anyhow::Result<()> {
    let a = log_std.len();
    let mut mean = vec![0.0f32; a];
    let mut act = vec![0.0f32; a];
    let held_count = if hold.every > 1 { a - hold.from.min(a) } else { 0 };
    for slot in slots {
        let Slot {
            env,
            roll,
            rng,
            ends,
            held,
            held_left,
        } = slot;
        held.resize(held_count, 0.0);
        env.net.read_state(&mut roll.state0);
        for s in 0..steps {
            let obs = env.observe_and_act(&mut mean)?;
            roll.obs[s * obs_dim..(s + 1) * obs_dim].copy_from_slice(obs);
            let cobs = &mut roll.critic_obs[s * critic_dim..(s + 1) * critic_dim];
            cobs[..obs_dim].copy_from_slice(obs);
            env.critic_extra(&mut cobs[obs_dim..]);
            explore(&mut act, &mean, log_std, rng, held, held_left, hold.every);
            roll.means[s * a..(s + 1) * a].copy_from_slice(&mean);
            roll.actions[s * a..(s + 1) * a].copy_from_slice(&act);
            roll.logp[s] = gaussian_logp(&act, &mean, log_std);
            let out = env.step(&act)?;
            roll.rewards[s] = out.reward;
            roll.terminated[s] = out.terminated;
            roll.truncated[s] = out.truncated;
            roll.masks[s] = if s > 0 && (roll.terminated[s - 1] || roll.truncated[s - 1]) {
                0.0
            } else {
                1.0
            };
            if out.truncated {
                let f = &mut roll.final_critic_obs[s * critic_dim..(s + 1) * critic_dim];
                let o = env.observe_peek();
                f[..obs_dim].copy_from_slice(&o);
                env.critic_extra(&mut f[obs_dim..]);
            }
            if out.terminated || out.truncated {
                *held_left = 0; // a new episode draws its own
                env.reset()?;
                if let Some(e) = env.last_end {
                    ends.push(e);
                }
            }
        }
        let o = env.observe_peek();
        roll.next_critic_obs[..obs_dim].copy_from_slice(&o);
        env.critic_extra(&mut roll.next_critic_obs[obs_dim..]);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_noise_lasts_its_steps_and_the_rest_draws_each_step() {
        let (mean, log_std) = (vec![0.0f32; 4], vec![0.0f32; 4]);
        let mut act = vec![0.0f32; 4];
        let (mut rng, mut held, mut left) = (Rng(3), vec![0.0f32; 1], 0usize);
        let mut rows = Vec::new();
        for _ in 0..12 {
            explore(&mut act, &mean, &log_std, &mut rng, &mut held, &mut left, 5);
            rows.push(act.clone());
        }
        for (k, r) in rows.iter().enumerate() {
            // The rate (last output) changes only at steps 0, 5, 10.
            let same_as_prev = k > 0 && r[3] == rows[k - 1][3];
            assert_eq!(same_as_prev, k % 5 != 0, "step {k}: {rows:?}");
            // Every joint draws anew each step.
            assert!(k == 0 || (0..3).all(|j| r[j] != rows[k - 1][j]), "step {k}");
        }
    }

    #[test]
    fn without_hold_the_noise_is_the_per_step_draw_bit_for_bit() {
        let mean = vec![0.1f32, -0.2, 0.3];
        let log_std = vec![-1.0f32, -2.0, -0.5];
        let mut act = vec![0.0f32; 3];
        let (mut rng, mut left) = (Rng(9), 0usize);
        let mut plain = Rng(9);
        for _ in 0..10 {
            explore(&mut act, &mean, &log_std, &mut rng, &mut [], &mut left, 1);
            for j in 0..3 {
                let want = mean[j] + (log_std[j] as f64).exp() as f32 * plain.gaussian() as f32;
                assert_eq!(act[j].to_bits(), want.to_bits());
            }
        }
    }
}
