//! The stair policy's networks in candle, for the PPO update, and their export to what `g1fw` runs.
//!
//! - Actor: whatever the deploy spec's `[policy.network]` lists, from the layers the trainer can
//!   differentiate: an optional single-layer LSTM first, then `linear` and `elu` layers. Tensor
//!   names come from the spec, so the export is read by the same layer list; sizes come from a
//!   weights file or, for a fresh actor, from `--actor-hidden`. Two shapes are in use: the peer
//!   walker's (Unitree's unitree_rl_gym G1 policy: LSTM `obs → 64`, `Linear(64 → 32)`, ELU,
//!   `Linear(32 → 12)`), and the field's MLP over a short observation history (IsaacLab,
//!   unitree_rl_lab, mjlab: `linear`/`elu` only). A learned log standard deviation per action.
//!   The rollout runs the *exported* actor in the firmware's executor (`control::nn::Network`);
//!   this module replays rollouts through the same maths with autograd.
//! - Critic: an MLP `[critic_obs → 128 → 64 → 1]`, ELU, on the actor's observation plus privileged
//!   inputs (asymmetric actor–critic; see `env::CRITIC_EXTRA`). It never leaves the trainer. It
//!   is small because the update is compute-bound on a CPU: at [256, 128] the critic was ~60 % of
//!   the learner's FLOPs and the learner ~75 % of wall time.
use std::path::Path;

use candle_core::{DType, Device, Result, Tensor, Var};
use candle_nn::{Init, VarMap};
use control::nn::{LayerDesc, NetworkDesc};
use control::spec::mirror::{PolicyMirror, SignedPermutation};

pub const CRITIC_HIDDEN: [usize; 2] = [128, 64];

/// One actor layer, in the order of the spec's `[policy.network]`, with its sizes.
#[derive(Clone, Debug, PartialEq)]
pub enum ActorLayer {
    /// Single-layer LSTM `input → hidden` (PyTorch gate order i, f, g, o; both biases).
    Lstm {
        weight_ih: String,
        weight_hh: String,
        bias_ih: String,
        bias_hh: String,
        input: usize,
        hidden: usize,
    },
    Linear {
        weight: String,
        bias: String,
        input: usize,
        output: usize,
    },
    Elu {
        alpha: f64,
    },
}

/// The actor's layers (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct ActorArch {
    pub layers: Vec<ActorLayer>,
}

/// Where the sizes of a spec's layers come from.
pub enum Sizes<'a> {
    /// The shapes of the named tensors in a safetensors file.
    Weights(&'a [u8]),
    /// A fresh actor: the output width of every shaped layer but the last (which has one output
    /// per action).
    Hidden(&'a [usize]),
}

impl ActorArch {
    /// The peer walker's layout: LSTM `obs → 64`, `Linear(64 → 32)`, ELU, `Linear(32 → act)`.
    pub fn peer_lstm(obs: usize, act: usize) -> Self {
        let s = |x: &str| x.to_string();
        Self {
            layers: vec![
                ActorLayer::Lstm {
                    weight_ih: s("memory.weight_ih_l0"),
                    weight_hh: s("memory.weight_hh_l0"),
                    bias_ih: s("memory.bias_ih_l0"),
                    bias_hh: s("memory.bias_hh_l0"),
                    input: obs,
                    hidden: 64,
                },
                ActorLayer::Linear {
                    weight: s("actor.0.weight"),
                    bias: s("actor.0.bias"),
                    input: 64,
                    output: 32,
                },
                ActorLayer::Elu { alpha: 1.0 },
                ActorLayer::Linear {
                    weight: s("actor.2.weight"),
                    bias: s("actor.2.bias"),
                    input: 32,
                    output: act,
                },
            ],
        }
    }

    /// The layers `desc` lists, sized by `sizes`, ending in `act` outputs.
    pub fn from_desc(desc: &NetworkDesc, act: usize, sizes: Sizes<'_>) -> anyhow::Result<Self> {
        let file = match sizes {
            Sizes::Weights(bytes) => Some(safetensors::SafeTensors::deserialize(bytes)?),
            Sizes::Hidden(_) => None,
        };
        let shape = |name: &str| -> anyhow::Result<Vec<usize>> {
            let f = file.as_ref().expect("weights given");
            Ok(f.tensor(name)
                .map_err(|_| anyhow::anyhow!("the weights have no tensor {name} (named in [policy.network])"))?
                .shape()
                .to_vec())
        };
        let n_shaped = desc
            .layers
            .iter()
            .filter(|l| matches!(l, LayerDesc::Linear { .. } | LayerDesc::Lstm { .. }))
            .count();
        let mut next_hidden = {
            let hidden: Vec<usize> = match &sizes {
                Sizes::Hidden(h) => h.to_vec(),
                Sizes::Weights(_) => Vec::new(),
            };
            if file.is_none() {
                anyhow::ensure!(
                    hidden.len() + 1 == n_shaped,
                    "[policy.network] has {n_shaped} linear/lstm layers: give {} hidden sizes (--actor-hidden), got {}",
                    n_shaped - 1,
                    hidden.len()
                );
            }
            hidden.into_iter()
        };
        let mut width = desc.input;
        let mut shaped = 0;
        let mut layers = Vec::new();
        for (i, l) in desc.layers.iter().enumerate() {
            match l {
                LayerDesc::Lstm {
                    weight_ih,
                    weight_hh,
                    bias_ih,
                    bias_hh,
                    ..
                } => {
                    anyhow::ensure!(i == 0, "the trainer supports an LSTM only as the first layer");
                    shaped += 1;
                    let hidden = match &file {
                        Some(_) => shape(weight_hh)?[1],
                        None => next_hidden.next().unwrap_or(act),
                    };
                    layers.push(ActorLayer::Lstm {
                        weight_ih: weight_ih.clone(),
                        weight_hh: weight_hh.clone(),
                        bias_ih: bias_ih.clone(),
                        bias_hh: bias_hh.clone(),
                        input: width,
                        hidden,
                    });
                    width = hidden;
                }
                LayerDesc::Linear { weight, bias } => {
                    shaped += 1;
                    // The last layer gives the spec's actions whatever the weights hold: an actor
                    // of the same spec without a policy-set clock has one output fewer, which
                    // [`ActorCritic::load_actor_widened`] pads.
                    let output = match &file {
                        _ if shaped == n_shaped => act,
                        Some(_) => shape(weight)?[0],
                        None => next_hidden.next().unwrap_or(act),
                    };
                    layers.push(ActorLayer::Linear {
                        weight: weight.clone(),
                        bias: bias.clone(),
                        input: width,
                        output,
                    });
                    width = output;
                }
                LayerDesc::Elu { alpha } => layers.push(ActorLayer::Elu { alpha: *alpha as f64 }),
                other => anyhow::bail!(
                    "[policy.network] layer {i} is {}: the PPO trainer differentiates lstm, linear and elu only",
                    other.kind()
                ),
            }
        }
        anyhow::ensure!(
            width == act,
            "[policy.network] ends in {width} outputs, the spec has {act} actions"
        );
        Ok(Self { layers })
    }

    /// LSTM hidden size (0 without an LSTM): the recurrent state is `h` then `c`, `2 × hidden`.
    pub fn lstm_hidden(&self) -> usize {
        match self.layers.first() {
            Some(ActorLayer::Lstm { hidden, .. }) => *hidden,
            _ => 0,
        }
    }

    pub fn input(&self) -> usize {
        match self.layers.first() {
            Some(ActorLayer::Lstm { input, .. } | ActorLayer::Linear { input, .. }) => *input,
            _ => 0,
        }
    }

    /// Tensor names and shapes, in layer order.
    pub fn shapes(&self) -> Vec<(String, Vec<usize>)> {
        let mut v = Vec::new();
        for l in &self.layers {
            match l {
                ActorLayer::Lstm {
                    weight_ih,
                    weight_hh,
                    bias_ih,
                    bias_hh,
                    input,
                    hidden,
                } => {
                    v.push((weight_ih.clone(), vec![4 * hidden, *input]));
                    v.push((weight_hh.clone(), vec![4 * hidden, *hidden]));
                    v.push((bias_ih.clone(), vec![4 * hidden]));
                    v.push((bias_hh.clone(), vec![4 * hidden]));
                }
                ActorLayer::Linear {
                    weight,
                    bias,
                    input,
                    output,
                } => {
                    v.push((weight.clone(), vec![*output, *input]));
                    v.push((bias.clone(), vec![*output]));
                }
                ActorLayer::Elu { .. } => {}
            }
        }
        v
    }

    /// The fan-in of a linear layer's tensor (weight or bias); `None` for an LSTM's.
    fn fan_in(&self, name: &str) -> Option<usize> {
        self.layers.iter().find_map(|l| match l {
            ActorLayer::Linear {
                weight, bias, input, ..
            } if weight == name || bias == name => Some(*input),
            _ => None,
        })
    }

    /// The name of the matrix that reads the observation (widened by a warm start).
    /// The last linear layer's weight and bias names (the actions).
    fn output_layer(&self) -> Option<(&str, &str)> {
        self.layers.iter().rev().find_map(|l| match l {
            ActorLayer::Linear { weight, bias, .. } => Some((weight.as_str(), bias.as_str())),
            _ => None,
        })
    }

    fn input_matrix(&self) -> Option<&str> {
        match self.layers.first() {
            Some(ActorLayer::Lstm { weight_ih, .. }) => Some(weight_ih),
            Some(ActorLayer::Linear { weight, .. }) => Some(weight),
            _ => None,
        }
    }
}

/// What [`ActorCritic::load_actor_widened`] added at zero weight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Widened {
    /// Input columns (the terrain token, for an actor trained without it).
    pub inputs: usize,
    /// Output rows (the gait clock's rate, for an actor of a fixed clock).
    pub outputs: usize,
}

pub struct ActorCritic {
    pub vars: VarMap,
    /// How the LSTM's recurrence is differentiated (the fused op unless a test or bench asks).
    pub recurrence: Recurrence,
    pub arch: ActorArch,
    pub obs_dim: usize,
    pub critic_dim: usize,
    pub act_dim: usize,
    /// With the spec's `[policy] mirror = "average"`: the mirror the firmware's `Actor` averages
    /// with; [`ActorCritic::policy_sequence`] replays the same. `None`: the network alone.
    pub mirror: Option<PolicyMirror>,
}

fn get(vars: &VarMap, name: &str) -> Tensor {
    vars.data().lock().expect("var map lock")[name].as_tensor().clone()
}

fn elu(x: &Tensor, alpha: f64) -> Result<Tensor> {
    super::elu_op::Elu { alpha: alpha as f32 }.apply(&x.contiguous()?)
}

/// `out[.., i] = factor[i] · x[.., source[i]]` over the last dimension of `x` (differentiable).
fn signed_permute(x: &Tensor, p: &SignedPermutation) -> Result<Tensor> {
    let last = x.rank() - 1;
    let idx: Vec<u32> = p.source.iter().map(|&s| s as u32).collect();
    let idx = Tensor::from_vec(idx, p.len(), x.device())?;
    let factor = Tensor::from_vec(p.factor.clone(), p.len(), x.device())?;
    x.contiguous()?.index_select(&idx, last)?.broadcast_mul(&factor)
}

/// How [`ActorCritic::actor_sequence`] runs an LSTM's recurrence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Recurrence {
    /// One op over the whole sequence with a hand-written backward ([`super::lstm_op`]).
    #[default]
    Fused,
    /// candle's own ops, step by step (the reference the fused op is tested and benched against).
    StepByStep,
}

/// The LSTM recurrence from candle's ops, step by step: `xproj` `[T, B, 4H]` (input projection and
/// both biases), `W_hh` `[4H, H]`, state `[B, H]`, `masks` `[T, B, 1]` → `h` `[T, B, H]`.
fn lstm_step_by_step(xproj: &Tensor, w_hh: &Tensor, h0: &Tensor, c0: &Tensor, masks: &Tensor) -> Result<Tensor> {
    let (t, _, g4) = xproj.dims3()?;
    let hd = g4 / 4;
    let w_hh_t = w_hh.t()?;
    let (mut h, mut c) = (h0.clone(), c0.clone());
    let mut outs = Vec::with_capacity(t);
    for s in 0..t {
        let m = masks.get(s)?;
        h = h.broadcast_mul(&m)?;
        c = c.broadcast_mul(&m)?;
        let g = (xproj.get(s)? + h.matmul(&w_hh_t)?)?;
        let sg = candle_nn::ops::sigmoid(&g)?;
        let gi = sg.narrow(1, 0, hd)?;
        let gf = sg.narrow(1, hd, hd)?;
        let gg = g.narrow(1, 2 * hd, hd)?.tanh()?;
        let go = sg.narrow(1, 3 * hd, hd)?;
        c = ((gf * &c)? + (gi * gg)?)?;
        h = (go * c.tanh()?)?;
        outs.push(h.clone());
    }
    Tensor::stack(&outs, 0)
}

impl ActorCritic {
    /// The peer walker's LSTM actor ([`ActorArch::peer_lstm`]) and a fresh critic.
    pub fn new(obs_dim: usize, critic_dim: usize, act_dim: usize, init_std: f64, seed: u64) -> Result<Self> {
        Self::with_arch(ActorArch::peer_lstm(obs_dim, act_dim), critic_dim, init_std, seed)
    }

    /// Fresh networks: actor `arch` and the critic with PyTorch-like uniform init, log std =
    /// ln(`init_std`).
    pub fn with_arch(arch: ActorArch, critic_dim: usize, init_std: f64, seed: u64) -> Result<Self> {
        // candle's CPU device cannot be seeded: draw the initial weights from our own generator.
        let dev = Device::Cpu;
        let mut rng = labkit::rng::Rng(seed ^ 0x1417_AC70);
        let vars = VarMap::new();
        let mut uniform = |name: &str, shape: Vec<usize>, b: f64| -> Result<()> {
            let n = shape.iter().product();
            let v: Vec<f32> = (0..n).map(|_| rng.range(-b, b) as f32).collect();
            vars.get(shape.clone(), name, Init::Const(0.0), DType::F32, &dev)?;
            vars.data().lock().expect("var map lock")[name].set(&Tensor::from_vec(v, shape, &dev)?)?;
            Ok(())
        };
        // PyTorch's defaults: an LSTM's tensors ±1/√hidden, a linear layer's ±1/√fan_in.
        let lstm_hidden = arch.lstm_hidden();
        for (name, shape) in arch.shapes() {
            let bound = match arch.fan_in(&name) {
                Some(f) => 1.0 / (f as f64).sqrt(),
                None => 1.0 / (lstm_hidden as f64).sqrt(),
            };
            uniform(&name, shape, bound)?;
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
        let act_dim = match arch.layers.iter().rev().find_map(|l| match l {
            ActorLayer::Linear { output, .. } => Some(*output),
            ActorLayer::Lstm { hidden, .. } => Some(*hidden),
            ActorLayer::Elu { .. } => None,
        }) {
            Some(a) => a,
            None => return Err(candle_core::Error::Msg("the actor has no linear or lstm layer".into())),
        };
        vars.get(act_dim, "log_std", Init::Const(init_std.ln()), DType::F32, &dev)?;
        Ok(Self {
            vars,
            recurrence: Recurrence::Fused,
            obs_dim: arch.input(),
            arch,
            critic_dim,
            act_dim,
            mirror: None,
        })
    }

    /// Length of the policy's recurrent state, as the firmware's `Actor::read_state` lays it out:
    /// the network's `h` then `c`, then the mirrored twin's (0 for an MLP).
    pub fn state_len(&self) -> usize {
        2 * self.arch.lstm_hidden() * if self.mirror.is_some() { 2 } else { 1 }
    }

    /// The policy's action means over sequences, as the spec runs it (the firmware's `Actor`):
    /// [`ActorCritic::actor_sequence`], or with a mirror the mean of that and the mirror image of
    /// the network's means on the mirrored sequence, which starts from the twin's own state.
    pub fn policy_sequence(
        &self,
        obs: &Tensor,
        state0: Option<(&Tensor, &Tensor)>,
        twin_state0: Option<(&Tensor, &Tensor)>,
        masks: &Tensor,
    ) -> Result<Tensor> {
        let mean = self.actor_sequence(obs, state0, masks)?;
        let Some(m) = &self.mirror else { return Ok(mean) };
        let mirrored = self.actor_sequence(&signed_permute(obs, &m.obs)?, twin_state0, masks)?;
        (mean + signed_permute(&mirrored, &m.action)?)? * 0.5
    }

    /// Overwrites actor tensors from a safetensors file with the spec's names. An input matrix
    /// narrower than ours is widened with zero columns on the right (the warm start: the peer
    /// walker, its input widened by the terrain token at zero weight).
    /// An actor with fewer outputs than the spec's actions (one without the policy-set clock's
    /// rate, `[phase] rate`) gets zero rows for them: rate 1, the fixed clock it was trained on.
    /// Returns how many zero input columns and output rows were added (none for an actor already
    /// in the spec's layout).
    pub fn load_actor_widened(&self, path: &Path) -> anyhow::Result<Widened> {
        let src = crate::read_safetensors(path, &Device::Cpu)?;
        let mut widened_by = 0;
        let mut outputs_added = 0;
        let input = self.arch.input_matrix().map(str::to_string);
        let output = self.arch.output_layer().map(|(w, b)| (w.to_string(), b.to_string()));
        let is_output = |name: &str| output.as_ref().is_some_and(|(w, b)| name == w || name == b);
        for (name, shape) in self.arch.shapes() {
            let Some(t) = src.get(&name) else {
                anyhow::bail!(
                    "{}: no tensor {name}; is it an actor of the spec's [policy.network] layout?",
                    path.display()
                )
            };
            let t = t.to_dtype(DType::F32)?;
            let t = if Some(&name) == input.as_ref() && t.dim(1)? < self.obs_dim {
                widened_by = self.obs_dim - t.dim(1)?;
                let pad = Tensor::zeros((t.dim(0)?, widened_by), DType::F32, &Device::Cpu)?;
                Tensor::cat(&[&t, &pad], 1)?
            } else if is_output(&name) && t.dim(0)? < self.act_dim {
                let mut pad_dims = t.dims().to_vec();
                pad_dims[0] = self.act_dim - pad_dims[0];
                outputs_added = pad_dims[0];
                let pad = Tensor::zeros(pad_dims, DType::F32, &Device::Cpu)?;
                Tensor::cat(&[&t, &pad], 0)?
            } else {
                t
            };
            if t.dims() != shape.as_slice() {
                anyhow::bail!("{}: {name} is {:?}, need {:?}", path.display(), t.dims(), shape);
            }
            self.vars.data().lock().unwrap()[&name].set(&t)?;
        }
        Ok(Widened {
            inputs: widened_by,
            outputs: outputs_added,
        })
    }

    /// Sets the action noise σ of every action dimension.
    pub fn set_action_std(&self, std: f64) -> anyhow::Result<()> {
        self.set_action_std_from(0, std)
    }

    /// Sets the action noise σ of the outputs from `from` on (the gait clock's rate), keeping the rest.
    pub fn set_action_std_from(&self, from: usize, std: f64) -> anyhow::Result<()> {
        anyhow::ensure!(
            std.is_finite() && std > 0.0,
            "the action noise σ must be positive (got {std})"
        );
        let mut ls: Vec<f32> = self.log_std().to_vec1()?;
        anyhow::ensure!(from < ls.len(), "no action output past {from} to set a σ for");
        for v in &mut ls[from..] {
            *v = std.ln() as f32;
        }
        let t = Tensor::from_vec(ls, self.act_dim, &Device::Cpu)?;
        self.vars.data().lock().expect("var map lock")["log_std"].set(&t)?;
        Ok(())
    }

    /// Caps every output's action noise σ at `max` (those below stay as they are).
    pub fn cap_action_std(&self, max: f64) -> anyhow::Result<()> {
        anyhow::ensure!(
            max.is_finite() && max > 0.0,
            "the largest action noise σ must be positive (got {max})"
        );
        let cap = max.ln() as f32;
        let mut ls: Vec<f32> = self.log_std().to_vec1()?;
        if ls.iter().all(|&v| v <= cap) {
            return Ok(());
        }
        ls.iter_mut().for_each(|v| *v = v.min(cap));
        let t = Tensor::from_vec(ls, self.act_dim, &Device::Cpu)?;
        self.vars.data().lock().expect("var map lock")["log_std"].set(&t)?;
        Ok(())
    }

    pub fn log_std(&self) -> Tensor {
        get(&self.vars, "log_std")
    }

    /// Actor means over sequences. `obs` [T, B, obs]; for an LSTM actor `h0`/`c0` [B, hidden] (the
    /// state before step 0) and `masks` [T, B, 1]: 0 where an episode starts at that step (state
    /// reset to zero first); an MLP ignores them (pass `None`).
    pub fn actor_sequence(&self, obs: &Tensor, state0: Option<(&Tensor, &Tensor)>, masks: &Tensor) -> Result<Tensor> {
        let (t, b, i) = obs.dims3()?;
        let mut x = obs.reshape((t * b, i))?;
        for l in &self.arch.layers {
            x = match l {
                ActorLayer::Lstm {
                    weight_ih,
                    weight_hh,
                    bias_ih,
                    bias_hh,
                    hidden,
                    ..
                } => {
                    let hd = *hidden;
                    let (h0, c0) =
                        state0.ok_or_else(|| candle_core::Error::Msg("an LSTM actor needs its state".into()))?;
                    let w_ih = get(&self.vars, weight_ih);
                    let w_hh = get(&self.vars, weight_hh);
                    let bias = (get(&self.vars, bias_ih) + get(&self.vars, bias_hh))?;
                    let xproj = x.matmul(&w_ih.t()?)?.broadcast_add(&bias)?.reshape((t, b, 4 * hd))?;
                    let hs = match self.recurrence {
                        Recurrence::Fused => super::lstm_op::LstmSequence::new(
                            t,
                            b,
                            hd,
                            h0.flatten_all()?.to_vec1()?,
                            c0.flatten_all()?.to_vec1()?,
                            masks.flatten_all()?.to_vec1()?,
                        )?
                        .apply(&xproj, &w_hh)?,
                        Recurrence::StepByStep => lstm_step_by_step(&xproj, &w_hh, h0, c0, masks)?,
                    };
                    hs.reshape((t * b, hd))?
                }
                ActorLayer::Linear { weight, bias, .. } => x
                    .matmul(&get(&self.vars, weight).t()?)?
                    .broadcast_add(&get(&self.vars, bias))?,
                ActorLayer::Elu { alpha } => elu(&x, *alpha)?,
            };
        }
        x.reshape((t, b, self.act_dim))
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
                h = elu(&h, 1.0)?;
            }
        }
        h.squeeze(1)
    }

    /// The actor as a safetensors file with the spec's tensor names (what its `[policy.network]`
    /// reads).
    pub fn actor_safetensors(&self) -> anyhow::Result<Vec<u8>> {
        let tensors = self
            .arch
            .shapes()
            .into_iter()
            .map(|(name, _)| crate::tensor_file::NamedTensor::from_candle(name.clone(), &get(&self.vars, &name)))
            .collect::<anyhow::Result<Vec<_>>>()?;
        crate::tensor_file::serialize(&tensors, None)
    }

    /// Every variable with its name, in name order (a hash map's order differs between
    /// processes; sums over the variables must not).
    pub fn named_vars(&self) -> Vec<(String, Var)> {
        let data = self.vars.data().lock().expect("var map lock");
        let mut v: Vec<_> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }

    /// The critic's variables with their names, in name order.
    pub fn named_critic_vars(&self) -> Vec<(String, Var)> {
        self.named_vars()
            .into_iter()
            .filter(|(k, _)| k.starts_with("critic."))
            .collect()
    }

    /// Every variable from the safetensors file at `path` (each must be there, in its shape).
    pub fn load(&mut self, path: &Path) -> anyhow::Result<()> {
        crate::tensor_file::load_vars(&self.vars, path)
    }
}
