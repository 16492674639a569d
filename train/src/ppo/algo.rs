//! PPO as rsl_rl does it (the runner legged_gym, IsaacLab and mjlab use), readable top to bottom:
//! rollouts of `steps` per environment, GAE, then `epochs` passes over `minibatches` of whole
//! environment sequences (the actor is recurrent: each sequence is replayed from the LSTM state it
//! started from, resetting where an episode started), with the clipped surrogate, clipped value
//! loss, entropy bonus, gradient-norm clipping and the adaptive-KL learning rate.
use candle_core::{Device, Tensor, Var};
use labkit::rng::Rng;

use super::adam::Adam;
use super::mlp_update::{FusedMlp, Minibatch, StepSettings};

use super::policy::ActorCritic;
use super::symmetry::{Mirror, SignedPermutation};

#[derive(Clone, Copy, Debug)]
pub struct PpoConfig {
    pub steps: usize,
    pub epochs: usize,
    pub minibatches: usize,
    pub clip: f64,
    pub value_coef: f64,
    pub entropy_coef: f64,
    pub gamma: f64,
    pub lambda: f64,
    pub max_grad_norm: f64,
    pub desired_kl: f64,
    pub lr: f64,
    /// How an LSTM actor's recurrence is differentiated (the fused op; the bench compares).
    pub recurrence: super::policy::Recurrence,
    /// A feed-forward actor's update without a tensor graph ([`super::mlp_update`]); off: candle's
    /// ops (the reference the fused step is checked against, and the bench's baseline).
    pub fused_mlp: bool,
    /// The largest action noise σ per output, applied after every update (`None`: no cap). Where a
    /// joint's target saturates at its range (the G1's ankle roll: ±0.26 rad against 0.25 rad per
    /// unit of action), more noise no longer changes the return, the surrogate stops pulling σ down
    /// and the entropy bonus inflates it without bound (the reference run's ankle roll reached σ 2.6).
    pub max_std: Option<f64>,
}

impl Default for PpoConfig {
    /// rsl_rl's defaults, except the learning rate: 1e-4 to start a fine-tune (adaptive from there).
    fn default() -> Self {
        Self {
            steps: 24,
            epochs: 5,
            minibatches: 4,
            clip: 0.2,
            value_coef: 1.0,
            entropy_coef: 0.005,
            gamma: 0.99,
            lambda: 0.95,
            max_grad_norm: 1.0,
            desired_kl: 0.01,
            lr: 1e-4,
            recurrence: super::policy::Recurrence::Fused,
            fused_mlp: true,
            max_std: None,
        }
    }
}

/// One environment's rollout: `steps` rows of everything PPO needs.
pub struct EnvRollout {
    pub obs: Vec<f32>,
    pub critic_obs: Vec<f32>,
    pub actions: Vec<f32>,
    pub means: Vec<f32>,
    pub logp: Vec<f32>,
    pub rewards: Vec<f32>,
    pub terminated: Vec<bool>,
    pub truncated: Vec<bool>,
    /// 0 where an episode starts at this step (the LSTM state is reset before it).
    pub masks: Vec<f32>,
    /// Critic observation of the final state of an episode truncated at this step.
    pub final_critic_obs: Vec<f32>,
    /// Critic observation after the last step (bootstrap).
    pub next_critic_obs: Vec<f32>,
    /// The actor's recurrent state (LSTM h then c) before step 0; empty for an MLP.
    pub state0: Vec<f32>,
    // Filled by the learner.
    pub values: Vec<f32>,
    pub advantages: Vec<f32>,
    pub returns: Vec<f32>,
}

impl EnvRollout {
    pub fn new(steps: usize, obs: usize, critic: usize, act: usize, state: usize) -> Self {
        Self {
            obs: vec![0.0; steps * obs],
            critic_obs: vec![0.0; steps * critic],
            actions: vec![0.0; steps * act],
            means: vec![0.0; steps * act],
            logp: vec![0.0; steps],
            rewards: vec![0.0; steps],
            terminated: vec![false; steps],
            truncated: vec![false; steps],
            masks: vec![1.0; steps],
            final_critic_obs: vec![0.0; steps * critic],
            next_critic_obs: vec![0.0; critic],
            state0: vec![0.0; state],
            values: vec![0.0; steps],
            advantages: vec![0.0; steps],
            returns: vec![0.0; steps],
        }
    }
}

/// log N(a; mean, exp(log_std)) summed over dimensions.
pub fn gaussian_logp(a: &[f32], mean: &[f32], log_std: &[f32]) -> f32 {
    let mut s = 0.0f64;
    for ((&a, &m), &ls) in a.iter().zip(mean).zip(log_std) {
        let z = (a - m) as f64 / (ls as f64).exp();
        s += -0.5 * z * z - ls as f64 - 0.5 * (2.0 * std::f64::consts::PI).ln();
    }
    s as f32
}

/// Running mean and variance of the critic's inputs (Welford), applied before the critic.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Normalizer {
    pub count: f64,
    pub mean: Vec<f64>,
    pub m2: Vec<f64>,
}

impl Normalizer {
    pub fn new(dim: usize) -> Self {
        Self {
            count: 0.0,
            mean: vec![0.0; dim],
            m2: vec![0.0; dim],
        }
    }

    pub fn update(&mut self, rows: &[f32]) {
        let d = self.mean.len();
        for row in rows.chunks_exact(d) {
            self.count += 1.0;
            for (i, &x) in row.iter().enumerate() {
                let delta = x as f64 - self.mean[i];
                self.mean[i] += delta / self.count;
                self.m2[i] += delta * (x as f64 - self.mean[i]);
            }
        }
    }

    pub fn apply(&self, rows: &[f32]) -> Vec<f32> {
        let std: Vec<f64> = self
            .m2
            .iter()
            .map(|m| (m / self.count.max(1.0) + 1e-8).sqrt())
            .collect();
        // One output vector (this ran a row at a time, a vector each: 3 % of a training run).
        let d = self.mean.len();
        let mut out = Vec::with_capacity(rows.len());
        for row in rows.chunks_exact(d) {
            for ((&x, &mean), &s) in row.iter().zip(&self.mean).zip(&std) {
                out.push(((x as f64 - mean) / s).clamp(-5.0, 5.0) as f32);
            }
        }
        out
    }
}

/// Values for every row of `rows` (critic inputs, un-normalised).
pub fn values(ac: &ActorCritic, norm: &Normalizer, rows: &[f32]) -> candle_core::Result<Vec<f32>> {
    let n = rows.len() / ac.critic_dim;
    if n == 0 {
        return Ok(Vec::new());
    }
    let x = Tensor::from_vec(norm.apply(rows), (n, ac.critic_dim), &Device::Cpu)?;
    ac.value(&x)?.to_vec1()
}

/// Fills `values`, `advantages` and `returns` of every rollout (GAE; time-outs and successes
/// bootstrap from the value of their final state). One critic pass over every row of every
/// rollout (a pass per rollout cost more in candle's per-call overhead than in arithmetic).
pub fn compute_gae(
    ac: &ActorCritic,
    norm: &Normalizer,
    rolls: &mut [EnvRollout],
    cfg: &PpoConfig,
) -> candle_core::Result<()> {
    let t = cfg.steps;
    let c = ac.critic_dim;
    // Rows per rollout: its `t` states, the state after the last step, and the `t` final states
    // of truncated episodes (unused rows are zeros; their values are ignored).
    let per = 2 * t + 1;
    let mut rows = Vec::with_capacity(rolls.len() * per * c);
    for r in rolls.iter() {
        rows.extend_from_slice(&r.critic_obs);
        rows.extend_from_slice(&r.next_critic_obs);
        rows.extend_from_slice(&r.final_critic_obs);
    }
    let all = values(ac, norm, &rows)?;
    for (k, r) in rolls.iter_mut().enumerate() {
        let v = &all[k * per..(k + 1) * per];
        r.values = v[..t].to_vec();
        let next_v = v[t];
        let final_v = &v[t + 1..];
        let mut gae = 0.0f64;
        for s in (0..t).rev() {
            let mut rew = r.rewards[s] as f64;
            if r.truncated[s] {
                rew += cfg.gamma * final_v[s] as f64;
            }
            let done = r.terminated[s] || r.truncated[s];
            let nonterminal = if done { 0.0 } else { 1.0 };
            let nv = if s + 1 < t { r.values[s + 1] } else { next_v } as f64;
            let delta = rew + cfg.gamma * nv * nonterminal - r.values[s] as f64;
            gae = delta + cfg.gamma * cfg.lambda * nonterminal * gae;
            r.advantages[s] = gae as f32;
            r.returns[s] = (gae + r.values[s] as f64) as f32;
        }
    }
    Ok(())
}

/// What one update did.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct UpdateStats {
    pub surrogate: f64,
    pub value_loss: f64,
    pub entropy: f64,
    pub kl: f64,
    pub lr: f64,
    pub mean_std: f64,
    /// The gradient's norm before clipping, mean over the update's steps.
    #[serde(default)]
    pub grad_norm: f64,
}

/// The learning side of a run: everything a checkpoint must hold to step as the run that went on
/// would have (the optimizers' moments and step counts, the adaptive rate, the minibatch shuffle).
pub struct Learner {
    pub cfg: PpoConfig,
    /// Every variable (actor, noise, critic).
    pub opt: Adam,
    /// The critic alone, for the critic's warm-up.
    pub critic_opt: Adam,
    pub lr: f64,
    /// Shuffles the minibatches.
    pub rng: Rng,
    /// Symmetry augmentation (MLP actors only: a mirrored LSTM state is not defined).
    mirror: Option<Mirror>,
    /// The fused step of a feed-forward actor ([`PpoConfig::fused_mlp`]; `None`: candle's ops).
    fused: Option<FusedMlp>,
    /// Where the critic's variables are among all of them (the fused critic warm-up).
    critic_idx: Vec<usize>,
}

/// A KL divergence below this is the float noise of means computed twice, not a step (the
/// fused path's reference means come from products of other shapes than its minibatches').
const KL_RESOLUTION: f64 = 1e-12;

/// The adaptive learning rate after a step that measured `kl` (rsl_rl's rule and bounds; no
/// change on a step that has not moved the policy yet, the first of an update).
fn adapted_lr(lr: f64, kl: f64, desired: f64) -> f64 {
    if kl > 2.0 * desired {
        (lr / 1.5).max(1e-5)
    } else if kl < 0.5 * desired && kl > KL_RESOLUTION {
        (lr * 1.5).min(1e-2)
    } else {
        lr
    }
}

/// An Adam step of `opt` (a subset of the variables, e.g. the critic's) on the fused buffers,
/// `idx[k]` being `opt`'s variable `k` among them.
fn step_subset(opt: &mut Adam, f: &mut FusedMlp, idx: &[usize]) {
    let mut params: Vec<Vec<f32>> = idx.iter().map(|&k| std::mem::take(&mut f.params[k])).collect();
    let grads: Vec<Vec<f32>> = idx.iter().map(|&k| std::mem::take(&mut f.grads[k])).collect();
    opt.step_flat(&mut params, &grads);
    for ((&k, p), g) in idx.iter().zip(params).zip(grads) {
        f.params[k] = p;
        f.grads[k] = g;
    }
}

impl Learner {
    pub fn new(ac: &ActorCritic, cfg: PpoConfig, seed: u64, mirror: Option<Mirror>) -> anyhow::Result<Self> {
        anyhow::ensure!(
            mirror.is_none() || ac.arch.lstm_hidden() == 0,
            "symmetry augmentation needs a feed-forward actor (a mirrored LSTM state is not defined)"
        );
        anyhow::ensure!(
            mirror.is_none() || ac.mirror.is_none(),
            "symmetry augmentation and a spec with [policy] mirror = \"average\" do not go together: that policy is symmetric by construction"
        );
        let names: Vec<String> = ac.named_vars().into_iter().map(|(n, _)| n).collect();
        // The spec's mirror averaging runs a twin through the actor: candle's path has it.
        let fused = (cfg.fused_mlp && ac.mirror.is_none())
            .then(|| FusedMlp::new(&ac.arch, &names))
            .flatten();
        let critic_idx = ac
            .named_critic_vars()
            .iter()
            .map(|(c, _)| {
                names
                    .iter()
                    .position(|n| n == c)
                    .expect("a critic variable is a variable")
            })
            .collect();
        Ok(Self {
            fused,
            critic_idx,
            opt: Adam::new(ac.named_vars(), cfg.lr),
            critic_opt: Adam::new(ac.named_critic_vars(), 1e-3),
            lr: cfg.lr,
            cfg,
            rng: Rng(seed ^ 0x11EA_12E2),
            mirror,
        })
    }

    /// One PPO update over the rollouts. With `critic_only`, the actor is left as it is (the
    /// critic's warm-up after a warm start: a random critic's advantages would wreck a good actor).
    pub fn update(
        &mut self,
        ac: &ActorCritic,
        norm: &Normalizer,
        rolls: &[EnvRollout],
        critic_only: bool,
    ) -> candle_core::Result<UpdateStats> {
        let cfg = self.cfg;
        let (t, o, c, a) = (cfg.steps, ac.obs_dim, ac.critic_dim, ac.act_dim);
        let dev = Device::Cpu;
        let e = rolls.len();
        let mb = e.div_ceil(cfg.minibatches).max(1);
        let mut stats = UpdateStats::default();
        let mut n = 0.0f64;
        // The adaptive learning rate measures how far each step moves the policy. Its reference is
        // the policy as this update starts, not the one that rolled out: half the environments'
        // rollouts are one update old (the runner overlaps rollout and update), and measuring from
        // there counted the previous update's step too, so the rate fell to its floor every other
        // iteration (run 6: 1e-5 for most of 20 M steps).
        if let Some(f) = self.fused.as_mut() {
            f.load(&self.opt, c)?;
        }
        let reference = if critic_only {
            Vec::new()
        } else if let Some(f) = self.fused.as_mut() {
            // The fused forward's own means: the first step's KL is then exactly 0, as in candle's.
            rolls.iter().map(|r| f.means(&r.obs, t).to_vec()).collect()
        } else {
            self.reference_means(ac, rolls, mb)?
        };
        for _ in 0..cfg.epochs {
            let mut order: Vec<usize> = (0..e).collect();
            for i in (1..e).rev() {
                let j = self.rng.int(0, i as u64) as usize;
                order.swap(i, j);
            }
            for chunk in order.chunks(mb) {
                let b = chunk.len();
                // With symmetry, each time step's rows are followed by their mirror images (actor
                // and critic inputs, actions mirrored; advantages, returns, old values and old
                // log-probabilities repeated, as rsl_rl's augmentation does): [T, 2B, ·].
                let aug = self.mirror.as_ref();
                let b2 = if aug.is_some() { 2 * b } else { b };
                let gather = |f: &dyn Fn(&EnvRollout) -> &[f32], w: usize, m: Option<&SignedPermutation>| -> Vec<f32> {
                    let mut v = Vec::with_capacity(t * b2 * w);
                    for s in 0..t {
                        for &k in chunk {
                            v.extend_from_slice(&f(&rolls[k])[s * w..(s + 1) * w]);
                        }
                        if aug.is_some() {
                            for &k in chunk {
                                let row = &f(&rolls[k])[s * w..(s + 1) * w];
                                match m {
                                    Some(p) => p.apply_rows(row, &mut v),
                                    None => v.extend_from_slice(row),
                                }
                            }
                        }
                    }
                    v
                };
                let (m_obs, m_act, m_critic) = match aug {
                    Some(m) => (Some(&m.obs), Some(&m.action), Some(&m.critic)),
                    None => (None, None, None),
                };
                let obs_rows = gather(&|r| &r.obs, o, m_obs);
                let act_rows = gather(&|r| &r.actions, a, m_act);
                let old_mean: Vec<f32> = if critic_only {
                    Vec::new()
                } else {
                    let mut v = Vec::with_capacity(t * b * a);
                    for s in 0..t {
                        for &k in chunk {
                            v.extend_from_slice(&reference[k][s * a..(s + 1) * a]);
                        }
                    }
                    v
                };
                let old_logp_rows = gather(&|r| &r.logp, 1, None);
                let mut adv = gather(&|r| &r.advantages, 1, None);
                let mean_adv = adv.iter().map(|&x| x as f64).sum::<f64>() / adv.len() as f64;
                let std_adv = (adv.iter().map(|&x| (x as f64 - mean_adv).powi(2)).sum::<f64>() / adv.len() as f64)
                    .sqrt()
                    .max(1e-8);
                adv.iter_mut()
                    .for_each(|x| *x = ((*x as f64 - mean_adv) / std_adv) as f32);
                let ret_rows = gather(&|r| &r.returns, 1, None);
                let old_v_rows = gather(&|r| &r.values, 1, None);
                let cobs_rows = norm.apply(&gather(&|r| &r.critic_obs, c, m_critic));
                if let Some(f) = self.fused.as_mut() {
                    let mb = Minibatch {
                        n: t * b2,
                        obs: &obs_rows,
                        actions: &act_rows,
                        old_logp: &old_logp_rows,
                        advantages: &adv,
                        returns: &ret_rows,
                        old_values: &old_v_rows,
                        critic_obs: &cobs_rows,
                        old_means: &old_mean,
                        per_step: b2,
                        own_per_step: b,
                    };
                    let settings = StepSettings {
                        clip: cfg.clip,
                        value_coef: cfg.value_coef,
                        entropy_coef: cfg.entropy_coef,
                        max_grad_norm: cfg.max_grad_norm,
                    };
                    let mut lr = self.lr;
                    let losses = f.gradients(&mb, settings, critic_only, &mut |kl| {
                        lr = adapted_lr(lr, kl, cfg.desired_kl)
                    });
                    self.lr = lr;
                    if critic_only {
                        step_subset(&mut self.critic_opt, f, &self.critic_idx);
                    } else {
                        stats.grad_norm += f.clip_gradients(cfg.max_grad_norm);
                        self.opt.lr = self.lr;
                        self.opt.step_flat(&mut f.params, &f.grads);
                        stats.surrogate += losses.surrogate;
                        stats.entropy += losses.entropy;
                        stats.kl += losses.kl;
                    }
                    stats.value_loss += losses.value_loss;
                    n += 1.0;
                    continue;
                }
                let obs = Tensor::from_vec(obs_rows, (t, b2, o), &dev)?;
                let act = Tensor::from_vec(act_rows, (t, b2, a), &dev)?;
                let masks = Tensor::from_vec(gather(&|r| &r.masks, 1, None), (t, b2, 1), &dev)?;
                let old_logp = Tensor::from_vec(old_logp_rows, (t, b2), &dev)?;
                let adv = Tensor::from_vec(adv, (t, b2), &dev)?;
                let ret = Tensor::from_vec(ret_rows, t * b2, &dev)?;
                let old_v = Tensor::from_vec(old_v_rows, t * b2, &dev)?;
                let cobs = Tensor::from_vec(cobs_rows, (t * b2, c), &dev)?;
                let (state0, twin0) = lstm_states0(ac, rolls, chunk)?;

                // Value loss (clipped around the rollout's values).
                let v = ac.value(&cobs)?;
                let v_clip = (&old_v + (&v - &old_v)?.clamp(-cfg.clip, cfg.clip)?)?;
                let vl = (&v - &ret)?.sqr()?.maximum(&(&v_clip - &ret)?.sqr()?)?.mean_all()?;
                if critic_only {
                    let grads = vl.backward()?;
                    self.critic_opt.step(&grads)?;
                    stats.value_loss += vl.to_scalar::<f32>()? as f64;
                    n += 1.0;
                    continue;
                }

                let mean = ac.policy_sequence(&obs, pair(&state0), pair(&twin0), &masks)?;
                let log_std = ac.log_std();
                // KL(old || new) on this minibatch (before the step) drives the learning rate.
                let new_mean: Vec<f32> = mean.flatten_all()?.to_vec1()?;
                let ls: Vec<f32> = log_std.to_vec1()?;
                let old_ls = &ls; // σ changes little within one update; rsl_rl uses the stored σ
                let mut kl = 0.0f64;
                // On the rollout's own rows only (as rsl_rl): a policy not yet symmetric is far
                // from its mirror image, and that gap is not a step size.
                let rows_new = new_mean.chunks_exact(a).enumerate().filter(|(r, _)| r % b2 < b);
                for ((_, row_new), row_old) in rows_new.zip(old_mean.chunks_exact(a)) {
                    for j in 0..a {
                        let (sn, so) = ((ls[j] as f64).exp(), (old_ls[j] as f64).exp());
                        kl += (sn / so).ln() + (so * so + (row_old[j] - row_new[j]).powi(2) as f64) / (2.0 * sn * sn)
                            - 0.5;
                    }
                }
                kl /= (t * b) as f64;
                self.lr = adapted_lr(self.lr, kl, cfg.desired_kl);
                self.opt.lr = self.lr;

                let inv_std = log_std.neg()?.exp()?;
                let z = (&act - &mean)?.broadcast_mul(&inv_std)?;
                let logp =
                    ((z.sqr()? * -0.5)?.broadcast_sub(&log_std)? - 0.5 * (2.0 * std::f64::consts::PI).ln())?.sum(2)?;
                let ratio = (&logp - &old_logp)?.exp()?;
                let s1 = (&ratio * &adv)?;
                let s2 = (ratio.clamp(1.0 - cfg.clip, 1.0 + cfg.clip)? * &adv)?;
                let surrogate = s1.minimum(&s2)?.mean_all()?.neg()?;
                let entropy =
                    (log_std.sum_all()? + a as f64 * 0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E).ln())?;
                let loss = ((&surrogate + (&vl * cfg.value_coef)?)? - (&entropy * cfg.entropy_coef)?)?;
                let mut grads = loss.backward()?;
                stats.grad_norm += clip_grad_norm(&mut grads, &self.opt.vars, cfg.max_grad_norm)?;
                self.opt.step(&grads)?;

                stats.surrogate += surrogate.to_scalar::<f32>()? as f64;
                stats.value_loss += vl.to_scalar::<f32>()? as f64;
                stats.entropy += entropy.to_scalar::<f32>()? as f64;
                stats.kl += kl;
                n += 1.0;
            }
        }
        if let Some(f) = &self.fused {
            f.store(&self.opt)?;
        }
        if let Some(max) = cfg.max_std {
            ac.cap_action_std(max)
                .map_err(|e| candle_core::Error::Msg(format!("capping the action noise: {e}")))?;
        }
        for v in [
            &mut stats.surrogate,
            &mut stats.value_loss,
            &mut stats.entropy,
            &mut stats.kl,
            &mut stats.grad_norm,
        ] {
            *v /= n.max(1.0);
        }
        stats.lr = self.lr;
        let ls: Vec<f32> = ac.log_std().to_vec1()?;
        stats.mean_std = ls.iter().map(|&x| (x as f64).exp()).sum::<f64>() / ls.len() as f64;
        Ok(stats)
    }
}

impl Learner {
    /// The actor's means on every rollout row (the rollout's own rows, not mirrored), per
    /// environment, `[steps × act]`, before this update changes anything.
    fn reference_means(&self, ac: &ActorCritic, rolls: &[EnvRollout], mb: usize) -> candle_core::Result<Vec<Vec<f32>>> {
        let (t, o, a) = (self.cfg.steps, ac.obs_dim, ac.act_dim);
        let dev = Device::Cpu;
        let mut out = vec![Vec::new(); rolls.len()];
        let idx: Vec<usize> = (0..rolls.len()).collect();
        for chunk in idx.chunks(mb.max(1)) {
            let b = chunk.len();
            let mut obs = Vec::with_capacity(t * b * o);
            let mut masks = Vec::with_capacity(t * b);
            for s in 0..t {
                for &k in chunk {
                    obs.extend_from_slice(&rolls[k].obs[s * o..(s + 1) * o]);
                    masks.push(rolls[k].masks[s]);
                }
            }
            let obs = Tensor::from_vec(obs, (t, b, o), &dev)?;
            let masks = Tensor::from_vec(masks, (t, b, 1), &dev)?;
            let (state0, twin0) = lstm_states0(ac, rolls, chunk)?;
            let mean: Vec<f32> = ac
                .policy_sequence(&obs, pair(&state0), pair(&twin0), &masks)?
                .detach()
                .flatten_all()?
                .to_vec1()?;
            for (i, &k) in chunk.iter().enumerate() {
                let v = &mut out[k];
                v.reserve(t * a);
                for s in 0..t {
                    let row = (s * b + i) * a;
                    v.extend_from_slice(&mean[row..row + a]);
                }
            }
        }
        Ok(out)
    }
}

/// The LSTM state each of `chunk`'s rollouts started from, as `(h0, c0)` of `[B, hidden]`, for the
/// network and for its mirrored twin (`None` for a feed-forward actor, and for a policy without a
/// twin). `state0` is laid out as the firmware's `Actor::read_state`: `h`, `c`, then the twin's.
type State0 = Option<(Tensor, Tensor)>;
fn lstm_states0(ac: &ActorCritic, rolls: &[EnvRollout], chunk: &[usize]) -> candle_core::Result<(State0, State0)> {
    let hidden = ac.arch.lstm_hidden();
    if hidden == 0 {
        return Ok((None, None));
    }
    let at = |offset: usize| -> candle_core::Result<State0> {
        let b = chunk.len();
        let mut h0 = Vec::with_capacity(b * hidden);
        let mut c0 = Vec::with_capacity(b * hidden);
        for &k in chunk {
            let s = &rolls[k].state0[offset..offset + 2 * hidden];
            h0.extend_from_slice(&s[..hidden]);
            c0.extend_from_slice(&s[hidden..]);
        }
        Ok(Some((
            Tensor::from_vec(h0, (b, hidden), &Device::Cpu)?,
            Tensor::from_vec(c0, (b, hidden), &Device::Cpu)?,
        )))
    };
    let twin = if ac.mirror.is_some() { at(2 * hidden)? } else { None };
    Ok((at(0)?, twin))
}

fn pair(s: &State0) -> Option<(&Tensor, &Tensor)> {
    s.as_ref().map(|(h, c)| (h, c))
}

/// Scales the gradients down to norm `max` when above it and returns their norm before; `vars` in a fixed order, so the sum of
/// squares (and so the result) is the same in every process.
fn clip_grad_norm(
    grads: &mut candle_core::backprop::GradStore,
    vars: &[(String, Var)],
    max: f64,
) -> candle_core::Result<f64> {
    let mut sq = 0.0f64;
    for (_, v) in vars {
        if let Some(g) = grads.get(v.as_tensor()) {
            sq += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
        }
    }
    let norm = sq.sqrt();
    if norm > max {
        let k = max / (norm + 1e-6);
        for (_, v) in vars {
            if let Some(g) = grads.get(v.as_tensor()) {
                let scaled = (g * k)?;
                grads.insert(v.as_tensor(), scaled);
            }
        }
    }
    Ok(norm)
}
