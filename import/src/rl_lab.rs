//! A unitree_rl_lab / IsaacLab export (`deploy.yaml` + `policy.onnx`) → a deploy spec and its
//! weights.
//!
//! `deploy.yaml` orders (checked against unitree_rl_lab's G1 exports):
//! - `joint_ids_map[i]`: the SDK motor slot of policy joint `i` (IsaacLab order → SDK order);
//! - `stiffness`, `damping`: **SDK motor order** (one per motor, 29 on the G1), while the spec's
//!   `kp`/`kd` are in policy order: `kp[i] = stiffness[joint_ids_map[i]]`;
//! - `default_joint_pos`, `actions.*.scale`/`offset`: policy order;
//! - observation `clip: [low, high]` is applied to the raw term before `scale` (IsaacLab), which
//!   the spec writes as `clip_before_scale`.
use std::fmt::Write as _;
use std::path::Path;

use serde_yaml_ng::Value;

use crate::onnx::{import_file, ImportError, ImportedNetwork};

/// Largest deploy.yaml read, bytes (rl_lab's are a few KB).
pub const MAX_DEPLOY_YAML_BYTES: u64 = 1 << 20;

/// The G1's SDK motor slots (29-dof).
pub const G1_SLOTS: usize = 29;

#[derive(Debug, thiserror::Error)]
pub enum DeployError {
    #[error("cannot read {path}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not valid YAML: {why}")]
    Yaml { path: String, why: String },
    #[error("export field `{field}`: {why}")]
    Field { field: String, why: String },
    #[error(transparent)]
    Onnx(#[from] ImportError),
    #[error(
        "the observation deploy.yaml describes has {obs} values ({terms}) but the ONNX network takes {input}: \
         check history_length and the terms against the export"
    )]
    InputSize { obs: usize, terms: String, input: usize },
}

/// Where the imported spec finds what it needs.
#[derive(Clone, Debug)]
pub struct RlLabOptions {
    pub control_hz: u32,
    /// The robot's MJCF for the estimator's leg kinematics (written as given; `None`: attitude only).
    pub estimator_model: Option<String>,
    pub ramp_s: f64,
    pub hold_s: f64,
}

impl Default for RlLabOptions {
    fn default() -> Self {
        Self {
            control_hz: 500,
            estimator_model: None,
            // Unitree's deploy examples and the peer walker's spec: with the export's walking gains
            // (ankle kp 40) a longer ramp lets the legs sag before the policy engages (measured: the
            // peer walker re-imported trips at ramp 1.0 s, walks 9.12 m at 0.5 s).
            ramp_s: 0.5,
            hold_s: 0.1,
        }
    }
}

/// One observation term as the spec will have it.
#[derive(Clone, Debug, PartialEq)]
pub struct Term {
    pub name: String,
    pub kind: &'static str,
    pub dim: usize,
    pub scale: Vec<f32>,
    pub clip: Option<[f32; 2]>,
    pub history: usize,
    pub period_s: Option<f64>,
}

/// The result: spec text, weights, and a table a person can check.
pub struct RlLabImport {
    pub spec_toml: String,
    pub weights: Vec<u8>,
    pub table: String,
    pub network: ImportedNetwork,
    pub joint_ids_map: Vec<usize>,
    pub kp: Vec<f32>,
    pub kd: Vec<f32>,
    pub default_pose: Vec<f32>,
    pub terms: Vec<Term>,
}

fn field(f: &str, why: impl Into<String>) -> DeployError {
    DeployError::Field {
        field: f.into(),
        why: why.into(),
    }
}

fn get<'a>(v: &'a Value, path: &[&str]) -> Option<&'a Value> {
    let mut cur = v;
    for k in path {
        cur = cur.get(*k)?;
    }
    Some(cur).filter(|v| !v.is_null())
}

fn num(v: &Value, f: &str) -> Result<f64, DeployError> {
    v.as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| field(f, format!("expected a finite number, got {}", short(v))))
}

fn short(v: &Value) -> String {
    let s = serde_yaml_ng::to_string(v).unwrap_or_default();
    let s = s.trim();
    if s.len() > 60 {
        format!("{}…", &s[..s.floor_char_boundary(60)])
    } else {
        s.to_string()
    }
}

fn list(v: &Value, f: &str) -> Result<Vec<f64>, DeployError> {
    let seq = v
        .as_sequence()
        .ok_or_else(|| field(f, format!("expected a list, got {}", short(v))))?;
    seq.iter()
        .enumerate()
        .map(|(i, x)| num(x, &format!("{f}[{i}]")))
        .collect()
}

/// A list of `n` numbers, or one number for all.
fn per_element(v: Option<&Value>, n: usize, f: &str, default: f64) -> Result<Vec<f32>, DeployError> {
    match v {
        None => Ok(vec![default as f32; n]),
        Some(v) if v.is_sequence() => {
            let l = list(v, f)?;
            if l.len() != n {
                return Err(field(f, format!("{} values, expected {n}", l.len())));
            }
            Ok(l.into_iter().map(|x| x as f32).collect())
        }
        Some(v) => Ok(vec![num(v, f)? as f32; n]),
    }
}

/// unitree_rl_lab / IsaacLab term names → the spec's kinds.
fn kind_of(name: &str) -> Option<&'static str> {
    Some(match name {
        "base_ang_vel" => "base_ang_vel",
        "projected_gravity" => "projected_gravity",
        "velocity_commands" | "keyboard_velocity_commands" | "generated_commands" | "base_velocity" => {
            "velocity_command"
        }
        "joint_pos_rel" | "joint_pos" => "joint_pos_rel",
        "joint_vel_rel" | "joint_vel" => "joint_vel",
        "last_action" | "actions" => "last_action",
        "gait_phase" | "phase" => "gait_phase",
        _ => return None,
    })
}

fn fmt_list(v: &[f32]) -> String {
    let items: Vec<String> = v.iter().map(|x| format!("{x:?}")).collect();
    format!("[{}]", items.join(", "))
}

/// Deepest nesting a deploy.yaml may have (rl_lab's nest 3 deep). The YAML parser is recursive and
/// slow on deep input (100k levels took 45 s before it gave up), so depth is bounded first.
pub const MAX_DEPLOY_YAML_DEPTH: usize = 64;

/// Why `text` nests too deep for a deploy.yaml: flow brackets (`[`, `{`) or block indentation
/// (leading spaces and `- ` markers, counted two columns per level).
fn too_deep(text: &str) -> Option<String> {
    let (mut depth, mut max_flow) = (0usize, 0usize);
    for b in text.bytes() {
        match b {
            b'[' | b'{' => {
                depth += 1;
                max_flow = max_flow.max(depth);
            }
            b']' | b'}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    let max_indent = text
        .lines()
        .map(|l| l.len() - l.trim_start_matches([' ', '-', '\t']).len())
        .max()
        .unwrap_or(0);
    let block = max_indent / 2;
    let deepest = max_flow.max(block);
    (deepest > MAX_DEPLOY_YAML_DEPTH)
        .then(|| format!("nested {deepest} levels deep, more than the {MAX_DEPLOY_YAML_DEPTH} a deploy.yaml may have"))
}

/// Reads `deploy` and `onnx` and builds the spec.
pub fn import_rl_lab(deploy: &Path, onnx: &Path, opts: &RlLabOptions) -> Result<RlLabImport, DeployError> {
    let y = read_deploy_yaml(deploy)?;
    let map = joint_map(&y)?;
    let n = map.len();
    if n == 0 {
        return Err(field("joint_ids_map", "empty"));
    }
    let step_dt = num(
        get(&y, &["step_dt"]).ok_or_else(|| field("step_dt", "missing"))?,
        "step_dt",
    )?;
    let policy_hz = (1.0 / step_dt).round() as u32;
    if step_dt <= 0.0
        || (1.0 / step_dt - policy_hz as f64).abs() > 1e-6
        || !opts.control_hz.is_multiple_of(policy_hz.max(1))
    {
        return Err(field(
            "step_dt",
            format!(
                "{step_dt} s is not a whole fraction of the {} Hz control loop",
                opts.control_hz
            ),
        ));
    }
    // Gains: SDK motor order.
    let sdk = |f: &str| -> Result<Vec<f64>, DeployError> {
        let v = list(get(&y, &[f]).ok_or_else(|| field(f, "missing"))?, f)?;
        if v.len() != G1_SLOTS {
            return Err(field(
                f,
                format!(
                    "{} values; unitree_rl_lab writes one per SDK motor ({G1_SLOTS} on the G1), in SDK order",
                    v.len()
                ),
            ));
        }
        if let Some((i, x)) = v.iter().enumerate().find(|(_, x)| **x < 0.0) {
            return Err(field(&format!("{f}[{i}]"), format!("{x} is negative")));
        }
        Ok(v)
    };
    let stiffness = sdk("stiffness")?;
    let damping = sdk("damping")?;
    let kp: Vec<f32> = map.iter().map(|&s| stiffness[s] as f32).collect();
    let kd: Vec<f32> = map.iter().map(|&s| damping[s] as f32).collect();
    let default_pose = per_element(get(&y, &["default_joint_pos"]), n, "default_joint_pos", 0.0)?;
    // Actions.
    let act = get(&y, &["actions", "JointPositionAction"]).ok_or_else(|| {
        field(
            "actions.JointPositionAction",
            "missing (only joint-position actions are supported)",
        )
    })?;
    let action_scale = per_element(
        act.get("scale").filter(|v| !v.is_null()),
        n,
        "actions.JointPositionAction.scale",
        1.0,
    )?;
    if let Some(off) = act.get("offset").filter(|v| !v.is_null()) {
        let off = per_element(Some(off), n, "actions.JointPositionAction.offset", 0.0)?;
        if let Some(i) = (0..n).find(|&i| (off[i] - default_pose[i]).abs() > 1e-6) {
            return Err(field(
                &format!("actions.JointPositionAction.offset[{i}]"),
                format!(
                    "{} differs from default_joint_pos[{i}] = {}: the spec's target is default pose + scale · action",
                    off[i], default_pose[i]
                ),
            ));
        }
    }
    let action_clip = match act.get("clip").filter(|v| !v.is_null()) {
        None => None,
        Some(v) => {
            let c = num(v, "actions.JointPositionAction.clip")?;
            if c <= 0.0 {
                return Err(field("actions.JointPositionAction.clip", "must be > 0"));
            }
            Some(c as f32)
        }
    };
    // Commands.
    let range = |k: &str| -> Result<[f32; 2], DeployError> {
        let f = format!("commands.base_velocity.ranges.{k}");
        let v = get(&y, &["commands", "base_velocity", "ranges", k]).ok_or_else(|| field(&f, "missing"))?;
        let l = list(v, &f)?;
        if l.len() != 2 || l[0] > l[1] {
            return Err(field(&f, "expected [low, high] with low <= high"));
        }
        Ok([l[0] as f32, l[1] as f32])
    };
    let (vx, vy, wz) = (range("lin_vel_x")?, range("lin_vel_y")?, range("ang_vel_z")?);
    let terms = observation_terms(&y, n)?;
    let network = import_file(onnx)?;
    let held: Vec<(usize, f32, f32)> = (0..G1_SLOTS)
        .filter(|sl| !map.contains(sl))
        .map(|sl| (sl, stiffness[sl] as f32, damping[sl] as f32))
        .collect();
    let draft = Draft {
        source: format!("{} and {}", deploy.display(), onnx.display()),
        name: deploy
            .parent()
            .and_then(|p| p.file_name())
            .map_or("imported".into(), |f| f.to_string_lossy().into_owned()),
        map,
        kp,
        kd,
        default_pose,
        action_scale,
        action_clip,
        ranges: [vx, vy, wz],
        terms,
        step_dt,
        policy_hz,
        held,
        notes: Vec::new(),
    };
    finish(draft, network, opts)
}

/// Everything a deploy spec needs, whichever export it came from.
pub struct Draft {
    pub source: String,
    pub name: String,
    pub map: Vec<usize>,
    pub kp: Vec<f32>,
    pub kd: Vec<f32>,
    pub default_pose: Vec<f32>,
    pub action_scale: Vec<f32>,
    pub action_clip: Option<f32>,
    /// vx, vy, wz: [low, high].
    pub ranges: [[f32; 2]; 3],
    pub terms: Vec<Term>,
    pub step_dt: f64,
    pub policy_hz: u32,
    /// Motor slots the policy does not drive: (slot, kp, kd), held at 0.
    pub held: Vec<(usize, f32, f32)>,
    /// Said in the table (defaults the export did not carry).
    pub notes: Vec<String>,
}

/// deploy.yaml, size-capped and depth-checked, as a YAML mapping.
fn read_deploy_yaml(deploy: &Path) -> Result<Value, DeployError> {
    let text = input_file::read_text_capped(deploy, MAX_DEPLOY_YAML_BYTES).map_err(|e| DeployError::Io {
        path: deploy.display().to_string(),
        source: e,
    })?;
    if let Some(why) = too_deep(&text) {
        return Err(DeployError::Yaml {
            path: deploy.display().to_string(),
            why,
        });
    }
    let y: Value = serde_yaml_ng::from_str(&text).map_err(|e| DeployError::Yaml {
        path: deploy.display().to_string(),
        why: e.to_string(),
    })?;
    if !y.is_mapping() {
        return Err(DeployError::Yaml {
            path: deploy.display().to_string(),
            why: "the top level is not a mapping of deploy fields".into(),
        });
    }
    Ok(y)
}

/// `joint_ids_map`: policy index → SDK slot, each slot once.
fn joint_map(y: &Value) -> Result<Vec<usize>, DeployError> {
    // Joint map: policy index → SDK slot, each slot once.
    let map_v = get(y, &["joint_ids_map"]).ok_or_else(|| field("joint_ids_map", "missing"))?;
    let map: Vec<usize> = list(map_v, "joint_ids_map")?
        .into_iter()
        .enumerate()
        .map(|(i, s)| {
            if s.fract() != 0.0 || s < 0.0 || s >= G1_SLOTS as f64 {
                Err(field(
                    &format!("joint_ids_map[{i}]"),
                    format!("{s} is not a G1 motor slot 0-28"),
                ))
            } else {
                Ok(s as usize)
            }
        })
        .collect::<Result<_, _>>()?;
    for (i, s) in map.iter().enumerate() {
        if let Some(j) = map[..i].iter().position(|t| t == s) {
            return Err(field(
                "joint_ids_map",
                format!(
                    "slot {s} ({}) is mapped twice, at policy indices {j} and {i}",
                    hal::G1_MOTOR_NAMES[*s]
                ),
            ));
        }
    }
    Ok(map)
}

/// The observation terms, in the file's order, for `n` policy joints.
fn observation_terms(y: &Value, n: usize) -> Result<Vec<Term>, DeployError> {
    // Observation terms, in the file's order.
    let obs = get(y, &["observations"])
        .and_then(|v| v.as_mapping())
        .ok_or_else(|| field("observations", "missing or not a mapping of terms"))?;
    let mut terms = Vec::new();
    for (k, v) in obs {
        let name = k.as_str().unwrap_or_default().to_string();
        let f = format!("observations.{name}");
        let kind = kind_of(&name).ok_or_else(|| {
            field(
                &f,
                "unknown term; supported: base_ang_vel, projected_gravity, velocity_commands (keyboard_/generated_), \
                 joint_pos_rel, joint_vel_rel, last_action, gait_phase",
            )
        })?;
        let dim = match kind {
            "base_ang_vel" | "projected_gravity" | "velocity_command" => 3,
            "gait_phase" => 2,
            _ => n,
        };
        let scale = per_element(v.get("scale").filter(|s| !s.is_null()), dim, &format!("{f}.scale"), 1.0)?;
        let clip = match v.get("clip").filter(|c| !c.is_null()) {
            None => None,
            Some(c) => {
                let l = list(c, &format!("{f}.clip"))?;
                if l.len() != 2 || l[0] > l[1] {
                    return Err(field(&format!("{f}.clip"), "expected [low, high] with low <= high"));
                }
                Some([l[0] as f32, l[1] as f32])
            }
        };
        let history = match v.get("history_length").filter(|h| !h.is_null()) {
            None => 1,
            Some(h) => {
                let h = num(h, &format!("{f}.history_length"))?;
                if h.fract() != 0.0 || !(0.0..=100.0).contains(&h) {
                    return Err(field(&format!("{f}.history_length"), "a whole number 0-100"));
                }
                (h as usize).max(1)
            }
        };
        let period_s = if kind == "gait_phase" {
            let p = get(v, &["params", "period"]).ok_or_else(|| field(&format!("{f}.params.period"), "missing"))?;
            Some(num(p, &format!("{f}.params.period"))?)
        } else {
            None
        };
        terms.push(Term {
            name,
            kind,
            dim,
            scale,
            clip,
            history,
            period_s,
        });
    }
    Ok(terms)
}

/// Checks the draft against the network and writes the spec and the table.
pub fn finish(d: Draft, network: ImportedNetwork, opts: &RlLabOptions) -> Result<RlLabImport, DeployError> {
    let Draft {
        source,
        name: stem,
        map,
        kp,
        kd,
        default_pose,
        action_scale,
        action_clip,
        ranges: [vx, vy, wz],
        terms,
        step_dt,
        policy_hz,
        held,
        notes,
    } = d;
    let n = map.len();
    let obs_dim: usize = terms.iter().map(|t| t.dim * t.history).sum();
    if network.desc.input != obs_dim {
        return Err(DeployError::InputSize {
            obs: obs_dim,
            terms: terms
                .iter()
                .map(|t| format!("{} {}×{}", t.name, t.dim, t.history))
                .collect::<Vec<_>>()
                .join(" + "),
            input: network.desc.input,
        });
    }
    if network.output_dim != n {
        return Err(field(
            "joint map",
            format!("{n} joints but the ONNX network outputs {} actions", network.output_dim),
        ));
    }
    let weights = network.safetensors_bytes()?;

    // The spec.
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Imported by g1-import from {source}.\n# kp/kd are in policy order (deploy.yaml's stiffness/damping are in SDK motor order: kp[i] =\n# stiffness[joint_ids_map[i]]). Observation clips are IsaacLab's (raw value, before scale).\n"
    );
    let _ = writeln!(
        s,
        "[meta]\nname = {:?}\ndescription = \"imported unitree_rl_lab export\"\n",
        stem
    );
    let _ = writeln!(
        s,
        "[rates]\ncontrol_hz = {}\npolicy_hz = {policy_hz}\n",
        opts.control_hz
    );
    let _ = writeln!(s, "[startup]\nramp_s = {:?}\nhold_s = {:?}\n", opts.ramp_s, opts.hold_s);
    let names: Vec<String> = map
        .iter()
        .map(|&sl| format!("{:?}", format!("{}_joint", hal::G1_MOTOR_NAMES[sl])))
        .collect();
    let _ = writeln!(s, "[policy]\nweights = \"policy.safetensors\"");
    let _ = writeln!(
        s,
        "joint_ids_map = [{}]",
        map.iter().map(|m| m.to_string()).collect::<Vec<_>>().join(", ")
    );
    let _ = writeln!(s, "joint_names = [{}]", names.join(", "));
    let _ = writeln!(s, "default_pose = {}", fmt_list(&default_pose));
    if action_scale.iter().all(|&a| a == action_scale[0]) {
        let _ = writeln!(s, "action_scale = {:?}", action_scale[0]);
    } else {
        let _ = writeln!(s, "action_scale = {}", fmt_list(&action_scale));
    }
    if let Some(c) = action_clip {
        let _ = writeln!(s, "action_clip = {c:?}");
    }
    let _ = writeln!(s, "kp = {}\nkd = {}\n", fmt_list(&kp), fmt_list(&kd));
    let _ = writeln!(s, "{}", network.spec_table()?);
    // Slots the policy does not drive are held at 0 with the export's own gains for them.
    for &(slot, hkp, hkd) in &held {
        let _ = writeln!(
            s,
            "[[held]]\njoints = [{:?}]\nq = 0.0\nkp = {hkp:?}\nkd = {hkd:?}\n",
            hal::G1_MOTOR_NAMES[slot]
        );
    }
    let _ = writeln!(
        s,
        "[commands]\nmin = {}\nmax = {}\n",
        fmt_list(&[vx[0], vy[0], wz[0]]),
        fmt_list(&[vx[1], vy[1], wz[1]])
    );
    if let Some(p) = terms.iter().find_map(|t| t.period_s) {
        let _ = writeln!(s, "[phase]\nperiod_s = {p:?}\nfirst_step_time_s = {step_dt:?}\n");
    }
    let _ = writeln!(s, "[observation]\nhistory_layout = \"term_major\"\nterms = [");
    for t in &terms {
        let scale = if t.scale.iter().all(|&v| v == t.scale[0]) {
            format!("{:?}", t.scale[0])
        } else {
            fmt_list(&t.scale)
        };
        let clip = t.clip.map_or(String::new(), |[lo, hi]| {
            format!(", clip_before_scale = [{lo:?}, {hi:?}]")
        });
        let _ = writeln!(
            s,
            "  {{ kind = \"{}\", scale = {scale}, history = {}{clip} }},  # {}",
            t.kind, t.history, t.name
        );
    }
    let _ = writeln!(s, "]");
    if let Some(m) = &opts.estimator_model {
        let _ = writeln!(s, "\n[estimator]\nmodel = {m:?}");
    }

    // The table a person checks before trying it on a robot.
    let mut table = observation_table(&terms, obs_dim);
    joint_table(&mut table, &map, &kp, &kd, &default_pose, &action_scale);
    let _ = writeln!(
        table,
        "commands: vx [{}, {}], vy [{}, {}], wz [{}, {}]; policy {policy_hz} Hz in a {} Hz loop; {} held motor(s)",
        vx[0],
        vx[1],
        vy[0],
        vy[1],
        wz[0],
        wz[1],
        opts.control_hz,
        held.len()
    );
    for note in &notes {
        let _ = writeln!(table, "note: {note}");
    }
    Ok(RlLabImport {
        spec_toml: s,
        weights,
        table,
        network,
        joint_ids_map: map,
        kp,
        kd,
        default_pose,
        terms,
    })
}

/// The observation half of the review table: each term's kind, size, history, scale and clip.
fn observation_table(terms: &[Term], obs_dim: usize) -> String {
    let mut table = String::new();
    let _ = writeln!(
        table,
        "observation ({obs_dim} values = the network's input; clip before scale, as IsaacLab):"
    );
    let _ = writeln!(
        table,
        "  {:<28} {:<18} {:>4} {:>4}  {:<26} clip",
        "term", "spec kind", "dims", "hist", "scale"
    );
    for t in terms {
        let _ = writeln!(
            table,
            "  {:<28} {:<18} {:>4} {:>4}  {:<26} {}",
            t.name,
            t.kind,
            t.dim,
            t.history,
            if t.scale.iter().all(|&v| v == t.scale[0]) {
                format!("{}", t.scale[0])
            } else {
                format!("{:?}", t.scale)
            },
            t.clip.map_or("none".into(), |c| format!("[{}, {}]", c[0], c[1]))
        );
    }
    table
}

/// The joint half of the review table: slot, gains, default pose and action scale per policy joint.
fn joint_table(table: &mut String, map: &[usize], kp: &[f32], kd: &[f32], default_pose: &[f32], action_scale: &[f32]) {
    let _ = writeln!(
        table,
        "joints (policy order; kp/kd taken from deploy.yaml's SDK-order lists at the slot):"
    );
    let _ = writeln!(
        table,
        "  {:>3}  {:<28} {:>4} {:>8} {:>7} {:>8} {:>6}",
        "#", "joint", "slot", "kp", "kd", "default", "scale"
    );
    for i in 0..map.len() {
        let _ = writeln!(
            table,
            "  {:>3}  {:<28} {:>4} {:>8} {:>7} {:>8} {:>6}",
            i,
            hal::G1_MOTOR_NAMES[map[i]],
            map[i],
            kp[i],
            kd[i],
            default_pose[i],
            action_scale[i]
        );
    }
}

/// mjlab / BeyondMimic-style term names (`observation_names` metadata) → the spec's kinds.
fn kind_of_meta(name: &str) -> Result<&'static str, String> {
    match name {
        "base_lin_vel" => Err("base_lin_vel: the base's linear velocity is not an observation g1fw offers yet".into()),
        "command" | "commands" | "generated_commands" | "twist" => Ok("velocity_command"),
        other => kind_of(other).ok_or_else(|| {
            format!(
                "'{other}' is not a term g1fw knows; supported: base_ang_vel, projected_gravity, command, joint_pos, \
                 joint_vel, actions, gait_phase"
            )
        }),
    }
}

/// An ONNX that carries its deploy data in `metadata_props`, as mjlab's and BeyondMimic's exporters
/// write it (comma-separated lists, in the policy's joint order): `joint_names`, `joint_stiffness`,
/// `joint_damping`, `default_joint_pos`, `action_scale`, `observation_names`. Command ranges and the
/// policy rate are not in it: defaults are used and said so.
pub fn import_onnx_metadata(onnx: &Path, opts: &RlLabOptions) -> Result<RlLabImport, DeployError> {
    let network = import_file(onnx)?;
    let meta: std::collections::HashMap<&str, &str> =
        network.metadata.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    let get = |k: &str| -> Result<&str, DeployError> {
        meta.get(k).copied().ok_or_else(|| {
            field(
                &format!("metadata_props.{k}"),
                "missing: this ONNX carries no deploy data (mjlab and BeyondMimic exports write it); use g1-import rl-lab with a deploy.yaml",
            )
        })
    };
    let csv = |k: &str| -> Result<Vec<f32>, DeployError> {
        get(k)?
            .split(',')
            .enumerate()
            .map(|(i, v)| {
                v.trim()
                    .parse::<f32>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| field(&format!("metadata_props.{k}[{i}]"), format!("'{v}' is not a number")))
            })
            .collect()
    };
    let names: Vec<&str> = get("joint_names")?.split(',').map(str::trim).collect();
    let mut map = Vec::with_capacity(names.len());
    for (i, name) in names.iter().enumerate() {
        let bare = name.strip_suffix("_joint").unwrap_or(name);
        let slot = hal::G1_MOTOR_NAMES[..G1_SLOTS]
            .iter()
            .position(|m| *m == bare)
            .ok_or_else(|| {
                field(
                    &format!("metadata_props.joint_names[{i}]"),
                    format!("'{name}' is not a G1 joint"),
                )
            })?;
        if let Some(j) = map.iter().position(|&s| s == slot) {
            return Err(field(
                "metadata_props.joint_names",
                format!("'{name}' appears twice, at {j} and {i}"),
            ));
        }
        map.push(slot);
    }
    let n = map.len();
    let per_joint = |k: &str| -> Result<Vec<f32>, DeployError> {
        let v = csv(k)?;
        if v.len() != n {
            return Err(field(
                &format!("metadata_props.{k}"),
                format!("{} values for {n} joints", v.len()),
            ));
        }
        if k != "default_joint_pos" && v.iter().any(|x| *x < 0.0) {
            return Err(field(&format!("metadata_props.{k}"), "a negative gain"));
        }
        Ok(v)
    };
    let kp = per_joint("joint_stiffness")?;
    let kd = per_joint("joint_damping")?;
    let default_pose = per_joint("default_joint_pos")?;
    let scale = csv("action_scale")?;
    let action_scale = match scale.len() {
        1 => vec![scale[0]; n],
        k if k == n => scale,
        k => {
            return Err(field(
                "metadata_props.action_scale",
                format!("{k} values for {n} joints"),
            ))
        }
    };
    let mut terms = Vec::new();
    for (i, t) in get("observation_names")?.split(',').map(str::trim).enumerate() {
        let kind = kind_of_meta(t).map_err(|why| field(&format!("metadata_props.observation_names[{i}]"), why))?;
        if kind == "gait_phase" {
            return Err(field(
                &format!("metadata_props.observation_names[{i}]"),
                "a gait phase needs its period, which the metadata does not carry",
            ));
        }
        let dim = match kind {
            "base_ang_vel" | "projected_gravity" | "velocity_command" => 3,
            _ => n,
        };
        terms.push(Term {
            name: t.to_string(),
            kind,
            dim,
            scale: vec![1.0; dim],
            clip: None,
            history: 1,
            period_s: None,
        });
    }
    let step_dt = 0.02;
    let held: Vec<(usize, f32, f32)> = (0..G1_SLOTS)
        .filter(|s| !map.contains(s))
        .map(|s| (s, 100.0, 5.0))
        .collect();
    let mut notes: Vec<String> = Vec::new();
    if !held.is_empty() {
        notes.push(format!(
            "{} motor(s) the policy does not drive are held at 0 with kp 100, kd 5 (the metadata has no gains for them); edit [[held]]",
            held.len()
        ));
    }
    let draft = Draft {
        source: onnx.display().to_string(),
        name: onnx
            .file_stem()
            .map_or("imported".into(), |f| f.to_string_lossy().into_owned()),
        map: map.clone(),
        kp,
        kd,
        default_pose,
        action_scale,
        action_clip: None,
        ranges: [[-1.0, 1.0], [-0.5, 0.5], [-1.0, 1.0]],
        terms,
        step_dt,
        policy_hz: 50,
        held,
        notes: [
            "the metadata carries no command ranges: vx [-1, 1], vy [-0.5, 0.5], wz [-1, 1] were used; edit [commands]".into(),
            "the metadata carries no policy rate: 50 Hz (step_dt 0.02, mjlab's decimation 4 × 5 ms) was used".into(),
            "observation terms: scale 1, no history, no clip (mjlab's velocity defaults); check them against the training config"
                .into(),
        ]
        .into_iter()
        .chain(notes)
        .collect(),
    };
    finish(draft, network, opts)
}

#[cfg(test)]
mod nesting {
    #[test]
    fn deep_yaml_is_refused_before_parsing() {
        assert!(super::too_deep("a:\n  b: [1, 2, {c: 3}]\n  - x\n").is_none());
        let flow = "[".repeat(100_000);
        let why = super::too_deep(&flow).unwrap();
        assert!(why.contains("nested 100000 levels deep"), "{why}");
        let block: String = (0..200).map(|i| format!("{}k{i}:\n", " ".repeat(2 * i))).collect();
        assert!(super::too_deep(&block).is_some());
    }
}
