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
}

/// Runs `steps` policy steps on every slot of `slots` (one worker's share).
pub fn rollout(
    slots: &mut [Slot],
    log_std: &[f32],
    steps: usize,
    obs_dim: usize,
    critic_dim: usize,
) -> anyhow::Result<()> {
    let a = log_std.len();
    let mut mean = vec![0.0f32; a];
    let mut act = vec![0.0f32; a];
    for slot in slots {
        let Slot { env, roll, rng, ends } = slot;
        env.net.read_state(&mut roll.state0);
        for s in 0..steps {
            let obs = env.observe_and_act(&mut mean)?;
            roll.obs[s * obs_dim..(s + 1) * obs_dim].copy_from_slice(obs);
            let cobs = &mut roll.critic_obs[s * critic_dim..(s + 1) * critic_dim];
            cobs[..obs_dim].copy_from_slice(obs);
            env.critic_extra(&mut cobs[obs_dim..]);
            for j in 0..a {
                act[j] = mean[j] + (log_std[j] as f64).exp() as f32 * rng.gaussian() as f32;
            }
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
