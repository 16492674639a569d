//! `cargo xtask hil` (being written).
use anyhow::{bail, Result};

#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("cargo xtask hil is not implemented yet")
}
