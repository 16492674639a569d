//! `g1-train fit`: Train on g1-dataset exports; writes the firmware export (terrain_cnn.safetensors + .toml),
use anyhow::Context;
use candle_core::Device;
use labkit::progress::bar;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;
use train::cnn::data::{split_by_world, Dataset};
use train::cnn::export::{fold, DESC_FILE, WEIGHTS_FILE};
use train::cnn::fit::{fit, FitConfig, LAMBDA_CLS, LAMBDA_D, LAMBDA_H, LAMBDA_YAW};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Dataset directories (g1-dataset export --out); repeat for several.
    #[arg(long, required = true)]
    data: Vec<PathBuf>,
    /// Output directory (created): the export, checkpoint, history.json, training.png
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = 30)]
    epochs: usize,
    #[arg(long, default_value_t = 64)]
    batch: usize,
    /// Peak learning rate (AdamW; cosine decay).
    #[arg(long, default_value_t = 2e-3)]
    lr: f64,
    /// Fraction of worlds (by seed) held out for validation.
    #[arg(long, default_value_t = 0.1)]
    val_fraction: f64,
    /// Train only on samples whose true step height is at most this (m): the out-of-range
    /// experiment (paper Table III) trains at ≤ 0.16 and tests up to 0.22.
    #[arg(long)]
    max_train_h: Option<f32>,
    /// Stop after this many optimiser steps (smoke tests).
    #[arg(long, default_value_t = 0)]
    max_steps: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Continue from this checkpoint (checkpoint.safetensors of an earlier fit), with a fresh
    /// schedule; or fine-tune an exported network (e.g. control/weights/terrain_cnn.safetensors,
    /// BatchNorm folded), which needs --freeze-bn.
    #[arg(long)]
    init: Option<PathBuf>,
    /// Keep BatchNorm in inference mode while training (fixed running statistics): for a
    /// fine-tune, and required with an exported --init.
    #[arg(long)]
    freeze_bn: bool,
    /// No left–right mirror augmentation.
    #[arg(long)]
    no_mirror: bool,
    /// Write into an --out that already holds files (an earlier run's export and checkpoint
    /// are replaced).
    #[arg(long)]
    force: bool,
    #[arg(long)]
    quiet: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        data,
        out,
        epochs,
        batch,
        lr,
        val_fraction,
        max_train_h,
        max_steps,
        seed,
        init,
        freeze_bn,
        no_mirror,
        force,
        quiet,
    } = args;
    fit_output_is_free(&out, &data, init.as_deref(), force)?;
    if let Some(path) = &init {
        anyhow::ensure!(
            freeze_bn || !train::cnn::export::is_export(path)?,
            "--init {} is an exported network (BatchNorm folded): fine-tune it with --freeze-bn",
            path.display()
        );
    }
    let t_load = Instant::now();
    let ds = Dataset::load_dirs(&data)?;
    let (mut tr, val) = split_by_world(&ds, val_fraction);
    if let Some(hmax) = max_train_h {
        tr.retain(|&i| ds.step_height[i] <= hmax);
    }
    println!(
        "{} samples loaded in {:.1} s: {} train, {} validation (split by world seed)",
        ds.len(),
        t_load.elapsed().as_secs_f64(),
        tr.len(),
        val.len()
    );
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let cfg = FitConfig {
        epochs,
        batch,
        lr,
        seed,
        mirror: !no_mirror,
        max_steps,
        init,
        freeze_bn,
        checkpoint: Some(out.join("checkpoint.safetensors")),
        ..FitConfig::default()
    };
    let dev = Device::Cpu;
    let steps = (epochs * tr.len().div_ceil(batch)).min(if max_steps > 0 { max_steps } else { usize::MAX });
    let pb = bar(steps, quiet, "steps");
    let t = Instant::now();
    let (varmap, model, history) = fit(
        &cfg,
        &ds,
        &tr,
        &val,
        &dev,
        &mut |s, _, l| {
            pb.set_position(s as u64);
            if s % 20 == 0 {
                pb.set_message(format!("loss {l:.3}"));
            }
        },
        &mut |e| {
            let v = e.val.as_ref().map_or(String::new(), |v| {
                format!(
                    " | val: class {:.2} %, MAE h {:.2} cm, d {:.2} cm, yaw {:.2} deg",
                    100.0 * v.class_accuracy,
                    v.mae_h_cm,
                    v.mae_d_cm,
                    v.mae_yaw_deg
                )
            });
            let line = format!(
                "epoch {:>3} ({:.0} s) loss {:.4} (ce {:.4} h {:.3} d {:.3} yaw {:.3}){v}",
                e.epoch, e.seconds, e.train.total, e.train.ce, e.train.h, e.train.d, e.train.yaw
            );
            if pb.is_hidden() {
                println!("{line}");
            } else {
                pb.println(line);
            }
        },
    )?;
    pb.finish_and_clear();
    // fit() wrote checkpoint.safetensors after the last epoch.
    let secs = t.elapsed().as_secs_f64();
    let mut meta = BTreeMap::new();
    meta.insert("format".into(), "g1-train terrain CNN v1 (BatchNorm folded)".into());
    meta.insert("train_samples".into(), tr.len().to_string());
    meta.insert("steps".into(), history.last().map_or(0, |e| e.steps).to_string());
    meta.insert("fit".into(), serde_json::to_string(&cfg)?);
    meta.insert(
            "loss".into(),
            format!("{LAMBDA_CLS}*CE + {LAMBDA_H}*SmoothL1(h cm) + {LAMBDA_D}*SmoothL1(d cm) + {LAMBDA_YAW}*SmoothL1(yaw vector deg)"),
        );
    let sha = fold(&varmap)?.write(&out, &meta)?;
    let pool = if val.is_empty() { &tr } else { &val };
    train::cnn::export::parity_fixture_from(
        &model,
        &ds,
        pool,
        &dev,
        &out.join(train::cnn::export::PARITY_FILE),
        &sha,
    )?;
    train::plot::training_png(&out.join("training.png"), &history)?;
    let hist = serde_json::json!({ "config": cfg, "train_seconds": secs, "epochs": history });
    std::fs::write(out.join("history.json"), serde_json::to_string_pretty(&hist)? + "\n")?;
    println!(
            "trained {} steps in {:.1} s ({:.0} samples/s); wrote {}/{{{WEIGHTS_FILE}, {DESC_FILE}, checkpoint.safetensors, history.json}}",
            history.last().map_or(0, |e| e.steps),
            secs,
            history.last().map_or(0, |e| e.steps) as f64 * batch as f64 / secs,
            out.display()
        );
    Ok(())
}

/// `fit` writes its export and checkpoint into `out`: refuse to replace an earlier run's files
/// unless forced, and never let an output be one of the run's inputs.
fn fit_output_is_free(out: &Path, data: &[PathBuf], init: Option<&Path>, force: bool) -> anyhow::Result<()> {
    let mut inputs: Vec<(&str, Option<&Path>)> =
        data.iter().map(|d| ("a --data directory", Some(d.as_path()))).collect();
    inputs.push(("--init", init));
    crate::outputs::refuse_clashes(&[("--out", Some(out), crate::outputs::Kind::Dir)], &inputs, None)?;
    // A --data directory that holds the run directory would take its checkpoints as data.
    if let Some(d) = data.iter().find(|d| output_file::is_inside(out, d)) {
        anyhow::bail!(
            "--out {} is inside the --data directory {}: write the training run elsewhere",
            out.display(),
            d.display()
        );
    }
    let occupied = std::fs::read_dir(out).is_ok_and(|mut d| d.next().is_some());
    anyhow::ensure!(
        !occupied || force,
        "{} exists and is not empty: choose a new --out, or pass --force to replace the run there",
        out.display()
    );
    Ok(())
}
