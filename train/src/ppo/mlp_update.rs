//! The PPO step of a feed-forward actor and critic without a tensor graph: forward (linear layers
//! with the bias fused into the product, ELU in the same pass), the Gaussian log-probability,
//! clipped surrogate, clipped value loss and entropy, the backward pass by hand, the
//! gradient-norm clip and Adam, over buffers that live as long as the learner.
//!
//! Built from candle's ops the same step spent most of its time outside the matrix products
//! (per-op allocation, unfused element-wise maps, zero-filled gradients); the maths here is the
//! candle path's (`algo::Learner`, checked against it in the tests below).
//!
//! Per row `i` of a minibatch of `N` (with symmetry, the mirrored rows too), actions `a`, means
//! `μ`, log-σ `s`:
//! ```text
//! z = (a − μ)·e^−s,  logp = Σ_j (−z²/2 − s_j − ln√(2π)),  r = e^(logp − logp_old)
//! surrogate = −(1/N) Σ_i min(r·A, clip(r)·A)        ∂/∂logp_i = −A_i·r_i/N where r·A ≤ clip(r)·A
//! ∂logp/∂μ_j = (a_j − μ_j)·e^−2s_j,  ∂logp/∂s_j = z_j² − 1,  entropy = Σ s + const
//! value loss = (1/N) Σ max((v − R)², (v_c − R)²),  v_c = v_old + clip(v − v_old, ±ε)
//! ```
//! ELU's derivative comes from its output: 1 where `h > 0`, `h + α` elsewhere.
use super::adam::Adam;
use super::matmul::MatMul;
use super::policy::{ActorArch, ActorLayer, CRITIC_HIDDEN};

/// `eˣ` for `x ≤ 0` within 3 ulp of libm's (tested), in plain f32 arithmetic that vectorises:
/// `eˣ = 2ᵏ·e^r`, `k = round(x·log₂e)`, `r = x − k·ln 2` (split in two for precision), `e^r` by
/// its degree-6 Taylor polynomial on |r| ≤ ln2/2, `2ᵏ` put into the exponent bits.
#[inline]
pub fn exp_nonpositive(x: f32) -> f32 {
    let x = x.max(-87.0);
    let k = (x * std::f32::consts::LOG2_E).round();
    let r = x - k * 0.693_145_75 - k * 1.428_606_8e-6;
    let p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    p * f32::from_bits(((k as i32 + 127) as u32) << 23)
}

/// A linear layer: the indices of its weight and bias among the learner's variables, its sizes,
/// and the ELU after it (`None` for the last).
#[derive(Clone, Debug)]
struct Dense {
    weight: usize,
    bias: usize,
    input: usize,
    output: usize,
    elu: Option<f32>,
}

/// One network's layers and the activations of the last forward pass, `[N, width]` each.
#[derive(Default)]
struct Net {
    layers: Vec<Dense>,
    /// `acts[0]` is the input; `acts[l + 1]` layer `l`'s output (after its ELU).
    acts: Vec<Vec<f32>>,
    /// The gradient at each activation, same shapes.
    grads: Vec<Vec<f32>>,
}

impl Net {
    /// Forward over `n` rows already in `acts[0]`.
    fn forward(&mut self, params: &[Vec<f32>], n: usize) {
        for (l, d) in self.layers.iter().enumerate() {
            let (before, after) = self.acts.split_at_mut(l + 1);
            let (x, h) = (&before[l], &mut after[0]);
            h.resize(n * d.output, 0.0);
            let b = &params[d.bias];
            for row in h.chunks_exact_mut(d.output) {
                row.copy_from_slice(b);
            }
            MatMul {
                m: n,
                n: d.output,
                k: d.input,
                accumulate: true,
            }
            .run((h, d.output, 1), (x, d.input, 1), (&params[d.weight], 1, d.input));
            if let Some(alpha) = d.elu {
                // Branch-free with a polynomial exp: the loop vectorises (libm's expf does not).
                for v in h.iter_mut() {
                    let e = alpha * (exp_nonpositive(v.min(0.0)) - 1.0);
                    *v = if *v > 0.0 { *v } else { e };
                }
            }
        }
    }

    /// Backward from the gradient at the output (already in `grads[last]`), accumulating the
    /// weight and bias gradients into `g` (zeroed by the caller once per step).
    fn backward(&mut self, params: &[Vec<f32>], g: &mut [Vec<f32>], n: usize) {
        for l in (0..self.layers.len()).rev() {
            let d = self.layers[l].clone();
            // ELU: the gradient at the pre-activation, in place.
            if let Some(alpha) = d.elu {
                let (h, gh) = (&self.acts[l + 1], &mut self.grads[l + 1]);
                for (gv, &hv) in gh.iter_mut().zip(h) {
                    // A select, not a branch: the loop vectorises.
                    *gv *= if hv > 0.0 { 1.0 } else { hv + alpha };
                }
            }
            let gz = &self.grads[l + 1];
            let bias = &mut g[d.bias];
            for row in gz.chunks_exact(d.output) {
                for (b, &v) in bias.iter_mut().zip(row) {
                    *b += v;
                }
            }
            // dW[out × in] += gzᵀ · x
            MatMul {
                m: d.output,
                n: d.input,
                k: n,
                accumulate: true,
            }
            .run(
                (&mut g[d.weight], d.input, 1),
                (gz, 1, d.output),
                (&self.acts[l], d.input, 1),
            );
            if l > 0 {
                let (before, after) = self.grads.split_at_mut(l + 1);
                let gx = &mut before[l];
                gx.resize(n * d.input, 0.0);
                // gx[N × in] = gz · W
                MatMul {
                    m: n,
                    n: d.input,
                    k: d.output,
                    accumulate: false,
                }
                .run(
                    (gx, d.input, 1),
                    (&after[0], d.output, 1),
                    (&params[d.weight], d.input, 1),
                );
            }
        }
    }

    fn output(&self) -> &[f32] {
        self.acts.last().expect("a network has layers")
    }
}

/// One minibatch, gathered by the learner: `n` rows (time-major, mirrored rows beside their
/// originals), `original(i)` telling the rollout's own rows apart.
pub struct Minibatch<'a> {
    pub n: usize,
    pub obs: &'a [f32],
    pub actions: &'a [f32],
    pub old_logp: &'a [f32],
    pub advantages: &'a [f32],
    pub returns: &'a [f32],
    pub old_values: &'a [f32],
    /// Critic inputs, normalised.
    pub critic_obs: &'a [f32],
    /// The reference means of the rollout's own rows, in their order (the adaptive rate's KL).
    pub old_means: &'a [f32],
    /// Rows per time step, and how many of them are the rollout's own (the rest mirrored).
    pub per_step: usize,
    pub own_per_step: usize,
}

/// The PPO settings a step uses.
#[derive(Clone, Copy, Debug)]
pub struct StepSettings {
    pub clip: f64,
    pub value_coef: f64,
    pub entropy_coef: f64,
    pub max_grad_norm: f64,
}

/// What one minibatch step computed (the losses before the step, the KL that set its rate).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepLosses {
    pub surrogate: f64,
    pub value_loss: f64,
    pub entropy: f64,
    pub kl: f64,
}

/// The fused learner of a feed-forward actor and critic: parameters in flat buffers in the
/// learner's variable order, copied in from the variables before an update and back after it.
pub struct FusedMlp {
    actor: Net,
    critic: Net,
    log_std: usize,
    act: usize,
    pub params: Vec<Vec<f32>>,
    pub grads: Vec<Vec<f32>>,
    /// Per row: ∂loss/∂logp; the gradient at the means lives in `actor.grads`.
    g_logp: Vec<f32>,
}

impl FusedMlp {
    /// For an actor of linear and ELU layers (`None` for any other, e.g. an LSTM) and the critic
    /// of [`CRITIC_HIDDEN`], with `names` the learner's variables in its order.
    pub fn new(arch: &ActorArch, names: &[String]) -> Option<Self> {
        let idx = |n: &str| names.iter().position(|m| m == n);
        let mut actor = Vec::new();
        for (i, l) in arch.layers.iter().enumerate() {
            match l {
                ActorLayer::Linear {
                    weight,
                    bias,
                    input,
                    output,
                } => actor.push(Dense {
                    weight: idx(weight)?,
                    bias: idx(bias)?,
                    input: *input,
                    output: *output,
                    elu: None,
                }),
                ActorLayer::Elu { alpha } => {
                    let last = actor.last_mut()?;
                    if last.elu.is_some() || i == 0 {
                        return None;
                    }
                    last.elu = Some(*alpha as f32);
                }
                ActorLayer::Lstm { .. } => return None,
            }
        }
        if actor.last()?.elu.is_some() {
            return None;
        }
        let act = actor.last()?.output;
        let mut critic = Vec::new();
        let n = CRITIC_HIDDEN.len();
        // The critic's input width is set by `load` (it is the normalised critic observation's).
        let mut input = 0;
        for (i, &output) in CRITIC_HIDDEN.iter().chain(&[1]).enumerate() {
            let (w, b) = (format!("critic.{i}.weight"), format!("critic.{i}.bias"));
            critic.push(Dense {
                weight: idx(&w)?,
                bias: idx(&b)?,
                input,
                output,
                elu: (i < n).then_some(1.0),
            });
            input = output;
        }
        let net = |layers: Vec<Dense>| Net {
            acts: vec![Vec::new(); layers.len() + 1],
            grads: vec![Vec::new(); layers.len() + 1],
            layers,
        };
        Some(Self {
            actor: net(actor),
            critic: net(critic),
            log_std: idx("log_std")?,
            act,
            params: Vec::new(),
            grads: Vec::new(),
            g_logp: Vec::new(),
        })
    }

    /// Copies the variables' values in (before an update).
    pub fn load(&mut self, opt: &Adam, critic_input: usize) -> candle_core::Result<()> {
        self.params.clear();
        for (_, v) in &opt.vars {
            self.params.push(v.as_tensor().flatten_all()?.to_vec1()?);
        }
        self.grads = self.params.iter().map(|p| vec![0.0; p.len()]).collect();
        self.critic.layers[0].input = critic_input;
        Ok(())
    }

    /// Copies the parameters back into the variables (after an update).
    pub fn store(&self, opt: &Adam) -> candle_core::Result<()> {
        for ((_, v), p) in opt.vars.iter().zip(&self.params) {
            v.set(&candle_core::Tensor::from_vec(p.clone(), v.shape(), v.device())?)?;
        }
        Ok(())
    }

    /// The actor's means for `n` rows of `obs` with the current parameters.
    pub fn means(&mut self, obs: &[f32], n: usize) -> &[f32] {
        self.actor.acts[0].clear();
        self.actor.acts[0].extend_from_slice(obs);
        self.actor.forward(&self.params, n);
        self.actor.output()
    }

    /// The KL divergence from the reference means to the current ones on the rollout's own rows
    /// (σ unchanged within an update, as the candle path), with the means of the last forward.
    fn kl(&self, mb: &Minibatch) -> f64 {
        let a = self.act;
        let ls = &self.params[self.log_std];
        let mean = self.actor.output();
        let mut kl = 0.0f64;
        let own = (0..mb.n).filter(|r| r % mb.per_step < mb.own_per_step);
        for (r, old) in own.zip(mb.old_means.chunks_exact(a)) {
            for j in 0..a {
                let s = (ls[j] as f64).exp();
                kl += (s * s + (old[j] - mean[r * a + j]).powi(2) as f64) / (2.0 * s * s) - 0.5;
            }
        }
        kl / (mb.n / mb.per_step * mb.own_per_step).max(1) as f64
    }

    /// Gradients of the PPO loss on `mb` into `self.grads` (zeroed first), and the losses. With
    /// `critic_only`, the value loss alone (the actor's gradients stay zero). Runs the actor
    /// forward unless `critic_only`; `lr_hook` sees the KL before the backward pass (the adaptive
    /// rate is set from it, as the candle path does).
    pub fn gradients(
        &mut self,
        mb: &Minibatch,
        s: StepSettings,
        critic_only: bool,
        lr_hook: &mut dyn FnMut(f64),
    ) -> StepLosses {
        let n = mb.n;
        for g in self.grads.iter_mut() {
            g.fill(0.0);
        }
        let mut out = StepLosses::default();
        // Critic.
        self.critic.acts[0].clear();
        self.critic.acts[0].extend_from_slice(mb.critic_obs);
        self.critic.forward(&self.params, n);
        let last = self.critic.layers.len();
        let gv = &mut self.critic.grads[last];
        gv.resize(n, 0.0);
        let v = &self.critic.acts[last];
        let mut vl = 0.0f64;
        let coef = if critic_only { 1.0 } else { s.value_coef } as f32;
        for i in 0..n {
            let (vi, ov, r) = (v[i], mb.old_values[i], mb.returns[i]);
            let d = (vi - ov).clamp(-s.clip as f32, s.clip as f32);
            let vc = ov + d;
            let (l1, l2) = ((vi - r).powi(2), (vc - r).powi(2));
            vl += l1.max(l2) as f64;
            // candle's maximum splits a tie; both branches then carry the same gradient here.
            let inside = (vi - ov).abs() < s.clip as f32;
            let g = if l1 > l2 {
                2.0 * (vi - r)
            } else if l2 > l1 {
                if inside {
                    2.0 * (vc - r)
                } else {
                    0.0
                }
            } else if inside {
                2.0 * (vi - r)
            } else {
                vi - r
            };
            gv[i] = coef * g / n as f32;
        }
        out.value_loss = vl / n as f64;
        self.critic.backward(&self.params, &mut self.grads, n);
        if critic_only {
            return out;
        }
        // Actor.
        let a = self.act;
        self.means(mb.obs, n);
        out.kl = self.kl(mb);
        lr_hook(out.kl);
        let ls = self.params[self.log_std].clone();
        let inv_var: Vec<f32> = ls.iter().map(|&l| (-2.0 * l).exp()).collect();
        let inv_std: Vec<f32> = ls.iter().map(|&l| (-l).exp()).collect();
        let half_ln_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln() as f32;
        let ls_sum: f32 = ls.iter().sum();
        self.g_logp.resize(n, 0.0);
        let mean = &self.actor.acts[self.actor.layers.len()];
        let (lo, hi) = (1.0 - s.clip as f32, 1.0 + s.clip as f32);
        let mut surrogate = 0.0f64;
        for i in 0..n {
            let row = i * a;
            let mut zz = 0.0f32;
            for j in 0..a {
                let z = (mb.actions[row + j] - mean[row + j]) * inv_std[j];
                zz += z * z;
            }
            let logp = -0.5 * zz - ls_sum - a as f32 * half_ln_2pi;
            let ratio = (logp - mb.old_logp[i]).exp();
            let adv = mb.advantages[i];
            let (s1, s2) = (ratio * adv, ratio.clamp(lo, hi) * adv);
            surrogate -= s1.min(s2) as f64;
            self.g_logp[i] = if s1 <= s2 { -adv * ratio / n as f32 } else { 0.0 };
        }
        out.surrogate = surrogate / n as f64;
        out.entropy = ls_sum as f64 + a as f64 * 0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E).ln();
        let la = self.actor.layers.len();
        let gm = &mut self.actor.grads[la];
        gm.resize(n * a, 0.0);
        let g_ls = &mut self.grads[self.log_std];
        for i in 0..n {
            let gl = self.g_logp[i];
            for j in 0..a {
                let diff = mb.actions[i * a + j] - mean[i * a + j];
                gm[i * a + j] = gl * diff * inv_var[j];
                g_ls[j] += gl * (diff * diff * inv_var[j] - 1.0);
            }
        }
        for g in g_ls.iter_mut() {
            *g -= s.entropy_coef as f32;
        }
        self.actor.backward(&self.params, &mut self.grads, n);
        out
    }

    /// Scales the gradients to norm `max` when above it (the sum of squares in variable order);
    /// returns their norm before.
    pub fn clip_gradients(&mut self, max: f64) -> f64 {
        let sq: f64 = self
            .grads
            .iter()
            .map(|g| g.iter().map(|&x| x * x).sum::<f32>() as f64)
            .sum();
        let norm = sq.sqrt();
        if norm > max {
            let k = (max / (norm + 1e-6)) as f32;
            for g in self.grads.iter_mut() {
                g.iter_mut().for_each(|x| *x *= k);
            }
        }
        norm
    }
}

#[cfg(test)]
mod tests {
    use super::exp_nonpositive;

    #[test]
    fn the_polynomial_exp_is_libms_within_3_ulp_where_elu_needs_it() {
        let mut worst = 0u32;
        let mut x = -87.0f32;
        while x <= 0.0 {
            let (a, b) = (exp_nonpositive(x), x.exp());
            let ulp = a.to_bits().abs_diff(b.to_bits());
            worst = worst.max(ulp);
            x += 0.000_37;
        }
        assert!(worst <= 3, "{worst} ulp");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert!(exp_nonpositive(-1000.0) < 1e-37 && exp_nonpositive(-1000.0) >= 0.0);
    }
}
