//! `g1-import`: brings a policy exported elsewhere into the form `g1fw` runs.
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "g1-import",
    version,
    about = "Import a policy exported by rsl_rl / IsaacLab / unitree_rl_lab / mjlab"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Convert an ONNX policy network (MLP with an optional observation normaliser, or one LSTM
    /// layer with its state as inputs) into a `[policy.network]` table and a safetensors file, and
    /// print what became of every node. Any other op is refused by name.
    Network {
        /// The exported network (`policy.onnx`).
        onnx: PathBuf,
        /// Directory for `network.toml` and `policy.safetensors` (created; not overwritten unless
        /// --force).
        #[arg(long)]
        out: PathBuf,
        /// Replace files already in --out.
        #[arg(long)]
        force: bool,
    },
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Network { onnx, out, force } => {
            let net = policy_import::import_file(&onnx)?;
            let weights = net.safetensors_bytes()?;
            // The firmware's own loader checks every shape before anything is written.
            let check = firmware::nn::Network::from_safetensors_bytes(&net.desc, &weights)
                .context("the converted network does not load in the firmware's executor")?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            let toml_path = out.join("network.toml");
            let st_path = out.join("policy.safetensors");
            for p in [&toml_path, &st_path] {
                if p.exists() && !force {
                    anyhow::bail!("{} exists; give --force to replace it", p.display());
                }
            }
            let table = toml::to_string(&net.desc).context("writing the network table")?;
            std::fs::write(
                &toml_path,
                format!(
                    "# [policy.network] of a deploy spec, imported from {} by g1-import; weights = \"policy.safetensors\"\n{table}",
                    onnx.display()
                ),
            )?;
            std::fs::write(&st_path, &weights)?;
            println!(
                "imported {} (input '{}', output '{}')",
                onnx.display(),
                net.input_name,
                net.output_name
            );
            for line in &net.trace {
                println!("  {line}");
            }
            println!(
                "network: {} inputs → {} outputs, {} parameters{}",
                check.input_dim(),
                check.output_dim(),
                check.param_count(),
                match &net.recurrent {
                    Some(r) => format!(
                        "; LSTM state {} (inputs {} / {}: the executor carries it, from zeros)",
                        r.hidden,
                        r.h_in.as_deref().unwrap_or("none"),
                        r.c_in.as_deref().unwrap_or("none")
                    ),
                    None => String::new(),
                }
            );
            for (k, v) in &net.metadata {
                println!(
                    "metadata {k}: {}",
                    if v.len() > 120 {
                        format!("{}…", &v[..v.floor_char_boundary(120)])
                    } else {
                        v.clone()
                    }
                );
            }
            println!("wrote {} and {}", toml_path.display(), st_path.display());
            Ok(())
        }
    }
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("g1-import: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
