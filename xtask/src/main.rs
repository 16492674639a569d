//! `cargo xtask …`: the project's automation in Rust instead of shell, so it runs the same on every
//! machine. Each subcommand lives in its own module.
use anyhow::Result;
use clap::{Parser, Subcommand};

mod cross;
mod hil;
mod image;

#[derive(Parser)]
#[command(
    name = "cargo xtask",
    about = "Project automation: HIL in a VM, aarch64 replay, deploy image"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Boot a User-Mode Linux VM with vcan and run the CAN hardware-in-loop suite inside it.
    Hil(hil::Args),
    /// Cross-build g1fw for aarch64 and replay the regression corpus under qemu-aarch64.
    CrossReplay(cross::Args),
    /// Build the reproducible deploy image target/image/g1fw-aarch64.tar.gz.
    Image(image::Args),
}

fn main() -> Result<()> {
    match Cli::parse().cmd {
        Cmd::Hil(a) => hil::run(a),
        Cmd::CrossReplay(a) => cross::run(a),
        Cmd::Image(a) => image::run(a),
    }
}
