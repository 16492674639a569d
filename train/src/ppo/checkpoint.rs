//! A run's checkpoint: the whole run in one safetensors file, so a resumed run is the run that
//! would have gone on, bit for bit (tests/ppo_resume.rs).
//!
//! It holds every variable (actor, action noise, critic), both optimizers' moments and step counts,
//! the critic's input normaliser, and in its header the counters, the adaptive learning rate, the
//! minibatch shuffle's random stream, every environment's curriculum level, the recipe it was
//! trained under and the deploy spec's sha256. The episodes in progress are not in it: every
//! checkpoint restarts every environment from a seed of (run seed, environment, iteration), in the
//! run that goes on as in the one that resumes (`runner`), so neither carries an episode across it.
//!
//! Written to a temporary file and renamed; read back only whole: a file that does not parse, is
//! not a run checkpoint, fails its sha256, or misses a tensor is refused, naming the file and what
//! is wrong with it.
use anyhow::Context;
use std::collections::HashMap;
use std::path::Path;

use candle_core::Tensor;
use safetensors::tensor::Dtype;
use serde::{Deserialize, Serialize};

use super::algo::{Learner, Normalizer};
use super::policy::ActorCritic;
use crate::tensor_file::{serialize, NamedTensor};

/// The header's `format`: what wrote the file, and which layout it has.
pub const FORMAT: &str = "g1-train run checkpoint 1";
/// A checkpoint larger than this is not one of ours (an MLP run's is about 2 MB).
const MAX_BYTES: u64 = 512 << 20;

/// The counters and streams of a run (the header's `state`). Floats that must come back
/// bit for bit travel as their bits: JSON's decimal form need not.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Counters {
    pub iteration: usize,
    pub env_steps: u64,
    /// Wall time of the run so far, s (not part of what must resume exactly).
    pub wall_s: f64,
    pub lr_bits: u64,
    pub learner_rng: u64,
    pub adam_step: u64,
    pub critic_adam_step: u64,
    pub normalizer_count_bits: u64,
    /// Each environment's curriculum level.
    pub levels: Vec<usize>,
    /// Where the run started from.
    pub started_from: String,
}

/// What a checkpoint says of the run it belongs to.
pub struct Identity<'a> {
    /// The run's settings as text, one per line (`runner::recipe_text`).
    pub recipe: &'a str,
    pub spec_sha256: &'a str,
}

/// Writes the checkpoint of the run at `path` (a temporary file beside it, then a rename).
pub fn write(
    path: &Path,
    ac: &ActorCritic,
    learner: &Learner,
    normalizer: &Normalizer,
    counters: &Counters,
    id: &Identity,
) -> anyhow::Result<()> {
    let mut tensors = Vec::new();
    for (name, var) in ac.named_vars() {
        tensors.push(NamedTensor::from_candle(name, var.as_tensor())?);
    }
    for (prefix, opt) in [("adam", &learner.opt), ("critic_adam", &learner.critic_opt)] {
        for (k, (name, var)) in opt.vars.iter().enumerate() {
            let shape = var.dims().to_vec();
            tensors.push(NamedTensor::f32(format!("{prefix}.m.{name}"), shape.clone(), &opt.m[k]));
            tensors.push(NamedTensor::f32(format!("{prefix}.v.{name}"), shape, &opt.v[k]));
        }
    }
    let d = normalizer.mean.len();
    tensors.push(NamedTensor::f64("normalizer.mean", vec![d], &normalizer.mean));
    tensors.push(NamedTensor::f64("normalizer.m2", vec![d], &normalizer.m2));
    let meta = HashMap::from([
        ("format".to_string(), FORMAT.to_string()),
        ("state".to_string(), serde_json::to_string(counters)?),
        ("recipe".to_string(), id.recipe.to_string()),
        ("spec_sha256".to_string(), id.spec_sha256.to_string()),
        ("data_sha256".to_string(), data_sha256(&tensors)),
    ]);
    let bytes = serialize(&tensors, Some(meta))?;
    output_file::write_atomically(path, &bytes).with_context(|| format!("writing {}", path.display()))
}

/// sha256 over every tensor's name, type, shape and bytes, in name order: damage anywhere in the
/// data (not only a truncation, which safetensors' own parse finds) is found on reading.
fn data_sha256(tensors: &[NamedTensor]) -> String {
    let mut sorted: Vec<&NamedTensor> = tensors.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    let mut all = Vec::new();
    for t in sorted {
        all.extend_from_slice(t.name.as_bytes());
        all.extend_from_slice(format!("{:?}{:?}", t.dtype, t.shape).as_bytes());
        all.extend_from_slice(&t.bytes);
    }
    control::nn::sha256_hex(&all)
}

/// A checkpoint read and checked, before anything of it is applied.
pub struct Loaded {
    pub counters: Counters,
    pub recipe: String,
    pub spec_sha256: String,
    tensors: HashMap<String, NamedTensor>,
}

/// Reads and checks the checkpoint at `path` (format, sha256, header).
pub fn read(path: &Path) -> anyhow::Result<Loaded> {
    let refuse = |why: String| {
        anyhow::anyhow!(
            "{} cannot resume the run: {why}. Restore it (e.g. `git checkout -- {}`) or start a new run in another directory",
            path.display(),
            path.display()
        )
    };
    let bytes = input_file::read_capped(path, MAX_BYTES).map_err(|e| refuse(format!("{e}")))?;
    let st = safetensors::SafeTensors::deserialize(&bytes)
        .map_err(|e| refuse(format!("it is damaged or truncated ({e:?})")))?;
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes)
        .map_err(|e| refuse(format!("its header is damaged ({e:?})")))?;
    let meta = header.metadata().clone().unwrap_or_default();
    let get = |k: &str| {
        meta.get(k).cloned().ok_or_else(|| {
            refuse(format!(
                "it is not a run checkpoint of this g1-train (its header has no `{k}`; older trainers wrote the weights alone)"
            ))
        })
    };
    let format = get("format")?;
    if format != FORMAT {
        return Err(refuse(format!(
            "its format is `{format}`, this g1-train reads `{FORMAT}`"
        )));
    }
    let mut tensors = HashMap::new();
    for (name, view) in st.tensors() {
        tensors.insert(
            name.clone(),
            NamedTensor {
                name,
                dtype: view.dtype(),
                shape: view.shape().to_vec(),
                bytes: view.data().to_vec(),
            },
        );
    }
    let all: Vec<NamedTensor> = tensors.values().cloned().collect();
    let want = get("data_sha256")?;
    let got = data_sha256(&all);
    if got != want {
        return Err(refuse(format!(
            "it is damaged: its data's sha256 is {got}, its header says {want}"
        )));
    }
    let counters: Counters =
        serde_json::from_str(&get("state")?).map_err(|e| refuse(format!("its run state does not parse ({e})")))?;
    Ok(Loaded {
        counters,
        recipe: get("recipe")?,
        spec_sha256: get("spec_sha256")?,
        tensors,
    })
}

impl Loaded {
    fn f32s(&self, name: &str, shape: &[usize]) -> anyhow::Result<Vec<f32>> {
        let t = self
            .tensors
            .get(name)
            .ok_or_else(|| anyhow::anyhow!("the checkpoint has no tensor {name}"))?;
        anyhow::ensure!(
            t.dtype == Dtype::F32 && t.shape == shape,
            "the checkpoint's {name} is {:?} {:?}, the run needs F32 {shape:?}",
            t.dtype,
            t.shape
        );
        Ok(t.bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect())
    }

    fn f64s(&self, name: &str, len: usize) -> anyhow::Result<Vec<f64>> {
        let t = self
            .tensors
            .get(name)
            .ok_or_else(|| anyhow::anyhow!("the checkpoint has no tensor {name}"))?;
        anyhow::ensure!(
            t.dtype == Dtype::F64 && t.shape == [len],
            "the checkpoint's {name} is {:?} {:?}, the run needs F64 [{len}]",
            t.dtype,
            t.shape
        );
        Ok(t.bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect())
    }

    /// Sets the variables, the optimizers and the learning rate, and returns the normaliser.
    pub fn apply(&self, ac: &ActorCritic, learner: &mut Learner) -> anyhow::Result<Normalizer> {
        for (name, var) in ac.named_vars() {
            let v = self.f32s(&name, var.dims())?;
            var.set(&Tensor::from_vec(v, var.dims(), var.device())?)?;
        }
        for (prefix, opt, step) in [
            ("adam", &mut learner.opt, self.counters.adam_step),
            ("critic_adam", &mut learner.critic_opt, self.counters.critic_adam_step),
        ] {
            for k in 0..opt.vars.len() {
                let (name, var) = &opt.vars[k];
                let dims = var.dims().to_vec();
                opt.m[k] = self.f32s(&format!("{prefix}.m.{name}"), &dims)?;
                opt.v[k] = self.f32s(&format!("{prefix}.v.{name}"), &dims)?;
            }
            opt.step = step;
        }
        learner.lr = f64::from_bits(self.counters.lr_bits);
        learner.rng = labkit::rng::Rng(self.counters.learner_rng);
        let d = ac.critic_dim;
        Ok(Normalizer {
            count: f64::from_bits(self.counters.normalizer_count_bits),
            mean: self.f64s("normalizer.mean", d)?,
            m2: self.f64s("normalizer.m2", d)?,
        })
    }
}

/// The settings where two recipes differ, as `was → now` (a line only one side has shows as
/// `—` on the other), at most `max`.
pub fn recipe_difference(was: &str, now: &str, max: usize) -> Vec<String> {
    let key = |l: &str| l.trim().split(':').next().unwrap_or("").to_string();
    let (a, b): (Vec<&str>, Vec<&str>) = (was.lines().collect(), now.lines().collect());
    let mut out = Vec::new();
    for x in a.iter().filter(|x| !b.contains(x)) {
        let y = b
            .iter()
            .find(|y| !a.contains(y) && key(y) == key(x))
            .map_or("—", |y| y.trim());
        out.push(format!("`{}` → `{y}`", x.trim()));
    }
    for y in b
        .iter()
        .filter(|y| !a.contains(y) && !a.iter().any(|x| !b.contains(x) && key(x) == key(y)))
    {
        out.push(format!("— → `{}`", y.trim()));
    }
    out.truncate(max);
    out
}
