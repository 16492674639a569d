//! The stair policy's networks in candle, for the PPO update, and their export to what `g1fw` runs.
//!
//! - Actor: the peer walker's architecture (Unitree's unitree_rl_gym G1 policy): a one-layer LSTM
//!   (`obs → 64`), then `Linear(64 → 32)`, ELU, `Linear(32 → 12)`, plus a learned log standard
//!   deviation per action. The rollout runs the *exported* actor in the firmware's executor
//!   (`firmware::nn::Network`); this module replays rollouts through the same maths with autograd.
//! - Critic: an MLP `[critic_obs → 128 → 64 → 1]`, ELU, on the actor's observation plus privileged
//!   inputs (asymmetric actor–critic; see `env::CRITIC_EXTRA`). It never leaves the trainer. It
//!   is small because the update is compute-bound on a CPU: at [256, 128] the critic was ~60 % of
//!   the learner's FLOPs and the learner ~75 % of wall time.
//!
//! Tensor names follow the peer's safetensors (`memory.weight_ih_l0`, `actor.0.weight`, …), so the
//! export is read by the same `[policy.network]` layer list as the peer spec.
use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Result, Tensor, Var};
use candle_nn::{Init, VarMap};

pub const HIDDEN: usize = 64;
pub const MLP_HIDDEN: usize = 32;
pub const CRITIC_HIDDEN: [usize; 2] = [128, 64];

/// Actor tensor names in export order, with their shapes for `obs` inputs and `act` outputs.
pub fn actor_shapes(obs: usize, act: usize) -> Vec<(&'static str, Vec<usize>)> {
    vec![
        ("memory.weight_ih_l0", vec![4 * HIDDEN, obs]),
        ("memory.weight_hh_l0", vec![4 * HIDDEN, HIDDEN]),
        ("memory.bias_ih_l0", vec![4 * HIDDEN]),
        ("memory.bias_hh_l0", vec![4 * HIDDEN]),
        ("actor.0.weight", vec![MLP_HIDDEN, HIDDEN]),
        ("actor.0.bias", vec![MLP_HIDDEN]),
        ("actor.2.weight", vec![act, MLP_HIDDEN]),
        ("actor.2.bias", vec![act]),
    ]
}

pub struct ActorCritic {
    pub vars: VarMap,
    pub obs_dim: usize,
    pub critic_dim: usize,
    pub act_dim: usize,
}

fn get(vars: &VarMap, name: &str) -> Tensor {
    vars.data().lock().expect("var map lock")[name].as_tensor().clone()
}

fn elu(x: &Tensor) -> Result<Tensor> {
    // elu(x) = relu(x) + (exp(min(x, 0)) - 1), alpha 1; built from ops candle differentiates.
    let neg = x.neg()?.relu()?.neg()?;
    x.relu()? + (neg.exp()? - 1.0)?
}

impl ActorCritic {
    /// Fresh networks: actor and critic with PyTorch-like uniform init, log std = ln(`init_std`).
    pub fn new(obs_dim: usize, critic_dim: usize, act_dim: usize, init_std: f64, seed: u64) -> Result<Self> {
        // candle's CPU device cannot be seeded: draw the initial weights from our own generator.
        let dev = Device::Cpu;
        let mut rng = g1_sim::rng::Rng(seed ^ 0x1417_AC70);
        let vars = VarMap::new();
        let mut uniform = |name: &str, shape: Vec<usize>, b: f64| -> Result<()> {
            let n = shape.iter().product();
            let v: Vec<f32> = (0..n).map(|_| rng.range(-b, b) as f32).collect();
            vars.get(shape.clone(), name, Init::Const(0.0), DType::F32, &dev)?;
            vars.data().lock().expect("var map lock")[name].set(&Tensor::from_vec(v, shape, &dev)?)?;
            Ok(())
        };
        for (name, shape) in actor_shapes(obs_dim, act_dim) {
            let fan_in = if name.starts_with("memory") {
                HIDDEN
            } else {
                *shape.last().unwrap()
            };
            uniform(name, shape, 1.0 / (fan_in as f64).sqrt())?;
        }
        let mut fan_in = critic_dim;
        for (i, &w) in CRITIC_HIDDEN.iter().chain(&[1]).enumerate() {
            uniform(
                &format!("critic.{i}.weight"),
                vec![w, fan_in],
                1.0 / (fan_in as f64).sqrt(),
            )?;
            vars.get(w, &format!("critic.{i}.bias"), Init::Const(0.0), DType::F32, &dev)?;
            fan_in = w;
        }
        vars.get(act_dim, "log_std", Init::Const(init_std.ln()), DType::F32, &dev)?;
        Ok(Self {
            vars,
            obs_dim,
            critic_dim,
            act_dim,
        })
    }

    /// Overwrites actor tensors from a safetensors file with the peer's names. A `weight_ih`
    /// narrower than ours is widened with zero columns on the right (the warm start: the peer
    /// walker, its input widened by the terrain token at zero weight).
    pub fn load_actor_widened(&self, path: &Path) -> anyhow::Result<usize> {
        let src = candle_core::safetensors::load(path, &Device::Cpu)?;
        let mut loaded = 0;
        for (name, shape) in actor_shapes(self.obs_dim, self.act_dim) {
            let Some(t) = src.get(name) else {
                anyhow::bail!(
                    "{}: no tensor {name}; is it an LSTM-64 actor like the peer's?",
                    path.display()
                )
            };
            let t = t.to_dtype(DType::F32)?;
            let t = if name == "memory.weight_ih_l0" && t.dim(1)? < self.obs_dim {
                let pad = Tensor::zeros((4 * HIDDEN, self.obs_dim - t.dim(1)?), DType::F32, &Device::Cpu)?;
                Tensor::cat(&[&t, &pad], 1)?
            } else {
                t
            };
            if t.dims() != shape.as_slice() {
                anyhow::bail!("{}: {name} is {:?}, need {:?}", path.display(), t.dims(), shape);
            }
            self.vars.data().lock().unwrap()[name].set(&t)?;
            loaded += 1;
        }
        Ok(loaded)
    }

    pub fn log_std(&self) -> Tensor {
        get(&self.vars, "log_std")
    }

    /// Actor means over sequences. `obs` [T, B, obs], `h0`/`c0` [B, 64] (the state before step 0),
    /// `masks` [T, B, 1]: 0 where an episode starts at that step (state reset to zero first).
    pub fn actor_sequence(&self, obs: &Tensor, h0: &Tensor, c0: &Tensor, masks: &Tensor) -> Result<Tensor> {
        let (t, b, i) = obs.dims3()?;
        let w_ih = get(&self.vars, "memory.weight_ih_l0");
        let w_hh = get(&self.vars, "memory.weight_hh_l0");
        let bias = (get(&self.vars, "memory.bias_ih_l0") + get(&self.vars, "memory.bias_hh_l0"))?;
        let xproj = obs
            .reshape((t * b, i))?
            .matmul(&w_ih.t()?)?
            .broadcast_add(&bias)?
            .reshape((t, b, 4 * HIDDEN))?;
        let w_hh_t = w_hh.t()?;
        let (mut h, mut c) = (h0.clone(), c0.clone());
        let mut outs = Vec::with_capacity(t);
        for s in 0..t {
            let m = masks.get(s)?;
            h = h.broadcast_mul(&m)?;
            c = c.broadcast_mul(&m)?;
            let g = (xproj.get(s)? + h.matmul(&w_hh_t)?)?;
            // One sigmoid over all four gate blocks (the g block's is unused): the update's cost
            // is the number of ops per step, not their size.
            let sg = candle_nn::ops::sigmoid(&g)?;
            let gi = sg.narrow(1, 0, HIDDEN)?;
            let gf = sg.narrow(1, HIDDEN, HIDDEN)?;
            let gg = g.narrow(1, 2 * HIDDEN, HIDDEN)?.tanh()?;
            let go = sg.narrow(1, 3 * HIDDEN, HIDDEN)?;
            c = ((gf * &c)? + (gi * gg)?)?;
            h = (go * c.tanh()?)?;
            outs.push(h.clone());
        }
        let hs = Tensor::stack(&outs, 0)?.reshape((t * b, HIDDEN))?;
        let y = elu(&hs
            .matmul(&get(&self.vars, "actor.0.weight").t()?)?
            .broadcast_add(&get(&self.vars, "actor.0.bias"))?)?;
        let mean = y
            .matmul(&get(&self.vars, "actor.2.weight").t()?)?
            .broadcast_add(&get(&self.vars, "actor.2.bias"))?;
        mean.reshape((t, b, self.act_dim))
    }

    /// Values of a batch of (normalised) critic observations [N, critic] → [N].
    pub fn value(&self, x: &Tensor) -> Result<Tensor> {
        let mut h = x.clone();
        let n = CRITIC_HIDDEN.len();
        for i in 0..=n {
            h = h
                .matmul(&get(&self.vars, &format!("critic.{i}.weight")).t()?)?
                .broadcast_add(&get(&self.vars, &format!("critic.{i}.bias")))?;
            if i < n {
                h = elu(&h)?;
            }
        }
        h.squeeze(1)
    }

    /// The actor as a safetensors file in the peer's layout (what the stair spec's
    /// `[policy.network]` reads).
    pub fn actor_safetensors(&self) -> anyhow::Result<Vec<u8>> {
        let mut map: HashMap<String, Tensor> = HashMap::new();
        for (name, _) in actor_shapes(self.obs_dim, self.act_dim) {
            map.insert(name.to_string(), get(&self.vars, name));
        }
        let mut names: Vec<_> = map.keys().cloned().collect();
        names.sort();
        let data: Vec<(String, Vec<u8>, Vec<usize>)> = names
            .iter()
            .map(|n| {
                let t = &map[n];
                let v: Vec<f32> = t.flatten_all()?.to_vec1()?;
                let bytes = v.iter().flat_map(|x| x.to_le_bytes()).collect();
                Ok((n.clone(), bytes, t.dims().to_vec()))
            })
            .collect::<anyhow::Result<_>>()?;
        let views: Vec<(String, safetensors::tensor::TensorView)> = data
            .iter()
            .map(|(n, b, s)| {
                Ok((
                    n.clone(),
                    safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b)?,
                ))
            })
            .collect::<anyhow::Result<_>>()?;
        Ok(safetensors::serialize(views, &None)?)
    }

    /// All trainable variables.
    pub fn all_vars(&self) -> Vec<Var> {
        self.vars.all_vars()
    }

    /// Critic variables only (the critic warm-up trains the critic alone).
    pub fn critic_vars(&self) -> Vec<Var> {
        let data = self.vars.data().lock().unwrap();
        let mut names: Vec<_> = data.keys().filter(|k| k.starts_with("critic.")).cloned().collect();
        names.sort();
        names.iter().map(|n| data[n].clone()).collect()
    }

    pub fn save(&self, path: &Path) -> Result<()> {
        self.vars.save(path)
    }

    pub fn load(&mut self, path: &Path) -> Result<()> {
        self.vars.load(path)
    }
}
