//! ELU as one candle op with a one-loop backward, computed by the firmware executor's own `elu`.
//! Built from candle's ops it was 8 ops forward and about twice that backward, each allocating a
//! tensor: after the LSTM's recurrence ([`super::lstm_op`]), the largest part of the update.
use candle_core::{CpuStorage, CustomOp1, Layout, Result, Shape, Tensor};
use control::nn::activation::elu;

/// `elu(x) = x` for `x > 0`, else `alpha·(eˣ − 1)`; its derivative `1`, else `elu(x) + alpha`.
pub struct Elu {
    pub alpha: f32,
}

impl Elu {
    pub fn apply(self, x: &Tensor) -> Result<Tensor> {
        x.apply_op1(self)
    }
}

impl CustomOp1 for Elu {
    fn name(&self) -> &'static str {
        "elu-fused"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let CpuStorage::F32(v) = s else {
            return Err(candle_core::Error::Msg("elu: f32 only".into()));
        };
        let Some((a, b)) = l.contiguous_offsets() else {
            return Err(candle_core::Error::Msg("elu: the input must be contiguous".into()));
        };
        let out = v[a..b].iter().map(|&x| elu(x, self.alpha)).collect();
        Ok((CpuStorage::F32(out), l.shape().clone()))
    }

    fn bwd(&self, x: &Tensor, y: &Tensor, grad: &Tensor) -> Result<Option<Tensor>> {
        let xs: Vec<f32> = x.flatten_all()?.to_vec1()?;
        let ys: Vec<f32> = y.flatten_all()?.to_vec1()?;
        let gs: Vec<f32> = grad.flatten_all()?.to_vec1()?;
        let d: Vec<f32> = xs
            .iter()
            .zip(&ys)
            .zip(&gs)
            .map(|((&x, &y), &g)| if x > 0.0 { g } else { g * (y + self.alpha) })
            .collect();
        Ok(Some(Tensor::from_vec(d, x.shape(), x.device())?))
    }
}
