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
    let path = train::ppo::runner::export(&checkpoint, &spec)?;
    println!("wrote {}", path.display());
    Ok(())
}
