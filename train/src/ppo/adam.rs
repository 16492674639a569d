//! Adam (Kingma & Ba; candle's `AdamW` with no weight decay, step for step) over named variables,
//! with its moments and step count in the open, so a checkpoint holds the whole optimizer and a
//! resumed run steps exactly as the run that went on would have. Plain loops over `f32`: one
//! allocation-free pass per variable instead of a dozen tensor ops.
use candle_core::backprop::GradStore;
use candle_core::{Tensor, Var};

pub const BETA1: f64 = 0.9;
pub const BETA2: f64 = 0.999;
pub const EPS: f64 = 1e-8;

/// Adam's state for a fixed, ordered list of variables.
pub struct Adam {
    /// The variables by name, in name order (a deterministic order for every sum over them).
    pub vars: Vec<(String, Var)>,
    pub lr: f64,
    /// First and second moments, one vector per variable.
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
    /// Steps taken (the bias correction's `t`).
    pub step: u64,
}

impl Adam {
    pub fn new(vars: Vec<(String, Var)>, lr: f64) -> Self {
        let zeros = || {
            vars.iter()
                .map(|(_, v)| vec![0.0f32; v.elem_count()])
                .collect::<Vec<_>>()
        };
        Self {
            m: zeros(),
            v: zeros(),
            vars,
            lr,
            step: 0,
        }
    }

    /// One step on the variables that have a gradient in `grads` (the others keep their moments).
    pub fn step(&mut self, grads: &GradStore) -> candle_core::Result<()> {
        let scales = self.next_step();
        for (k, (_, var)) in self.vars.iter().enumerate() {
            let Some(g) = grads.get(var.as_tensor()) else {
                continue;
            };
            let g: Vec<f32> = g.flatten_all()?.to_vec1()?;
            let mut theta: Vec<f32> = var.as_tensor().flatten_all()?.to_vec1()?;
            scales.apply(&mut self.m[k], &mut self.v[k], &mut theta, &g);
            var.set(&Tensor::from_vec(theta, var.shape(), var.device())?)?;
        }
        Ok(())
    }

    /// One step on parameters held outside the variables (the fused update's buffers), `params[k]`
    /// and `grads[k]` being variable `k`'s, in [`Adam::vars`] order.
    pub fn step_flat(&mut self, params: &mut [Vec<f32>], grads: &[Vec<f32>]) {
        let scales = self.next_step();
        for k in 0..self.vars.len() {
            scales.apply(&mut self.m[k], &mut self.v[k], &mut params[k], &grads[k]);
        }
    }

    fn next_step(&mut self) -> Scales {
        self.step += 1;
        let t = self.step.min(i32::MAX as u64) as i32;
        Scales {
            m: (1.0 / (1.0 - BETA1.powi(t))) as f32,
            v: (1.0 / (1.0 - BETA2.powi(t))) as f32,
            lr: self.lr as f32,
        }
    }
}

/// One step's bias corrections and rate.
struct Scales {
    m: f32,
    v: f32,
    lr: f32,
}

impl Scales {
    fn apply(&self, m: &mut [f32], v: &mut [f32], theta: &mut [f32], g: &[f32]) {
        let (b1, b2, eps) = (BETA1 as f32, BETA2 as f32, EPS as f32);
        for i in 0..theta.len() {
            m[i] = m[i] * b1 + g[i] * (1.0 - b1);
            v[i] = v[i] * b2 + g[i] * g[i] * (1.0 - b2);
            let (m_hat, v_hat) = (m[i] * self.m, v[i] * self.v);
            theta[i] -= m_hat / (v_hat.sqrt() + eps) * self.lr;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::{AdamW, Optimizer, ParamsAdamW};

    #[test]
    fn steps_as_candles_adamw_without_weight_decay() {
        let dev = Device::Cpu;
        let x0 = Tensor::new(&[[0.3f32, -1.2, 2.0], [0.7, 0.1, -0.4]], &dev).unwrap();
        let (a, b) = (Var::from_tensor(&x0).unwrap(), Var::from_tensor(&x0).unwrap());
        let mut ours = Adam::new(vec![("x".into(), a.clone())], 3e-3);
        let mut theirs = AdamW::new(
            vec![b.clone()],
            ParamsAdamW {
                lr: 3e-3,
                weight_decay: 0.0,
                ..Default::default()
            },
        )
        .unwrap();
        let target = Tensor::new(&[[1.0f32, 0.0, -1.0], [0.5, 0.5, 0.5]], &dev).unwrap();
        for _ in 0..20 {
            let loss = |v: &Var| (v.as_tensor() - &target).unwrap().sqr().unwrap().sum_all().unwrap();
            ours.step(&loss(&a).backward().unwrap()).unwrap();
            theirs.step(&loss(&b).backward().unwrap()).unwrap();
        }
        let (pa, pb): (Vec<f32>, Vec<f32>) = (
            a.flatten_all().unwrap().to_vec1().unwrap(),
            b.flatten_all().unwrap().to_vec1().unwrap(),
        );
        let moved = pa
            .iter()
            .zip(x0.flatten_all().unwrap().to_vec1::<f32>().unwrap())
            .any(|(p, q)| (p - q).abs() > 0.02);
        assert!(moved, "20 steps at 3e-3 move the parameters: {pa:?}");
        for (p, q) in pa.iter().zip(&pb) {
            assert!((p - q).abs() <= 1e-6, "ours {pa:?}\ncandle {pb:?}");
        }
        assert_eq!(ours.step, 20);
        assert_eq!(a.dtype(), DType::F32);
    }

    #[test]
    fn a_variable_without_gradient_keeps_its_moments() {
        let dev = Device::Cpu;
        let a = Var::new(&[1.0f32, 2.0], &dev).unwrap();
        let b = Var::new(&[3.0f32], &dev).unwrap();
        let mut adam = Adam::new(vec![("a".into(), a.clone()), ("b".into(), b.clone())], 0.1);
        let grads = a.as_tensor().sqr().unwrap().sum_all().unwrap().backward().unwrap();
        adam.step(&grads).unwrap();
        assert!(adam.m[0].iter().all(|&m| m != 0.0));
        assert_eq!(adam.m[1], [0.0]);
        assert_eq!(b.to_vec1::<f32>().unwrap(), [3.0]);
    }
}
