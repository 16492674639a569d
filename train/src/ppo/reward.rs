//! Every reward term of the stair policy and its weight, in one place.
//!
//! IsaacLab's rough-terrain G1 velocity reward (the paper's choice; `velocity_env_cfg.py` +
//! `config/g1/rough_env_cfg.py`), plus two terms stairs need (mjlab's terrain-relative foot
//! clearance and legged_gym's stumble penalty) and one for shins/knees hitting a riser. As in
//! IsaacLab's reward manager, each term is `weight · value · dt` with dt = 0.02 s (one policy step),
//! so the sum over a 20 s episode is comparable across step rates.
//!
//! | term | value (per policy step) | weight |
//! |---|---|---|
//! | `track_lin_vel_xy` | exp(−‖v_cmd,xy − v_xy‖² / σ²), v in the yaw frame, σ = 0.5 unless `--tracking-std` sets it | +1.0 |
//! | `track_ang_vel_z` | exp(−(ω_cmd,z − ω_z)² / σ²) | +2.0 |
//! | `feet_air_time` | biped: min(time in the current mode of the single stance foot, 0.4 s), if ‖cmd‖ > 0.1 | +0.25 |
//! | `feet_slide` | Σ feet in contact ‖v_foot,xy‖ | −0.1 |
//! | `flat_orientation` | ‖g_xy‖² (projected gravity) | −1.0 |
//! | `ang_vel_xy` | ‖ω_xy‖² | −0.05 |
//! | `action_rate` | ‖a_t − a_{t−1}‖² | −0.005 |
//! | `torques` | Σ τ² (legs) | −1.5e-7 |
//! | `joint_acc` | Σ q̈² (finite difference over the policy step) | −1.25e-7 |
//! | `joint_deviation` | Σ \|q − q_default\| over hip yaw and hip roll | −0.1 |
//! | `joint_speed` | Σ max(\|q̇\| − s × the joint's limit, 0)² with s = 0.9 unless `--soft-joint-speed` sets it, \|q̇\| the fastest over the policy step's physics steps (legged_gym's `soft_dof_vel_limit`; limits from the spec, as the supervisor's) | −1.0 |
//! | `ankle_limits` | Σ ankle joint excursion past 90 % of its range, rad | −1.0 |
//! | `foot_clearance` | Σ swing feet max(0.10 m − clearance, 0) · min(‖v_foot,xy‖, 1 m/s); clearance from the highest terrain under the foot and along its travel up to 0.12 m ahead (the toe; `--clearance-lookahead` sets it) | −10 |
//! | `riser_clearance` | Σ swing feet max(top of the next higher tread within 0.40 m ahead of the foot along its travel + 0.05 m − sole height, 0) · min(‖v_foot,xy‖, 1 m/s); only while a higher tread lies ahead (up flights) | 0 unless `--riser-clearance` sets it |
//! | `token_clearance` | Σ swing feet max(the token's step height + 0.05 m − (sole height − terrain under the foot), 0) · min(‖v_foot,xy‖, 1 m/s), while the policy's own token (as observed, noise and all) reads up | 0 unless `--token-clearance` sets it |
//! | `swing_apex` | at each touchdown while the token reads up: max(the token's step height + 0.05 m − the ended swing's highest sole clearance over the ground under the foot, 0) / dt, so P costs P per metre of deficit per swing | 0 unless `--swing-apex` sets it |
//! | `swing_advance` | at each touchdown while the token reads up and the command is not a stand: max(min(the token's step depth, 0.25 m) − the ended swing's advance along the base's heading, 0) / dt, so P costs P per metre of shortfall per swing | 0 unless `--swing-advance` sets it |
//! | `swing_overshoot` | at each touchdown while the token reads up: max(the ended swing's highest sole clearance over the ground under the foot − (the token's step height + 0.05 m + 0.10 m), 0) / dt, so P costs P per metre a swing rose more than 0.10 m above what `swing_apex` asks for | 0 unless `--swing-overshoot` sets it |
//! | `base_height` | while the token reads up: max(0.70 m − (base height − the mean of the ground heights under the two feet), 0), m | 0 unless `--base-height` sets it |
//! | `up_lean` | while the token reads up: max(0.10 rad − the base's pitch (nose down positive, from the projected gravity), 0), rad | 0 unless `--up-lean` sets it |
//! | `stance_lead` | while the token reads up and one foot stands alone: max(how far that foot's origin lies ahead of the base along the base's heading − 0.05 m, 0), m | 0 unless `--stance-lead` sets it |
//! | `foothold_edge` | Σ feet in contact whose sole straddles a tread's edge: the terrain under its heel (0.05 m behind the foot origin), origin, mid-foot and toe (0.12 m ahead), along the base's heading, spans more than 0.02 m | 0 unless `--foothold-edge` sets it |
//! | `stumble` | feet touching a near-vertical surface (contact normal \|n_z\| < 0.5: a riser) | −1.0 |
//! | `body_contact` | any robot geom other than a foot touching the terrain, and the legs touching each other | −1.0 |
//! | `termination` | 1 on a fall, a base below 0.4 m, or a supervisor limit (tilt, joint speed, base angular speed per axis) at any physics step, as `g1fw` checks every 2 ms tick, or with `--end-stalled` a stall on a staircase (< 0.1 m in 3 s, `g1fw eval`'s; not on time-out or success) | −200 |
//! | `progress` | speed along the target heading, clamped to 0 … the commanded forward speed, m/s | +2.0 |
//! | `drift` | \|distance of the base across the target heading's line through the start\|, m, capped at 1 m; heading-hold episodes only (a joystick episode has no line) | 0 unless `--drift-penalty` sets it |
//! | `yaw_rate_error` | (ω_cmd,z − ω_z)², rad²/s², every episode | 0 unless `--yaw-error-penalty` sets it |
//! | `success` | 1 / dt on the step the base has stood on the end landing for `LANDING_HOLD_S` (1 s) without a fall: `g1fw eval`'s success (a one-off +3) | +3 |
//!
//! Why `foot_clearance` differs from mjlab's (−2 · (clearance − 0.1)² · speed): in metres squared
//! a 6 cm deficit cost 0.0001 per step against ~0.06 for tracking, nothing the policy noticed, and
//! toes caught on risers (the joint-speed guard's trips); the linear deficit costs ~0.012.
//!
//! Why `success`: with only the tracking kernels, standing at the first riser still earns ~80 % of
//! walking's reward per step, while a fall costs 200 · dt = 4, so the policy learned to stop at
//! the riser and time out (run 5: success 0–25 % at 5 cm steps after 7 M steps, most stair episodes
//! ending by time-out). The bonus pays for the attempt.
//!
//! Why `progress`, and a bonus of 3, not 10: with γ = 0.99 at 50 Hz a one-off bonus is worth
//! 10 · 0.99^(50 T) when T s away, so in the last 2–3 s before the landing hurrying gained more
//! than tracking lost, and the run-8 policies climbed at 1.0–1.4 m/s when asked for 0.5
//! (`g1-train ppo-eval`), falling on the risers. Speed along the heading, capped at the command,
//! pays for the attempt at every step instead and never for going faster than asked. A fall that
//! carries the base past the landing earned the bonus and a promotion before; now it earns neither.
//! And the bonus waits until the base has stood on the landing for 1 s, as `g1fw eval` scores a
//! climb: paid on crossing a line, it taught run 14 to dive across the line and fall just after.
//!
//! Why `drift`: heading hold turns the robot back to the staircase axis but nothing brought it back
//! to the line, and a drift across the axis cost nothing until the base left the staircase. A
//! quarter of the committed actor's failed climbs up 12–22 cm through `g1fw eval` ended off the
//! side of the staircase (12-dof 99 of 372, 29-dof 66 of 179), and successes drifted 0.29 m (median
//! of the largest offset) on stairs 1.2–2.0 m wide. The policy cannot see the offset, and run 39
//! (P = 2 from the committed actor) drifted more and climbed worse
//! (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-11-30): off by default.
//!
//! Why `yaw_rate_error`: on a flight the robot turns in bursts of 0.7–1.6 rad/s (a foot meeting
//! a riser pivots the base) against heading hold's ±0.1, and these end climbs off the side of the
//! staircase or in base angular-speed trips. `track_ang_vel_z`'s kernel is flat there: at σ = 0.35
//! an error of 0.6 rad/s already earns 5 % of the term and 1 rad/s 0.03 %, so the policy gains
//! nothing by making a burst smaller. A squared error keeps a gradient at any size (a burst of
//! 1.5 rad/s costs 2.25 P per second, the kernel's whole term is worth 2). Off by default: from the
//! committed actor, P = 1 (run 42) cut the presets' turn-rate RMSE from 0.53 to 0.36 rad/s and
//! taught the policy to stand before the stairs; P = 0.3 (run 43) passed 23 of 30 presets against
//! 19 and swept a little below (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-11-30).
//!
//! Why `--clearance-lookahead`: the foot's point is the ankle-roll body's origin, and the G1's toe
//! contacts sit 0.12 m ahead of it, so the default look-ahead of 0.12 m reaches only the toe: a
//! riser enters the term when the toe is already over it, at the moment a low toe meets its face,
//! and the term then charges what the stumble term charges. Through `g1fw` the committed actor's
//! climbs of 18–22 cm stall at the first riser (185 of its 492 table failures): its swing foot
//! peaks behind the base and meets the riser's face. A longer look-ahead charges a low swing before
//! the toe gets there. Off by default (0.12, bit for bit the old rule).
//!
//! Why `riser_clearance`: through `g1fw`, the committed actor's swing foot lifts 11–14 cm on the
//! approach to a staircase whatever its step height (8, 12, 16 or 20 cm, ground-truth token), and
//! at 20 cm the swing that meets the first riser passes 7.8 cm below its top: the policy reads the
//! token's class, not its height (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-11-30).
//! `foot_clearance` asks for 0.10 m above the terrain under the toe, so a riser counts only once
//! the toe is over it, when a low foot has already met its face; a longer look-ahead there (run 44,
//! 0.24 m) counts the highest terrain ahead, two risers up on shallow treads. This term measures
//! the sole against the top of the *next* higher tread only, from liftoff on, so the lift it asks
//! for is the step's height plus a margin: it grows with the step, as the paper's clearance does.
//! Off by default.
//!
//! Why `token_clearance`: the policy observes no distance to the first riser, only the token
//! (class, height, depth, yaw), so a term that asks for lift only near a riser (`riser_clearance`)
//! asks for what it cannot see coming: run 51 learned it by touch, lifting at the riser's face
//! and landing on it, while its approach lifts shrank to 4–12 cm. This term asks for a swing that
//! clears the token's step height wherever the token reads up (the approach included), from what
//! the policy observes: the paper's swing clearance that grows with the stair height. Off by
//! default.
//!
//! Why `swing_apex`: `token_clearance` weighs its deficit by the foot's speed, and from
//! `--token-clearance 12` on the policy escaped it by shuffling up to the flight with 2–4 cm swings
//! that move slowly (runs 54–55, notebook/2026-11-24_to_2026-12-02_stair_policy.md). Charged once
//! per swing for the swing's apex, a shuffle pays for every short step. Off by default.
//!
//! Why `swing_advance`: with `--swing-apex 2` alone (run 56) the policy stopped at the riser
//! and inched there, and with `--token-clearance` it shuffled up to the flight (runs 54–55):
//! short swings that carry the foot a few cm. A swing on an up flight should carry the foot at
//! least a tread forward (capped at 0.25 m, less than the 0.32–0.4 m a swing advances when
//! walking at the 0.4–0.5 m/s that the stairs are trained at), so walking pays nothing and each
//! short step pays for its shortfall. Off by default.
//!
//! Why `swing_overshoot`: the lift terms charge only a swing that stays low. With them on, the
//! climbs at 20 cm passed two risers and then fell, with swings rising 40–55 cm over the ground
//! under the foot (runs 57–58, notebook/2026-11-24_to_2026-12-02_stair_policy.md): twice the 25 cm
//! asked for. This charges only the excess past the asked apex plus [`SWING_OVERSHOOT_MARGIN_M`],
//! so the swings of a normal climb pay nothing. Off by default.
//!
//! Why `base_height`: once the lift terms got both feet onto the first two treads of a 20 cm flight
//! (run 58), the climbs ended with the feet on the treads and the body left behind: the robot
//! stopped with its feet at the second riser and fell back down the flight
//! (notebook/2026-11-24_to_2026-12-02_stair_policy.md). Measured from the feet's ground rather than
//! the ground under the base, a body that stays low while its feet stand higher pays, and one that
//! rises onto them does not; 0.70 m lies below the G1's walking height, so flat walking would pay
//! nothing. legged_gym's `base_height` measures from the terrain too. Off by default.
//!
//! Why `up_lean`: the policy walks with its body pitched back 3–8°, on flat ground and on flights
//! alike. On a 20 cm flight, with the ankles at their dorsiflexion stop (−0.87 rad; the stance
//! ankle reads −0.92 to −1.05 under load), the shin cannot tilt further over the foot on the tread,
//! so only a forward lean of the upper body can bring the centre of mass over the higher foot. Run
//! 58's climbs at 20 cm get both feet onto the second tread with the base over the rear foot,
//! pitched back 6–8°, and then slide back down the flight
//! (notebook/2026-11-24_to_2026-12-02_stair_policy.md, 2026-12-01). This asks for the body pitched
//! 0.10 rad (6°) forward while the token reads up; flat walking and descents pay nothing. Off by
//! default.
//!
//! Why `stance_lead`: where run 62's 20 cm climbs end
//! (notebook/2026-11-24_to_2026-12-02_stair_policy.md), a long step up (0.34 m forward and 0.21 m
//! up) puts the leading foot on the second tread while the base stays 0.25 m behind it, and the
//! trailing foot then lifts, as the gait clock has it, leaving the robot on one foot far ahead of
//! its body: it pitches back and falls down the flight. Climbing the `ppo_env` test's 15 cm flight,
//! the committed actor's lone stance foot lies at most 0.10 m ahead of the base (median: 0.06 m
//! behind it). This charges standing on one foot more than 0.05 m ahead of the base while the token
//! reads up, so the trailing foot waits until the body has come over the leading one. Off by
//! default.
//!
//! Why `foothold_edge`: with `riser_clearance` on (run 51), the swings at a 20 cm riser lift 24–30
//! cm and both feet reach the first tread, and then the robot falls back; both failures traced at
//! 20 cm start with the toe on the riser's face or a heel over the tread's nose, not with a foot
//! flat on a tread (run 51, notebook/2026-11-24_to_2026-12-02_stair_policy.md). Legged robots'
//! stair and parkour rewards charge such footholds (extreme-parkour's `feet_edge`). Off by default.
//!
//! Terminations mirror what stops the robot in `g1fw`, from the same spec values through the
//! supervisor's own type (`control::supervisor::MotionLimits`): tilt, a joint faster than its
//! motor's limit, a gyro axis past the angular-speed limit; plus the base within 0.4 m of the ground
//! under it (fallen).

/// Term weights (see the module table): one [`Terms`] value per term.
pub type Weights = Terms;

pub const WEIGHTS: Weights = Weights {
    track_lin_vel_xy: 1.0,
    track_ang_vel_z: 2.0,
    feet_air_time: 0.25,
    feet_slide: -0.1,
    flat_orientation: -1.0,
    ang_vel_xy: -0.05,
    action_rate: -0.005,
    torques: -1.5e-7,
    joint_acc: -1.25e-7,
    joint_deviation: -0.1,
    joint_speed: -1.0,
    ankle_limits: -1.0,
    foot_clearance: -10.0,
    riser_clearance: 0.0,
    token_clearance: 0.0,
    swing_apex: 0.0,
    swing_advance: 0.0,
    swing_overshoot: 0.0,
    base_height: 0.0,
    up_lean: 0.0,
    stance_lead: 0.0,
    foothold_edge: 0.0,
    stumble: -1.0,
    body_contact: -1.0,
    termination: -200.0,
    progress: 2.0,
    drift: 0.0,
    yaw_rate_error: 0.0,
    success: 3.0,
};

/// The lowest reward one policy step may give. A plain step stays within a few units (a fall's
/// termination is −200 · 0.02 = −4); a physics blow-up does not: one in a from-scratch run drove
/// q̈ to ~3e6 rad/s² and its joint-acceleration penalty alone gave its episode a return of −24 455,
/// which reached the critic and the advantages. Such a step counts as a bad fall, not as that.
pub const STEP_REWARD_FLOOR: f64 = -20.0;

/// A step's reward bounded below by [`STEP_REWARD_FLOOR`] (a NaN, from a simulator that blew up,
/// counts as the floor).
pub fn bounded(reward: f64) -> f64 {
    if reward.is_nan() {
        STEP_REWARD_FLOOR
    } else {
        reward.max(STEP_REWARD_FLOOR)
    }
}

/// Tracking kernels' standard deviation (m/s, rad/s).
pub const TRACKING_STD: f64 = 0.5;
/// Air-time threshold, s.
pub const AIR_TIME_THRESHOLD: f64 = 0.4;
/// Target swing-foot clearance above the terrain, m (sole; mjlab's 0.1).
pub const CLEARANCE_TARGET: f64 = 0.10;
/// How far ahead of the swing foot the terrain counts for clearance, m, by default
/// (`--clearance-lookahead` sets it). The foot's point is the ankle-roll body's origin and the
/// G1's toe contacts sit 0.12 m ahead of it, so by default the look-ahead reaches the toe and no
/// further: a riser enters the term when the toe is over it.
pub const CLEARANCE_LOOKAHEAD: f64 = 0.12;
/// Spacing of the terrain samples between the foot and the end of the look-ahead, m: below the
/// shallowest tread drawn (0.22 m), so no riser falls between two samples.
pub const CLEARANCE_SAMPLE_M: f64 = 0.12;

/// The highest terrain under the swing foot at `(x, y)` and along its direction of travel
/// `(ux, uy)` (a unit vector) up to `lookahead` m ahead, sampled every [`CLEARANCE_SAMPLE_M`] or
/// closer: the terrain the `foot_clearance` term measures the foot against.
pub fn clearance_terrain(
    ground: impl Fn(f64, f64) -> f64,
    (x, y): (f64, f64),
    (ux, uy): (f64, f64),
    lookahead: f64,
) -> f64 {
    let n = (lookahead / CLEARANCE_SAMPLE_M).ceil().max(1.0) as usize;
    (1..=n).fold(ground(x, y), |high, k| {
        let ahead = lookahead * k as f64 / n as f64;
        high.max(ground(x + ux * ahead, y + uy * ahead))
    })
}

/// Margin of the sole over the next higher tread's top that `riser_clearance` asks for, m.
pub const RISER_MARGIN: f64 = 0.05;
/// How far ahead of the swing foot (the ankle-roll origin), along its travel, `riser_clearance`
/// looks for the next higher tread, m: past the toe (0.12 m) by more than the deepest foot
/// placement from a riser, so the riser counts from liftoff on.
pub const RISER_LOOKAHEAD: f64 = 0.40;
/// Spacing of `riser_clearance`'s terrain samples, m: fine enough to find the riser within 4 cm.
pub const RISER_SAMPLE_M: f64 = 0.04;
/// Rise over the terrain under the foot past which a tread ahead counts as higher, m: the
/// terrain's own unevenness is not a step.
pub const RISER_MIN_RISE: f64 = 0.02;

/// The top of the first tread ahead of the swing foot at `(x, y)` along its travel `(ux, uy)` (a
/// unit vector), within `lookahead` m, that stands more than [`RISER_MIN_RISE`] above the terrain
/// under the foot; `None` on flat ground, going down, or once the foot is over the last riser.
pub fn next_tread_top(
    ground: impl Fn(f64, f64) -> f64,
    (x, y): (f64, f64),
    (ux, uy): (f64, f64),
    lookahead: f64,
) -> Option<f64> {
    let under = ground(x, y);
    let n = (lookahead / RISER_SAMPLE_M).ceil().max(1.0) as usize;
    (1..=n)
        .map(|k| {
            let ahead = lookahead * k as f64 / n as f64;
            ground(x + ux * ahead, y + uy * ahead)
        })
        .find(|&z| z > under + RISER_MIN_RISE)
}

/// The swing clearance over the terrain under the foot that `token_clearance` asks for, m, from
/// the token the policy observes: its step height plus [`RISER_MARGIN`] when it reads up, nothing
/// (`None`) on flat ground or down a flight.
pub fn token_clearance_target(token: &hal::TerrainToken) -> Option<f64> {
    (token.class == hal::TerrainClass::StairsUp).then(|| token.step_height_m.max(0.0) as f64 + RISER_MARGIN)
}

/// How far a swing's apex may rise above [`token_clearance_target`] before `swing_overshoot`
/// charges it, m.
pub const SWING_OVERSHOOT_MARGIN_M: f64 = 0.10;

/// How far the apex of a swing (its highest sole clearance over the ground under the foot, m) rose
/// past [`token_clearance_target`] plus [`SWING_OVERSHOOT_MARGIN_M`], m; `None` (nothing charged)
/// when the token does not read up.
pub fn swing_overshoot(token: &hal::TerrainToken, apex: f64) -> Option<f64> {
    token_clearance_target(token).map(|target| (apex - target - SWING_OVERSHOOT_MARGIN_M).max(0.0))
}

/// The base height over the feet's ground below which `base_height` charges, m.
pub const BASE_HEIGHT_TARGET_M: f64 = 0.70;

/// How far the base (`height`: its height over the mean of the ground heights under the two feet,
/// m) sits below [`BASE_HEIGHT_TARGET_M`], m; `None` (nothing charged) when the token does not read
/// up.
pub fn base_height_deficit(token: &hal::TerrainToken, height: f64) -> Option<f64> {
    (token.class == hal::TerrainClass::StairsUp).then(|| (BASE_HEIGHT_TARGET_M - height).max(0.0))
}

/// The forward pitch of the base (nose down) that `up_lean` asks for while the token reads up, rad.
pub const UP_LEAN_TARGET_RAD: f64 = 0.10;

/// How far the base's pitch falls short of [`UP_LEAN_TARGET_RAD`], rad: `forward_gravity` is the
/// x component of the projected gravity (the sine of the pitch, nose down positive). `None`
/// (nothing charged) when the token does not read up.
pub fn up_lean_deficit(token: &hal::TerrainToken, forward_gravity: f64) -> Option<f64> {
    (token.class == hal::TerrainClass::StairsUp)
        .then(|| (UP_LEAN_TARGET_RAD - forward_gravity.clamp(-1.0, 1.0).asin()).max(0.0))
}

/// How far ahead of the base a lone stance foot may stand before `stance_lead` charges, m.
pub const STANCE_LEAD_MAX_M: f64 = 0.05;

/// How far a lone stance foot lies ahead of the base (`lead`: along the base's heading, m) past
/// [`STANCE_LEAD_MAX_M`], m; `None` (nothing charged) when the token does not read up.
pub fn stance_lead_excess(token: &hal::TerrainToken, lead: f64) -> Option<f64> {
    (token.class == hal::TerrainClass::StairsUp).then(|| (lead - STANCE_LEAD_MAX_M).max(0.0))
}

/// Longest advance per swing that `swing_advance` asks for, m.
pub const SWING_ADVANCE_MAX_M: f64 = 0.25;

/// How far forward along the base's heading a swing on an up flight should carry the foot, m:
/// one tread of the token the policy observes, at most [`SWING_ADVANCE_MAX_M`]; `None` (nothing
/// asked) on flat ground or down a flight.
pub fn swing_advance_target(token: &hal::TerrainToken) -> Option<f64> {
    (token.class == hal::TerrainClass::StairsUp).then(|| (token.step_depth_m.max(0.0) as f64).min(SWING_ADVANCE_MAX_M))
}

/// Where the G1's sole reaches behind and ahead of the foot origin (the ankle-roll body), m: the
/// model's heel and toe contact spheres sit at x = −0.05 and +0.12.
pub const FOOT_HEEL_M: f64 = 0.05;
pub const FOOT_TOE_M: f64 = 0.12;

/// Whether a foot at `(x, y)` facing `(ux, uy)` (a unit vector) straddles a tread's edge: the
/// terrain under its heel, origin, mid-foot and toe spans more than [`RISER_MIN_RISE`]. The
/// `foothold_edge` term counts such feet in contact.
pub fn straddles_edge(ground: impl Fn(f64, f64) -> f64, (x, y): (f64, f64), (ux, uy): (f64, f64)) -> bool {
    let along = [-FOOT_HEEL_M, 0.0, 0.5 * FOOT_TOE_M, FOOT_TOE_M];
    let (lo, hi) = along.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &a| {
        let z = ground(x + ux * a, y + uy * a);
        (lo.min(z), hi.max(z))
    });
    hi - lo > RISER_MIN_RISE
}

/// Base height above the ground under it below which the episode ends, m. (Tilt, joint-speed and
/// base angular-speed terminations come from the spec's `[safety]`, as the supervisor's do:
/// `control::supervisor::MotionLimits`.)
pub const MIN_BASE_HEIGHT: f64 = 0.4;

/// Largest drift the `drift` term counts, m: past it the base is off any staircase we draw.
pub const MAX_DRIFT_M: f64 = 1.0;

/// The `drift` term: the distance of `(x, y)` from the line through the start `(0, 0)` along
/// `heading` (rad; `control::operator::left_of_line`, the line `--hold-line` steers to), capped
/// at [`MAX_DRIFT_M`].
pub fn drift(heading: f64, x: f64, y: f64) -> f64 {
    (control::operator::left_of_line(heading as f32, x as f32, y as f32) as f64)
        .abs()
        .min(MAX_DRIFT_M)
}

/// Raw term values of one step (before weights and dt); `Terms::total` applies them.
#[derive(Clone, Copy, Debug, Default)]
pub struct Terms {
    pub track_lin_vel_xy: f64,
    pub track_ang_vel_z: f64,
    pub feet_air_time: f64,
    pub feet_slide: f64,
    pub flat_orientation: f64,
    pub ang_vel_xy: f64,
    pub action_rate: f64,
    pub torques: f64,
    pub joint_acc: f64,
    pub joint_deviation: f64,
    pub joint_speed: f64,
    pub ankle_limits: f64,
    pub foot_clearance: f64,
    pub riser_clearance: f64,
    pub token_clearance: f64,
    pub swing_apex: f64,
    pub swing_advance: f64,
    pub swing_overshoot: f64,
    pub base_height: f64,
    pub up_lean: f64,
    pub stance_lead: f64,
    pub foothold_edge: f64,
    pub stumble: f64,
    pub body_contact: f64,
    pub termination: f64,
    pub progress: f64,
    pub drift: f64,
    pub yaw_rate_error: f64,
    pub success: f64,
}

/// How many terms [`Terms`] has.
pub const TERM_COUNT: usize = 29;

impl Terms {
    /// Every term by name, in the module table's order.
    pub fn named(&self) -> [(&'static str, f64); TERM_COUNT] {
        [
            ("track_lin_vel_xy", self.track_lin_vel_xy),
            ("track_ang_vel_z", self.track_ang_vel_z),
            ("feet_air_time", self.feet_air_time),
            ("feet_slide", self.feet_slide),
            ("flat_orientation", self.flat_orientation),
            ("ang_vel_xy", self.ang_vel_xy),
            ("action_rate", self.action_rate),
            ("torques", self.torques),
            ("joint_acc", self.joint_acc),
            ("joint_deviation", self.joint_deviation),
            ("joint_speed", self.joint_speed),
            ("ankle_limits", self.ankle_limits),
            ("foot_clearance", self.foot_clearance),
            ("riser_clearance", self.riser_clearance),
            ("token_clearance", self.token_clearance),
            ("swing_apex", self.swing_apex),
            ("swing_advance", self.swing_advance),
            ("swing_overshoot", self.swing_overshoot),
            ("base_height", self.base_height),
            ("up_lean", self.up_lean),
            ("stance_lead", self.stance_lead),
            ("foothold_edge", self.foothold_edge),
            ("stumble", self.stumble),
            ("body_contact", self.body_contact),
            ("termination", self.termination),
            ("progress", self.progress),
            ("drift", self.drift),
            ("yaw_rate_error", self.yaw_rate_error),
            ("success", self.success),
        ]
    }

    /// Adds this step's weighted terms (`weight · value · dt`, what [`Terms::total`] sums) to
    /// `by_term`: an episode's return split by term.
    pub fn accumulate(&self, w: &Weights, dt: f64, by_term: &mut [f64; TERM_COUNT]) {
        for ((acc, (_, v)), (_, wv)) in by_term.iter_mut().zip(self.named()).zip(w.named()) {
            *acc += wv * v * dt;
        }
    }

    /// The step's reward: Σ weight · value, times `dt`, summed left to right in [`Terms::named`]'s
    /// order (the order the sum was once written out in, so the same bits).
    pub fn total(&self, w: &Weights, dt: f64) -> f64 {
        let sum = self
            .named()
            .iter()
            .zip(w.named())
            .map(|((_, v), (_, wv))| wv * v)
            .reduce(|a, b| a + b)
            .unwrap_or(0.0);
        dt * sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A riser 0.2 m high at x = 0.3 m.
    fn riser(x: f64, _y: f64) -> f64 {
        if x >= 0.3 {
            0.2
        } else {
            0.0
        }
    }

    #[test]
    fn clearance_terrain_sees_a_riser_as_far_ahead_as_the_lookahead_reaches() {
        let (at, fwd) = ((0.1, 0.0), (1.0, 0.0));
        // The default reaches the toe (0.22 m): the riser is not there yet.
        assert_eq!(clearance_terrain(riser, at, fwd, CLEARANCE_LOOKAHEAD), 0.0);
        assert_eq!(clearance_terrain(riser, at, fwd, 0.24), 0.2);
        // Walking away from it, or sideways past it, it never counts.
        assert_eq!(clearance_terrain(riser, at, (-1.0, 0.0), 0.5), 0.0);
        assert_eq!(clearance_terrain(riser, at, (0.0, 1.0), 0.5), 0.0);
        // The default is the old two-point rule (under the foot and 0.12 m ahead), bit for bit.
        let wavy = |x: f64, y: f64| (7.0 * x).sin() * 0.1 + 0.03 * y;
        for i in 0..50 {
            let (x, y, a) = (0.05 * i as f64, 0.5 - 0.02 * i as f64, 0.3 * i as f64);
            let old = wavy(x, y).max(wavy(x + a.cos() * 0.12, y + a.sin() * 0.12));
            let new = clearance_terrain(wavy, (x, y), (a.cos(), a.sin()), CLEARANCE_LOOKAHEAD);
            assert_eq!(new.to_bits(), old.to_bits(), "sample {i}");
        }
    }

    #[test]
    fn clearance_terrain_misses_no_tread_between_samples() {
        // A single 0.13 m-wide block anywhere within the look-ahead is found: samples are at most
        // CLEARANCE_SAMPLE_M apart.
        for start in [0.05, 0.11, 0.2, 0.33, 0.41] {
            let block = |x: f64, _y: f64| if (start..start + 0.13).contains(&x) { 0.15 } else { 0.0 };
            assert_eq!(clearance_terrain(block, (0.0, 0.0), (1.0, 0.0), 0.5), 0.15, "{start}");
        }
    }

    /// A flight of 0.15 m risers every 0.25 m from x = 0.3 m.
    fn flight(x: f64, _y: f64) -> f64 {
        if x < 0.3 {
            0.0
        } else {
            0.15 * (1.0 + ((x - 0.3) / 0.25).floor())
        }
    }

    #[test]
    fn token_clearance_asks_for_the_tokens_step_height_up_flights_only() {
        use hal::{TerrainClass, TerrainToken};
        let token = |class, h| TerrainToken {
            class,
            step_height_m: h,
            step_depth_m: 0.3,
            yaw_rad: 0.1,
        };
        let up20 = token_clearance_target(&token(TerrainClass::StairsUp, 0.20)).unwrap();
        let up12 = token_clearance_target(&token(TerrainClass::StairsUp, 0.12)).unwrap();
        assert!((up20 - 0.25).abs() < 1e-6, "{up20}");
        assert!(up20 > up12, "the target grows with the step height");
        // A noisy token's negative height asks for the margin, never less.
        assert_eq!(
            token_clearance_target(&token(TerrainClass::StairsUp, -0.01)),
            Some(RISER_MARGIN)
        );
        assert_eq!(token_clearance_target(&token(TerrainClass::StairsDown, 0.20)), None);
        assert_eq!(token_clearance_target(&TerrainToken::FLAT), None);
    }

    #[test]
    fn swing_overshoot_charges_only_the_excess_past_the_asked_apex_on_up_flights() {
        use hal::{TerrainClass, TerrainToken};
        let token = |class, h| TerrainToken {
            class,
            step_height_m: h,
            step_depth_m: 0.3,
            yaw_rad: 0.0,
        };
        let up20 = token(TerrainClass::StairsUp, 0.20);
        // The asked apex is 0.25 m: up to 0.35 m is free, 0.45 m pays for 0.10 m.
        assert_eq!(swing_overshoot(&up20, 0.30), Some(0.0));
        assert_eq!(swing_overshoot(&up20, 0.35), Some(0.0));
        let over = swing_overshoot(&up20, 0.45).unwrap();
        assert!((over - 0.10).abs() < 1e-6, "{over}");
        assert_eq!(swing_overshoot(&token(TerrainClass::StairsDown, 0.3), 0.9), None);
        assert_eq!(swing_overshoot(&TerrainToken::FLAT, 0.9), None);
        assert_eq!(WEIGHTS.swing_overshoot, 0.0, "off by default");
    }

    /// The token of a flight of 20 cm risers and 0.30 m treads, read as `class`.
    fn flight_token(class: hal::TerrainClass) -> hal::TerrainToken {
        hal::TerrainToken {
            class,
            step_height_m: 0.2,
            step_depth_m: 0.3,
            yaw_rad: 0.0,
        }
    }

    /// `term` charges nothing on a down flight or flat ground, whatever the measure, and its
    /// weight is 0 (off) by default.
    fn assert_up_flights_only(term: fn(&hal::TerrainToken, f64) -> Option<f64>, measure: f64, weight: f64) {
        assert_eq!(term(&flight_token(hal::TerrainClass::StairsDown), measure), None);
        assert_eq!(term(&hal::TerrainToken::FLAT, measure), None);
        assert_eq!(weight, 0.0, "off by default");
    }

    #[test]
    fn base_height_charges_a_low_body_on_up_flights_only() {
        let up = flight_token(hal::TerrainClass::StairsUp);
        assert_eq!(base_height_deficit(&up, 0.75), Some(0.0));
        let low = base_height_deficit(&up, 0.55).unwrap();
        assert!((low - 0.15).abs() < 1e-9, "{low}");
        assert_up_flights_only(base_height_deficit, 0.5, WEIGHTS.base_height);
    }

    #[test]
    fn up_lean_charges_a_body_pitched_back_on_up_flights_only() {
        let up = flight_token(hal::TerrainClass::StairsUp);
        // Pitched 0.15 rad forward: nothing; level: the whole target; pitched 0.1 rad back: both.
        assert_eq!(up_lean_deficit(&up, 0.15f64.sin()), Some(0.0));
        assert!((up_lean_deficit(&up, 0.0).unwrap() - UP_LEAN_TARGET_RAD).abs() < 1e-12);
        let back = up_lean_deficit(&up, (-0.1f64).sin()).unwrap();
        assert!((back - 0.2).abs() < 1e-9, "{back}");
        // A value past ±1 (rounding of a unit quaternion) is clamped, not NaN.
        assert_eq!(up_lean_deficit(&up, 1.0 + 1e-7), Some(0.0));
        assert_up_flights_only(up_lean_deficit, -0.2, WEIGHTS.up_lean);
    }

    #[test]
    fn stance_lead_charges_a_lone_foot_far_ahead_on_up_flights_only() {
        let up = flight_token(hal::TerrainClass::StairsUp);
        assert_eq!(stance_lead_excess(&up, 0.04), Some(0.0));
        assert_eq!(
            stance_lead_excess(&up, -0.2),
            Some(0.0),
            "a foot behind the base is not charged"
        );
        let far = stance_lead_excess(&up, 0.25).unwrap();
        assert!((far - 0.20).abs() < 1e-9, "{far}");
        assert_up_flights_only(stance_lead_excess, 0.3, WEIGHTS.stance_lead);
    }

    #[test]
    fn swing_advance_asks_for_a_tread_capped_up_flights_only() {
        use hal::{TerrainClass, TerrainToken};
        let token = |class, d| TerrainToken {
            class,
            step_height_m: 0.18,
            step_depth_m: d,
            yaw_rad: 0.0,
        };
        let short = swing_advance_target(&token(TerrainClass::StairsUp, 0.22)).unwrap();
        assert!((short - 0.22).abs() < 1e-6, "{short}");
        assert_eq!(
            swing_advance_target(&token(TerrainClass::StairsUp, 0.40)),
            Some(SWING_ADVANCE_MAX_M),
            "deep treads ask for the cap"
        );
        assert_eq!(swing_advance_target(&token(TerrainClass::StairsUp, -0.02)), Some(0.0));
        assert_eq!(swing_advance_target(&token(TerrainClass::StairsDown, 0.3)), None);
        assert_eq!(swing_advance_target(&TerrainToken::FLAT), None);
        assert_eq!(WEIGHTS.swing_advance, 0.0, "off by default");
    }

    #[test]
    fn straddles_edge_finds_a_foot_across_a_riser_and_not_one_flat_on_a_tread() {
        // The riser at x = 0.3: a foot whose toe (origin + 0.12) or heel (origin − 0.05) is past
        // it straddles the edge; one wholly on either side does not.
        let fwd = (1.0, 0.0);
        assert!(!straddles_edge(riser, (0.1, 0.0), fwd), "on the floor, toe 8 cm short");
        assert!(
            straddles_edge(riser, (0.2, 0.0), fwd),
            "toe on the tread, heel on the floor"
        );
        assert!(straddles_edge(riser, (0.33, 0.0), fwd), "heel hanging over the nose");
        assert!(!straddles_edge(riser, (0.36, 0.0), fwd), "wholly on the tread");
        // Facing along the riser, the foot lies on one side of it.
        assert!(!straddles_edge(riser, (0.25, 0.0), (0.0, 1.0)));
        // Uneven ground below RISER_MIN_RISE is not an edge.
        let bumpy = |x: f64, _: f64| 0.009 * (x * 20.0).sin();
        assert!((0..40).all(|i| !straddles_edge(bumpy, (0.05 * i as f64, 0.0), fwd)));
    }

    #[test]
    fn next_tread_top_is_the_next_riser_only_not_the_highest_ahead() {
        // Before the flight: the first tread (0.15), though two more lie within reach.
        assert_eq!(
            next_tread_top(flight, (0.1, 0.0), (1.0, 0.0), RISER_LOOKAHEAD),
            Some(0.15)
        );
        // On the first tread: the second; the foot's own tread never counts.
        assert_eq!(
            next_tread_top(flight, (0.4, 0.0), (1.0, 0.0), RISER_LOOKAHEAD),
            Some(0.3)
        );
        // Out of reach, walking back down, sideways along a tread, on flat ground: nothing.
        assert_eq!(next_tread_top(flight, (-0.2, 0.0), (1.0, 0.0), RISER_LOOKAHEAD), None);
        assert_eq!(next_tread_top(flight, (0.9, 0.0), (-1.0, 0.0), RISER_LOOKAHEAD), None);
        assert_eq!(next_tread_top(flight, (0.4, 0.0), (0.0, 1.0), RISER_LOOKAHEAD), None);
        assert_eq!(
            next_tread_top(|_, _| 0.0, (0.0, 0.0), (1.0, 0.0), RISER_LOOKAHEAD),
            None
        );
        // Bumps below RISER_MIN_RISE are not steps.
        let bumpy = |x: f64, _: f64| 0.015 * (x * 20.0).sin();
        assert_eq!(next_tread_top(bumpy, (0.0, 0.0), (1.0, 0.0), RISER_LOOKAHEAD), None);
        // No riser falls between two samples: found within RISER_SAMPLE_M of its face.
        for i in 0..40 {
            let x = 0.3 - RISER_LOOKAHEAD + 0.001 + i as f64 * 0.01;
            assert_eq!(
                next_tread_top(flight, (x, 0.0), (1.0, 0.0), RISER_LOOKAHEAD),
                Some(0.15),
                "{x}"
            );
        }
        // Off by default: the committed recipe's reward is unchanged.
        assert_eq!(WEIGHTS.riser_clearance, 0.0);
        assert_eq!(WEIGHTS.foothold_edge, 0.0);
        assert_eq!(WEIGHTS.token_clearance, 0.0);
        assert_eq!(WEIGHTS.swing_apex, 0.0);
    }

    #[test]
    fn a_blown_up_step_is_bounded_and_a_plain_one_is_not_touched() {
        let blown = Terms {
            joint_acc: 1e13,
            ..Terms::default()
        };
        assert!(blown.total(&WEIGHTS, 0.02) < -1e4);
        assert_eq!(bounded(blown.total(&WEIGHTS, 0.02)), STEP_REWARD_FLOOR);
        assert_eq!(bounded(f64::NAN), STEP_REWARD_FLOOR);
        let fall = Terms {
            termination: 1.0,
            ..Terms::default()
        };
        assert_eq!(bounded(fall.total(&WEIGHTS, 0.02)), fall.total(&WEIGHTS, 0.02));
        assert_eq!(bounded(3.0), 3.0);
    }

    #[test]
    fn total_is_weighted_sum_times_dt() {
        let t = Terms {
            track_lin_vel_xy: 1.0,
            termination: 1.0,
            ..Terms::default()
        };
        assert!((t.total(&WEIGHTS, 0.02) - 0.02 * (1.0 - 200.0)).abs() < 1e-12);
        assert_eq!(Terms::default().total(&WEIGHTS, 0.02), 0.0);
    }

    #[test]
    fn the_return_by_term_sums_to_the_total_and_names_every_field() {
        // Every field set to a distinct value: a term missing from `named` would not add up.
        let mut t = Terms::default();
        let names: Vec<&str> = t.named().iter().map(|(n, _)| *n).collect();
        let mut unique = names.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), TERM_COUNT, "a term is named twice");
        let w = Terms {
            drift: 0.7,
            swing_apex: 1.3,
            ..WEIGHTS
        };
        t = Terms {
            track_lin_vel_xy: 0.3,
            progress: 0.4,
            drift: 0.2,
            swing_apex: 0.1,
            termination: 1.0,
            foot_clearance: 0.05,
            success: 50.0,
            ..Terms::default()
        };
        let mut by_term = [0.0; TERM_COUNT];
        t.accumulate(&w, 0.02, &mut by_term);
        t.accumulate(&w, 0.02, &mut by_term);
        let sum: f64 = by_term.iter().sum();
        assert!(
            (sum - 2.0 * t.total(&w, 0.02)).abs() < 1e-9,
            "{sum} vs {}",
            2.0 * t.total(&w, 0.02)
        );
        let at = |name: &str| by_term[names.iter().position(|n| *n == name).unwrap()];
        assert!((at("drift") - 2.0 * 0.7 * 0.2 * 0.02).abs() < 1e-12);
        assert!((at("termination") + 2.0 * 200.0 * 0.02).abs() < 1e-9);
    }

    #[test]
    fn drift_is_the_distance_across_the_heading_line_and_capped() {
        // Along the line, at any heading: no drift.
        assert!(drift(0.0, 3.0, 0.0).abs() < 1e-6);
        let h = 25f64.to_radians();
        assert!(drift(h, 2.0 * h.cos(), 2.0 * h.sin()).abs() < 1e-6);
        // Across it: the perpendicular distance, either side.
        assert!((drift(0.0, 1.0, 0.3) - 0.3).abs() < 1e-6);
        assert!((drift(0.0, 1.0, -0.3) - 0.3).abs() < 1e-6);
        assert!((drift(h, 2.0 * h.cos() - 0.4 * h.sin(), 2.0 * h.sin() + 0.4 * h.cos()) - 0.4).abs() < 1e-6);
        assert_eq!(drift(0.0, 0.0, 5.0), MAX_DRIFT_M);
        // Off by default: the committed recipe's reward is unchanged.
        assert_eq!(WEIGHTS.drift, 0.0);
        assert_eq!(WEIGHTS.yaw_rate_error, 0.0);
    }
}
