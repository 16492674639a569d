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
    /// Import a unitree_rl_lab / IsaacLab export: `deploy.yaml` + `policy.onnx` → a deploy spec
    /// (`policy.toml`) and its weights (`policy.safetensors`) in --out, then load them with the
    /// firmware's own validation. Prints the observation terms and, per joint, slot, kp, kd and
    /// default pose to check before trying it on a robot. deploy.yaml's stiffness/damping are in SDK
    /// motor order; the spec's kp/kd are in policy order (converted through joint_ids_map).
    RlLab {
        /// The export's deploy.yaml.
        #[arg(long)]
        deploy: PathBuf,
        /// The export's policy network.
        #[arg(long)]
        onnx: PathBuf,
        #[command(flatten)]
        spec: SpecOut,
    },
    /// Import an ONNX that carries its deploy data in metadata_props (mjlab, BeyondMimic):
    /// joint_names, joint_stiffness, joint_damping, default_joint_pos, action_scale,
    /// observation_names. Writes `policy.toml` + `policy.safetensors` like `rl-lab`; what the
    /// metadata lacks (command ranges, policy rate) gets defaults, listed as notes.
    Mjlab {
        /// The exported network with its metadata.
        #[arg(long)]
        onnx: PathBuf,
        #[command(flatten)]
        spec: SpecOut,
    },
    /// Convert an ONNX policy network (MLP with an optional observation normaliser, or one LSTM
    /// layer with its state as inputs) into a `[policy.network]` table and a safetensors file, and
    /// print what became of every node. Any other op is refused by name.
    Network {
        /// The exported network (`policy.onnx`).
        onnx: PathBuf,
        /// Where `network.toml` and `policy.safetensors` go.
        #[command(flatten)]
        dir: OutDir,
    },
}

/// Where an import writes.
#[derive(clap::Args)]
struct OutDir {
    /// Output directory (created; files already in it are not replaced unless --force).
    #[arg(long)]
    out: PathBuf,
    /// Replace files already in --out.
    #[arg(long)]
    force: bool,
}

impl OutDir {
    /// Creates the directory and, before anything is written, refuses to replace any of `names`
    /// without --force, and any of `inputs` (through symlinks) even with it. Returns their paths.
    fn paths<const N: usize>(&self, names: [&str; N], inputs: &[&std::path::Path]) -> Result<[PathBuf; N]> {
        std::fs::create_dir_all(&self.out).with_context(|| format!("creating {}", self.out.display()))?;
        let paths = names.map(|n| self.out.join(n));
        // `output_file`'s rule (links and hard links followed), --force or not.
        let outs: Vec<(&str, &std::path::Path, output_file::Kind)> = paths
            .iter()
            .map(|p| ("the import's output", p.as_path(), output_file::Kind::File))
            .collect();
        let ins: Vec<(&str, &std::path::Path)> = inputs.iter().map(|p| ("an input", *p)).collect();
        output_file::check(&outs, &ins)
            .map_err(|e| anyhow::anyhow!("{e} (an import never overwrites what it reads; give another --out)"))?;
        for p in &paths {
            let Ok(out) = std::fs::canonicalize(p) else { continue };
            if let Some(input) = inputs.iter().find(|i| std::fs::canonicalize(i).is_ok_and(|i| i == out)) {
                anyhow::bail!(
                    "{} is the input {}: an import never overwrites what it reads, --force or not; give another --out",
                    p.display(),
                    input.display()
                );
            }
        }
        if let Some(p) = paths.iter().find(|p| p.exists() && !self.force) {
            anyhow::bail!("{} exists; give --force to replace it", p.display());
        }
        Ok(paths)
    }
}

/// The output of a spec import (`rl-lab`, `mjlab`).
#[derive(clap::Args)]
struct SpecOut {
    #[command(flatten)]
    dir: OutDir,
    /// The robot's MJCF for the estimator's leg kinematics, written into the spec as given
    /// (relative paths are relative to --out); without it the estimator runs attitude only.
    #[arg(long, value_name = "MJCF")]
    estimator_model: Option<String>,
}

impl SpecOut {
    fn options(&self) -> policy_import::RlLabOptions {
        policy_import::RlLabOptions {
            estimator_model: self.estimator_model.clone(),
            ..Default::default()
        }
    }
}

/// Writes `data` to a temporary file beside `path`, then renames it into place: a full disk or an
/// interrupted import leaves the old file or none, never a truncated one.
fn write(path: &std::path::Path, data: &[u8]) -> Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".partial-{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let written = std::fs::write(&tmp, data).and_then(|()| std::fs::rename(&tmp, path));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(anyhow::Error::new(e).context(format!("writing {} (nothing was left there)", path.display())));
    }
    Ok(())
}

/// What an import writes into --out: a deploy spec and its weights, or a network alone.
const SPEC_FILES: [&str; 2] = ["policy.toml", "policy.safetensors"];
const NETWORK_FILES: [&str; 2] = ["network.toml", "policy.safetensors"];

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::RlLab { deploy, onnx, spec } => {
            spec.dir.paths(SPEC_FILES, &[&deploy, &onnx])?;
            let imp = policy_import::import_rl_lab(&deploy, &onnx, &spec.options())?;
            let what = format!("{} + {}", deploy.display(), onnx.display());
            write_spec(&imp, &spec, &what, &[&deploy, &onnx])
        }
        Cmd::Mjlab { onnx, spec } => {
            spec.dir.paths(SPEC_FILES, &[&onnx])?;
            let imp = policy_import::import_onnx_metadata(&onnx, &spec.options())?;
            write_spec(&imp, &spec, &onnx.display().to_string(), &[&onnx])
        }
        Cmd::Network { onnx, dir } => {
            dir.paths(NETWORK_FILES, &[&onnx])?;
            let net = policy_import::import_file(&onnx)?;
            let weights = net.safetensors_bytes()?;
            // The firmware's own loader checks every shape before anything is written.
            let check = control::nn::Network::from_safetensors_bytes(&net.desc, &weights)
                .context("the converted network does not load in the firmware's executor")?;
            let [toml_path, st_path] = dir.paths(NETWORK_FILES, &[&onnx])?;
            let table = net.spec_table()?;
            let text = format!(
                "# A deploy spec's network, imported from {} by g1-import; with [policy] weights = \"policy.safetensors\"\n{table}",
                onnx.display()
            );
            write(&toml_path, text.as_bytes())?;
            write(&st_path, &weights)?;
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

/// Writes an import's spec and weights into `out`, loads them with the firmware's own validation,
/// and prints the table.
fn write_spec(imp: &policy_import::RlLabImport, out: &SpecOut, what: &str, inputs: &[&std::path::Path]) -> Result<()> {
    let [spec_path, weights_path] = out.dir.paths(SPEC_FILES, inputs)?;
    // The firmware's own loader and controller judge the result before anything is written (the
    // spec as if it were in --out already, so its relative paths resolve as they will).
    let spec = control::spec::DeploySpec::from_toml(&imp.spec_toml, &spec_path).context(
        "the imported spec does not load in g1fw (check --estimator-model and the inputs); nothing was written",
    )?;
    let warnings = spec.explicit_pd_warnings();
    let net = control::nn::Network::from_safetensors_bytes(&spec.policy.network, &imp.weights)
        .context("the imported weights do not load in g1fw; nothing was written")?;
    control::controller::Controller::with_network(spec, net)
        .context("the imported policy does not load in g1fw; nothing was written")?;
    write(&weights_path, &imp.weights)?;
    write(&spec_path, imp.spec_toml.as_bytes())?;
    println!("imported {what}");
    for line in &imp.network.trace {
        println!("  {line}");
    }
    print!("{}", imp.table);
    for w in &warnings {
        println!("warning: {w}");
    }
    if out.estimator_model.is_none() {
        println!("note: no --estimator-model: the state estimator runs attitude only (the policy does not need it)");
    }
    println!(
        "wrote {} and policy.safetensors; check it with `g1fw check-spec --spec {}`",
        spec_path.display(),
        spec_path.display()
    );
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The README's commands are checked against the parser in CI (tests/tests/readme.rs).
    if std::env::var_os("G1_CHECK_ARGS").is_some() {
        eprintln!("G1_CHECK_ARGS is set: the arguments parse; nothing was run");
        return ExitCode::SUCCESS;
    }
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("g1-import: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
