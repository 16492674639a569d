//! `g1-train ppo`: Train the stair policy with PPO on in-process MuJoCo environments (docs/stair_policy.md).
use anyhow::Context;
use labkit::progress::default_jobs;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The deploy spec to train (its observation, gains, rates and network layout).
    #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
    spec: PathBuf,
    /// g1-12dof (default), g1-29dof (upper body held by the spec's [[held]] groups) or an MJCF.
    #[arg(long, default_value = "g1-12dof")]
    model: g1_sim::ModelChoice,
    /// A second model for a share of the environments, MODEL:SHARE, e.g. g1-29dof:0.5: one actor
    /// that learns both bodies it is deployed on (the judge stays on --model).
    #[arg(long, value_name = "MODEL:SHARE", value_parser = parse_mixed_model)]
    mix_model: Option<(g1_sim::ModelChoice, f64)>,
    /// Run directory: created if missing; a run whose directory holds a checkpoint resumes from it
    /// (under the same settings; see --resume). A new run writes its recipe.toml there.
    #[arg(long, required_unless_present = "resume")]
    out: Option<PathBuf>,
    /// Continue the run in DIR from its checkpoint with its own recipe.toml: nothing else is
    /// needed (--iterations, --max-wall, --threads and --judge-every may be given).
    #[arg(long, value_name = "DIR")]
    resume: Option<PathBuf>,
    /// Take the options from a recipe file (TOML, one key per option, as a run's recipe.toml);
    /// options on the command line win over the file's.
    #[arg(long, value_name = "FILE")]
    recipe: Option<PathBuf>,
    /// Resume a run whose checkpoint was written under other settings than the recipe's now (a
    /// change of recipe mid-run, on purpose); without it such a resume is refused, naming the
    /// difference.
    #[arg(long)]
    accept_recipe_change: bool,
    /// Parallel environments.
    #[arg(long, default_value_t = 256)]
    envs: usize,
    /// Worker threads stepping environments (default: every core).
    #[arg(long, default_value_t = default_jobs())]
    threads: usize,
    /// Total PPO iterations (a resumed run continues up to this count).
    #[arg(long, default_value_t = 1000)]
    iterations: usize,
    /// Policy steps per environment and iteration.
    #[arg(long, default_value_t = 24)]
    steps: usize,
    /// Passes over each rollout.
    #[arg(long, default_value_t = 4)]
    epochs: usize,
    /// Minibatches per pass (of whole environment sequences), as rsl_rl.
    #[arg(long, default_value_t = 4)]
    minibatches: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Warm start: an actor with the tensor names of the spec's [policy.network] (its input is
    /// widened with zero columns for the token), e.g. the peer walker
    /// ../shared/peer_policy/unitree_g1_lstm/policy.safetensors for the LSTM spec. Ignored when
    /// resuming.
    #[arg(long)]
    init_actor: Option<PathBuf>,
    /// The critic that goes with --init-actor: its weights, input normaliser and action noise
    /// (kept unless --init-std is given), as every checkpoint writes them beside its actor
    /// (`<actor>.critic.safetensors`), e.g. specs/stairs/g1_stairs_lstm.critic.safetensors. A
    /// fine-tune then needs no --critic-warmup. Ignored when resuming.
    #[arg(long, requires = "init_actor")]
    init_critic: Option<PathBuf>,
    /// Hidden sizes of a fresh actor, one per linear/lstm layer of the spec's network but the
    /// last, e.g. 128,64,64 for specs/stairs/g1_stairs_mlp.toml or 64,32 for the LSTM spec.
    /// Needed without --init-actor on a new run; resuming and warm starts take the weights'.
    #[arg(long, value_delimiter = ',')]
    actor_hidden: Vec<usize>,
    /// Also learn every transition mirrored left–right (the G1's symmetry: twice the data per
    /// simulated step; feed-forward actors only).
    #[arg(long)]
    symmetry: bool,
    /// Initial action noise standard deviation, in units of action_scale (default 0.3; with
    /// --init-critic, the critic file's noise unless this is given).
    #[arg(long)]
    init_std: Option<f64>,
    /// The gait clock's rate output (a spec with [phase] rate): its initial action noise σ on a new
    /// run, in place of the joints' (e.g. 0.3 to try clocks ±30 % off). Ignored when resuming.
    #[arg(long)]
    rate_std: Option<f64>,
    /// Policy steps the rate output's noise is held (and redrawn at each episode start), so a
    /// slower or faster clock lasts long enough to change a step (e.g. 25: 0.5 s at 50 Hz). 1: drawn
    /// every step, as the joints'.
    #[arg(long, default_value_t = 1)]
    rate_hold: usize,
    /// Iterations that train only the critic (after a warm start).
    #[arg(long, default_value_t = 10)]
    critic_warmup: usize,
    /// Starting learning rate (adaptive KL from there).
    #[arg(long, default_value_t = 1e-4)]
    lr: f64,
    #[arg(long, default_value_t = 0.005)]
    entropy_coef: f64,
    /// The largest action noise σ per output, applied after every update (default: no cap). Where
    /// a joint's target saturates at its range, the entropy bonus otherwise inflates its σ unchecked.
    #[arg(long, value_parser = parse_max_std)]
    max_std: Option<f64>,
    /// KL divergence per update that the adaptive learning rate aims at (rsl_rl's 0.01); a smaller
    /// target takes smaller steps, for fine-tuning a policy that already works.
    #[arg(long, default_value_t = 0.01)]
    desired_kl: f64,
    /// Episode length, s (long enough for the longest staircase at the slowest command:
    /// up to 2 m + 8 × 0.4 m + 0.5 m at 0.4 m/s is 14 s).
    #[arg(long, default_value_t = train::ppo::env::EnvSettings::DEFAULT.episode_s)]
    episode_s: f64,
    /// Highest curriculum level environments start at (0: 5 cm steps … 10: 26 cm).
    #[arg(long, default_value_t = train::ppo::env::EnvSettings::DEFAULT.max_init_level)]
    max_init_level: usize,
    /// Forward speed commands, m/s, drawn uniformly per episode: MIN,MAX (runs up to 11 used
    /// 0.4,0.8; below 0.4 such policies stood at the first riser).
    #[arg(long, value_name = "MIN,MAX", default_value = "0.3,0.8", value_parser = parse_vx_range)]
    vx: (f64, f64),
    /// No observation/token noise, latency or pushes (tests).
    #[arg(long)]
    no_randomization: bool,
    /// Train on one terrain column only (default: the curriculum's mix of flat 15 %, stairs
    /// up 30 %, down 30 %, irregular outdoor up and down 12.5 % each).
    #[arg(long, value_enum)]
    only: Option<train::ppo::env::Column>,
    /// Share of flat-ground episodes commanded as a joystick does: a constant (vx, vy ±0.2 m/s,
    /// wz ±0.5 rad/s) without heading hold, so the policy holds its own turn rate (`g1fw sim`
    /// without `--heading`). 0 (default): every episode holds a heading.
    #[arg(long, default_value_t = 0.0, value_name = "SHARE", value_parser = parse_joystick_share)]
    joystick_share: f64,
    /// Where the soft joint-speed penalty starts, as a share of each joint's limit from the
    /// spec (legged_gym's `soft_dof_vel_limit`, 0.9). A smaller share leaves a margin below the
    /// supervisor's trip for the deploy physics, whose 2 ms peaks run higher than training's.
    #[arg(long, default_value_t = train::ppo::env::SOFT_JOINT_SPEED, value_name = "SHARE", value_parser = parse_soft_joint_speed)]
    soft_joint_speed: f32,
    /// End a staircase episode as a failure (the termination penalty, and a demotion) once the
    /// base has gained less than 0.1 m along the staircase in 3 s: `g1fw eval`'s `stalled`. Keeps
    /// the policy from learning to stand at the first riser.
    #[arg(long)]
    end_stalled: bool,
    /// Flat ground's share of environments (0.15 by default); the stair columns split the rest
    /// in their usual ratios. Flat episodes are where the policy learns to follow the command.
    #[arg(long, default_value_t = train::ppo::curriculum::FLAT_SHARE, value_name = "SHARE", value_parser = parse_flat_share)]
    flat_share: f64,
    /// Share of the stair environments that climb (the columns up and outdoor up; 0.5 by
    /// default, the rest go down). Going up is the harder half: raise it to train more climbs.
    #[arg(long, default_value_t = train::ppo::curriculum::UP_SHARE, value_name = "SHARE", value_parser = parse_up_share)]
    up_share: f64,
    /// Standard deviation of the tracking kernels exp(−err² / std²), m/s and rad/s (IsaacLab's
    /// 0.5 by default). A tighter kernel pays more for walking at the commanded speed.
    #[arg(long, default_value_t = train::ppo::reward::TRACKING_STD, value_name = "STD", value_parser = parse_tracking_std)]
    tracking_std: f64,
    /// Forward speed commands of joystick episodes, m/s: MIN,MAX with −1 ≤ MIN ≤ MAX ≤ 2, e.g.
    /// -0.5,1.0 so the policy learns to stop and back up (default: the --vx range).
    #[arg(long, value_name = "MIN,MAX", allow_hyphen_values = true, value_parser = parse_joystick_vx)]
    joystick_vx: Option<(f64, f64)>,
    /// Share of episodes, on every column, commanded to stand (vx 0; IsaacLab's
    /// rel_standing_envs). On a staircase a stand is neither a stall nor a success.
    #[arg(long, default_value_t = train::ppo::env::STAND_SHARE, value_name = "SHARE", value_parser = parse_stand_share)]
    stand_share: f64,
    /// Lowest curriculum level of the climbing columns (0: 5 cm … 10: 26 cm; 4: 13.4 cm): they
    /// start there at least and are never demoted below it, so climbs train at the heights that
    /// fail. 0 (default): no floor.
    #[arg(long, default_value_t = 0, value_name = "LEVEL", value_parser = parse_level)]
    up_level_floor: usize,
    /// Share of staircase episodes that review a level drawn uniformly from the column's floor to
    /// its current level; a review moves no level and is left out of the success rates. Keeps
    /// the heights a column has passed in training. 0 (default): none.
    #[arg(long, default_value_t = 0.0, value_name = "SHARE", value_parser = parse_review_share)]
    review_share: f64,
    /// Weight of the upright penalty ‖g_xy‖² (projected gravity), given as a positive number P
    /// for a weight of −P: IsaacLab's G1 1 (default), mjlab's G1 5.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.flat_orientation), value_name = "P", value_parser = parse_orientation_penalty)]
    orientation_penalty: f64,
    /// Weight of the drift penalty (metres across the line through the start along the target
    /// heading, per second; heading-hold episodes), given as a positive number P for a weight
    /// of −P. 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.drift), value_name = "P", value_parser = parse_drift_penalty)]
    drift_penalty: f64,
    /// Heading-hold episodes also steer back to the line through the start along the target
    /// heading (a staircase's centre line), by `g1fw sim|eval --hold-line`'s rule, from the
    /// simulator's base position.
    #[arg(long)]
    hold_line: bool,
    /// Share of heading-hold staircase episodes whose target heading leaves the staircase's
    /// axis once, by 0.15–0.45 rad for 1–2.5 s during the approach or the flight, and comes back
    /// (`train::ppo::stair_turn`): turn-rate commands where the robot climbs. 0 (default): none.
    #[arg(long, default_value_t = 0.0, value_name = "SHARE", value_parser = parse_stair_turns)]
    stair_turns: f64,
    /// Weight of a squared turn-rate error penalty, (commanded − measured yaw rate)², given as a
    /// positive number P for a weight of −P: unlike the tracking kernel it still pays to make a
    /// large turn-rate error smaller. 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.yaw_rate_error), value_name = "P", value_parser = parse_yaw_error_penalty)]
    yaw_error_penalty: f64,
    /// How far ahead of a swing foot, along its travel, the foot-clearance term looks for
    /// terrain, m. The default, 0.12, reaches the toe only, so a riser counts once the toe is
    /// over it; 0.24 asks for the lift 0.12 m before the toe gets there.
    #[arg(long, default_value_t = train::ppo::reward::CLEARANCE_LOOKAHEAD, value_name = "M", value_parser = parse_clearance_lookahead)]
    clearance_lookahead: f64,
    /// Weight of the riser-clearance penalty, given as a positive number P for a weight of −P:
    /// while a higher tread lies within 0.40 m ahead of a swing foot, the sole is charged for
    /// every metre below that tread's top plus 0.05 m, times its speed, so the lift asked for
    /// grows with the step height. 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.riser_clearance), value_name = "P", value_parser = parse_riser_clearance)]
    riser_clearance: f64,
    /// Weight of the foothold-edge penalty, given as a positive number P for a weight of −P:
    /// every policy step a foot in contact straddles a tread's edge (heel, mid-foot and toe on
    /// terrain more than 0.02 m apart) costs P. 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.foothold_edge), value_name = "P", value_parser = parse_foothold_edge)]
    foothold_edge: f64,
    /// Weight of the token-clearance penalty, given as a positive number P for a weight of −P:
    /// while the policy's terrain token reads up, a swing foot is charged for every metre its
    /// sole is below the token's step height plus 0.05 m over the terrain under it, times its
    /// speed, the approach included (the policy sees the token, not the distance to the
    /// riser). 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.token_clearance), value_name = "P", value_parser = parse_token_clearance)]
    token_clearance: f64,
    /// Weight of the swing-apex penalty, given as a positive number P for a weight of −P: while
    /// the policy's terrain token reads up, each swing is charged at touchdown P per metre its
    /// highest sole clearance stayed below the token's step height plus 0.05 m. Unlike
    /// --token-clearance, a slow shuffle pays for every short step. 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.swing_apex), value_name = "P", value_parser = parse_swing_apex)]
    swing_apex: f64,
    /// Weight of the swing-advance penalty, given as a positive number P for a weight of −P:
    /// while the policy's terrain token reads up (and the command is not a stand), each swing is
    /// charged at touchdown P per metre it carried the foot less than one tread (the token's
    /// depth, at most 0.25 m) forward along the heading. Walking pays nothing; shuffling and
    /// marking time at a riser pay for every short step. 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.swing_advance), value_name = "P", value_parser = parse_swing_advance)]
    swing_advance: f64,
    /// Weight of the swing-overshoot penalty, given as a positive number P for a weight of −P:
    /// while the policy's terrain token reads up, each swing is charged at touchdown P per metre
    /// its highest sole clearance rose past the token's step height plus 0.15 m (0.10 m above what
    /// --swing-apex asks). The lift terms charge only low swings; this caps the kicks that
    /// overshoot. 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.swing_overshoot), value_name = "P", value_parser = parse_swing_overshoot)]
    swing_overshoot: f64,
    /// Weight of the base-height penalty, given as a positive number P for a weight of −P: while
    /// the policy's terrain token reads up, P per second per metre the base sits lower than 0.70 m
    /// over the mean of the ground heights under the two feet (a body left behind its feet on the
    /// treads). 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.base_height), value_name = "P", value_parser = parse_base_height)]
    base_height: f64,
    /// Weight of the up-lean penalty, given as a positive number P for a weight of −P: while the
    /// policy's terrain token reads up, P per second per radian the base is pitched less than
    /// 0.10 rad forward (a body leaning back on an up flight). 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.up_lean), value_name = "P", value_parser = parse_up_lean)]
    up_lean: f64,
    /// Weight of the stance-lead penalty, given as a positive number P for a weight of −P: while
    /// the policy's terrain token reads up and one foot stands alone, P per second per metre that
    /// foot lies more than 0.05 m ahead of the base (a trailing foot lifted before the body came
    /// over the leading one). 0 (default): off.
    #[arg(long, default_value_t = penalty_size(train::ppo::reward::WEIGHTS.stance_lead), value_name = "P", value_parser = parse_stance_lead)]
    stance_lead: f64,
    /// Share of the climbing columns' episodes that are assisted: a helping hand on the base
    /// (a quarter of the weight carried, the torso held upright and its spin damped, a sinking base
    /// lifted, a pull along the staircase up to the commanded speed) that decays to nothing over
    /// --assist-decay env steps, on staircases drawn from --assist-levels. They move no curriculum
    /// level and have their own success rate. For climbs the policy cannot yet do alone
    /// (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-12-02). 0 (default): off.
    #[arg(long, default_value_t = 0.0, value_name = "SHARE", value_parser = parse_assist_share)]
    assist_share: f64,
    /// Curriculum levels of the assisted episodes' staircases, LO,HI (0: 5 cm … 10: 26 cm; 6,8:
    /// 17.6–22 cm).
    #[arg(long, default_value = "6,8", value_name = "LO,HI", value_parser = parse_assist_levels)]
    assist_levels: (usize, usize),
    /// Env steps of the run over which the assistant's strength falls linearly from full to
    /// nothing (counted from the run's start, across resumes).
    #[arg(long, default_value_t = 15e6, value_name = "STEPS", value_parser = parse_assist_decay)]
    assist_decay: f64,
    /// Checkpoint every this many iterations. Every checkpoint restarts every environment (so
    /// that a resumed run is bit for bit the run that went on; docs/stair_policy.md), so it is
    /// part of the recipe.
    #[arg(long, default_value_t = 100, value_name = "ITERATIONS")]
    checkpoint_every: usize,
    /// Stop at the first checkpoint after this run has spent this many seconds.
    #[arg(long, default_value_t = f64::INFINITY)]
    max_wall: f64,
    /// Judge every Nth checkpoint through g1fw (up and down at 12, 16 and 20 cm, 2 episodes
    /// each, and a flat run, with perception and the spec's terrain estimator; ~1 min):
    /// judge.json, best.safetensors and the points in curves.png. 0: never.
    #[arg(long, default_value_t = 5)]
    judge_every: usize,
    /// The deployed policy (a spec, run with its own weights), judged once on the same set
    /// (reference.json): the level line in curves.png that a run must pass. `none`: no line.
    #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml", value_name = "SPEC")]
    judge_reference: String,
    #[arg(long)]
    quiet: bool,
}

impl Args {
    /// The environment settings these options give (`EnvSettings::DEFAULT` when none is set).
    fn env_settings(&self) -> train::ppo::env::EnvSettings {
        train::ppo::env::EnvSettings {
            episode_s: self.episode_s,
            random: if self.no_randomization {
                train::ppo::env::Randomization::NONE
            } else {
                train::ppo::env::Randomization::DEFAULT
            },
            max_init_level: self.max_init_level,
            vx: self.vx,
            only: self.only,
            joystick_share: self.joystick_share,
            soft_joint_speed: self.soft_joint_speed,
            end_stalled: self.end_stalled,
            mix: train::ppo::curriculum::ColumnMix {
                flat: self.flat_share,
                up: self.up_share,
            },
            tracking_std: self.tracking_std,
            joystick_vx: self.joystick_vx,
            stand_share: self.stand_share,
            up_level_floor: self.up_level_floor,
            review_share: self.review_share,
            flat_orientation_weight: -self.orientation_penalty,
            drift_weight: -self.drift_penalty,
            hold_line: self.hold_line,
            stair_turn_share: self.stair_turns,
            yaw_error_weight: -self.yaw_error_penalty,
            clearance_lookahead: self.clearance_lookahead,
            riser_clearance_weight: -self.riser_clearance,
            foothold_edge_weight: -self.foothold_edge,
            token_clearance_weight: -self.token_clearance,
            swing_apex_weight: -self.swing_apex,
            swing_advance_weight: -self.swing_advance,
            swing_overshoot_weight: -self.swing_overshoot,
            base_height_weight: -self.base_height,
            up_lean_weight: -self.up_lean,
            stance_lead_weight: -self.stance_lead,
            assist: train::ppo::assist::Assist {
                share: self.assist_share,
                levels: self.assist_levels,
                decay_steps: self.assist_decay as u64,
            },
        }
    }
}

/// `args`: the options as given after `ppo` (recipe expanded), for the run's recipe.toml.
pub fn run(args: Args, argv: &[std::ffi::OsString]) -> anyhow::Result<()> {
    let env = args.env_settings();
    let Args {
        spec,
        model,
        mix_model,
        out,
        envs,
        threads,
        iterations,
        steps,
        epochs,
        minibatches,
        seed,
        init_actor,
        init_critic,
        actor_hidden,
        symmetry,
        init_std,
        rate_std,
        rate_hold,
        critic_warmup,
        lr,
        entropy_coef,
        max_std,
        desired_kl,
        checkpoint_every,
        max_wall,
        judge_every,
        quiet,
        accept_recipe_change,
        judge_reference,
        ..
    } = args;
    let out = out.ok_or_else(|| anyhow::anyhow!("give --out DIR (a new run) or --resume DIR"))?;
    let episode_s = env.episode_s;
    tracing_subscriber::fmt().with_writer(std::io::stderr).init();
    // Counts that size allocations are bounded before anything is built: each environment
    // holds its own MuJoCo model (~80 MB), each rollout steps × envs rows.
    let bounded = |flag: &str, v: usize, lo: usize, hi: usize| -> anyhow::Result<()> {
        anyhow::ensure!((lo..=hi).contains(&v), "{flag} must be {lo} to {hi} (got {v})");
        Ok(())
    };
    bounded("--envs", envs, 2, 4096)?;
    bounded("--threads", threads, 1, 256)?;
    bounded("--steps", steps, 1, 10_000)?;
    bounded("--epochs", epochs, 1, 100)?;
    bounded("--minibatches", minibatches, 1, envs)?;
    bounded("--rate-hold", rate_hold, 1, 10_000)?;
    bounded("--iterations", iterations, 1, usize::MAX)?;
    bounded("--checkpoint-every", checkpoint_every, 1, usize::MAX)?;
    bounded(
        "--max-init-level",
        env.max_init_level,
        0,
        train::ppo::curriculum::LEVELS - 1,
    )?;
    anyhow::ensure!(
        entropy_coef.is_finite() && (0.0..=1.0).contains(&entropy_coef),
        "--entropy-coef {entropy_coef}: give a number in [0, 1] (rsl_rl's G1 recipes: 0.005–0.01)"
    );
    anyhow::ensure!(
        max_wall > 0.0,
        "--max-wall {max_wall}: give seconds > 0 (the run stops at the first checkpoint after them)"
    );
    anyhow::ensure!(
        lr.is_finite()
            && lr > 0.0
            && init_std.is_none_or(|s| s.is_finite() && s > 0.0)
            && rate_std.is_none_or(|s| s.is_finite() && s > 0.0)
            && episode_s.is_finite()
            && episode_s > 0.0
            && desired_kl.is_finite()
            && desired_kl > 0.0,
        "--lr, --init-std, --rate-std, --episode-s and --desired-kl must be positive numbers"
    );
    if judge_every > 0 {
        // The judge runs g1fw's eval, each episode with its own g1-sim: find it now, not at the
        // first judged checkpoint minutes into the run (a trainer copied away from target/ once
        // trained 27 min unjudged).
        sim_hal::bridge::find_sim_bin(None).map_err(|e| {
            anyhow::anyhow!("--judge-every {judge_every}: {e}; or pass --judge-every 0 to train unjudged")
        })?;
    }
    let judge_model = model.to_string();
    // The judge runs on every model the run trains.
    let judge_also: Vec<String> = mix_model.iter().map(|(m, _)| m.to_string()).collect();
    // The run directory may hold nothing the run reads: `--out specs/stairs` would overwrite the
    // committed actor and critic it started from.
    let deploy = control::spec::DeploySpec::load(&spec)?;
    crate::outputs::refuse_clashes(
        &[("--out", Some(&out), crate::outputs::Kind::Dir)],
        &[
            ("--spec", Some(&spec)),
            ("--init-actor", init_actor.as_deref()),
            ("--init-critic", init_critic.as_deref()),
        ],
        Some(&deploy),
    )?;
    // A new run states its recipe; a resumed one keeps the one it was started with.
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let recipe = out.join(crate::recipe::RECIPE);
    if !out.join(train::ppo::runner::CHECKPOINT).exists() || !recipe.exists() {
        train::ppo::runner::write_atomically(&recipe, crate::recipe::text(argv)?.as_bytes())?;
    }
    let cfg = train::ppo::runner::RunConfig {
        spec,
        model,
        mixed_model: mix_model,
        out: out.clone(),
        envs,
        threads,
        iterations,
        seed,
        init_actor,
        init_critic,
        actor_hidden,
        symmetry,
        init_std,
        rate_noise: train::ppo::runner::RateNoise {
            std: rate_std,
            hold: rate_hold,
        },
        critic_warmup,
        ppo: train::ppo::algo::PpoConfig {
            steps,
            epochs,
            minibatches,
            lr,
            entropy_coef,
            desired_kl,
            max_std,
            ..Default::default()
        },
        env,
        checkpoint_every,
        quiet,
        max_wall_s: max_wall,
        accept_recipe_change,
        judge: train::ppo::judge::JudgeConfig {
            also_models: judge_also,
            reference: (judge_reference != "none").then(|| PathBuf::from(&judge_reference)),
            ..train::ppo::judge::JudgeConfig::standard(judge_every, &judge_model)
        },
    };
    let history = train::ppo::runner::train(&cfg)?;
    if let Some(l) = history.last() {
        println!(
            "iteration {}: {} env steps in {:.0} s ({:.0} steps/s, learner {:.0} % of wall time); \
                 reward/step {:+.3}, level {:.2}; curves in {}",
            l.iteration,
            l.env_steps,
            l.wall_s,
            l.env_steps_per_s,
            100.0 * l.learner_share,
            l.mean_reward_per_step,
            l.mean_level,
            out.join(train::ppo::runner::CURVES).display()
        );
    }
    Ok(())
}

/// `--vx MIN,MAX`: a forward speed range, m/s.
fn parse_vx_range(s: &str) -> Result<(f64, f64), String> {
    parse_speed_range(s, 0.0, "0.3,0.8")
}

/// `--joystick-vx MIN,MAX`: a forward speed range of joystick episodes, m/s, backwards allowed.
fn parse_joystick_vx(s: &str) -> Result<(f64, f64), String> {
    parse_speed_range(s, -1.0, "-0.5,1.0")
}

/// `MIN,MAX` in m/s with `lowest <= MIN <= MAX <= 2`.
fn parse_speed_range(s: &str, lowest: f64, example: &str) -> Result<(f64, f64), String> {
    let bad = || format!("'{s}': give MIN,MAX in m/s with {lowest} <= MIN <= MAX <= 2, e.g. {example}");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let (a, b): (f64, f64) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if !(lowest..=2.0).contains(&a) || !(a..=2.0).contains(&b) {
        return Err(bad());
    }
    Ok((a, b))
}

/// `--soft-joint-speed SHARE`: a share of the joint-speed limit in (0, 1].
fn parse_soft_joint_speed(s: &str) -> Result<f32, String> {
    let want = "a share of each joint's speed limit in (0, 1], e.g. 0.8";
    parse_number(s, |v| v > 0.0 && v <= 1.0, want).map(|v| v as f32)
}

/// `--joystick-share SHARE`: a share of flat-ground episodes in [0, 1].
fn parse_joystick_share(s: &str) -> Result<f64, String> {
    let want = "the joystick episodes' share of flat ground in [0, 1], e.g. 0.7";
    parse_number(s, |v| (0.0..=1.0).contains(&v), want)
}

/// `--flat-share SHARE`: flat ground's share of environments, in [0, 1).
fn parse_flat_share(s: &str) -> Result<f64, String> {
    let want = "flat ground's share of environments in [0, 1), e.g. 0.3";
    parse_number(s, |v| (0.0..1.0).contains(&v), want)
}

/// `--up-share SHARE`: the climbing share of the stair environments, in (0, 1).
fn parse_up_share(s: &str) -> Result<f64, String> {
    let want = "the climbing share of the stair environments in (0, 1), e.g. 0.65";
    parse_number(s, |v| v > 0.0 && v < 1.0, want)
}

/// `--tracking-std STD`: the tracking kernels' standard deviation, in (0, 2].
fn parse_max_std(s: &str) -> Result<f64, String> {
    let want = "the largest action noise σ in (0, 10], e.g. 1.0 (the usual starting σ)";
    parse_number(s, |v| v > 0.0 && v <= 10.0, want)
}

fn parse_tracking_std(s: &str) -> Result<f64, String> {
    let want = "the tracking kernels' standard deviation in (0, 2] m/s, e.g. 0.35";
    parse_number(s, |v| v > 0.0 && v <= 2.0, want)
}

/// One number that `accept` takes (NaN never passes a comparison); otherwise an error that says
/// what to give.
fn parse_stand_share(s: &str) -> Result<f64, String> {
    parse_number(
        s,
        |v| (0.0..0.5).contains(&v),
        "the share of episodes told to stand, in [0, 0.5), e.g. 0.1",
    )
}

fn parse_review_share(s: &str) -> Result<f64, String> {
    parse_number(
        s,
        |v| (0.0..1.0).contains(&v),
        "the share of staircase episodes that review lower levels, in [0, 1), e.g. 0.3",
    )
}

fn parse_orientation_penalty(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "upright", "5")
}

fn parse_stair_turns(s: &str) -> Result<f64, String> {
    parse_number(
        s,
        |v| (0.0..=1.0).contains(&v),
        "the share of staircase episodes with a commanded turn in [0, 1], e.g. 0.5",
    )
}

fn parse_yaw_error_penalty(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "turn-rate error", "1")
}

fn parse_clearance_lookahead(s: &str) -> Result<f64, String> {
    parse_number(
        s,
        |v| (0.0..=0.5).contains(&v),
        "the clearance look-ahead in m within [0, 0.5], e.g. 0.24",
    )
}

/// The size P that a penalty's option takes for the reward weight −P. `0.0 - w`, not `-w`: an
/// off term (w = 0) reads "0" in `--help`, not "-0".
const fn penalty_size(weight: f64) -> f64 {
    0.0 - weight
}

fn parse_riser_clearance(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "riser-clearance", "10")
}

fn parse_foothold_edge(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "foothold-edge", "1")
}

fn parse_token_clearance(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "token-clearance", "5")
}

fn parse_swing_apex(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "swing-apex", "3")
}

fn parse_swing_advance(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "swing-advance", "2")
}

fn parse_swing_overshoot(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "swing-overshoot", "2")
}

fn parse_base_height(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "base-height", "5")
}

fn parse_up_lean(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "up-lean", "4")
}

fn parse_stance_lead(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "stance-lead", "5")
}

fn parse_assist_share(s: &str) -> Result<f64, String> {
    parse_number(
        s,
        |v| (0.0..=1.0).contains(&v),
        "the share of climbing episodes that are assisted, in [0, 1], e.g. 0.5",
    )
}

fn parse_assist_decay(s: &str) -> Result<f64, String> {
    parse_number(
        s,
        |v| (1.0..=1e10).contains(&v),
        "the env steps over which the assistant fades, from 1 to 1e10, e.g. 15e6",
    )
}

/// `--assist-levels LO,HI`: curriculum levels with LO <= HI.
fn parse_assist_levels(s: &str) -> Result<(usize, usize), String> {
    let top = train::ppo::curriculum::LEVELS - 1;
    let bad = || format!("'{s}': give LO,HI curriculum levels with 0 <= LO <= HI <= {top}, e.g. 6,8");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let (a, b) = (parse_level(a).map_err(|_| bad())?, parse_level(b).map_err(|_| bad())?);
    if a > b {
        return Err(bad());
    }
    Ok((a, b))
}

fn parse_drift_penalty(s: &str) -> Result<f64, String> {
    parse_penalty_size(s, "drift", "2")
}

/// `--up-level-floor LEVEL`: a curriculum level, 0 … 10.
fn parse_level(s: &str) -> Result<usize, String> {
    let top = train::ppo::curriculum::LEVELS - 1;
    match s.trim().parse::<usize>() {
        Ok(v) if v <= top => Ok(v),
        _ => Err(format!(
            "'{s}': give a curriculum level from 0 (5 cm steps) to {top} (26 cm), e.g. 4"
        )),
    }
}

fn parse_mixed_model(s: &str) -> Result<(g1_sim::ModelChoice, f64), String> {
    let want = "MODEL:SHARE with a share in (0, 1), e.g. g1-29dof:0.5";
    let (model, share) = s.rsplit_once(':').ok_or_else(|| format!("'{s}': give {want}"))?;
    let Ok(model) = model.parse::<g1_sim::ModelChoice>();
    Ok((model, parse_number(share, |v| v > 0.0 && v < 1.0, want)?))
}

/// A penalty's size P (the weight is −P), within [0, 50]; `what` names the penalty in the error.
fn parse_penalty_size(s: &str, what: &str, example: &str) -> Result<f64, String> {
    parse_number(
        s,
        |v| (0.0..=50.0).contains(&v),
        &format!("the {what} penalty's size in [0, 50] (the weight is minus it), e.g. {example}"),
    )
}

fn parse_number(s: &str, accept: impl Fn(f64) -> bool, want: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if accept(v) => Ok(v),
        _ => Err(format!("'{s}': give {want}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    #[test]
    fn penalty_defaults_read_as_plain_numbers_in_help() {
        use clap::CommandFactory;
        let help = Cli::command().render_long_help().to_string();
        assert!(help.contains("--riser-clearance"), "{help}");
        assert!(!help.contains("[default: -0]"), "an off penalty shows as -0:\n{help}");
        assert_eq!(penalty_size(-1.0), 1.0);
        assert!(penalty_size(0.0).is_sign_positive());
    }

    #[test]
    fn options_left_unset_give_the_library_defaults_and_each_option_reaches_its_setting() {
        let parse = |extra: &[&str]| {
            let argv = [&["g1-train", "--out", "run"][..], extra].concat();
            Cli::try_parse_from(argv).expect("parses").args.env_settings()
        };
        assert_eq!(parse(&[]), train::ppo::env::EnvSettings::DEFAULT);
        let set = parse(&[
            "--episode-s",
            "9",
            "--max-init-level",
            "4",
            "--vx",
            "0.4,0.6",
            "--no-randomization",
            "--only",
            "up",
            "--joystick-share",
            "0.7",
            "--soft-joint-speed",
            "0.8",
            "--end-stalled",
            "--flat-share",
            "0.3",
            "--up-share",
            "0.65",
            "--tracking-std",
            "0.35",
            "--joystick-vx",
            "-0.5,1.0",
            "--stand-share",
            "0.1",
            "--up-level-floor",
            "4",
            "--review-share",
            "0.3",
            "--orientation-penalty",
            "5",
            "--drift-penalty",
            "2",
            "--hold-line",
            "--stair-turns",
            "0.5",
            "--yaw-error-penalty",
            "1",
            "--clearance-lookahead",
            "0.24",
            "--riser-clearance",
            "10",
            "--foothold-edge",
            "2",
            "--token-clearance",
            "5",
            "--swing-apex",
            "3",
            "--swing-advance",
            "2",
            "--swing-overshoot",
            "4",
            "--base-height",
            "5",
            "--up-lean",
            "4",
            "--stance-lead",
            "5",
            "--assist-share",
            "0.5",
            "--assist-levels",
            "5,7",
            "--assist-decay",
            "12e6",
        ]);
        let want = train::ppo::env::EnvSettings {
            episode_s: 9.0,
            random: train::ppo::env::Randomization::NONE,
            max_init_level: 4,
            vx: (0.4, 0.6),
            only: Some(train::ppo::env::Column::Up),
            joystick_share: 0.7,
            soft_joint_speed: 0.8,
            end_stalled: true,
            mix: train::ppo::curriculum::ColumnMix { flat: 0.3, up: 0.65 },
            tracking_std: 0.35,
            joystick_vx: Some((-0.5, 1.0)),
            stand_share: 0.1,
            up_level_floor: 4,
            review_share: 0.3,
            flat_orientation_weight: -5.0,
            drift_weight: -2.0,
            hold_line: true,
            stair_turn_share: 0.5,
            yaw_error_weight: -1.0,
            clearance_lookahead: 0.24,
            riser_clearance_weight: -10.0,
            foothold_edge_weight: -2.0,
            token_clearance_weight: -5.0,
            swing_apex_weight: -3.0,
            swing_advance_weight: -2.0,
            swing_overshoot_weight: -4.0,
            base_height_weight: -5.0,
            up_lean_weight: -4.0,
            stance_lead_weight: -5.0,
            assist: train::ppo::assist::Assist {
                share: 0.5,
                levels: (5, 7),
                decay_steps: 12_000_000,
            },
        };
        assert_eq!(set, want);
    }

    #[test]
    fn soft_joint_speed_share_must_lie_in_zero_to_one() {
        assert_eq!(parse_soft_joint_speed("0.8"), Ok(0.8));
        assert_eq!(parse_soft_joint_speed("1"), Ok(1.0));
        for bad in ["0", "-0.5", "1.2", "NaN", "fast"] {
            let e = parse_soft_joint_speed(bad).unwrap_err();
            assert!(e.contains("(0, 1]"), "{bad}: {e}");
        }
    }

    #[test]
    fn shares_std_and_speed_ranges_refuse_values_outside_their_ranges() {
        assert_eq!(parse_flat_share("0.3"), Ok(0.3));
        assert_eq!(parse_flat_share("0"), Ok(0.0));
        for bad in ["1", "-0.1", "NaN", "most"] {
            assert!(parse_flat_share(bad).unwrap_err().contains("[0, 1)"), "{bad}");
        }
        assert_eq!(parse_tracking_std("0.35"), Ok(0.35));
        for bad in ["0", "-0.5", "3", "NaN", "tight"] {
            assert!(parse_tracking_std(bad).unwrap_err().contains("(0, 2]"), "{bad}");
        }
        assert_eq!(parse_up_share("0.65"), Ok(0.65));
        for bad in ["0", "1", "-0.2", "NaN", "more"] {
            assert!(parse_up_share(bad).unwrap_err().contains("(0, 1)"), "{bad}");
        }
        assert_eq!(parse_joystick_share("0"), Ok(0.0));
        assert_eq!(parse_joystick_share("1"), Ok(1.0));
        for bad in ["1.1", "-0.1", "NaN", "half"] {
            assert!(parse_joystick_share(bad).unwrap_err().contains("[0, 1]"), "{bad}");
        }
        assert_eq!(parse_joystick_vx("-0.5,1.0"), Ok((-0.5, 1.0)));
        for bad in ["-1.5,0", "0.5,0.2", "0,3", "0.5", "a,b"] {
            assert!(parse_joystick_vx(bad).unwrap_err().contains("-1 <= MIN"), "{bad}");
        }
        assert_eq!(parse_level("4"), Ok(4));
        for bad in ["11", "-1", "4.5", "high"] {
            assert!(parse_level(bad).unwrap_err().contains("curriculum level"), "{bad}");
        }
        assert_eq!(parse_orientation_penalty("5"), Ok(5.0));
        assert_eq!(parse_orientation_penalty("0"), Ok(0.0));
        for bad in ["-1", "60", "NaN", "upright"] {
            assert!(parse_orientation_penalty(bad).unwrap_err().contains("[0, 50]"), "{bad}");
        }
        assert_eq!(parse_drift_penalty("2"), Ok(2.0));
        assert_eq!(parse_stair_turns("0.5"), Ok(0.5));
        assert_eq!(parse_yaw_error_penalty("1"), Ok(1.0));
        assert_eq!(parse_clearance_lookahead("0.24"), Ok(0.24));
        assert_eq!(parse_riser_clearance("10"), Ok(10.0));
        assert_eq!(parse_foothold_edge("1.5"), Ok(1.5));
        assert_eq!(parse_token_clearance("5"), Ok(5.0));
        assert!(parse_token_clearance("-5").unwrap_err().contains("[0, 50]"));
        assert_eq!(parse_swing_apex("3"), Ok(3.0));
        assert!(parse_swing_apex("51").unwrap_err().contains("[0, 50]"));
        assert_eq!(parse_swing_advance("2"), Ok(2.0));
        assert!(parse_swing_advance("-2").unwrap_err().contains("[0, 50]"));
        assert_eq!(parse_swing_overshoot("4"), Ok(4.0));
        assert!(parse_swing_overshoot("nan").is_err());
        assert_eq!(parse_base_height("5"), Ok(5.0));
        assert_eq!(parse_up_lean("4"), Ok(4.0));
        assert!(parse_up_lean("-4").unwrap_err().contains("[0, 50]"));
        assert_eq!(parse_stance_lead("5"), Ok(5.0));
        assert!(parse_stance_lead("NaN").is_err());
        assert_eq!(parse_assist_share("0.5"), Ok(0.5));
        for bad in ["-0.1", "1.5", "NaN", "some"] {
            assert!(parse_assist_share(bad).unwrap_err().contains("[0, 1]"), "{bad}");
        }
        assert_eq!(parse_assist_levels("6,8"), Ok((6, 8)));
        for bad in ["8,6", "6", "6,11", "a,b"] {
            assert!(parse_assist_levels(bad).unwrap_err().contains("LO,HI"), "{bad}");
        }
        assert_eq!(parse_assist_decay("15e6"), Ok(15e6));
        assert!(parse_assist_decay("0").is_err() && parse_assist_decay("NaN").is_err());
        for bad in ["-1", "60", "NaN", "high"] {
            assert!(parse_riser_clearance(bad).unwrap_err().contains("[0, 50]"), "{bad}");
        }
        for bad in ["-0.1", "0.6", "NaN", "far"] {
            assert!(
                parse_clearance_lookahead(bad).unwrap_err().contains("[0, 0.5]"),
                "{bad}"
            );
        }
        for bad in ["-1", "60", "NaN", "strong"] {
            assert!(parse_yaw_error_penalty(bad).unwrap_err().contains("[0, 50]"), "{bad}");
        }
        for bad in ["-0.1", "1.5", "NaN", "some"] {
            assert!(parse_stair_turns(bad).unwrap_err().contains("[0, 1]"), "{bad}");
        }
        for bad in ["-1", "60", "NaN", "sideways"] {
            assert!(parse_drift_penalty(bad).unwrap_err().contains("[0, 50]"), "{bad}");
        }
        assert_eq!(parse_stand_share("0.1"), Ok(0.1));
        for bad in ["0.5", "-0.1", "NaN", "some"] {
            assert!(parse_stand_share(bad).unwrap_err().contains("[0, 0.5)"), "{bad}");
        }
        assert_eq!(
            parse_mixed_model("g1-29dof:0.5"),
            Ok((g1_sim::ModelChoice::G1_29Dof, 0.5))
        );
        for bad in ["g1-29dof", "g1-29dof:0", "g1-29dof:1", "g1-29dof:half"] {
            assert!(parse_mixed_model(bad).unwrap_err().contains("MODEL:SHARE"), "{bad}");
        }
        assert_eq!(parse_vx_range("0.4,0.8"), Ok((0.4, 0.8)));
        assert!(parse_vx_range("-0.5,1.0").unwrap_err().contains("0 <= MIN"));
    }
}
