//! `g1-train export`: Fold a checkpoint (checkpoint.safetensors from `fit`) into the firmware's format again.
use anyhow::Context;
use candle_core::Device;
use std::collections::BTreeMap;
use std::path::PathBuf;
use train::cnn::data::{split_by_world, Dataset};
use train::cnn::export::{fold, DESC_FILE, WEIGHTS_FILE};

#[derive(clap::Args, Debug)]
pub struct Args {
    #[arg(long)]
    checkpoint: PathBuf,
    /// Directory for terrain_cnn.safetensors and terrain_cnn.toml.
    #[arg(long)]
    out: PathBuf,
    /// Also write the parity fixture (terrain_cnn_parity.safetensors) from grids of this
    /// dataset (g1-dataset export directory).
    #[arg(long)]
    data: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Args { checkpoint, out, data } = args;
    crate::outputs::refuse_clashes(
        &[("--out", Some(&out), crate::outputs::Kind::Dir)],
        &[("--checkpoint", Some(&checkpoint)), ("--data", data.as_deref())],
        None,
    )?;
    let vm = candle_nn::VarMap::new();
    let model = train::cnn::model::TerrainCnn::new(candle_nn::VarBuilder::from_varmap(
        &vm,
        candle_core::DType::F32,
        &Device::Cpu,
    ))?;
    train::tensor_file::load_vars(&vm, &checkpoint).with_context(|| format!("loading {}", checkpoint.display()))?;
    let mut meta = BTreeMap::new();
    meta.insert("format".into(), "g1-train terrain CNN v1 (BatchNorm folded)".into());
    let sha = fold(&vm)?.write(&out, &meta)?;
    println!("wrote {}/{{{WEIGHTS_FILE}, {DESC_FILE}}}", out.display());
    if let Some(d) = data {
        let ds = Dataset::load_dir(&d)?;
        let (_, val) = split_by_world(&ds, 0.1);
        let path = out.join(train::cnn::export::PARITY_FILE);
        train::cnn::export::parity_fixture_from(&model, &ds, &val, &Device::Cpu, &path, &sha)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
