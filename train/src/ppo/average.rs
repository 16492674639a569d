//! A weighted average of actors that share one start (a "model soup"): `g1-train average-actors`.
//!
//! Why: snapshots of one fine-tune, ~0.5 M env steps apart, differ more than their training says.
//! Run 37's flat-ground speed jumps between 0.45 and 0.64 m/s for a command of 0.5 from one
//! snapshot to the next, and a preset passed at one noise seed fails at the next. Along these
//! fine-tunes the flat speed is close to linear in the weights: the average of snapshots walks at
//! the mean of their speeds (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-11-30). So
//! averaging the snapshots of a stretch of training keeps what they share and cancels what each
//! update added by chance, as stochastic weight averaging does. Averaging is only meaningful for
//! actors fine-tuned from one start; actors trained apart have no common basin and their average is
//! a broken network.
use anyhow::Context;

/// The weighted mean of `actors` (safetensors bytes, each with its weight > 0), tensor by tensor.
/// Every actor must hold the same f32 tensors in the same shapes. The sum runs in f64 in the
/// order given, each value times its share `w / Σw`, and is rounded to f32 once, so the same
/// inputs in the same order give the same bits.
pub fn average_actors(actors: &[(&[u8], f64)]) -> anyhow::Result<Vec<u8>> {
    anyhow::ensure!(!actors.is_empty(), "give at least one actor to average");
    for (i, (_, w)) in actors.iter().enumerate() {
        anyhow::ensure!(
            w.is_finite() && *w > 0.0,
            "actor {} has weight {w}: weights must be finite and above 0",
            i + 1
        );
    }
    let total: f64 = actors.iter().map(|(_, w)| w).sum();
    let files = actors
        .iter()
        .enumerate()
        .map(|(i, (bytes, _))| {
            safetensors::SafeTensors::deserialize(bytes)
                .map_err(|e| anyhow::anyhow!("actor {} is not a safetensors file: {e:?}", i + 1))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let sorted_names = |f: &safetensors::SafeTensors<'_>| {
        let mut names: Vec<String> = f.names().into_iter().cloned().collect();
        names.sort();
        names
    };
    let names = sorted_names(&files[0]);
    let mut out = Vec::with_capacity(names.len());
    for (i, f) in files.iter().enumerate().skip(1) {
        let other = sorted_names(f);
        anyhow::ensure!(
            other == names,
            "actor {} holds the tensors {other:?}, actor 1 holds {names:?}: only actors of one \
             network can be averaged",
            i + 1
        );
    }
    for name in &names {
        let first = files[0].tensor(name)?;
        let shape = first.shape().to_vec();
        let mut acc = vec![0.0f64; shape.iter().product()];
        for (i, (f, (_, w))) in files.iter().zip(actors).enumerate() {
            let t = f.tensor(name)?;
            anyhow::ensure!(
                t.shape() == shape.as_slice(),
                "{name} is {:?} in actor {} but {shape:?} in actor 1",
                t.shape(),
                i + 1
            );
            let values =
                crate::tensor_file::f32_values(&t).with_context(|| format!("reading {name} of actor {}", i + 1))?;
            let share = w / total;
            for (a, v) in acc.iter_mut().zip(values) {
                *a += v as f64 * share;
            }
        }
        let values: Vec<f32> = acc.iter().map(|&a| a as f32).collect();
        out.push(crate::tensor_file::NamedTensor::f32(name.clone(), shape, &values));
    }
    crate::tensor_file::serialize(&out, None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tensor_file::{f32_values, serialize, NamedTensor};

    fn file(a: &[f32], b: &[f32]) -> Vec<u8> {
        serialize(
            &[
                NamedTensor::f32("layer.weight", vec![2, 2], a),
                NamedTensor::f32("layer.bias", vec![2], b),
            ],
            None,
        )
        .unwrap()
    }

    fn values(bytes: &[u8], name: &str) -> Vec<f32> {
        let st = safetensors::SafeTensors::deserialize(bytes).unwrap();
        f32_values(&st.tensor(name).unwrap()).unwrap()
    }

    #[test]
    fn weighted_mean_tensor_by_tensor_and_one_actor_is_itself() {
        let a = file(&[1.0, 2.0, 3.0, 4.0], &[0.5, -0.5]);
        let b = file(&[5.0, 6.0, 7.0, 8.0], &[1.5, 0.5]);
        let m = average_actors(&[(&a, 1.0), (&b, 1.0)]).unwrap();
        assert_eq!(values(&m, "layer.weight"), [3.0, 4.0, 5.0, 6.0]);
        assert_eq!(values(&m, "layer.bias"), [1.0, 0.0]);
        let w = average_actors(&[(&a, 3.0), (&b, 1.0)]).unwrap();
        assert_eq!(values(&w, "layer.weight"), [2.0, 3.0, 4.0, 5.0]);
        assert_eq!(
            average_actors(&[(&a, 0.2)]).unwrap(),
            a,
            "one actor averages to itself, bit for bit"
        );
    }

    #[test]
    fn the_committed_actor_averaged_with_itself_is_unchanged() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../specs/stairs/g1_stairs_lstm.safetensors"
        );
        let actor = std::fs::read(path).unwrap();
        let m = average_actors(&[(&actor, 1.0), (&actor, 1.0), (&actor, 1.0)]).unwrap();
        let (x, y) = (
            safetensors::SafeTensors::deserialize(&actor).unwrap(),
            safetensors::SafeTensors::deserialize(&m).unwrap(),
        );
        assert_eq!(x.len(), y.len());
        for (name, t) in x.tensors() {
            let (p, q) = (f32_values(&t).unwrap(), f32_values(&y.tensor(&name).unwrap()).unwrap());
            let worst = p
                .iter()
                .zip(&q)
                .map(|(p, q)| (p - q).abs() / p.abs().max(1e-30))
                .fold(0.0, f32::max);
            assert!(worst <= f32::EPSILON, "{name}: relative change {worst}");
        }
    }

    #[test]
    fn mismatched_actors_and_bad_weights_are_refused_by_name() {
        let a = file(&[1.0, 2.0, 3.0, 4.0], &[0.5, -0.5]);
        let other_shape = serialize(
            &[
                NamedTensor::f32("layer.weight", vec![1, 4], &[1.0, 2.0, 3.0, 4.0]),
                NamedTensor::f32("layer.bias", vec![2], &[0.0, 0.0]),
            ],
            None,
        )
        .unwrap();
        let e = average_actors(&[(&a, 1.0), (&other_shape, 1.0)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("layer.weight is [1, 4] in actor 2"), "{e}");
        let other_names = serialize(&[NamedTensor::f32("layer.weight", vec![2, 2], &[0.0; 4])], None).unwrap();
        let e = average_actors(&[(&a, 1.0), (&other_names, 1.0)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("only actors of one network"), "{e}");
        let e = average_actors(&[(&a, 1.0), (&a, 0.0)]).unwrap_err().to_string();
        assert!(e.contains("actor 2 has weight 0"), "{e}");
        let e = average_actors(&[(&a, f64::NAN)]).unwrap_err().to_string();
        assert!(e.contains("finite and above 0"), "{e}");
        assert!(average_actors(&[]).is_err());
        let e = average_actors(&[(b"not a file", 1.0)]).unwrap_err().to_string();
        assert!(e.contains("actor 1 is not a safetensors file"), "{e}");
    }
}
