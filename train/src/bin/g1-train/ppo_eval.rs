//! `g1-train ppo-eval`: Evaluate an actor in the training environment itself (its physics, worlds, starts, token and
use anyhow::Context;
use labkit::progress::default_jobs;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The deploy spec the actor was trained with.
    #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
    spec: PathBuf,
    /// The actor (default: the spec's weights), e.g. a run's actors/actor_<steps>.safetensors.
    #[arg(long)]
    weights: Option<PathBuf>,
    #[arg(long, default_value = "g1-12dof")]
    model: g1_sim::ModelChoice,
    /// Terrain columns to run, e.g. up,down.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "up,down")]
    columns: Vec<train::ppo::env::Column>,
    /// Curriculum levels (step height 5 + 2.1·level cm), e.g. 1,3,5.
    #[arg(long, value_delimiter = ',', default_value = "1,3,5")]
    levels: Vec<usize>,
    /// Episodes per column and level.
    #[arg(long, default_value_t = 16)]
    episodes: usize,
    /// Commanded forward speed, m/s.
    #[arg(long, default_value_t = 0.5)]
    vx: f32,
    /// Training's randomisation (noise, latency, pushes, dynamics) on; default off.
    #[arg(long)]
    randomization: bool,
    #[arg(long, default_value_t = 20.0)]
    episode_s: f64,
    /// Run every episode assisted at this strength (0–1; `g1-train ppo --assist-share`'s helping
    /// hand on the base). 0 (default): no help, as on the robot.
    #[arg(long, default_value_t = 0.0)]
    assist: f64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long, default_value_t = default_jobs())]
    threads: usize,
    /// Also print each cell's mean return per episode split by reward term (the terms that are
    /// not zero), to see what the policy is paid for and what it pays.
    #[arg(long)]
    terms: bool,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        spec,
        weights,
        model,
        columns,
        levels,
        episodes,
        vx,
        randomization,
        episode_s,
        assist,
        seed,
        threads,
        terms,
        json,
    } = args;
    anyhow::ensure!((0.0..=1.0).contains(&assist), "--assist must be a strength from 0 to 1");
    anyhow::ensure!((1..=100_000).contains(&episodes), "--episodes must be 1 to 100000");
    anyhow::ensure!(
        levels.iter().all(|&l| l < train::ppo::env::LEVELS),
        "--levels must be 0 to {}",
        train::ppo::env::LEVELS - 1
    );
    anyhow::ensure!(
        vx.is_finite() && episode_s.is_finite() && episode_s > 0.0,
        "--vx and --episode-s must be numbers (--episode-s positive)"
    );
    let deploy = control::spec::DeploySpec::load(&spec)
        .with_context(|| format!("loading the deploy spec {}", spec.display()))?;
    crate::outputs::refuse_clashes(
        &[("--json", json.as_deref(), crate::outputs::Kind::File)],
        &[("--spec", Some(&spec)), ("--weights", weights.as_deref())],
        Some(&deploy),
    )?;
    let wpath = weights.unwrap_or_else(|| deploy.weights_path());
    let bytes = input_file::read_capped(&wpath, control::nn::MAX_WEIGHTS_BYTES)
        .with_context(|| format!("reading the actor {}", wpath.display()))?;
    let deploy = std::sync::Arc::new(deploy);
    let mut reports = Vec::new();
    println!(
        "column  level  step cm  episodes  success  falls ({})  timeouts  mean s",
        train::ppo::env::FALL_CAUSES.join("/")
    );
    for &column in &columns {
        for &level in &levels {
            let r = train::ppo::in_env::evaluate(
                &train::ppo::in_env::InEnvOptions {
                    model: model.clone(),
                    spec: deploy.clone(),
                    column,
                    level,
                    vx,
                    episodes,
                    random: if randomization {
                        train::ppo::env::Randomization::DEFAULT
                    } else {
                        train::ppo::env::Randomization::NONE
                    },
                    episode_s,
                    assist,
                    seed,
                    threads,
                },
                &bytes,
            )?;
            let causes: Vec<String> = r.fall_causes.iter().map(|(_, n)| n.to_string()).collect();
            println!(
                "{:<7} {:>5}  {:>7.1}  {:>8}  {:>7}  {:>5} ({})  {:>8}  {:>6.1}",
                r.column,
                r.level,
                100.0 * r.step_height_m,
                r.episodes,
                r.successes,
                r.falls,
                causes.join("/"),
                r.timeouts,
                r.mean_steps / deploy.rates.policy_hz as f64
            );
            if terms {
                print_terms(r.mean_return, &r.mean_return_by_term);
            }
            reports.push(r);
        }
    }
    if let Some(path) = json {
        std::fs::write(&path, serde_json::to_string_pretty(&reports)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// One cell's mean return by term, largest magnitude first, zeros left out.
fn print_terms(total: f64, by_term: &[(String, f64)]) {
    let mut rows: Vec<&(String, f64)> = by_term.iter().filter(|(_, v)| *v != 0.0).collect();
    rows.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    println!("        return per episode {total:+.3}, by term:");
    for (name, v) in rows {
        println!("          {name:<18} {v:+9.3}");
    }
}
