//! `g1-train eval-terrain`: Evaluate the CNN (run by the firmware's executor) and the geometric baseline side by side
use anyhow::Context;
use labkit::progress::{bar, default_jobs};
use std::path::PathBuf;
use train::cnn::export::{DESC_FILE, WEIGHTS_FILE};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// N (random held-out worlds) or a comma-separated list of scenario files / presets.
    #[arg(long, default_value = "1000")]
    worlds: String,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Evaluate on the export's own world seeds (World::random(SEED + i), the worlds
    /// `g1-dataset export --seed SEED` renders) instead of held-out ones: the fit check.
    /// Errors here close to the held-out ones mean the network underfits, not overfits.
    #[arg(long)]
    training_worlds: bool,
    #[arg(long, default_value_t = 2)]
    poses_per_world: usize,
    /// standing, walking or mixed.
    #[arg(long, default_value = "mixed")]
    mode: train::cnn::dataset::ModeChoice,
    /// BEV memory keyframes of the grids (0: single-frame); must match what the weights were
    /// trained with. Default: that of the firmware's built-in network.
    #[arg(long, value_parser = sensor_io::bev_memory::parse_keyframes, default_value_t = train::cnn::dataset::MemoryConfig::BUILTIN.keyframes)]
    memory_keyframes: usize,
    /// Scale of the memory keyframes' simulated odometry drift (1: the renderer's model; 0:
    /// perfect odometry, the upper bound of what the memory gives).
    #[arg(long, default_value_t = 1.0)]
    odometry_drift: f64,
    #[command(flatten)]
    posture: train::cnn::dataset::PostureArgs,
    /// Directory holding terrain_cnn.safetensors + terrain_cnn.toml (default: the weights
    /// built into the firmware).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Write the figures (and every sample's truth and estimates) as JSON here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Plot of the errors versus true step height (PNG); a second one, `<stem>_by_riser.png`
    /// beside it, plots them versus the labelled riser's distance ahead. None when not given.
    #[arg(long)]
    plot: Option<PathBuf>,
    #[arg(long, default_value_t = default_jobs())]
    jobs: usize,
    #[arg(long)]
    quiet: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        worlds,
        seed,
        training_worlds,
        poses_per_world,
        mode,
        memory_keyframes,
        odometry_drift,
        posture,
        weights,
        report,
        plot,
        jobs,
        quiet,
    } = args;
    use train::cnn::dataset::{DatasetConfig, WorldSet, EVAL_SEED_BASE};
    let base = if training_worlds {
        eprintln!(
            "note: --training-worlds: world seeds {seed}.. are the ones `g1-dataset export --seed {seed}` \
                 renders, NOT held out; these figures measure the fit, not generalisation"
        );
        0
    } else {
        EVAL_SEED_BASE
    };
    let first = base
        .checked_add(seed)
        .with_context(|| format!("--seed {seed}: held-out seeds start at {base} + SEED, past u64"))?;
    let set = match worlds.trim().parse::<usize>() {
        Ok(count) => WorldSet::Random {
            first_seed: first,
            count,
        },
        Err(_) => WorldSet::Named {
            args: worlds
                .split(',')
                .map(|w| w.trim().to_string())
                .filter(|w| !w.is_empty())
                .collect(),
            seed: first,
        },
    };
    set.check().context("--worlds/--seed")?;
    crate::outputs::refuse_clashes(
        &[
            ("--report", report.as_deref(), crate::outputs::Kind::File),
            ("--plot", plot.as_deref(), crate::outputs::Kind::File),
        ],
        &[("--weights", weights.as_deref())],
        None,
    )?;
    anyhow::ensure!(
        poses_per_world > 0,
        "--poses-per-world 0 evaluates nothing: give at least 1"
    );
    let mut net = load_net(weights.as_deref())?;
    let cfg = DatasetConfig {
        mode,
        memory: train::cnn::dataset::MemoryConfig::with_keyframes(memory_keyframes),
        odometry_drift,
        posture: posture.posture(),
        ..DatasetConfig::default()
    };
    let pb = bar(set.len() * poses_per_world, quiet, "samples");
    let r = train::cnn::eval::evaluate(&set, poses_per_world, cfg, jobs, &mut net, &|| pb.inc(1))?;
    pb.finish_and_clear();
    print!("{r}");
    let title = format!(
        "terrain token errors vs step height: {} ({} samples)",
        r.world_set, r.cnn.samples
    );
    if let Some(plot) = &plot {
        train::plot::error_vs_height_png(plot, &r.by_step_height, &title)?;
        println!("plot: {}", plot.display());
        let riser_plot = plot.with_file_name(format!(
            "{}_by_riser.png",
            plot.file_stem().and_then(|s| s.to_str()).unwrap_or("eval_terrain")
        ));
        let title = format!(
            "terrain token errors vs the labelled riser's distance: {} ({} samples)",
            r.world_set, r.cnn.samples
        );
        train::plot::error_vs_riser_png(&riser_plot, &r.by_riser_ahead, &title)?;
        println!("plot: {}", riser_plot.display());
    }
    if let Some(path) = report {
        train::cnn::eval::write_report(&path, &r)?;
        println!("report: {}", path.display());
    }
    Ok(())
}

fn load_net(weights: Option<&std::path::Path>) -> anyhow::Result<control::terrain_net::TerrainNet> {
    Ok(match weights {
        None => control::terrain_net::TerrainNet::embedded()?,
        Some(dir) => control::terrain_net::TerrainNet::load(&dir.join(DESC_FILE), &dir.join(WEIGHTS_FILE))
            .with_context(|| {
                format!(
                    "loading the terrain CNN from {} (written by `g1-train fit`)",
                    dir.display()
                )
            })?,
    })
}
