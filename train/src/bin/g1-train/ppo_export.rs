//! `g1-train ppo-export`: Write a PPO checkpoint's actor as the weights file its deploy spec names.
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// `checkpoint.safetensors` in a `g1-train ppo --out` directory (its actor is written)
    #[arg(long)]
    checkpoint: PathBuf,
    /// Deploy spec whose `[policy] weights` file receives the actor (overwritten)
    #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
    spec: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Args { checkpoint, spec } = args;
    // The export is the spec's weights file: never the checkpoint it comes from.
    let deploy = control::spec::DeploySpec::load(&spec)?;
    crate::outputs::refuse_clashes(
        &[(
            "the spec's policy.weights",
            Some(&deploy.weights_path()),
            crate::outputs::Kind::File,
        )],
        &[("--checkpoint", Some(&checkpoint)), ("--spec", Some(&spec))],
        None,
    )?;
    let path = train::ppo::runner::export(&checkpoint, &spec)?;
    println!("wrote {}", path.display());
    Ok(())
}
