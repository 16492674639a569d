//! The actor's LSTM recurrence over a whole rollout sequence as one candle op with a hand-written
//! backward (issue 29: "keep the LSTM only if you make its update cheap").
//!
//! Built step by step from candle's ops, the recurrence cost ~15 small tensor ops per time step
//! forward and twice that backward, each allocating; profiled, the learner spent under 3 % of its
//! time in matrix products and the rest in element-wise maps, allocation and page faults. Here the
//! gates of a step are one matrix product and one fused loop, and the backward pass (BPTT) keeps
//! every intermediate in a few flat buffers, with the recurrent weight's gradient one matrix
//! product over all steps at the end.
//!
//! Maths (PyTorch's LSTM, gate order i, f, g, o), per step `t` with the episode mask `m_t` (0 where
//! an episode starts, so the state is reset first):
//! ```text
//! hp = m_t·h_{t−1}, cp = m_t·c_{t−1}
//! G  = xproj_t + hp·W_hhᵀ          (xproj = x·W_ihᵀ + b_ih + b_hh, computed by candle)
//! i, f, o = σ(G_i, G_f, G_o), g = tanh(G_g)
//! c_t = f·cp + i·g,  h_t = o·tanh(c_t)
//! ```
//! The op's inputs are `xproj` `[T, B, 4H]` and `W_hh` `[4H, H]` (both get gradients); the initial
//! state and the masks are constants of the op (they come from the rollout).
use std::sync::Mutex;

use candle_core::{CpuStorage, CustomOp2, Layout, Result, Shape, Tensor};

use super::matmul::MatMul;
// The firmware executor's own activations: the replay computes what the rollout's actor computed.
use control::nn::activation::{sigmoid, tanh};

/// Everything the backward pass needs, per step, flat `[T, B, ·]`.
struct Trace {
    /// Masked previous state, `[T, B, H]` each.
    hp: Vec<f32>,
    cp: Vec<f32>,
    /// Gate activations i, f, g, o, `[T, B, 4H]`.
    gates: Vec<f32>,
    /// tanh(c_t), `[T, B, H]`.
    tanh_c: Vec<f32>,
    /// h_t, `[T, B, H]` (the op's output).
    h: Vec<f32>,
}

/// The recurrence over `T` steps of `B` sequences.
pub struct LstmSequence {
    t: usize,
    b: usize,
    hidden: usize,
    h0: Vec<f32>,
    c0: Vec<f32>,
    /// `[T, B]`.
    masks: Vec<f32>,
    /// The last forward pass's intermediates, taken by the backward pass.
    trace: Mutex<Option<Trace>>,
}

impl LstmSequence {
    /// `h0`, `c0`: `[B, H]`; `masks`: `[T, B]`.
    pub fn new(t: usize, b: usize, hidden: usize, h0: Vec<f32>, c0: Vec<f32>, masks: Vec<f32>) -> Result<Self> {
        if h0.len() != b * hidden || c0.len() != b * hidden || masks.len() != t * b {
            return Err(candle_core::Error::Msg(format!(
                "lstm sequence: state {} / {} and masks {} do not fit T {t}, B {b}, H {hidden}",
                h0.len(),
                c0.len(),
                masks.len()
            )));
        }
        Ok(Self {
            t,
            b,
            hidden,
            h0,
            c0,
            masks,
            trace: Mutex::new(None),
        })
    }

    /// `h` for every step, `[T, B, H]`, from `xproj` `[T, B, 4H]` and `W_hh` `[4H, H]`.
    pub fn apply(self, xproj: &Tensor, w_hh: &Tensor) -> Result<Tensor> {
        xproj.contiguous()?.apply_op2(&w_hh.contiguous()?, self)
    }

    fn forward(&self, xproj: &[f32], w_hh: &[f32]) -> Trace {
        let (t, b, h) = (self.t, self.b, self.hidden);
        let g4 = 4 * h;
        let mut tr = Trace {
            hp: vec![0.0; t * b * h],
            cp: vec![0.0; t * b * h],
            gates: xproj.to_vec(),
            tanh_c: vec![0.0; t * b * h],
            h: vec![0.0; t * b * h],
        };
        let mut c = vec![0.0f32; b * h];
        let recurrent = MatMul {
            m: b,
            n: g4,
            k: h,
            accumulate: true,
        };
        for s in 0..t {
            let bh = s * b * h..(s + 1) * b * h;
            // hp, cp: the previous step's state (or h0, c0), masked.
            let (prev_h, prev_c): (&[f32], &[f32]) = if s == 0 {
                (&self.h0, &self.c0)
            } else {
                (&tr.h[(s - 1) * b * h..s * b * h], &c)
            };
            for r in 0..b {
                let m = self.masks[s * b + r];
                for j in 0..h {
                    let k = r * h + j;
                    tr.hp[s * b * h + k] = m * prev_h[k];
                    tr.cp[s * b * h + k] = m * prev_c[k];
                }
            }
            // G += hp · W_hhᵀ (W_hh is [4H, H] row-major: its transpose has row stride 1).
            recurrent.run(
                (&mut tr.gates[s * b * g4..(s + 1) * b * g4], g4, 1),
                (&tr.hp[bh.clone()], h, 1),
                (w_hh, 1, h),
            );
            for r in 0..b {
                let g = &mut tr.gates[(s * b + r) * g4..(s * b + r + 1) * g4];
                for j in 0..h {
                    let i = sigmoid(g[j]);
                    let f = sigmoid(g[h + j]);
                    let gg = tanh(g[2 * h + j]);
                    let o = sigmoid(g[3 * h + j]);
                    let k = r * h + j;
                    let cn = f * tr.cp[s * b * h + k] + i * gg;
                    let tc = tanh(cn);
                    c[k] = cn;
                    tr.tanh_c[s * b * h + k] = tc;
                    tr.h[s * b * h + k] = o * tc;
                    g[j] = i;
                    g[h + j] = f;
                    g[2 * h + j] = gg;
                    g[3 * h + j] = o;
                }
            }
        }
        tr
    }

    /// Gradients of `xproj` and `W_hh` from the gradient of every step's `h`.
    fn backward(&self, tr: &Trace, w_hh: &[f32], d_h: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let (t, b, h) = (self.t, self.b, self.hidden);
        let g4 = 4 * h;
        let mut d_gates = vec![0.0f32; t * b * g4];
        let mut dh_next = vec![0.0f32; b * h];
        let mut dc_next = vec![0.0f32; b * h];
        let mut dhp = vec![0.0f32; b * h];
        let to_prev = MatMul {
            m: b,
            n: h,
            k: g4,
            accumulate: false,
        };
        for s in (0..t).rev() {
            for r in 0..b {
                let k0 = s * b * h + r * h;
                let gates = &tr.gates[(s * b + r) * g4..(s * b + r + 1) * g4];
                let dg = &mut d_gates[(s * b + r) * g4..(s * b + r + 1) * g4];
                for j in 0..h {
                    let k = k0 + j;
                    let (i, f, gg, o) = (gates[j], gates[h + j], gates[2 * h + j], gates[3 * h + j]);
                    let dh = d_h[k] + dh_next[r * h + j];
                    let tc = tr.tanh_c[k];
                    let dc = dc_next[r * h + j] + dh * o * (1.0 - tc * tc);
                    dg[j] = dc * gg * i * (1.0 - i);
                    dg[h + j] = dc * tr.cp[k] * f * (1.0 - f);
                    dg[2 * h + j] = dc * i * (1.0 - gg * gg);
                    dg[3 * h + j] = dh * tc * o * (1.0 - o);
                    // The previous cell state's gradient, before the mask.
                    dc_next[r * h + j] = dc * f;
                }
            }
            // dhp = dG · W_hh.
            to_prev.run(
                (&mut dhp, h, 1),
                (&d_gates[s * b * g4..(s + 1) * b * g4], g4, 1),
                (w_hh, h, 1),
            );
            for r in 0..b {
                let m = self.masks[s * b + r];
                for j in 0..h {
                    dh_next[r * h + j] = m * dhp[r * h + j];
                    dc_next[r * h + j] *= m;
                }
            }
        }
        // dW_hh = Σ_t dG_tᵀ · hp_t: one product over all T·B rows.
        let mut d_w = vec![0.0f32; g4 * h];
        MatMul {
            m: g4,
            n: h,
            k: t * b,
            accumulate: false,
        }
        .run((&mut d_w, h, 1), (&d_gates, 1, g4), (&tr.hp, h, 1));
        (d_gates, d_w)
    }
}

fn contiguous_f32<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> Result<&'a [f32]> {
    let CpuStorage::F32(v) = s else {
        return Err(candle_core::Error::Msg(format!("lstm sequence: {what} must be f32")));
    };
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&v[a..b]),
        None => Err(candle_core::Error::Msg(format!(
            "lstm sequence: {what} must be contiguous"
        ))),
    }
}

impl CustomOp2 for LstmSequence {
    fn name(&self) -> &'static str {
        "lstm-sequence"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (t, b, h) = (self.t, self.b, self.hidden);
        if l1.shape().dims() != [t, b, 4 * h] || l2.shape().dims() != [4 * h, h] {
            return Err(candle_core::Error::Msg(format!(
                "lstm sequence: xproj {:?} and W_hh {:?}, need [{t}, {b}, {}] and [{}, {h}]",
                l1.shape().dims(),
                l2.shape().dims(),
                4 * h,
                4 * h
            )));
        }
        let xproj = contiguous_f32(s1, l1, "xproj")?;
        let w_hh = contiguous_f32(s2, l2, "W_hh")?;
        let tr = self.forward(xproj, w_hh);
        let out = tr.h.clone();
        *self.trace.lock().expect("lstm trace lock") = Some(tr);
        Ok((CpuStorage::F32(out), Shape::from((t, b, h))))
    }

    fn bwd(
        &self,
        xproj: &Tensor,
        w_hh: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let w: Vec<f32> = w_hh.flatten_all()?.to_vec1()?;
        let d_h: Vec<f32> = grad.flatten_all()?.to_vec1()?;
        // The forward pass's trace; recomputed if this op's forward ran again or never kept one.
        let kept = self.trace.lock().expect("lstm trace lock").take();
        let tr = match kept {
            Some(tr) => tr,
            None => self.forward(&xproj.flatten_all()?.to_vec1::<f32>()?, &w),
        };
        let (d_x, d_w) = self.backward(&tr, &w, &d_h);
        Ok((
            Some(Tensor::from_vec(d_x, xproj.shape(), xproj.device())?),
            Some(Tensor::from_vec(d_w, w_hh.shape(), w_hh.device())?),
        ))
    }
}
