//! Supervised training of the terrain CNN, top to bottom: shuffle, mirror-augment, forward,
//! the paper's terrain loss, AdamW with a cosine learning-rate schedule, validation each epoch.
//!
//! Loss (paper eq. for L_terrain, plus our yaw term):
//! `0.6·CE(class) + 1·SmoothL1(h) + 1·SmoothL1(d) + LAMBDA_YAW·SmoothL1(yaw vector)`, with h and d
//! in centimetres and the yaw unit vector scaled by 180/π (one unit ≈ 1°), SmoothL1's β = 1, so the
//! quadratic zone is exactly the sub-centimetre / sub-degree band the accuracy targets live in.
//! h, d and yaw are supervised on stairs samples only (flat has no geometry; its θ is the robot's
//! heading, which a robot-centred grid cannot show). The yaw term's weight is 0.5: the vector
//! has two components, so 0.5 puts yaw on the same footing as one of h or d.
use crate::cnn::dataset::EvalStats;
use anyhow::Context;
use candle_core::{DType, Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarBuilder, VarMap};
use labkit::rng::Rng;

use crate::cnn::data::{batch, Dataset};
use crate::cnn::model::TerrainCnn;

pub const LAMBDA_CLS: f64 = 0.6;
pub const LAMBDA_H: f64 = 1.0;
pub const LAMBDA_D: f64 = 1.0;
pub const LAMBDA_YAW: f64 = 0.5;

/// Training settings.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FitConfig {
    pub epochs: usize,
    pub batch: usize,
    pub lr: f64,
    pub weight_decay: f64,
    /// Shuffling, mirroring and initialisation seed.
    pub seed: u64,
    /// Mirror half of the training samples left–right.
    pub mirror: bool,
    /// Stop after this many optimiser steps (0: no limit) — for smoke tests.
    pub max_steps: usize,
    /// Start from this checkpoint (`checkpoint.safetensors` of an earlier `fit`) instead of the
    /// seeded initialisation: continues a run with a fresh schedule.
    pub init: Option<std::path::PathBuf>,
    /// Train with BatchNorm in inference mode: its running statistics stay fixed and only its
    /// scale and shift learn. A fine-tune of an exported (folded) network needs it: batch
    /// statistics would change what the network computes at the first step.
    pub freeze_bn: bool,
    /// Write the unfolded weights here after every epoch (atomically: a temporary file, then a
    /// rename), so a long run stopped part-way keeps its last finished epoch for `--init`.
    pub checkpoint: Option<std::path::PathBuf>,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self {
            epochs: 30,
            batch: 64,
            lr: 2e-3,
            weight_decay: 1e-4,
            seed: 0,
            mirror: true,
            max_steps: 0,
            init: None,
            freeze_bn: false,
            checkpoint: None,
        }
    }
}

/// Loss terms of one batch (means).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct LossParts {
    pub total: f64,
    pub ce: f64,
    pub h: f64,
    pub d: f64,
    pub yaw: f64,
}

fn smooth_l1(err: &Tensor) -> candle_core::Result<Tensor> {
    let a = err.abs()?;
    let quad = (a.sqr()? * 0.5)?;
    let lin = (&a - 0.5)?;
    a.lt(1.0)?.where_cond(&quad, &lin)
}

/// The terrain loss of `out` (`[b,7]`) against a batch's targets; returns the scalar and its parts.
pub fn terrain_loss(
    out: &Tensor,
    class: &Tensor,
    reg: &Tensor,
    stairs: &Tensor,
) -> candle_core::Result<(Tensor, [Tensor; 4])> {
    let logits = out.narrow(1, 0, 3)?;
    let ce = candle_nn::loss::cross_entropy(&logits, class)?;
    let n_stairs = (stairs.sum_all()? + 1e-6)?;
    let per = smooth_l1(&(out.narrow(1, 3, 4)? - reg)?)?; // [b,4]
    let masked = per.broadcast_mul(&stairs.unsqueeze(1)?)?;
    let col = |k: usize, w: usize| -> candle_core::Result<Tensor> {
        masked.narrow(1, k, w)?.sum_all()?.broadcast_div(&n_stairs)
    };
    let (h, d, yaw) = (col(0, 1)?, col(1, 1)?, col(2, 2)?);
    let total = ((&ce * LAMBDA_CLS)? + (&h * LAMBDA_H)? + (&d * LAMBDA_D)? + (&yaw * LAMBDA_YAW)?)?;
    Ok((total, [ce, h, d, yaw]))
}

/// One epoch's record.
#[derive(Clone, Debug, serde::Serialize)]
pub struct EpochLog {
    pub epoch: usize,
    pub steps: usize,
    pub lr: f64,
    pub train: LossParts,
    pub val: Option<EvalStats>,
    pub seconds: f64,
}

/// Errors of raw outputs against the dataset's truth, decoded exactly as the firmware decodes.
pub fn score(ds: &Dataset, idx: &[usize], outs: &[[f32; 7]]) -> EvalStats {
    let mut s = EvalStats::default();
    for (&i, o) in idx.iter().zip(outs) {
        let est = estimator::terrain_cnn::decode(o, ds.heading[i]).unwrap_or(hal::TerrainToken::FLAT);
        s.add(&ds.token(i), &est);
    }
    s
}

/// Re-initialises conv and linear weights and biases from `seed` (uniform ±1/sqrt(fan_in), as
/// PyTorch's defaults), because candle's CPU generator cannot be seeded: the same seed and data give
/// the same starting point.
pub fn seeded_init(varmap: &VarMap, seed: u64, dev: &Device) -> anyhow::Result<()> {
    let data = varmap
        .data()
        .lock()
        .map_err(|_| anyhow::anyhow!("variable map lock poisoned"))?;
    let mut names: Vec<&String> = data.keys().filter(|n| !n.starts_with("bn")).collect();
    names.sort();
    let mut rng = Rng(seed ^ 0x1417_0000);
    for name in names {
        let var = &data[name];
        let layer = name.rsplit_once('.').map_or(name.as_str(), |(l, _)| l);
        let w = &data[&format!("{layer}.weight")];
        let fan_in: usize = w.dims()[1..].iter().product();
        let bound = 1.0 / (fan_in as f64).sqrt();
        let n = var.elem_count();
        let v: Vec<f32> = (0..n).map(|_| rng.range(-bound, bound) as f32).collect();
        var.set(&Tensor::from_vec(v, var.dims(), dev)?)?;
    }
    Ok(())
}

/// Loads `--init` into `varmap`: a checkpoint of an earlier `fit`, or an export (the firmware's
/// `terrain_cnn.safetensors`, BatchNorm folded into the convs), unfolded by
/// [`crate::cnn::export::unfold`] so that BatchNorm in inference mode computes exactly the
/// export.
pub fn load_init(varmap: &VarMap, path: &std::path::Path, dev: &Device) -> anyhow::Result<()> {
    let loaded =
        crate::read_safetensors(path, dev).map_err(|e| anyhow::anyhow!("loading --init {}: {e}", path.display()))?;
    let names: Vec<&String> = loaded.keys().collect();
    let tensors = if crate::cnn::export::is_export_layout(&names) {
        crate::cnn::export::unfold(&loaded)
            .with_context(|| format!("--init {}: unfolding the exported network", path.display()))?
    } else {
        loaded
    };
    let data = varmap
        .data()
        .lock()
        .map_err(|_| anyhow::anyhow!("variable map lock poisoned"))?;
    for (name, var) in data.iter() {
        let t = tensors
            .get(name)
            .with_context(|| format!("--init {}: no tensor `{name}`", path.display()))?;
        anyhow::ensure!(
            t.dims() == var.dims(),
            "--init {}: `{name}` has shape {:?}, the network {:?}",
            path.display(),
            t.dims(),
            var.dims()
        );
        var.set(t)?;
    }
    Ok(())
}

/// Saves `varmap` to `path` through a temporary file and a rename, so `path` always holds a
/// complete checkpoint even if the process dies while writing.
fn save_atomically(varmap: &VarMap, path: &std::path::Path) -> anyhow::Result<()> {
    let tmp = path.with_extension("safetensors.partial");
    varmap
        .save(&tmp)
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, path).map_err(|e| anyhow::anyhow!("renaming {} to {}: {e}", tmp.display(), path.display()))
}

/// Trains a fresh model on `train` (indices into `ds`), validating on `val` after each epoch.
/// `on_step(step, total_steps, loss)` reports progress; `on_epoch` gets each epoch's record.
pub fn fit(
    cfg: &FitConfig,
    ds: &Dataset,
    train: &[usize],
    val: &[usize],
    dev: &Device,
    on_step: &mut dyn FnMut(usize, usize, f64),
    on_epoch: &mut dyn FnMut(&EpochLog),
) -> anyhow::Result<(VarMap, TerrainCnn, Vec<EpochLog>)> {
    anyhow::ensure!(!train.is_empty(), "no training samples");
    anyhow::ensure!(cfg.batch > 0 && cfg.epochs > 0, "batch and epochs must be at least 1");
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, dev);
    let model = TerrainCnn::new(vb)?;
    seeded_init(&varmap, cfg.seed, dev)?;
    if let Some(path) = &cfg.init {
        load_init(&varmap, path, dev)?;
    }
    // The running statistics are estimates, not parameters (with frozen BatchNorm they are in
    // the graph, and a gradient step could make a variance negative).
    let params: Vec<candle_core::Var> = {
        let data = varmap
            .data()
            .lock()
            .map_err(|_| anyhow::anyhow!("variable map lock poisoned"))?;
        let mut named: Vec<_> = data.iter().filter(|(n, _)| !n.contains(".running_")).collect();
        named.sort_by(|a, b| a.0.cmp(b.0));
        named.into_iter().map(|(_, v)| v.clone()).collect()
    };
    let mut opt = AdamW::new(
        params,
        ParamsAdamW {
            lr: cfg.lr,
            weight_decay: cfg.weight_decay,
            ..Default::default()
        },
    )?;
    let steps_per_epoch = train.len().div_ceil(cfg.batch);
    let mut total_steps = cfg.epochs * steps_per_epoch;
    if cfg.max_steps > 0 {
        total_steps = total_steps.min(cfg.max_steps);
    }
    let mut rng = Rng(cfg.seed ^ 0x7EA1_0000);
    let mut order = train.to_vec();
    let mut log = Vec::new();
    let mut step = 0;
    'epochs: for epoch in 0..cfg.epochs {
        let t0 = std::time::Instant::now();
        // Fisher–Yates with our own generator: the order is a function of the seed only.
        for i in (1..order.len()).rev() {
            order.swap(i, rng.int(0, i as u64) as usize);
        }
        let mut sums = LossParts::default();
        let mut batches = 0;
        for chunk in order.chunks(cfg.batch) {
            if step >= total_steps {
                break;
            }
            // Cosine decay to 2 % of the peak, with a short linear warm-up.
            let warm = (total_steps / 50).max(1);
            let lr = if step < warm {
                cfg.lr * (step + 1) as f64 / warm as f64
            } else {
                let p = (step - warm) as f64 / (total_steps - warm).max(1) as f64;
                cfg.lr * (0.02 + 0.98 * 0.5 * (1.0 + (std::f64::consts::PI * p).cos()))
            };
            opt.set_learning_rate(lr);
            let mirror: Vec<bool> = chunk.iter().map(|_| cfg.mirror && rng.chance(0.5)).collect();
            let b = batch(ds, chunk, &mirror, dev)?;
            let out = model.forward_t(&b.x, !cfg.freeze_bn)?;
            let (loss, [ce, h, d, yaw]) = terrain_loss(&out, &b.class, &b.reg, &b.stairs)?;
            opt.backward_step(&loss)?;
            let v = |t: &Tensor| -> candle_core::Result<f64> { Ok(t.to_scalar::<f32>()? as f64) };
            let l = v(&loss)?;
            anyhow::ensure!(l.is_finite(), "loss became {l} at step {step}; lower --lr");
            sums.total += l;
            sums.ce += v(&ce)?;
            sums.h += v(&h)?;
            sums.d += v(&d)?;
            sums.yaw += v(&yaw)?;
            batches += 1;
            step += 1;
            on_step(step, total_steps, l);
        }
        let n = batches.max(1) as f64;
        let train_parts = LossParts {
            total: sums.total / n,
            ce: sums.ce / n,
            h: sums.h / n,
            d: sums.d / n,
            yaw: sums.yaw / n,
        };
        let val_stats = if val.is_empty() {
            None
        } else {
            Some(score(ds, val, &crate::cnn::model::predict(&model, ds, val, dev)?))
        };
        let e = EpochLog {
            epoch,
            steps: step,
            lr: opt.learning_rate(),
            train: train_parts,
            val: val_stats,
            seconds: t0.elapsed().as_secs_f64(),
        };
        if let Some(path) = &cfg.checkpoint {
            save_atomically(&varmap, path)?;
        }
        on_epoch(&e);
        log.push(e);
        if step >= total_steps {
            break 'epochs;
        }
    }
    Ok((varmap, model, log))
}
