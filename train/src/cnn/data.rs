//! Datasets written by `g1-dataset export` (safetensors shards + manifest.json), held in memory,
//! split by world seed, and served as candle batches.
use std::path::Path;

use anyhow::{bail, ensure, Context};
use candle_core::{Device, Tensor};
use hal::{TerrainClass, TerrainToken};
use labkit::rng::Rng;
use safetensors::{Dtype, SafeTensors};
use sensor_io::bev::{BEV_CELLS, BEV_CHANNELS};

/// Floats per BEV grid.
pub const GRID: usize = BEV_CHANNELS * BEV_CELLS * BEV_CELLS;

/// Samples in memory (structure of arrays, as in the shards).
#[derive(Clone, Debug, Default)]
pub struct Dataset {
    /// `[n, 6, 60, 60]` row-major.
    pub bev: Vec<f32>,
    pub class: Vec<u8>,
    pub step_height: Vec<f32>,
    pub step_depth: Vec<f32>,
    pub yaw: Vec<f32>,
    pub world_seed: Vec<i64>,
    /// Pelvis heading at the labelled instant, rad (the flat token's yaw).
    pub heading: Vec<f32>,
    /// 0 standing, 1 walking.
    pub mode: Vec<u8>,
}

#[derive(serde::Deserialize)]
struct Manifest {
    shards: Vec<ShardEntry>,
}
#[derive(serde::Deserialize)]
struct ShardEntry {
    file: String,
}

fn tensor_bytes<'a>(st: &'a SafeTensors, name: &str, dtype: Dtype, shape_tail: &[usize]) -> anyhow::Result<&'a [u8]> {
    let t = st
        .tensor(name)
        .with_context(|| format!("tensor `{name}` missing (is this a g1-dataset export?)"))?;
    ensure!(
        t.dtype() == dtype,
        "tensor `{name}` is {:?}, expected {dtype:?}",
        t.dtype()
    );
    ensure!(
        t.shape().len() == 1 + shape_tail.len() && t.shape()[1..] == *shape_tail,
        "tensor `{name}` has shape {:?}, expected [n, {shape_tail:?}]",
        t.shape()
    );
    Ok(t.data())
}

fn f32s(b: &[u8]) -> impl Iterator<Item = f32> + '_ {
    b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
}

impl Dataset {
    pub fn len(&self) -> usize {
        self.class.len()
    }

    pub fn is_empty(&self) -> bool {
        self.class.is_empty()
    }

    /// Loads every shard of every directory, in order (see [`Dataset::load_dir`]).
    pub fn load_dirs(dirs: &[impl AsRef<Path>]) -> anyhow::Result<Self> {
        let mut ds = Dataset::default();
        for d in dirs {
            ds.append_dir(d.as_ref())?;
        }
        Ok(ds)
    }

    /// Loads every shard that `dir/manifest.json` lists.
    pub fn load_dir(dir: &Path) -> anyhow::Result<Self> {
        Self::load_dirs(&[dir])
    }

    /// Appends every shard that `dir/manifest.json` lists.
    fn append_dir(&mut self, dir: &Path) -> anyhow::Result<()> {
        let mpath = dir.join("manifest.json");
        let text = input_file::read_text_capped(&mpath, crate::MAX_TEXT_BYTES).with_context(|| {
            format!(
                "reading {} (make a dataset with `g1-dataset export --out {}`)",
                mpath.display(),
                dir.display()
            )
        })?;
        let m: Manifest = serde_json::from_str(&text).with_context(|| format!("parsing {}", mpath.display()))?;
        let before = self.len();
        for s in &m.shards {
            self.append_shard(&dir.join(&s.file))?;
        }
        ensure!(self.len() > before, "{} holds no samples", dir.display());
        Ok(())
    }

    /// Appends one shard file.
    pub fn append_shard(&mut self, path: &Path) -> anyhow::Result<()> {
        let bytes = input_file::read_capped(path, crate::MAX_DATA_BYTES)
            .with_context(|| format!("reading {}", path.display()))?;
        let st = SafeTensors::deserialize(&bytes).with_context(|| format!("{} is not safetensors", path.display()))?;
        let ctx = |e: anyhow::Error| e.context(format!("in {}", path.display()));
        let bev = tensor_bytes(&st, "bev", Dtype::F32, &[BEV_CHANNELS, BEV_CELLS, BEV_CELLS]).map_err(ctx)?;
        let class = tensor_bytes(&st, "class", Dtype::U8, &[]).map_err(ctx)?;
        let n = class.len();
        let h = tensor_bytes(&st, "step_height", Dtype::F32, &[]).map_err(ctx)?;
        let d = tensor_bytes(&st, "step_depth", Dtype::F32, &[]).map_err(ctx)?;
        let yaw = tensor_bytes(&st, "yaw", Dtype::F32, &[]).map_err(ctx)?;
        let seed = tensor_bytes(&st, "world_seed", Dtype::I64, &[]).map_err(ctx)?;
        let pose = tensor_bytes(&st, "pose", Dtype::F32, &[4]).map_err(ctx)?;
        let mode = tensor_bytes(&st, "mode", Dtype::U8, &[]).map_err(ctx)?;
        for (name, len) in [
            ("bev", bev.len() / (4 * GRID)),
            ("step_height", h.len() / 4),
            ("step_depth", d.len() / 4),
            ("yaw", yaw.len() / 4),
            ("world_seed", seed.len() / 8),
            ("pose", pose.len() / 16),
            ("mode", mode.len()),
        ] {
            ensure!(len == n, "{}: `{name}` has {len} samples, `class` {n}", path.display());
        }
        if let Some(c) = class.iter().find(|&&c| c > 2) {
            bail!("{}: class {c} is not 0, 1 or 2", path.display());
        }
        self.bev.extend(f32s(bev));
        self.class.extend_from_slice(class);
        self.step_height.extend(f32s(h));
        self.step_depth.extend(f32s(d));
        self.yaw.extend(f32s(yaw));
        self.world_seed.extend(
            seed.chunks_exact(8)
                .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes"))),
        );
        self.heading.extend(f32s(pose).skip(3).step_by(4));
        self.mode.extend_from_slice(mode);
        Ok(())
    }

    /// Grid of sample `i`.
    pub fn grid(&self, i: usize) -> &[f32] {
        &self.bev[i * GRID..(i + 1) * GRID]
    }

    /// Ground-truth token of sample `i`.
    pub fn token(&self, i: usize) -> TerrainToken {
        TerrainToken {
            class: TerrainClass::from_index(self.class[i] as usize).unwrap_or(TerrainClass::Flat),
            step_height_m: self.step_height[i],
            step_depth_m: self.step_depth[i],
            yaw_rad: self.yaw[i],
        }
    }
}

/// Splits sample indices by world: a world goes to validation when a hash of its seed falls in
/// the first `val_fraction` of the range, so every sample of a world lands on the same side and
/// the split does not depend on sample order.
pub fn split_by_world(ds: &Dataset, val_fraction: f64) -> (Vec<usize>, Vec<usize>) {
    let (mut train, mut val) = (Vec::new(), Vec::new());
    for i in 0..ds.len() {
        let u = Rng(ds.world_seed[i] as u64 ^ 0x5EED_5011).uniform();
        if u < val_fraction {
            val.push(i);
        } else {
            train.push(i);
        }
    }
    (train, val)
}

/// A batch on `dev`: inputs `[b,6,60,60]`, classes `[b]` (u32), regression targets `[b,4]`
/// (h cm, d cm, scaled yaw vector; see `estimator::terrain_cnn::targets`) and the stairs mask
/// `[b]` (1 for stairs samples: h, d and yaw are only supervised there).
pub struct Batch {
    pub x: Tensor,
    pub class: Tensor,
    pub reg: Tensor,
    pub stairs: Tensor,
}

/// Builds a batch from `idx`; where `mirror[k]` the grid is mirrored left–right (y → −y), which
/// negates the yaw and keeps class, h and d: a free, exact augmentation because the robot, its
/// lidar mount and the self-filter are left–right symmetric.
pub fn batch(ds: &Dataset, idx: &[usize], mirror: &[bool], dev: &Device) -> candle_core::Result<Batch> {
    let b = idx.len();
    let mut x = vec![0.0f32; b * GRID];
    let (mut class, mut reg, mut stairs) = (Vec::with_capacity(b), Vec::with_capacity(4 * b), Vec::with_capacity(b));
    for (k, &i) in idx.iter().enumerate() {
        let src = ds.grid(i);
        let dst = &mut x[k * GRID..(k + 1) * GRID];
        let flip = mirror.get(k).copied().unwrap_or(false);
        if flip {
            for (drow, srow) in dst.chunks_exact_mut(BEV_CELLS).zip(src.chunks_exact(BEV_CELLS)) {
                for (dv, sv) in drow.iter_mut().zip(srow.iter().rev()) {
                    *dv = *sv;
                }
            }
        } else {
            dst.copy_from_slice(src);
        }
        let mut t = ds.token(i);
        if flip {
            t.yaw_rad = -t.yaw_rad;
        }
        let (c, r) = estimator::terrain_cnn::targets(&t);
        class.push(c as u32);
        reg.extend_from_slice(&r);
        stairs.push(if c == 0 { 0.0f32 } else { 1.0 });
    }
    Ok(Batch {
        x: Tensor::from_vec(x, (b, BEV_CHANNELS, BEV_CELLS, BEV_CELLS), dev)?,
        class: Tensor::from_vec(class, b, dev)?,
        reg: Tensor::from_vec(reg, (b, 4), dev)?,
        stairs: Tensor::from_vec(stairs, b, dev)?,
    })
}
