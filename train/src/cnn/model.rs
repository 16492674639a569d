//! The terrain CNN of the paper ("BEV Terrain Encoder"): Conv + BatchNorm + ReLU blocks with
//! stride-2 downsampling from the 6×60×60 BEV grid to 128×8×8, then a shared fully connected
//! layer and one linear head whose seven outputs are laid out as `estimator::terrain_cnn`
//! documents (class logits, h cm, d cm, scaled yaw vector).
//!
//! This file is the single definition of the architecture: training builds it with candle, and
//! [`crate::cnn::export`] writes the same layers (BatchNorm folded) as a `control::nn::NetworkDesc`
//! for the firmware's executor.
use candle_core::Var;
use candle_core::{CpuStorage, CustomOp1, CustomOp3, Layout, Module, Result, Shape, Tensor};
use candle_nn::{Conv2d, Conv2dConfig, Init, Linear, VarBuilder};
use estimator::terrain_cnn::OUTPUTS;
use sensor_io::bev::{BEV_CELLS, BEV_CHANNELS};

/// Conv blocks: (in channels, out channels); each is a 3×3 conv, stride 2, padding 1
/// (60 → 30 → 15 → 8).
pub const CONV_BLOCKS: [(usize, usize); 3] = [(BEV_CHANNELS, 24), (24, 48), (48, 128)];
pub const KERNEL: usize = 3;
pub const STRIDE: usize = 2;
pub const PADDING: usize = 1;
/// Width of the shared fully connected layer.
pub const FC_WIDTH: usize = 128;
/// BatchNorm epsilon (PyTorch's default).
pub const BN_EPS: f64 = 1e-5;

/// Spatial size after the conv blocks.
pub const fn encoded_cells() -> usize {
    let mut n = BEV_CELLS;
    let mut i = 0;
    while i < CONV_BLOCKS.len() {
        n = (n + 2 * PADDING - KERNEL) / STRIDE + 1;
        i += 1;
    }
    n
}

/// Channels × cells × cells of the encoder output (128 × 8 × 8).
pub const ENCODED: usize = CONV_BLOCKS[CONV_BLOCKS.len() - 1].1 * encoded_cells() * encoded_cells();

/// Variable names: `conv{i}.weight`, `bn{i}.{weight,bias,running_mean,running_var}`,
/// `fc.{weight,bias}`, `head.{weight,bias}` (i from 1).
pub struct TerrainCnn {
    blocks: Vec<(Conv2d, BatchNorm2d)>,
    fc: Linear,
    head: Linear,
}

impl TerrainCnn {
    pub fn new(vb: VarBuilder) -> Result<Self> {
        let mut blocks = Vec::new();
        for (i, &(cin, cout)) in CONV_BLOCKS.iter().enumerate() {
            let cfg = Conv2dConfig {
                padding: PADDING,
                stride: STRIDE,
                ..Default::default()
            };
            // No conv bias: the BatchNorm shift replaces it (and folds into it at export).
            let conv = candle_nn::conv2d_no_bias(cin, cout, KERNEL, cfg, vb.pp(format!("conv{}", i + 1)))?;
            let bn = BatchNorm2d::new(cout, vb.pp(format!("bn{}", i + 1)))?;
            blocks.push((conv, bn));
        }
        let fc = candle_nn::linear(ENCODED, FC_WIDTH, vb.pp("fc"))?;
        let head = candle_nn::linear(FC_WIDTH, OUTPUTS, vb.pp("head"))?;
        Ok(Self { blocks, fc, head })
    }

    /// `x`: `[batch, 6, 60, 60]` → `[batch, 7]`. `train` selects batch statistics (and updates
    /// the running ones) versus the running statistics the firmware's folded weights use.
    pub fn forward_t(&self, x: &Tensor, train: bool) -> Result<Tensor> {
        let mut x = x.clone();
        for (conv, bn) in &self.blocks {
            x = bn.forward_t(&conv_im2col(&x, conv.weight())?, train)?.relu()?;
        }
        let x = self.fc.forward(&x.flatten_from(1)?)?.relu()?;
        self.head.forward(&x)
    }
}

/// Spatial BatchNorm over `[b, c, h, w]` (PyTorch semantics: biased batch variance to normalise,
/// unbiased for the running estimate, momentum 0.1). Written with reductions over the `[b, c, hw]`
/// view instead of candle-nn's transpose-based one, which costs 3× the conv it follows on the CPU.
pub struct BatchNorm2d {
    weight: Tensor,
    bias: Tensor,
    running_mean: Var,
    running_var: Var,
}

/// Running-statistics momentum (PyTorch's default).
pub const BN_MOMENTUM: f64 = 0.1;

impl BatchNorm2d {
    pub fn new(c: usize, vb: VarBuilder) -> Result<Self> {
        let weight = vb.get_with_hints(c, "weight", Init::Const(1.0))?;
        let bias = vb.get_with_hints(c, "bias", Init::Const(0.0))?;
        let running_mean = Var::from_tensor(&vb.get_with_hints(c, "running_mean", Init::Const(0.0))?)?;
        let running_var = Var::from_tensor(&vb.get_with_hints(c, "running_var", Init::Const(1.0))?)?;
        Ok(Self {
            weight,
            bias,
            running_mean,
            running_var,
        })
    }

    pub fn forward_t(&self, x: &Tensor, train: bool) -> Result<Tensor> {
        let (b, c, h, w) = x.dims4()?;
        if !train {
            let x3 = x.reshape((b, c, h * w))?;
            let mean = self.running_mean.as_tensor().reshape((1, c, 1))?;
            let var = self.running_var.as_tensor().reshape((1, c, 1))?;
            let scale = self
                .weight
                .reshape((1, c, 1))?
                .broadcast_div(&(var + BN_EPS)?.sqrt()?)?;
            let shift = self
                .bias
                .reshape((1, c, 1))?
                .broadcast_sub(&mean.broadcast_mul(&scale)?)?;
            return x3.broadcast_mul(&scale)?.broadcast_add(&shift)?.reshape((b, c, h, w));
        }
        let stats = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let y = x
            .contiguous()?
            .apply_op3(&self.weight, &self.bias, BnTrain { stats: stats.clone() })?;
        let st = stats
            .lock()
            .map_err(|_| candle_core::Error::Msg("bn stats lock".into()))?;
        let n = (b * h * w) as f64;
        let mean = Tensor::from_vec(
            st.iter().map(|s: &(f64, f64)| s.0 as f32).collect::<Vec<_>>(),
            c,
            x.device(),
        )?;
        let var = Tensor::from_vec(
            st.iter()
                .map(|s| (s.1 * n / (n - 1.0).max(1.0)) as f32)
                .collect::<Vec<_>>(),
            c,
            x.device(),
        )?;
        let m = BN_MOMENTUM;
        self.running_mean
            .set(&((self.running_mean.as_tensor() * (1.0 - m))? + (mean * m)?)?)?;
        self.running_var
            .set(&((self.running_var.as_tensor() * (1.0 - m))? + (var * m)?)?)?;
        Ok(y)
    }
}

/// Training-mode BatchNorm as one fused op: `y = γ (x − μ) / σ + β` with batch statistics (μ,
/// biased σ², per channel), and the textbook backward
/// `dx = γ/σ · (dy − mean(dy) − x̂ · mean(dy · x̂))`, `dγ = Σ dy x̂`, `dβ = Σ dy`.
/// The statistics of the forward pass are left in `stats`, for the running averages and for the
/// backward pass.
struct BnTrain {
    stats: std::sync::Arc<std::sync::Mutex<Vec<(f64, f64)>>>,
}

fn bn_stats(x: &[f32], b: usize, c: usize, hw: usize) -> Vec<(f64, f64)> {
    (0..c)
        .map(|ci| {
            let (mut s, mut s2) = (0.0f64, 0.0f64);
            for bi in 0..b {
                for &v in &x[(bi * c + ci) * hw..(bi * c + ci + 1) * hw] {
                    s += v as f64;
                    s2 += v as f64 * v as f64;
                }
            }
            let n = (b * hw) as f64;
            let mean = s / n;
            (mean, (s2 / n - mean * mean).max(0.0))
        })
        .collect()
}

impl CustomOp3 for BnTrain {
    fn name(&self) -> &'static str {
        "batch_norm_train"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let x = contiguous_f32(s1, l1)?;
        let (gamma, beta) = (contiguous_f32(s2, l2)?, contiguous_f32(s3, l3)?);
        let dims = l1.shape().dims();
        let (b, c) = (dims[0], dims[1]);
        let hw: usize = dims[2..].iter().product();
        let st = bn_stats(x, b, c, hw);
        let mut y = vec![0.0f32; x.len()];
        for bi in 0..b {
            for ci in 0..c {
                let scale = gamma[ci] as f64 / (st[ci].1 + BN_EPS).sqrt();
                let shift = beta[ci] as f64 - st[ci].0 * scale;
                let (scale, shift) = (scale as f32, shift as f32);
                let r = (bi * c + ci) * hw..(bi * c + ci + 1) * hw;
                for (yv, &xv) in y[r.clone()].iter_mut().zip(&x[r]) {
                    *yv = xv * scale + shift;
                }
            }
        }
        *self
            .stats
            .lock()
            .map_err(|_| candle_core::Error::Msg("bn stats lock".into()))? = st;
        Ok((CpuStorage::F32(y), l1.shape().clone()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        gamma: &Tensor,
        _beta: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let dims = x.dims().to_vec();
        let (b, c) = (dims[0], dims[1]);
        let hw: usize = dims[2..].iter().product();
        let xv = x.flatten_all()?.to_vec1::<f32>()?;
        let dy = grad.flatten_all()?.to_vec1::<f32>()?;
        let g = gamma.to_vec1::<f32>()?;
        // The batch statistics of this op's own forward pass.
        let st = self
            .stats
            .lock()
            .map_err(|_| candle_core::Error::Msg("bn stats lock".into()))?
            .clone();
        if st.len() != c {
            candle_core::bail!("batch_norm_train backward without its forward statistics");
        }
        let n = (b * hw) as f64;
        let mut dx = vec![0.0f32; xv.len()];
        let (mut dgamma, mut dbeta) = (vec![0.0f32; c], vec![0.0f32; c]);
        for ci in 0..c {
            let (mean, var) = st[ci];
            let inv = 1.0 / (var + BN_EPS).sqrt();
            let (mut sdy, mut sdyx) = (0.0f64, 0.0f64);
            for bi in 0..b {
                let r = (bi * c + ci) * hw..(bi * c + ci + 1) * hw;
                for (&d, &v) in dy[r.clone()].iter().zip(&xv[r]) {
                    sdy += d as f64;
                    sdyx += d as f64 * (v as f64 - mean) * inv;
                }
            }
            dgamma[ci] = sdyx as f32;
            dbeta[ci] = sdy as f32;
            let k = g[ci] as f64 * inv;
            let (mdy, mdyx) = (sdy / n, sdyx / n);
            for bi in 0..b {
                let r = (bi * c + ci) * hw..(bi * c + ci + 1) * hw;
                for ((o, &d), &v) in dx[r.clone()].iter_mut().zip(&dy[r.clone()]).zip(&xv[r]) {
                    let xhat = (v as f64 - mean) * inv;
                    *o = (k * (d as f64 - mdy - xhat * mdyx)) as f32;
                }
            }
        }
        let dev = x.device();
        Ok((
            Some(Tensor::from_vec(dx, dims, dev)?),
            Some(Tensor::from_vec(dgamma, c, dev)?),
            Some(Tensor::from_vec(dbeta, c, dev)?),
        ))
    }
}

/// `conv2d(x, w)` with stride [`STRIDE`] and padding [`PADDING`] as im2col followed by one
/// matrix product. Same numbers as `Tensor::conv2d`, but the gradient is a matrix product plus
/// col2im: candle's CPU conv backward (a transposed convolution) is about 8× slower than its
/// forward pass; this one is not.
pub fn conv_im2col(x: &Tensor, w: &Tensor) -> Result<Tensor> {
    let (b, c, h, wd) = x.dims4()?;
    let (cout, cin, k, k2) = w.dims4()?;
    if cin != c || k != k2 {
        candle_core::bail!("conv weight {:?} does not fit input {:?}", w.dims(), x.dims());
    }
    let geo = Geometry::new(c, h, wd, k);
    let cols = x.contiguous()?.apply_op1(Im2Col(geo))?; // [b, c*k*k, ho*wo]
    w.reshape((cout, c * k * k))?
        .broadcast_matmul(&cols)?
        .reshape((b, cout, geo.ho, geo.wo))
}

/// Shapes of one convolution (stride [`STRIDE`], padding [`PADDING`]).
#[derive(Clone, Copy, Debug)]
struct Geometry {
    c: usize,
    h: usize,
    w: usize,
    k: usize,
    ho: usize,
    wo: usize,
}

impl Geometry {
    fn new(c: usize, h: usize, w: usize, k: usize) -> Self {
        let (ho, wo) = ((h + 2 * PADDING - k) / STRIDE + 1, (w + 2 * PADDING - k) / STRIDE + 1);
        Self { c, h, w, k, ho, wo }
    }

    /// Calls `f(col_index, input_index)` for every (tap, output pixel) that reads the input
    /// (taps in the zero padding are skipped), per image. Column layout: row `c*k*k + ky*k + kx`,
    /// column `oy*wo + ox`, i.e. `[c*k*k, ho*wo]` row-major, matching the weight's flattening.
    #[inline]
    fn for_each(&self, mut f: impl FnMut(usize, usize)) {
        let n = self.ho * self.wo;
        for ci in 0..self.c {
            for ky in 0..self.k {
                for kx in 0..self.k {
                    let row = (ci * self.k + ky) * self.k + kx;
                    for oy in 0..self.ho {
                        let iy = (oy * STRIDE + ky) as isize - PADDING as isize;
                        if iy < 0 || iy >= self.h as isize {
                            continue;
                        }
                        for ox in 0..self.wo {
                            let ix = (ox * STRIDE + kx) as isize - PADDING as isize;
                            if ix < 0 || ix >= self.w as isize {
                                continue;
                            }
                            f(
                                row * n + oy * self.wo + ox,
                                (ci * self.h + iy as usize) * self.w + ix as usize,
                            );
                        }
                    }
                }
            }
        }
    }

    fn cols_len(&self) -> usize {
        self.c * self.k * self.k * self.ho * self.wo
    }
}

fn contiguous_f32<'a>(storage: &'a CpuStorage, layout: &Layout) -> Result<&'a [f32]> {
    let Some((start, end)) = layout.contiguous_offsets() else {
        candle_core::bail!("im2col/col2im need a contiguous input");
    };
    Ok(&storage.as_slice::<f32>()?[start..end])
}

/// `[b, c, h, w]` → `[b, c*k*k, ho*wo]`.
struct Im2Col(Geometry);

impl CustomOp1 for Im2Col {
    fn name(&self) -> &'static str {
        "im2col"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let g = self.0;
        let x = contiguous_f32(storage, layout)?;
        let per_in = g.c * g.h * g.w;
        let b = x.len() / per_in;
        let mut out = vec![0.0f32; b * g.cols_len()];
        for (xi, oi) in x.chunks_exact(per_in).zip(out.chunks_exact_mut(g.cols_len())) {
            g.for_each(|o, i| oi[o] = xi[i]);
        }
        Ok((CpuStorage::F32(out), Shape::from((b, g.c * g.k * g.k, g.ho * g.wo))))
    }

    fn bwd(&self, _arg: &Tensor, _res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        Ok(Some(grad_res.contiguous()?.apply_op1_no_bwd(&Col2Im(self.0))?))
    }
}

/// The adjoint of [`Im2Col`]: sums each column entry back into the input pixel it came from.
struct Col2Im(Geometry);

impl CustomOp1 for Col2Im {
    fn name(&self) -> &'static str {
        "col2im"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let g = self.0;
        let cols = contiguous_f32(storage, layout)?;
        let b = cols.len() / g.cols_len();
        let per_in = g.c * g.h * g.w;
        let mut out = vec![0.0f32; b * per_in];
        for (ci, oi) in cols.chunks_exact(g.cols_len()).zip(out.chunks_exact_mut(per_in)) {
            g.for_each(|o, i| oi[i] += ci[o]);
        }
        Ok((CpuStorage::F32(out), Shape::from((b, g.c, g.h, g.w))))
    }
}

/// Predictions of `model` (eval mode) for samples `idx`, as raw outputs.
pub fn predict(
    model: &TerrainCnn,
    ds: &crate::cnn::data::Dataset,
    idx: &[usize],
    dev: &candle_core::Device,
) -> candle_core::Result<Vec<[f32; 7]>> {
    let mut outs = Vec::with_capacity(idx.len());
    for chunk in idx.chunks(256) {
        let b = crate::cnn::data::batch(ds, chunk, &[], dev)?;
        let o = model.forward_t(&b.x, false)?.to_vec2::<f32>()?;
        outs.extend(o.into_iter().map(|r| <[f32; 7]>::try_from(r).expect("7 outputs")));
    }
    Ok(outs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn fused_batch_norm_matches_candle_nn_in_value_and_gradient() {
        use candle_core::{DType, Var};
        let dev = Device::Cpu;
        let x = Var::randn(0.5f32, 2.0, (4, 3, 5, 5), &dev).unwrap();
        let vm = candle_nn::VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &dev);
        let ours = BatchNorm2d::new(3, vb.pp("a")).unwrap();
        let theirs = candle_nn::batch_norm(3, candle_nn::BatchNormConfig::default(), vb.pp("b")).unwrap();
        let probe = Tensor::randn(0f32, 1.0, (4, 3, 5, 5), &dev).unwrap();
        let ya = ours.forward_t(x.as_tensor(), true).unwrap();
        let yb = candle_core::ModuleT::forward_t(&theirs, x.as_tensor(), true).unwrap();
        let max = |t: Tensor| t.abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(max((&ya - &yb).unwrap()) < 1e-4);
        let ga = (ya * &probe).unwrap().sum_all().unwrap().backward().unwrap();
        let gb = (yb * &probe).unwrap().sum_all().unwrap().backward().unwrap();
        let (dxa, dxb) = (ga.get(x.as_tensor()).unwrap(), gb.get(x.as_tensor()).unwrap());
        assert!(max((dxa - dxb).unwrap()) < 1e-4);
        // Running statistics follow the same update.
        let data = vm.data().lock().unwrap();
        for s in ["running_mean", "running_var"] {
            let d = (data[&format!("a.{s}")].as_tensor() - data[&format!("b.{s}")].as_tensor()).unwrap();
            assert!(max(d) < 1e-4, "{s}");
        }
    }

    #[test]
    fn im2col_conv_matches_candle_conv2d() {
        let dev = Device::Cpu;
        for (c, n, cout) in [(6usize, 60usize, 5usize), (4, 15, 3), (3, 7, 2)] {
            let x = Tensor::randn(0f32, 1.0, (2, c, n, n), &dev).unwrap();
            let w = Tensor::randn(0f32, 1.0, (cout, c, 3, 3), &dev).unwrap();
            let a = conv_im2col(&x, &w).unwrap();
            let b = x.conv2d(&w, PADDING, STRIDE, 1, 1).unwrap();
            assert_eq!(a.dims(), b.dims());
            let diff = (a - b)
                .unwrap()
                .abs()
                .unwrap()
                .max_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap();
            assert!(diff < 1e-4, "max diff {diff}");
        }
    }

    #[test]
    fn encoder_output_is_the_papers_128x8x8() {
        assert_eq!(encoded_cells(), 8);
        assert_eq!(ENCODED, 128 * 8 * 8);
    }
}
