//! Which MJCF to load, and the edits that make it a G1 the bridge can drive.
//!
//! Edits (through MuJoCo's `MjSpec`, before compiling), each applied only where the model lacks it,
//! so the 12-dof model keeps its own armature and motors and its `qpos0` bit for bit:
//! - a floor plane on the world body, if the world has no plane geom;
//! - joint armature from the G1 table, for slot joints whose armature is zero (the 29-dof MJCF
//!   ships none, and is unstable under explicit PD without it);
//! - one PD actuator per slot joint (see [`crate`]'s actuator model): a general actuator with
//!   gain 1, an affine bias whose `[0, −kp, −kd]` the simulator rewrites per command, and
//!   `forcerange` = the effort limit. A shipped gear-1 `motor` on the joint (the 12-dof model has
//!   one each) is converted in place rather than duplicated; the joint's own `actuatorfrcrange` moves
//!   to the actuator (one clamp, which MuJoCo's implicit derivative knows about);
//! - integrator `implicitfast`, so the PD's damping is integrated implicitly;
//! - site `imu_in_pelvis` on the pelvis and gyro / accelerometer sensors on it;
//! - [`PhysicsProfile::Training`] only: solver 10 / 20 iterations, no joint friction loss, shin and
//!   thigh capsules where the model has none and a foot capsule, collisions between feet / shins and
//!   the world, and between the left leg and the right leg (thighs, shins, feet).
//! - a terrain pool (mocap bodies with one box or cylinder each) when asked for one.
use crate::quat_mul;
use crate::world::{Primitive, World};
use std::path::PathBuf;
use std::str::FromStr;

use hal::NUM_MOTORS;
use mujoco_rs::mujoco_c::{
    _mjtGeomBase, _mjtObjBase, mjtBias, mjtDyn, mjtGain, mjtIntegrator, mjtJoint, mjtLimited, mjtSensor, mjtTrn,
};
use mujoco_rs::prelude::*;

use crate::model_cache;
use crate::slots;
use crate::SimError;

/// Name of the pelvis IMU site (the one the 29-dof MJCF ships).
pub const IMU_SITE: &str = "imu_in_pelvis";
/// Its position in the pelvis frame (G1 hardware).
pub const IMU_SITE_POS: [f64; 3] = hal::G1_PELVIS_IMU_POS;
/// Body carrying the IMU and the free joint.
pub const PELVIS: &str = "pelvis";

/// The model to simulate.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ModelChoice {
    /// The 29-dof G1 from mjlab 1.6.0 (`.deps/g1_29dof/g1.xml`), started in mjlab's home pose.
    G1_29Dof,
    /// The 12-dof legs-only G1 from unitree_rl_gym (`../shared/assets/unitree_g1_12dof/scene.xml`),
    /// started at its `qpos0`.
    G1_12Dof,
    /// Any MJCF file; started at its keyframe `home` if it has one, else at `qpos0`.
    Path(PathBuf),
}

impl FromStr for ModelChoice {
    type Err = std::convert::Infallible;
    /// `g1-29dof`, `g1-12dof`, or anything else as a path.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s {
            "g1-29dof" => ModelChoice::G1_29Dof,
            "g1-12dof" => ModelChoice::G1_12Dof,
            p => ModelChoice::Path(PathBuf::from(p)),
        })
    }
}

impl std::fmt::Display for ModelChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ModelChoice::G1_29Dof => f.write_str("g1-29dof"),
            ModelChoice::G1_12Dof => f.write_str("g1-12dof"),
            ModelChoice::Path(p) => write!(f, "{}", p.display()),
        }
    }
}

/// `.deps` of this checkout (from `scripts/install.sh`), or `$G1_DEPS_DIR`.
pub fn deps_dir() -> PathBuf {
    match std::env::var_os("G1_DEPS_DIR") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../.deps")),
    }
}

/// `Err` saying what to run when `scripts/install.sh` has not put the 29-dof model into
/// [`deps_dir`] (the tests of every crate that loads it ask this first).
pub fn check_installed() -> Result<(), String> {
    let xml = ModelChoice::G1_29Dof.path();
    if xml.exists() {
        return Ok(());
    }
    Err(format!(
        "\n\nThe 29-dof G1 model is missing at {}.\nRun scripts/install.sh from the repository root \
         (it installs MuJoCo 3.17.0 and the G1 MJCF into .deps/), then re-run the tests.\n",
        xml.display()
    ))
}

/// The read-only `shared` directory next to the checkout, or `$G1_SHARED_DIR`.
pub fn shared_dir() -> PathBuf {
    match std::env::var_os("G1_SHARED_DIR") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared")),
    }
}

impl ModelChoice {
    /// The MJCF file this choice loads.
    pub fn path(&self) -> PathBuf {
        match self {
            ModelChoice::G1_29Dof => deps_dir().join("g1_29dof/g1.xml"),
            ModelChoice::G1_12Dof => shared_dir().join("assets/unitree_g1_12dof/scene.xml"),
            ModelChoice::Path(p) => p.clone(),
        }
    }

    /// What to tell the user when the file is missing.
    fn missing_hint(&self) -> &'static str {
        match self {
            ModelChoice::G1_29Dof => {
                "run scripts/install.sh (or point G1_DEPS_DIR at a directory holding g1_29dof/g1.xml)"
            }
            ModelChoice::G1_12Dof => "point G1_SHARED_DIR at the shared directory holding assets/unitree_g1_12dof",
            ModelChoice::Path(_) => "check the --model path",
        }
    }
}

/// How the simulator drives one present motor slot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlotMap {
    pub slot: usize,
    pub joint: usize,
    pub qpos_adr: usize,
    pub dof_adr: usize,
    /// The slot's PD actuator (gear 1, gain 1, affine bias, force-limited).
    pub actuator: usize,
    /// Torque clamp, N·m (`lo < 0 < hi` for the G1).
    pub tau_lo: f64,
    pub tau_hi: f64,
}

/// A compiled model plus everything the simulator looks up once.
pub struct Loaded {
    pub model: MjModel,
    pub slots: Vec<SlotMap>,
    /// Bit `i`: slot `i` is present.
    pub present: u64,
    pub initial_qpos: Vec<f64>,
    pub mode_machine: u8,
    pub pelvis_body: usize,
    /// `qpos` address of the pelvis free joint, if it has one.
    pub root_qpos_adr: Option<usize>,
    pub root_dof_adr: Option<usize>,
    pub gyro_adr: usize,
    pub acc_adr: usize,
    /// Per body: 0 not a foot, 1 left foot, 2 right foot.
    pub foot_side: Vec<u8>,
    /// Terrain pool: mocap index and geom id of each pooled box, then each pooled cylinder.
    pub pool_boxes: Vec<PoolGeom>,
    pub pool_cylinders: Vec<PoolGeom>,
    /// `initial_qpos` before a world's start pose was applied (flat ground at the origin).
    pub base_qpos: Vec<f64>,
    /// What the model cache did ([`model_cache`]), if one is configured.
    pub cache_note: Option<String>,
}

/// Which physics settings the model is compiled with (see [`crate::SimConfig::physics`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PhysicsProfile {
    /// The model's own solver settings, contacts and joint friction (the deploy-side simulator).
    #[default]
    Deploy,
    /// Lean settings for RL training: 10 solver / 20 line-search iterations, joint friction loss 0,
    /// and only feet and shins colliding, with the world only (no self-collision, no meshes).
    Training,
}

impl FromStr for PhysicsProfile {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "deploy" => Ok(Self::Deploy),
            "training" => Ok(Self::Training),
            _ => Err(format!("physics profile '{s}': expected deploy or training")),
        }
    }
}

/// How many static terrain geoms to preallocate for [`crate::Simulator::set_world`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TerrainPool {
    pub boxes: usize,
    pub cylinders: usize,
}

/// One pooled terrain geom: its mocap slot (pose in `mjData`) and its geom (size in `mjModel`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PoolGeom {
    pub mocap: usize,
    pub geom: usize,
    pub body: usize,
}

/// Where unused pool geoms wait: far below the floor, out of every contact and ray.
pub const POOL_PARK_Z: f64 = -100.0;

/// Collision bits of the training profile (MuJoCo pairs `a`, `b` when `contype_a & conaffinity_b`
/// or the reverse is set): feet and shins have ROBOT in `contype`, world geoms add ROBOT to their
/// `conaffinity`, so those meet the world. Leg geoms of one side carry their side's bit in `contype`
/// and the other side's in `conaffinity`, so the legs meet each other and nothing else of the robot.
const TRAINING_ROBOT_BIT: i32 = 2;
const TRAINING_LEFT_LEG_BIT: i32 = 4;
const TRAINING_RIGHT_LEG_BIT: i32 = 8;
/// Name suffix of the foot capsule added for leg-against-leg contacts only (the soles' own
/// colliders stay what touches the ground).
const FOOT_SELF_SUFFIX: &str = "_foot_self_collision";

fn edit_err(what: &str, e: impl std::fmt::Display) -> SimError {
    SimError::Model(format!("{what}: {e}"))
}

/// A joint-transmission gear-1 actuator without dynamics: a shipped `motor`, or our PD actuator.
fn is_direct_motor(trn: mjtTrn, gain: mjtGain, gainprm0: f64, bias: mjtBias, dyn_: mjtDyn, gear: &[f64]) -> bool {
    trn == mjtTrn::mjTRN_JOINT
        && gain == mjtGain::mjGAIN_FIXED
        && gainprm0 == 1.0
        && (bias == mjtBias::mjBIAS_NONE || bias == mjtBias::mjBIAS_AFFINE)
        && dyn_ == mjtDyn::mjDYN_NONE
        && gear[0] == 1.0
}

/// Loads `choice`, applies the edits above, sets the timestep and resolves the slot map. With
/// `cache_dir`, a compile of the same inputs is taken from there, or stored there ([`model_cache`]).
pub fn load(
    choice: &ModelChoice,
    config: &crate::SimConfig,
    world: Option<&World>,
    pool: TerrainPool,
    cache_dir: Option<&std::path::Path>,
) -> Result<Loaded, SimError> {
    let profile = config.physics;
    let path = choice.path();
    if !path.exists() {
        return Err(SimError::ModelMissing {
            path: path.clone(),
            hint: choice.missing_hint(),
        });
    }
    let cache_entry = cache_dir.map(|d| model_cache::entry_path(d, &path, &format!("{config:?} {world:?} {pool:?}")));
    let mut cache_note = None;
    if let Some(entry) = &cache_entry {
        match model_cache::read(entry) {
            Some(Ok((model, limits))) => {
                let note = format!("model from cache {}", entry.display());
                return finish_load(choice, config, world, model, &limits, Some(note));
            }
            Some(Err(e)) => cache_note = Some(format!("model cache entry unusable ({e}); compiled again")),
            None => {}
        }
    }
    let mut spec = MjSpec::from_xml(&path).map_err(|e| edit_err(&format!("parsing {}", path.display()), e))?;
    spec.option_mut().timestep = config.physics_dt;
    // The PD's damping (kd up to 10 on sub-kg wrist links) is stiff: integrated explicitly it
    // diverges once kd·dt/I > 2; implicitfast folds −kd into the mass matrix of each step.
    spec.option_mut().integrator = match config.integrator {
        crate::Integrator::ImplicitFast => mjtIntegrator::mjINT_IMPLICITFAST,
        crate::Integrator::Euler => mjtIntegrator::mjINT_EULER,
    } as i32;
    if profile == PhysicsProfile::Training {
        spec.option_mut().iterations = 10;
        spec.option_mut().ls_iterations = 20;
        for j in spec.joint_iter_mut() {
            j.set_frictionloss(0.0);
        }
        add_leg_capsules(&mut spec)?;
        strip_meshes(&mut spec)?;
    }

    add_floor_if_missing(&mut spec)?;
    let limits = prepare_slot_joints(&mut spec)?;
    add_imu_if_missing(&mut spec)?;
    if let Some(w) = world {
        add_world(&mut spec, w)?;
    }
    add_pool(&mut spec, pool)?;

    let model = spec
        .compile()
        .map_err(|e| edit_err(&format!("compiling {}", path.display()), e))?;
    if let Some(entry) = &cache_entry {
        let written = model_cache::write(entry, &model, &limits);
        let note = match written {
            Ok(()) => format!("model compiled and cached in {}", entry.display()),
            Err(e) => format!("model compiled; the cache could not be written ({e})"),
        };
        cache_note = Some(cache_note.map_or(note.clone(), |n| format!("{n}; {note}")));
    }
    finish_load(choice, config, world, model, &limits, cache_note)
}

/// The steps after compiling (or loading a cached compile): the training profile's collision
/// bits, the slot map, the start pose.
fn finish_load(
    choice: &ModelChoice,
    config: &crate::SimConfig,
    world: Option<&World>,
    mut model: MjModel,
    limits: &model_cache::Limits,
    cache_note: Option<String>,
) -> Result<Loaded, SimError> {
    if config.physics == PhysicsProfile::Training {
        lean_collisions(&mut model);
    }
    let mut loaded = resolve(choice, model, limits)?;
    loaded.cache_note = cache_note;
    loaded.base_qpos = loaded.initial_qpos.clone();
    if let (Some(w), Some(qa)) = (world, loaded.root_qpos_adr) {
        // Stand the robot on the world's start pose (its ground may be a raised landing).
        place_on_start(&mut loaded.initial_qpos, qa, w.start());
    }
    Ok(loaded)
}

/// Moves the free joint at `qa` of `q` by a world's start pose `[x, y, ground, yaw]`.
pub fn place_on_start(q: &mut [f64], qa: usize, [x, y, ground, yaw]: [f64; 4]) {
    q[qa] += x;
    q[qa + 1] += y;
    q[qa + 2] += ground;
    let r = [(0.5 * yaw).cos(), 0.0, 0.0, (0.5 * yaw).sin()];
    let o = [q[qa + 3], q[qa + 4], q[qa + 5], q[qa + 6]];
    let m = quat_mul(r, o);
    q[qa + 3..qa + 7].copy_from_slice(&m);
}

/// The world's static geoms (named `terrain_N`, grey, colliding like the floor).
fn add_world(spec: &mut MjSpec, world: &World) -> Result<(), SimError> {
    for (i, p) in world.primitives().into_iter().enumerate() {
        let g = spec.world_body_mut().add_geom();
        match p {
            Primitive::Box { pos, quat, half } => {
                g.set_type(_mjtGeomBase::mjGEOM_BOX);
                *g.pos_mut() = pos;
                *g.quat_mut() = quat;
                *g.size_mut() = half;
            }
            Primitive::Cylinder {
                pos,
                quat,
                radius,
                half_len,
            } => {
                g.set_type(_mjtGeomBase::mjGEOM_CYLINDER);
                *g.pos_mut() = pos;
                *g.quat_mut() = quat;
                *g.size_mut() = [radius, half_len, 0.0];
            }
        }
        *g.rgba_mut() = [0.62, 0.6, 0.55, 1.0];
        g.set_name(&format!("terrain_{i}"))
            .map_err(|e| edit_err("naming a terrain geom", e))?;
    }
    Ok(())
}

fn add_floor_if_missing(spec: &mut MjSpec) -> Result<(), SimError> {
    let has_plane = spec
        .world_body()
        .geom_iter(false)
        .any(|g| g.type_() == _mjtGeomBase::mjGEOM_PLANE);
    if !has_plane {
        let g = spec.world_body_mut().add_geom();
        g.set_type(_mjtGeomBase::mjGEOM_PLANE);
        *g.size_mut() = [0.0, 0.0, 0.05];
        g.set_name("floor").map_err(|e| edit_err("naming the floor", e))?;
    }
    Ok(())
}

/// Armature and a PD actuator for every slot joint present. Returns each slot's torque clamp.
fn prepare_slot_joints(spec: &mut MjSpec) -> Result<[Option<(f64, f64)>; NUM_MOTORS], SimError> {
    let mut limits = [None; NUM_MOTORS];
    let mut joints: Vec<String> = Vec::new();
    for (slot, lim) in limits.iter_mut().enumerate() {
        let (Some(sname), Some(jname)) = (slots::slot_name(slot), slots::joint_name(slot)) else {
            continue;
        };
        let Some(j) = spec.joint_mut(&jname) else {
            continue;
        };
        if j.type_() != mjtJoint::mjJNT_HINGE {
            return Err(SimError::Model(format!("joint {jname} is not a hinge")));
        }
        if j.armature() == 0.0 {
            j.set_armature(slots::armature(sname).unwrap_or(0.0));
        }
        // The joint's own actuatorfrcrange wins over the table (the 12-dof model sets it).
        let r = *j.actfrcrange();
        let e = slots::effort_limit(sname).unwrap_or(f64::INFINITY);
        let (lo, hi) = if j.actfrclimited() != mjtLimited::mjLIMITED_FALSE && r[0] < r[1] {
            (r[0], r[1])
        } else {
            (-e, e)
        };
        // One clamp, on the actuator: MuJoCo's implicit derivative (`mjd_actuator_vel`) drops the
        // −kd term of an actuator saturated at its forcerange, but knows nothing of a joint-level
        // clamp, and `actuator_force` (our tau_est) is the force before a joint-level clamp.
        j.set_actfrclimited(mjtLimited::mjLIMITED_FALSE);
        *lim = Some((lo, hi));
        joints.push(jname);
    }
    // Shipped gear-1 motors on slot joints become our PD actuators in place (ids and names kept).
    let mut has_actuator: Vec<String> = Vec::new();
    for a in spec.actuator_iter_mut() {
        let target = a.target().to_owned();
        let Some(slot) = (0..NUM_MOTORS).find(|&s| slots::joint_name(s).as_deref() == Some(target.as_str())) else {
            continue;
        };
        let (Some((lo, hi)), true) = (limits[slot], joints.contains(&target)) else {
            continue;
        };
        if is_direct_motor(
            a.trntype(),
            a.gaintype(),
            a.gainprm()[0],
            a.biastype(),
            a.dyntype(),
            a.gear(),
        ) && !has_actuator.contains(&target)
        {
            make_pd_actuator(a, lo, hi);
            has_actuator.push(target);
        }
    }
    for (slot, lim) in limits.iter().enumerate() {
        let (Some(sname), Some(jname), Some((lo, hi))) = (slots::slot_name(slot), slots::joint_name(slot), lim) else {
            continue;
        };
        if has_actuator.contains(&jname) {
            continue;
        }
        let a = spec.add_actuator();
        a.set_trntype(mjtTrn::mjTRN_JOINT);
        a.set_target(&jname);
        a.gear_mut()[0] = 1.0;
        make_pd_actuator(a, *lo, *hi);
        a.set_name(&format!("g1sim_{sname}"))
            .map_err(|e| edit_err("naming an actuator", e))?;
    }
    Ok(limits)
}

/// `force = ctrl + biasprm[1]·q + biasprm[2]·dq`, clamped to `[lo, hi]`; ctrl unlimited (it
/// carries `tau_ff + kp·q_des + kd·dq_des`).
fn make_pd_actuator<C>(a: &mut mujoco_rs::wrappers::mj_editing::MjsActuator<C>, lo: f64, hi: f64) {
    a.set_gaintype(mjtGain::mjGAIN_FIXED);
    a.set_dyntype(mjtDyn::mjDYN_NONE);
    a.set_biastype(mjtBias::mjBIAS_AFFINE);
    *a.gainprm_mut() = [0.0; 10];
    a.gainprm_mut()[0] = 1.0;
    *a.biasprm_mut() = [0.0; 10];
    a.set_ctrllimited(mjtLimited::mjLIMITED_FALSE);
    a.set_forcelimited(mjtLimited::mjLIMITED_TRUE);
    *a.forcerange_mut() = [lo, hi];
}

/// Training profile: no mesh geoms and no meshes. Training collides only primitives
/// ([`lean_collisions`]) and renders nothing, and the G1's meshes (~200 000 vertices) were ~70 of
/// the ~80 MB of each environment's compiled model. Body masses and inertias are the MJCF's own
/// `inertial` elements, not the geoms' (a test compares them with the deploy profile's).
fn strip_meshes(spec: &mut MjSpec) -> Result<(), SimError> {
    while let Some(g) = spec.geom_iter_mut().find(|g| g.type_() == _mjtGeomBase::mjGEOM_MESH) {
        // SAFETY: `g` is the live geom just found; it is deleted once and no other handle of the
        // spec is held across the call (the next round walks the spec afresh).
        unsafe { g.delete() }.map_err(|e| edit_err("removing a mesh geom (training profile)", e))?;
    }
    while let Some(m) = spec.mesh_iter_mut().next() {
        // SAFETY: as above, for the first mesh left; no geom refers to it any more.
        unsafe { m.delete() }.map_err(|e| edit_err("removing a mesh (training profile)", e))?;
    }
    Ok(())
}

/// Training profile: a shin capsule on each knee link that has no primitive collider (the 12-dof
/// model's shins are meshes only), sized like the 29-dof model's shin + linkage capsules.
fn add_leg_capsules(spec: &mut MjSpec) -> Result<(), SimError> {
    // (body, name, fromto, radius, only if the body has no capsule): the 29-dof MJCF ships thigh and
    // shin capsules (mjlab's sizes, used here for the 12-dof model too); the foot capsule is ours.
    type Capsule = (&'static str, &'static str, [f64; 6], f64, bool);
    const CAPSULES: [Capsule; 4] = [
        (
            "hip_yaw_link",
            "_thigh_collision",
            [0.0, 0.0, -0.03, -0.06, 0.0, -0.17],
            0.055,
            true,
        ),
        (
            "knee_link",
            "_shin_collision",
            [0.01, 0.0, -0.02, 0.01, 0.0, -0.22],
            0.045,
            true,
        ),
        // The ankle linkage below the shin: through g1fw the lower shin met stair nosings that the
        // training profile let it pass through.
        (
            "knee_link",
            "_linkage_brace_collision",
            [0.01, 0.0, -0.2, 0.01, 0.0, -0.28],
            0.03,
            false,
        ),
        (
            "ankle_roll_link",
            FOOT_SELF_SUFFIX,
            [-0.05, 0.0, -0.025, 0.12, 0.0, -0.025],
            0.025,
            false,
        ),
    ];
    for side in ["left", "right"] {
        for (link, suffix, fromto, radius, if_missing) in CAPSULES {
            let Some(b) = spec.body_mut(&format!("{side}_{link}")) else {
                continue;
            };
            let capsules = b
                .geom_iter(false)
                .filter(|g| g.type_() == _mjtGeomBase::mjGEOM_CAPSULE)
                .count();
            if if_missing && capsules > 0 {
                continue;
            }
            if suffix == "_linkage_brace_collision" && capsules >= 2 {
                continue; // mjlab's 29-dof MJCF ships its own
            }
            let g = b.add_geom();
            g.set_type(_mjtGeomBase::mjGEOM_CAPSULE);
            *g.fromto_mut() = fromto;
            *g.size_mut() = [radius, 0.0, 0.0];
            g.set_density(0.0);
            g.set_group(3);
            g.set_name(&format!("g1sim_{side}{suffix}"))
                .map_err(|e| edit_err("naming a leg capsule", e))?;
        }
    }
    Ok(())
}

/// Training profile: only primitive geoms of the feet, shins and thighs collide with the world;
/// primitive geoms of the thighs, shins and feet of one leg collide with the other leg's
/// (a policy trained without it learns a gait whose legs touch, which the deployed model, like the
/// robot, does not let pass). Everything else (meshes, arms, pelvis) keeps its visuals only.
fn lean_collisions(model: &mut MjModel) {
    let bodies = |model: &MjModel, joint: &str| -> Vec<(i32, i32)> {
        [("left", TRAINING_LEFT_LEG_BIT), ("right", TRAINING_RIGHT_LEG_BIT)]
            .iter()
            .filter_map(|&(side, bit)| {
                model
                    .name_to_id(_mjtObjBase::mjOBJ_JOINT, &format!("{side}_{joint}"))
                    .map(|j| (model.jnt_bodyid()[j], bit))
            })
            .collect()
    };
    let thighs = bodies(model, "hip_yaw_joint");
    let shins = bodies(model, "knee_joint");
    let feet = bodies(model, "ankle_roll_joint");
    let side_of = |b: i32| {
        thighs
            .iter()
            .chain(&shins)
            .chain(&feet)
            .find(|&&(body, _)| body == b)
            .map(|&(_, bit)| bit)
    };
    let other = |bit: i32| TRAINING_LEFT_LEG_BIT + TRAINING_RIGHT_LEG_BIT - bit;
    let ngeom = model.ngeom() as usize;
    for g in 0..ngeom {
        let body = model.geom_bodyid()[g];
        let ty = model.geom_type()[g];
        let primitive = matches!(
            ty,
            _mjtGeomBase::mjGEOM_SPHERE | _mjtGeomBase::mjGEOM_CAPSULE | _mjtGeomBase::mjGEOM_BOX
        );
        // Terrain: geoms welded to the world body, and the terrain pool's mocap bodies (a mocap
        // body is its own weld root, so the weld test alone would disable the pool's collisions).
        let world = model.body_weldid()[body as usize] == 0 || model.body_mocapid()[body as usize] >= 0;
        let was_colliding = model.geom_contype()[g] != 0 || model.geom_conaffinity()[g] != 0;
        let self_only = model
            .id_to_name(_mjtObjBase::mjOBJ_GEOM, g)
            .is_some_and(|n| n.ends_with(FOOT_SELF_SUFFIX));
        let foot_or_shin = feet.iter().chain(&shins).any(|&(b, _)| b == body);
        let (ct, ca) = if world {
            (
                model.geom_contype()[g],
                model.geom_conaffinity()[g] | TRAINING_ROBOT_BIT,
            )
        } else if let Some(bit) =
            side_of(body).filter(|_| primitive && (was_colliding || ty == _mjtGeomBase::mjGEOM_CAPSULE))
        {
            // Feet, shins and thighs meet the terrain (through g1fw the thighs and knees met stair
            // edges that a feet-and-shins-only profile let them pass through).
            let ground = !self_only && (foot_or_shin || thighs.iter().any(|&(b, _)| b == body));
            (bit | if ground { TRAINING_ROBOT_BIT } else { 0 }, other(bit))
        } else {
            (0, 0)
        };
        model.geom_contype_mut()[g] = ct;
        model.geom_conaffinity_mut()[g] = ca;
    }
}

/// The terrain pool: one mocap body per geom, parked far below the floor, named `g1sim_pool_*`.
fn add_pool(spec: &mut MjSpec, pool: TerrainPool) -> Result<(), SimError> {
    for (kind, n, ty) in [
        ("box", pool.boxes, _mjtGeomBase::mjGEOM_BOX),
        ("cyl", pool.cylinders, _mjtGeomBase::mjGEOM_CYLINDER),
    ] {
        for i in 0..n {
            let b = spec.world_body_mut().add_body();
            b.set_mocap(true);
            *b.pos_mut() = [0.0, 0.0, POOL_PARK_Z];
            b.set_name(&format!("g1sim_pool_{kind}_{i}"))
                .map_err(|e| edit_err("naming a terrain pool body", e))?;
            let g = b.add_geom();
            g.set_type(ty);
            *g.size_mut() = [0.1, 0.1, 0.1];
            *g.rgba_mut() = [0.62, 0.6, 0.55, 1.0];
            g.set_name(&format!("g1sim_pool_{kind}_{i}"))
                .map_err(|e| edit_err("naming a terrain pool geom", e))?;
        }
    }
    Ok(())
}

fn add_imu_if_missing(spec: &mut MjSpec) -> Result<(), SimError> {
    if spec.site(IMU_SITE).is_none() {
        let pelvis = spec
            .body_mut(PELVIS)
            .ok_or_else(|| SimError::Model(format!("model has no body named {PELVIS:?}")))?;
        let s = pelvis.add_site();
        *s.pos_mut() = IMU_SITE_POS;
        s.set_name(IMU_SITE).map_err(|e| edit_err("naming the IMU site", e))?;
    }
    let on_site = |t: mjtSensor| {
        spec.sensor_iter()
            .any(|s| s.type_() == t && s.objtype() == _mjtObjBase::mjOBJ_SITE && s.objname() == IMU_SITE)
    };
    let want = [
        (
            mjtSensor::mjSENS_GYRO,
            !on_site(mjtSensor::mjSENS_GYRO),
            "g1sim_imu_gyro",
        ),
        (
            mjtSensor::mjSENS_ACCELEROMETER,
            !on_site(mjtSensor::mjSENS_ACCELEROMETER),
            "g1sim_imu_acc",
        ),
    ];
    for (t, missing, name) in want {
        if missing {
            let s = spec.add_sensor();
            s.set_type(t);
            s.set_objtype(_mjtObjBase::mjOBJ_SITE);
            s.set_objname(IMU_SITE);
            s.set_name(name).map_err(|e| edit_err("naming an IMU sensor", e))?;
        }
    }
    Ok(())
}

fn resolve(
    choice: &ModelChoice,
    model: MjModel,
    limits: &[Option<(f64, f64)>; NUM_MOTORS],
) -> Result<Loaded, SimError> {
    let id = |t: _mjtObjBase, n: &str| model.name_to_id(t, n);
    let mut slots_v = Vec::new();
    let mut present = 0u64;
    for (slot, lim) in limits.iter().enumerate() {
        let (Some(jname), Some((lo, hi))) = (slots::joint_name(slot), lim) else {
            continue;
        };
        let Some(joint) = id(_mjtObjBase::mjOBJ_JOINT, &jname) else {
            continue;
        };
        let actuator = (0..model.nu() as usize)
            .find(|&a| {
                model.actuator_trnid()[a][0] == joint as i32
                    && model.actuator_biastype()[a] == mjtBias::mjBIAS_AFFINE
                    && is_direct_motor(
                        model.actuator_trntype()[a],
                        model.actuator_gaintype()[a],
                        model.actuator_gainprm()[a][0],
                        model.actuator_biastype()[a],
                        model.actuator_dyntype()[a],
                        &model.actuator_gear()[a],
                    )
            })
            .ok_or_else(|| SimError::Model(format!("no PD actuator for {jname} after editing")))?;
        slots_v.push(SlotMap {
            slot,
            joint,
            qpos_adr: model.jnt_qposadr()[joint] as usize,
            dof_adr: model.jnt_dofadr()[joint] as usize,
            actuator,
            tau_lo: *lo,
            tau_hi: *hi,
        });
        present |= 1 << slot;
    }

    let pelvis_body = id(_mjtObjBase::mjOBJ_BODY, PELVIS)
        .ok_or_else(|| SimError::Model(format!("model has no body named {PELVIS:?}")))?;
    let (root_qpos_adr, root_dof_adr) = {
        let n = model.body_jntnum()[pelvis_body];
        let j = model.body_jntadr()[pelvis_body];
        if n >= 1 && model.jnt_type()[j as usize] == mjtJoint::mjJNT_FREE {
            (
                Some(model.jnt_qposadr()[j as usize] as usize),
                Some(model.jnt_dofadr()[j as usize] as usize),
            )
        } else {
            (None, None)
        }
    };

    let site = id(_mjtObjBase::mjOBJ_SITE, IMU_SITE).expect("IMU site added before compiling");
    let sensor_adr = |t: mjtSensor| {
        (0..model.nsensor() as usize)
            .find(|&s| {
                model.sensor_type()[s] == t
                    && model.sensor_objtype()[s] == _mjtObjBase::mjOBJ_SITE as _
                    && model.sensor_objid()[s] == site as i32
            })
            .map(|s| model.sensor_adr()[s] as usize)
            .expect("IMU sensors added before compiling")
    };
    let gyro_adr = sensor_adr(mjtSensor::mjSENS_GYRO);
    let acc_adr = sensor_adr(mjtSensor::mjSENS_ACCELEROMETER);

    // Feet: the ankle-roll joints' bodies and any body named like them.
    let mut foot_side = vec![0u8; model.nbody() as usize];
    for (side, tag) in [(1u8, "left_ankle_roll"), (2u8, "right_ankle_roll")] {
        if let Some(j) = id(_mjtObjBase::mjOBJ_JOINT, &format!("{tag}_joint")) {
            foot_side[model.jnt_bodyid()[j] as usize] = side;
        }
        for (b, f) in foot_side.iter_mut().enumerate() {
            if model
                .id_to_name(_mjtObjBase::mjOBJ_BODY, b)
                .is_some_and(|n| n.contains(tag))
            {
                *f = side;
            }
        }
    }

    let mut initial_qpos = model.qpos0().to_vec();
    let mode_machine = match choice {
        ModelChoice::G1_29Dof => {
            let adr = root_qpos_adr.ok_or_else(|| SimError::Model("the 29-dof pelvis has no free joint".into()))?;
            initial_qpos[adr + 2] = slots::HOME_ROOT_Z;
            for s in &slots_v {
                let name = slots::slot_name(s.slot).expect("present slots are named");
                initial_qpos[s.qpos_adr] = slots::home_angle(name);
            }
            hal::mode_machine::G1_29DOF_REV_1_0
        }
        ModelChoice::G1_12Dof => hal::mode_machine::G1_23DOF_REV_1_0,
        ModelChoice::Path(_) => {
            if let Some(k) = id(_mjtObjBase::mjOBJ_KEY, "home") {
                let nq = model.nq() as usize;
                initial_qpos.copy_from_slice(&model.key_qpos()[k * nq..(k + 1) * nq]);
            }
            // Guess the variant from the slots present: all 29 → 29-dof, legs only → 23-dof family.
            if present == (1u64 << 29) - 1 {
                hal::mode_machine::G1_29DOF_REV_1_0
            } else {
                hal::mode_machine::G1_23DOF_REV_1_0
            }
        }
    };

    let pool_of = |kind: &str| -> Vec<PoolGeom> {
        (0..)
            .map_while(|i| {
                let n = format!("g1sim_pool_{kind}_{i}");
                let body = id(_mjtObjBase::mjOBJ_BODY, &n)?;
                let geom = id(_mjtObjBase::mjOBJ_GEOM, &n)?;
                Some(PoolGeom {
                    mocap: model.body_mocapid()[body] as usize,
                    geom,
                    body,
                })
            })
            .collect()
    };
    let (pool_boxes, pool_cylinders) = (pool_of("box"), pool_of("cyl"));

    Ok(Loaded {
        model,
        slots: slots_v,
        present,
        initial_qpos,
        mode_machine,
        pelvis_body,
        root_qpos_adr,
        root_dof_adr,
        gyro_adr,
        acc_adr,
        foot_side,
        pool_boxes,
        pool_cylinders,
        base_qpos: Vec::new(),
        cache_note: None,
    })
}
