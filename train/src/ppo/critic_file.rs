//! The critic that goes with an actor: its weights, the running statistics that normalise its
//! input, and the actor's action noise (`log_std`), in one safetensors file beside the actor
//! (`policy.safetensors` → `policy.critic.safetensors`).
//!
//! Why: a fine-tune that starts from a committed actor with a new critic first trains against
//! advantages from a critic that knows nothing, and measured through `g1fw` that cost about a third
//! of the stair successes in the first ~9 M env steps (runs 25–27,
//! notebook/2026-11-24_to_2026-12-02_stair_policy.md). The checkpoint in `--out` holds the critic
//! too, but a run directory outside the repository may be lost, and the repository keeps only the
//! actor. With this file beside it, `g1-train ppo --init-critic` continues where the actor's
//! training stopped.
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use candle_core::{DType, Device, Tensor};

use super::algo::Normalizer;
use super::policy::ActorCritic;
use crate::tensor_file::NamedTensor;

/// `foo.safetensors` → `foo.critic.safetensors`.
pub fn beside(actor: &Path) -> PathBuf {
    let stem = actor
        .file_stem()
        .map_or_else(|| "policy".into(), |s| s.to_string_lossy().into_owned());
    actor.with_file_name(format!("{stem}.critic.safetensors"))
}

/// What a critic file says about where it came from.
#[derive(Clone, Debug, PartialEq)]
pub struct Provenance {
    /// sha256 of the actor file it was trained with (the export beside it).
    pub actor_sha256: String,
    /// Env steps of the run when it was written.
    pub env_steps: u64,
}

/// Which of an actor-critic's variables the file holds: the critic's and the action noise, by name.
fn file_vars(data: &HashMap<String, candle_core::Var>) -> Vec<String> {
    let mut names: Vec<String> = data
        .keys()
        .filter(|k| k.starts_with("critic.") || *k == "log_std")
        .cloned()
        .collect();
    names.sort();
    names
}

/// The file's bytes: every `critic.*` tensor and `log_std` (f32), the normaliser's `count`, `mean`
/// and `m2` (f64, as accumulated), and the provenance as metadata.
pub fn to_bytes(ac: &ActorCritic, normalizer: &Normalizer, from: &Provenance) -> anyhow::Result<Vec<u8>> {
    let mut tensors = Vec::new();
    {
        let data = ac.vars.data().lock().expect("var map lock");
        for n in &file_vars(&data) {
            tensors.push(NamedTensor::from_candle(n.clone(), data[n].as_tensor())?);
        }
    }
    let d = normalizer.mean.len();
    tensors.push(NamedTensor::f64("normalizer.count", vec![1], &[normalizer.count]));
    tensors.push(NamedTensor::f64("normalizer.mean", vec![d], &normalizer.mean));
    tensors.push(NamedTensor::f64("normalizer.m2", vec![d], &normalizer.m2));
    let meta = HashMap::from([
        ("actor_sha256".to_string(), from.actor_sha256.clone()),
        ("env_steps".to_string(), from.env_steps.to_string()),
    ]);
    crate::tensor_file::serialize(&tensors, Some(meta))
}

/// Writes [`to_bytes`] to `path` (write, then rename: a killed run keeps the previous file).
pub fn save(path: &Path, ac: &ActorCritic, normalizer: &Normalizer, from: &Provenance) -> anyhow::Result<()> {
    output_file::write_atomically(path, &to_bytes(ac, normalizer, from)?)
        .with_context(|| format!("writing {}", path.display()))
}

fn f64s(st: &safetensors::SafeTensors<'_>, name: &str, len: usize, path: &Path) -> anyhow::Result<Vec<f64>> {
    let t = st
        .tensor(name)
        .with_context(|| format!("{}: no tensor {name}; is it a critic file?", path.display()))?;
    anyhow::ensure!(
        t.dtype() == safetensors::Dtype::F64 && t.shape() == [len],
        "{}: {name} is {:?} {:?}, need F64 [{len}] (a critic of another observation layout?)",
        path.display(),
        t.dtype(),
        t.shape()
    );
    Ok(t.data()
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect())
}

/// Loads a critic file into `ac` (its critic and `log_std`) and returns the normaliser and the
/// provenance. Every tensor must have the shape of `ac`'s: a critic of another spec's observation
/// layout is refused, naming the tensor, before anything is overwritten.
pub fn load(ac: &ActorCritic, path: &Path) -> anyhow::Result<(Normalizer, Provenance)> {
    let bytes = input_file::read_capped(path, control::nn::MAX_WEIGHTS_BYTES)
        .with_context(|| format!("reading the critic file {}", path.display()))?;
    let st = safetensors::SafeTensors::deserialize(&bytes)
        .with_context(|| format!("{}: not a safetensors file", path.display()))?;
    let mut loaded: Vec<(String, Tensor)> = Vec::new();
    {
        let data = ac.vars.data().lock().expect("var map lock");
        for n in &file_vars(&data) {
            let want = data[n].as_tensor().dims().to_vec();
            let t = st
                .tensor(n)
                .with_context(|| format!("{}: no tensor {n}; is it a critic file for this spec?", path.display()))?;
            // Action noise written for one output fewer (before the spec's policy-set clock,
            // `[phase] rate`): the new output starts at the mean noise of the others.
            let widen_noise = n == "log_std" && t.shape().len() == 1 && t.shape()[0] < want[0];
            anyhow::ensure!(
                t.dtype() == safetensors::Dtype::F32 && (t.shape() == want.as_slice() || widen_noise),
                "{}: {n} is {:?} {:?}, this spec's critic needs F32 {want:?} (written for another observation layout?)",
                path.display(),
                t.dtype(),
                t.shape()
            );
            let mut v = crate::tensor_file::f32_values(&t)?;
            anyhow::ensure!(
                v.iter().all(|x| x.is_finite()),
                "{}: {n} holds a non-finite value",
                path.display()
            );
            if widen_noise {
                let mean = v.iter().sum::<f32>() / v.len().max(1) as f32;
                v.resize(want[0], mean);
            }
            loaded.push((
                n.clone(),
                Tensor::from_vec(v, want, &Device::Cpu)?.to_dtype(DType::F32)?,
            ));
        }
    }
    let d = ac.critic_dim;
    let count = f64s(&st, "normalizer.count", 1, path)?[0];
    let normalizer = Normalizer {
        count,
        mean: f64s(&st, "normalizer.mean", d, path)?,
        m2: f64s(&st, "normalizer.m2", d, path)?,
    };
    anyhow::ensure!(
        count.is_finite() && count >= 0.0 && normalizer.mean.iter().chain(&normalizer.m2).all(|x| x.is_finite()),
        "{}: the normaliser's statistics are not finite",
        path.display()
    );
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)?;
    let meta = meta.metadata().clone().unwrap_or_default();
    let from = Provenance {
        actor_sha256: meta.get("actor_sha256").cloned().unwrap_or_default(),
        env_steps: meta.get("env_steps").and_then(|s| s.parse().ok()).unwrap_or(0),
    };
    let data = ac.vars.data().lock().expect("var map lock");
    for (n, t) in loaded {
        data[&n].set(&t)?;
    }
    Ok((normalizer, from))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ppo::policy::ActorArch;

    fn actor_critic(critic_dim: usize, seed: u64) -> ActorCritic {
        ActorCritic::with_arch(ActorArch::peer_lstm(51, 12), critic_dim, 0.3, seed).unwrap()
    }

    fn vars(ac: &ActorCritic) -> Vec<(String, Vec<u32>)> {
        let data = ac.vars.data().lock().unwrap();
        let mut v: Vec<_> = data
            .iter()
            .map(|(n, t)| {
                let x: Vec<f32> = t.as_tensor().flatten_all().unwrap().to_vec1().unwrap();
                (n.clone(), x.iter().map(|f| f.to_bits()).collect())
            })
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_critic_file_round_trips_the_critic_the_noise_and_the_normaliser_bit_for_bit() {
        let dir = std::env::temp_dir().join(format!("g1_critic_file_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let src = actor_critic(80, 1);
        let mut norm = Normalizer::new(80);
        norm.update(&(0..800).map(|i| (i as f32 * 0.37).sin()).collect::<Vec<_>>());
        let from = Provenance {
            actor_sha256: "ab12".into(),
            env_steps: 55_578_624,
        };
        let path = dir.join("policy.critic.safetensors");
        save(&path, &src, &norm, &from).unwrap();
        // Another seed: every critic tensor differs before the load.
        let dst = actor_critic(80, 2);
        let critic_and_noise = |v: Vec<(String, Vec<u32>)>| -> Vec<(String, Vec<u32>)> {
            v.into_iter()
                .filter(|(n, _)| n.starts_with("critic.") || n == "log_std")
                .collect()
        };
        let actor_only = |v: Vec<(String, Vec<u32>)>| -> Vec<(String, Vec<u32>)> {
            v.into_iter()
                .filter(|(n, _)| !n.starts_with("critic.") && n != "log_std")
                .collect()
        };
        assert_ne!(critic_and_noise(vars(&src)), critic_and_noise(vars(&dst)));
        src.vars.data().lock().unwrap()["log_std"]
            .set(&Tensor::full(-1.7f32, 12, &Device::Cpu).unwrap())
            .unwrap();
        save(&path, &src, &norm, &from).unwrap();
        let dst_actor = actor_only(vars(&dst));
        let (n2, from2) = load(&dst, &path).unwrap();
        assert_eq!(critic_and_noise(vars(&src)), critic_and_noise(vars(&dst)));
        assert_eq!(
            actor_only(vars(&dst)),
            dst_actor,
            "the actor is not the critic file's to change"
        );
        assert_eq!(from2, from);
        assert_eq!(n2.count, norm.count);
        assert_eq!(n2.mean, norm.mean);
        assert_eq!(n2.m2, norm.m2);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_critic_of_another_layout_or_a_damaged_file_is_refused_and_changes_nothing() {
        let dir = std::env::temp_dir().join(format!("g1_critic_refused_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("other.critic.safetensors");
        let other = actor_critic(70, 1);
        save(
            &path,
            &other,
            &Normalizer::new(70),
            &Provenance {
                actor_sha256: String::new(),
                env_steps: 0,
            },
        )
        .unwrap();
        let ac = actor_critic(80, 2);
        let before = vars(&ac);
        let e = load(&ac, &path).unwrap_err().to_string();
        assert!(e.contains("critic.0.weight") && e.contains("[128, 80]"), "{e}");
        assert_eq!(vars(&ac), before);
        std::fs::write(&path, b"not safetensors").unwrap();
        let e = load(&ac, &path).unwrap_err().to_string();
        assert!(e.contains("not a safetensors file"), "{e}");
        let e = load(&ac, &dir.join("missing.critic.safetensors"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("reading the critic file"), "{e}");
        assert_eq!(vars(&ac), before);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_critic_file_sits_beside_its_actor() {
        assert_eq!(
            beside(Path::new("specs/stairs/g1_stairs_lstm.safetensors")),
            Path::new("specs/stairs/g1_stairs_lstm.critic.safetensors")
        );
        assert_eq!(
            beside(Path::new("run/actors/actor_000055578624.safetensors")),
            Path::new("run/actors/actor_000055578624.critic.safetensors")
        );
    }
}
