//! `g1-train average-actors`: the weighted average of snapshots of one fine-tune (a "model soup",
//! `train::ppo::average`), checked to load as the spec's network.
use std::path::PathBuf;

use anyhow::Context;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Actors to average, each FILE or FILE:WEIGHT (weight 1 by default), all fine-tuned from one
    /// start, e.g. a run's `actors/actor_<steps>.safetensors` over a stretch of training
    #[arg(required = true, num_args = 1.., value_name = "ACTOR[:WEIGHT]")]
    actors: Vec<String>,
    /// Deploy spec whose [policy.network] the actors follow (the average must load as it)
    #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
    spec: PathBuf,
    /// Where the averaged actor goes (then `g1fw eval --weights OUT`, or beside the spec)
    #[arg(long)]
    out: PathBuf,
}

/// `FILE` or `FILE:WEIGHT`; a path that itself holds a ':' keeps it unless what follows parses.
fn parse_actor(s: &str) -> (PathBuf, f64) {
    match s.rsplit_once(':').map(|(path, w)| (path, w.parse::<f64>())) {
        Some((path, Ok(w))) => (PathBuf::from(path), w),
        _ => (PathBuf::from(s), 1.0),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let spec = control::spec::DeploySpec::load(&args.spec)
        .with_context(|| format!("loading the deploy spec {}", args.spec.display()))?;
    let mut files = Vec::with_capacity(args.actors.len());
    for a in &args.actors {
        let (path, w) = parse_actor(a);
        let bytes = input_file::read_capped(&path, control::nn::MAX_WEIGHTS_BYTES)
            .with_context(|| format!("reading the actor {}", path.display()))?;
        files.push((path, bytes, w));
    }
    let mut named: Vec<(&str, Option<&std::path::Path>)> =
        files.iter().map(|(p, _, _)| ("an actor", Some(p.as_path()))).collect();
    named.push(("--spec", Some(&args.spec)));
    crate::outputs::refuse_clashes(
        &[("--out", Some(&args.out), crate::outputs::Kind::File)],
        &named,
        Some(&spec),
    )?;
    let inputs: Vec<(&[u8], f64)> = files.iter().map(|(_, b, w)| (b.as_slice(), *w)).collect();
    let averaged = train::ppo::average::average_actors(&inputs).with_context(|| {
        let names: Vec<_> = files.iter().map(|(p, _, _)| p.display().to_string()).collect();
        format!("averaging {}", names.join(", "))
    })?;
    control::nn::Network::from_safetensors_bytes(&spec.policy.network, &averaged).with_context(|| {
        format!(
            "the average does not load as {}'s [policy.network]: are these actors of that spec?",
            args.spec.display()
        )
    })?;
    output_file::write_atomically(&args.out, &averaged).with_context(|| format!("writing {}", args.out.display()))?;
    let total: f64 = files.iter().map(|(_, _, w)| w).sum();
    println!("wrote {} from {} actors:", args.out.display(), files.len());
    for (p, _, w) in &files {
        println!("  {:.4}  {}", w / total, p.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_actor_takes_an_optional_weight_after_its_last_colon() {
        assert_eq!(parse_actor("a.safetensors"), (PathBuf::from("a.safetensors"), 1.0));
        assert_eq!(
            parse_actor("run/a.safetensors:2.5"),
            (PathBuf::from("run/a.safetensors"), 2.5)
        );
        assert_eq!(
            parse_actor("c:/x.safetensors"),
            (PathBuf::from("c:/x.safetensors"), 1.0)
        );
    }
}
