//! `g1-train widen-actor`: a wider actor that computes what the given one did, to fine-tune with
//! more capacity (`train::ppo::widen`).
use std::path::PathBuf;

use anyhow::Context;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The actor to widen (the tensor names of the spec's [policy.network])
    #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.safetensors")]
    actor: PathBuf,
    /// Deploy spec whose [policy.network] the actor follows
    #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
    spec: PathBuf,
    /// New hidden sizes, one per linear/lstm layer but the last, each at least the present one
    /// (e.g. 128,256 for the LSTM spec, whose actor is LSTM-64 → 32 → 12)
    #[arg(long, value_delimiter = ',', required = true)]
    hidden: Vec<usize>,
    /// Seed of the new units' initial weights
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where the widened actor goes (then `g1-train ppo --init-actor OUT`)
    #[arg(long)]
    out: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let spec = control::spec::DeploySpec::load(&args.spec)
        .with_context(|| format!("loading the deploy spec {}", args.spec.display()))?;
    crate::outputs::refuse_clashes(
        &[("--out", Some(&args.out), crate::outputs::Kind::File)],
        &[("--actor", Some(&args.actor)), ("--spec", Some(&args.spec))],
        Some(&spec),
    )?;
    let weights = input_file::read_capped(&args.actor, control::nn::MAX_WEIGHTS_BYTES)
        .with_context(|| format!("reading {}", args.actor.display()))?;
    let wide = train::ppo::widen::widen_actor(
        &spec.policy.network,
        spec.action_dim(),
        &weights,
        &args.hidden,
        args.seed,
    )
    .with_context(|| format!("widening {}", args.actor.display()))?;
    output_file::write_atomically(&args.out, &wide).with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "wrote {} (hidden {:?}; it acts as {} did)",
        args.out.display(),
        args.hidden,
        args.actor.display()
    );
    Ok(())
}
