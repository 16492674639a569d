//! Export in the firmware's format: BatchNorm folded into each conv's weight and bias, written as
//! a safetensors file, plus the `control::nn::NetworkDesc` that lists the same layers.
//!
//! Folding (per output channel c): `s = γ / sqrt(σ² + ε)`, `W'[c] = s · W[c]`,
//! `b'[c] = β − s · μ`, computed in f64 and rounded once to f32. After folding, conv → ReLU in
//! the firmware equals conv → BatchNorm(eval) → ReLU in training.
use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{ensure, Context};
use candle_core::Tensor;
use candle_nn::VarMap;
use control::nn::{sha256_hex, LayerDesc, NetworkDesc};

use crate::cnn::data::GRID;
use crate::cnn::model::{BN_EPS, CONV_BLOCKS, PADDING, STRIDE};
use crate::tensor_file::NamedTensor;
use sensor_io::bev::{BEV_CELLS, BEV_CHANNELS};

/// File names inside an export directory.
pub const WEIGHTS_FILE: &str = "terrain_cnn.safetensors";
pub const DESC_FILE: &str = "terrain_cnn.toml";

/// The folded tensors (name → (shape, data)) and the description that uses them.
pub struct Exported {
    pub tensors: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    pub desc: NetworkDesc,
}

fn var(vm: &VarMap, name: &str) -> anyhow::Result<Tensor> {
    let data = vm
        .data()
        .lock()
        .map_err(|_| anyhow::anyhow!("variable map lock poisoned"))?;
    data.get(name)
        .map(|v| v.as_tensor().clone())
        .with_context(|| format!("checkpoint has no variable `{name}`"))
}

fn flat(t: &Tensor) -> anyhow::Result<Vec<f32>> {
    Ok(t.flatten_all()?.to_vec1::<f32>()?)
}

/// Folds the trained variables into the firmware's layers.
pub fn fold(vm: &VarMap) -> anyhow::Result<Exported> {
    let mut tensors = BTreeMap::new();
    let mut layers = Vec::new();
    for (i, &(cin, cout)) in CONV_BLOCKS.iter().enumerate() {
        let (conv, bn) = (format!("conv{}", i + 1), format!("bn{}", i + 1));
        let w = var(vm, &format!("{conv}.weight"))?;
        let dims = w.dims().to_vec();
        ensure!(dims[0] == cout && dims[1] == cin, "{conv}.weight has shape {dims:?}");
        let w = flat(&w)?;
        let gamma = flat(&var(vm, &format!("{bn}.weight"))?)?;
        let beta = flat(&var(vm, &format!("{bn}.bias"))?)?;
        let mean = flat(&var(vm, &format!("{bn}.running_mean"))?)?;
        let var_ = flat(&var(vm, &format!("{bn}.running_var"))?)?;
        let per_out = w.len() / cout;
        let mut wf = Vec::with_capacity(w.len());
        let mut bf = Vec::with_capacity(cout);
        for c in 0..cout {
            let s = gamma[c] as f64 / (var_[c] as f64 + BN_EPS).sqrt();
            wf.extend(w[c * per_out..(c + 1) * per_out].iter().map(|&v| (v as f64 * s) as f32));
            bf.push((beta[c] as f64 - s * mean[c] as f64) as f32);
        }
        tensors.insert(format!("{conv}.weight"), (dims, wf));
        tensors.insert(format!("{conv}.bias"), (vec![cout], bf));
        layers.push(LayerDesc::Conv2d {
            weight: format!("{conv}.weight"),
            bias: format!("{conv}.bias"),
            stride: STRIDE,
            padding: PADDING,
        });
        layers.push(LayerDesc::Relu);
    }
    for (name, relu) in [("fc", true), ("head", false)] {
        let w = var(vm, &format!("{name}.weight"))?;
        let b = var(vm, &format!("{name}.bias"))?;
        tensors.insert(format!("{name}.weight"), (w.dims().to_vec(), flat(&w)?));
        tensors.insert(format!("{name}.bias"), (b.dims().to_vec(), flat(&b)?));
        layers.push(LayerDesc::Linear {
            weight: format!("{name}.weight"),
            bias: format!("{name}.bias"),
        });
        if relu {
            layers.push(LayerDesc::Relu);
        }
    }
    Ok(Exported {
        tensors,
        desc: NetworkDesc {
            input: GRID,
            input_shape: Some(vec![BEV_CHANNELS, BEV_CELLS, BEV_CELLS]),
            layers,
        },
    })
}

/// Whether the safetensors file at `path` is an export (conv biases, no BatchNorm) rather than a
/// training checkpoint.
pub fn is_export(path: &Path) -> anyhow::Result<bool> {
    let bytes = input_file::read_capped(path, control::nn::MAX_WEIGHTS_BYTES)
        .with_context(|| format!("reading {}", path.display()))?;
    let st = safetensors::SafeTensors::deserialize(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: not a safetensors file ({e})", path.display()))?;
    Ok(is_export_layout(&st.names()))
}

/// Whether these tensor names are an export's: conv biases and no BatchNorm (a training
/// checkpoint's convs have no bias; its BatchNorm holds the shift).
pub fn is_export_layout<S: AsRef<str>>(names: &[S]) -> bool {
    names.iter().any(|n| n.as_ref() == "conv1.bias") && !names.iter().any(|n| n.as_ref().starts_with("bn"))
}

/// The inverse of [`fold`] for a fine-tune: an export's tensors as training variables whose
/// BatchNorm, in inference mode, is the identity plus the conv's bias: `γ = 1`, `β = b'`, `μ = 0`,
/// `σ² = 1 − ε`. Folding them again gives the export back bit for bit (`s` is exactly 1).
pub fn unfold(
    folded: &std::collections::HashMap<String, Tensor>,
) -> anyhow::Result<std::collections::HashMap<String, Tensor>> {
    let get = |name: &str| {
        folded
            .get(name)
            .cloned()
            .with_context(|| format!("the export has no tensor `{name}`"))
    };
    let mut out = std::collections::HashMap::new();
    for (i, &(_, cout)) in CONV_BLOCKS.iter().enumerate() {
        let (conv, bn) = (format!("conv{}", i + 1), format!("bn{}", i + 1));
        let b = get(&format!("{conv}.bias"))?;
        ensure!(b.dims() == [cout], "{conv}.bias has shape {:?}", b.dims());
        let dev = b.device().clone();
        out.insert(format!("{conv}.weight"), get(&format!("{conv}.weight"))?);
        out.insert(
            format!("{bn}.weight"),
            Tensor::ones(cout, candle_core::DType::F32, &dev)?,
        );
        out.insert(format!("{bn}.bias"), b);
        out.insert(
            format!("{bn}.running_mean"),
            Tensor::zeros(cout, candle_core::DType::F32, &dev)?,
        );
        out.insert(
            format!("{bn}.running_var"),
            Tensor::full((1.0 - BN_EPS) as f32, cout, &dev)?,
        );
    }
    for name in ["fc.weight", "fc.bias", "head.weight", "head.bias"] {
        out.insert(name.to_string(), get(name)?);
    }
    Ok(out)
}

impl Exported {
    /// The safetensors bytes (tensors sorted by name; `metadata` goes into the header).
    pub fn safetensors_bytes(&self, metadata: &BTreeMap<String, String>) -> anyhow::Result<Vec<u8>> {
        let tensors: Vec<_> = self
            .tensors
            .iter()
            .map(|(n, (shape, data))| NamedTensor::f32(n.clone(), shape.clone(), data))
            .collect();
        crate::tensor_file::serialize(&tensors, Some(metadata.clone().into_iter().collect()))
    }

    /// The description as TOML, with a header saying what it is.
    pub fn desc_toml(&self) -> anyhow::Result<String> {
        Ok(format!(
            "# Terrain CNN (BEV 6x60x60 -> class logits, h cm, d cm, yaw vector), written by `g1-train`.\n\
             # BatchNorm is folded into the conv weights; outputs are decoded by estimator::terrain_cnn.\n{}",
            toml::to_string(&self.desc)?
        ))
    }

    /// Writes `terrain_cnn.safetensors` and `terrain_cnn.toml` into `dir`; returns the weights'
    /// SHA-256.
    pub fn write(&self, dir: &Path, metadata: &BTreeMap<String, String>) -> anyhow::Result<String> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let w = dir.join(WEIGHTS_FILE);
        let bytes = self.safetensors_bytes(metadata)?;
        std::fs::write(&w, &bytes).with_context(|| format!("writing {}", w.display()))?;
        let d = dir.join(DESC_FILE);
        std::fs::write(&d, self.desc_toml()?).with_context(|| format!("writing {}", d.display()))?;
        Ok(sha256_hex(&bytes))
    }
}

/// Reads a description file written by [`Exported::write`].
pub fn read_desc(path: &Path) -> anyhow::Result<NetworkDesc> {
    let text = input_file::read_text_capped(path, crate::MAX_TEXT_BYTES)
        .with_context(|| format!("reading {}", path.display()))?;
    toml::from_str(&text).with_context(|| format!("parsing network description {}", path.display()))
}

/// File name of the parity fixture written next to an export.
pub const PARITY_FILE: &str = "terrain_cnn_parity.safetensors";

/// Writes `grids` (`[n, 6, 60, 60]`) and the training-side outputs for them (`[n, 7]`, candle,
/// BatchNorm in eval mode, before folding) with the folded weights' SHA-256 in the header: the
/// firmware's parity test runs its executor on the grids and must match the outputs to 1e-4.
pub fn write_parity_fixture(
    path: &Path,
    grids: &[f32],
    outputs: &[[f32; 7]],
    weights_sha256: &str,
) -> anyhow::Result<()> {
    let n = outputs.len();
    ensure!(
        grids.len() == n * GRID,
        "parity fixture: {n} outputs but {} grid values",
        grids.len()
    );
    let outputs: Vec<f32> = outputs.iter().flatten().copied().collect();
    let tensors = [
        NamedTensor::f32("bev", vec![n, BEV_CHANNELS, BEV_CELLS, BEV_CELLS], grids),
        NamedTensor::f32("outputs", vec![n, 7], &outputs),
    ];
    let meta = std::collections::HashMap::from([
        ("weights_sha256".to_string(), weights_sha256.to_string()),
        (
            "about".to_string(),
            "BEV grids and the terrain CNN outputs g1-train computed for them (candle, before BatchNorm folding)"
                .to_string(),
        ),
    ]);
    let bytes = crate::tensor_file::serialize(&tensors, Some(meta))?;
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// Picks two grids of each class from `pool` (indices into `ds`), runs `model` (eval mode) on them
/// and writes the parity fixture to `path`.
pub fn parity_fixture_from(
    model: &crate::cnn::model::TerrainCnn,
    ds: &crate::cnn::data::Dataset,
    pool: &[usize],
    dev: &candle_core::Device,
    path: &Path,
    weights_sha256: &str,
) -> anyhow::Result<()> {
    let mut pick = Vec::new();
    for class in 0..3u8 {
        pick.extend(pool.iter().copied().filter(|&i| ds.class[i] == class).take(2));
    }
    ensure!(!pick.is_empty(), "parity fixture: no samples to pick from");
    let outs = crate::cnn::model::predict(model, ds, &pick, dev)?;
    let grids: Vec<f32> = pick.iter().flat_map(|&i| ds.grid(i).iter().copied()).collect();
    write_parity_fixture(path, &grids, &outs, weights_sha256)
}
