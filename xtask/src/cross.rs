//! `cargo xtask cross` (being written).
use anyhow::{bail, Result};

#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("cargo xtask cross is not implemented yet")
}
