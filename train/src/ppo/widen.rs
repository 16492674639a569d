//! A wider actor that computes what the narrow one did (net2net's function-preserving widening):
//! `g1-train widen-actor`.
//!
//! Why: fine-tunes of the committed actor (the peer walker's LSTM-64 → 32 → 12) trade descents for
//! climbs at about the same total (runs 27–29, notebook/2026-11-24_to_2026-12-02_stair_policy.md),
//! as a network out of capacity does, and the field's rough-terrain actors are far wider. Training
//! a wide actor from scratch costs more env steps than this machine has, so the trained one is
//! widened instead:
//! - every old unit reads only old units (the new inputs of an old row are zero), so the old units
//!   compute exactly what they did;
//! - every new unit gets PyTorch's uniform initialisation, but its output is read with weight zero
//!   by the next layer, so the actor's output is unchanged until PPO grows those weights (their
//!   gradients are not zero: the new units' activations are).
//!
//! For an LSTM the same holds gate by gate: the new hidden units' rows of `W_ih`, `W_hh` and the
//! biases are random, and the old units' rows read the new units' `h` with zeros.
use std::collections::HashMap;

use anyhow::Context;
use control::nn::NetworkDesc;

use super::policy::{ActorArch, ActorLayer, Sizes};

struct Tensor2 {
    rows: usize,
    cols: usize,
    v: Vec<f32>,
}

fn read(st: &safetensors::SafeTensors<'_>, name: &str) -> anyhow::Result<Tensor2> {
    let t = st
        .tensor(name)
        .with_context(|| format!("the actor has no tensor {name}"))?;
    let (rows, cols) = match t.shape() {
        [r] => (*r, 1),
        [r, c] => (*r, *c),
        s => anyhow::bail!("{name} has shape {s:?}"),
    };
    let v = crate::tensor_file::f32_values(&t).with_context(|| format!("reading {name}"))?;
    Ok(Tensor2 { rows, cols, v })
}

/// `old` placed in a `rows × cols` matrix: old row `r` lands on `row_map(r)`, old column `c` on
/// column `c`; every other entry, in row-major order, is `fill(new_row)`.
fn grow(
    old: &Tensor2,
    rows: usize,
    cols: usize,
    row_map: impl Fn(usize) -> usize,
    mut fill: impl FnMut(bool) -> f32,
) -> Vec<f32> {
    let mut old_row = vec![None; rows];
    for r in 0..old.rows {
        old_row[row_map(r)] = Some(r);
    }
    let mut out = Vec::with_capacity(rows * cols);
    for from in &old_row {
        for c in 0..cols {
            out.push(match from {
                Some(r) if c < old.cols => old.v[r * old.cols + c],
                _ => fill(from.is_none()),
            });
        }
    }
    out
}

/// The actor in `weights` (the layout of `desc`), its hidden layers widened to `hidden` (one size
/// per linear/lstm layer but the last, each at least the present one). Same tensor names; `g1fw`
/// and `g1-train ppo --init-actor` read the result with the same spec.
pub fn widen_actor(
    desc: &NetworkDesc,
    act: usize,
    weights: &[u8],
    hidden: &[usize],
    seed: u64,
) -> anyhow::Result<Vec<u8>> {
    let old = ActorArch::from_desc(desc, act, Sizes::Weights(weights))?;
    let new = ActorArch::from_desc(desc, act, Sizes::Hidden(hidden))?;
    for (o, n) in old.layers.iter().zip(&new.layers) {
        let (ow, nw) = match (o, n) {
            (ActorLayer::Lstm { hidden: a, .. }, ActorLayer::Lstm { hidden: b, .. }) => (*a, *b),
            (ActorLayer::Linear { output: a, .. }, ActorLayer::Linear { output: b, .. }) => (*a, *b),
            _ => continue,
        };
        anyhow::ensure!(nw >= ow, "widening only: a layer of {ow} units cannot become {nw}");
    }
    let st = safetensors::SafeTensors::deserialize(weights)?;
    let mut rng = labkit::rng::Rng(seed ^ 0x00D1_DE17);
    let mut out: HashMap<String, (Vec<usize>, Vec<f32>)> = HashMap::new();
    for (o, n) in old.layers.iter().zip(&new.layers) {
        match (o, n) {
            (
                ActorLayer::Lstm {
                    weight_ih,
                    weight_hh,
                    bias_ih,
                    bias_hh,
                    input,
                    hidden: h,
                },
                ActorLayer::Lstm { hidden: h2, .. },
            ) => {
                let (h, h2) = (*h, *h2);
                let bound = 1.0 / (h2 as f64).sqrt();
                // Gate g's unit u sits at row g·H + u; in the wider layer at g·H2 + u.
                let row_map = |r: usize| (r / h) * h2 + r % h;
                let mut uniform = |_: bool| rng.range(-bound, bound) as f32;
                let w_ih = grow(&read(&st, weight_ih)?, 4 * h2, *input, row_map, &mut uniform);
                // Old units read the new units' h with zero; new units read everything.
                let w_hh = grow(&read(&st, weight_hh)?, 4 * h2, h2, row_map, |new_row| {
                    if new_row {
                        uniform(true)
                    } else {
                        0.0
                    }
                });
                let b_ih = grow(&read(&st, bias_ih)?, 4 * h2, 1, row_map, &mut uniform);
                let b_hh = grow(&read(&st, bias_hh)?, 4 * h2, 1, row_map, &mut uniform);
                out.insert(weight_ih.clone(), (vec![4 * h2, *input], w_ih));
                out.insert(weight_hh.clone(), (vec![4 * h2, h2], w_hh));
                out.insert(bias_ih.clone(), (vec![4 * h2], b_ih));
                out.insert(bias_hh.clone(), (vec![4 * h2], b_hh));
            }
            (
                ActorLayer::Linear { weight, bias, .. },
                ActorLayer::Linear {
                    input: in2,
                    output: out2,
                    ..
                },
            ) => {
                let bound = 1.0 / (*in2 as f64).sqrt();
                let mut uniform = || rng.range(-bound, bound) as f32;
                let w = grow(
                    &read(&st, weight)?,
                    *out2,
                    *in2,
                    |r| r,
                    |new_row| {
                        if new_row {
                            uniform()
                        } else {
                            0.0
                        }
                    },
                );
                let b = grow(&read(&st, bias)?, *out2, 1, |r| r, |_| uniform());
                out.insert(weight.clone(), (vec![*out2, *in2], w));
                out.insert(bias.clone(), (vec![*out2], b));
            }
            _ => {}
        }
    }
    let tensors: Vec<_> = out
        .iter()
        .map(|(name, (shape, values))| crate::tensor_file::NamedTensor::f32(name.clone(), shape.clone(), values))
        .collect();
    crate::tensor_file::serialize(&tensors, None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use control::nn::Network;
    use control::spec::DeploySpec;
    use std::path::PathBuf;

    fn root() -> PathBuf {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
    }

    #[test]
    fn a_widened_actor_computes_what_the_committed_one_did() {
        let spec = DeploySpec::load(&root().join("specs/stairs/g1_stairs_lstm.toml")).unwrap();
        let desc = &spec.policy.network;
        let narrow = std::fs::read(root().join("specs/stairs/g1_stairs_lstm.safetensors")).unwrap();
        let wide = widen_actor(desc, spec.action_dim(), &narrow, &[128, 256], 5).unwrap();
        let arch = ActorArch::from_desc(desc, spec.action_dim(), Sizes::Weights(&wide)).unwrap();
        assert_eq!(arch.lstm_hidden(), 128);
        assert!(matches!(
            arch.layers[1],
            ActorLayer::Linear {
                input: 128,
                output: 256,
                ..
            }
        ));
        let (mut a, mut b) = (
            Network::from_safetensors_bytes(desc, &narrow).unwrap(),
            Network::from_safetensors_bytes(desc, &wide).unwrap(),
        );
        assert!(b.param_count() > 3 * a.param_count());
        // 200 steps of the recurrence on observation-like inputs: the outputs stay equal (to the
        // rounding of sums that now hold zero terms), and they move, so the check has teeth.
        let mut rng = labkit::rng::Rng(9);
        let (mut ya, mut yb) = (vec![0.0f32; 12], vec![0.0f32; 12]);
        let (mut worst, mut moved) = (0.0f32, 0.0f32);
        let mut first = None;
        for _ in 0..200 {
            let x: Vec<f32> = (0..desc.input).map(|_| rng.range(-1.5, 1.5) as f32).collect();
            a.step(&x, &mut ya).unwrap();
            b.step(&x, &mut yb).unwrap();
            for (p, q) in ya.iter().zip(&yb) {
                worst = worst.max((p - q).abs());
            }
            let f: &Vec<f32> = first.get_or_insert_with(|| ya.clone());
            moved = moved.max(ya.iter().zip(f).map(|(p, q)| (p - q).abs()).fold(0.0, f32::max));
        }
        eprintln!("widened actor: max |Δ| {worst:e} over 200 steps; outputs moved up to {moved}");
        assert!(worst < 1e-5, "widened actor differs by {worst}");
        assert!(
            moved > 0.1,
            "outputs barely moved ({moved}): the comparison is not exercised"
        );
    }

    #[test]
    fn narrowing_or_a_wrong_count_of_sizes_is_refused() {
        let spec = DeploySpec::load(&root().join("specs/stairs/g1_stairs_lstm.toml")).unwrap();
        let narrow = std::fs::read(root().join("specs/stairs/g1_stairs_lstm.safetensors")).unwrap();
        let e = widen_actor(&spec.policy.network, 12, &narrow, &[32, 32], 0).unwrap_err();
        assert!(e.to_string().contains("cannot become 32"), "{e}");
        let e = widen_actor(&spec.policy.network, 12, &narrow, &[128], 0).unwrap_err();
        assert!(e.to_string().contains("give 2 hidden sizes"), "{e:#}");
    }
}
