//! The G1's left–right mirror symmetry (reflection through the sagittal plane, y → −y) of a deploy
//! spec's observation and action: what the trainer's symmetry augmentation learns from, and what a
//! spec with `[policy] mirror = "average"` runs (the policy and its mirror image averaged, so the
//! deployed policy has no left–right bias by construction).
//!
//! A mirror is a signed permutation: `out[i] = factor[i] · x[source[i]]`. It is built from the
//! deploy spec's own observation layout (terms, history, scales, joint names), so it follows any
//! spec; `train/tests/symmetry.rs` checks it against `PolicyIo` on a mirrored robot. Mirrored, per
//! term:
//! - a joint (position, velocity, action) takes its partner's value (left ↔ right), negated for roll
//!   and yaw joints (their axes are x and z, which the reflection flips);
//! - gyro (ωx, ωy, ωz) → (−ωx, ωy, −ωz); projected gravity (gx, gy, gz) → (gx, −gy, gz); command
//!   (vx, vy, ωz) → (vx, −vy, −ωz);
//! - the two-leg gait clock moves half a period (the other leg leads): (sin, cos) → (−sin, −cos);
//! - the terrain token keeps class, height and depth and negates its yaw;
//! - a policy-set gait clock's rate (`[phase] rate`, the action after the joints) is its own mirror.
use super::{DeploySpec, HistoryLayout, ObsKind};

/// Why a spec has no mirror.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MirrorError {
    #[error("mirror: policy.joint_names must name each of the policy's {expected} joints (it names {found})")]
    JointNames { expected: usize, found: usize },
    #[error("mirror: policy joint {joint} has no partner {partner} in the spec's joint_names")]
    NoPartner { joint: String, partner: String },
    #[error("mirror: {joint} and {partner} have unmirrored default poses or action scales (a mirrored action would not give mirrored targets)")]
    Unmirrored { joint: String, partner: String },
    #[error("mirror: observation term {term}'s scale has the wrong length")]
    ScaleLength { term: usize },
    #[error("mirror: observation term {term} scales element {element} by 0, so its mirror is lost")]
    ZeroScale { term: usize, element: usize },
    #[error("mirror: the observation layout does not cover every value")]
    Uncovered,
}

/// A signed permutation of a vector.
#[derive(Clone, Debug, PartialEq)]
pub struct SignedPermutation {
    pub source: Vec<usize>,
    pub factor: Vec<f32>,
}

impl SignedPermutation {
    pub fn len(&self) -> usize {
        self.source.len()
    }

    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }

    /// `out = mirror(x)`; both `len()` long (shorter slices are mirrored as far as they go).
    pub fn apply(&self, x: &[f32], out: &mut [f32]) {
        for ((o, &s), &f) in out.iter_mut().zip(&self.source).zip(&self.factor) {
            *o = f * x[s];
        }
    }

    /// Mirrors every row of `rows` (each `len()` wide) onto the end of `out`.
    pub fn apply_rows(&self, rows: &[f32], out: &mut Vec<f32>) {
        let w = self.len();
        for row in rows.chunks_exact(w) {
            out.extend(self.source.iter().zip(&self.factor).map(|(&s, &f)| f * row[s]));
        }
    }

    /// `self` followed by `other` (indices of `other` shifted past `self`).
    pub fn then(mut self, other: &SignedPermutation) -> Self {
        let off = self.source.len();
        self.source.extend(other.source.iter().map(|s| s + off));
        self.factor.extend_from_slice(&other.factor);
        self
    }
}

/// The mirrors of one spec's policy: observation and action.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyMirror {
    pub obs: SignedPermutation,
    pub action: SignedPermutation,
}

/// The partner of a G1 joint (`left_…` ↔ `right_…`; a waist joint is its own) and the sign its value
/// takes mirrored.
fn joint_partner(name: &str) -> (String, f32) {
    let partner = if let Some(rest) = name.strip_prefix("left_") {
        format!("right_{rest}")
    } else if let Some(rest) = name.strip_prefix("right_") {
        format!("left_{rest}")
    } else {
        name.to_string()
    };
    let sign = if name.contains("_roll") || name.contains("_yaw") {
        -1.0
    } else {
        1.0
    };
    (partner, sign)
}

/// Element `e` of one frame of `kind`, mirrored: (source element, sign).
fn term_mirror(kind: ObsKind, joints: &[(usize, f32)], e: usize) -> (usize, f32) {
    match kind {
        ObsKind::BaseAngVel => (e, [-1.0, 1.0, -1.0][e]),
        ObsKind::ProjectedGravity => (e, [1.0, -1.0, 1.0][e]),
        ObsKind::VelocityCommand => (e, [1.0, -1.0, -1.0][e]),
        ObsKind::JointPosRel | ObsKind::JointVel | ObsKind::LastAction => joints[e],
        ObsKind::GaitPhase => (e, -1.0),
        ObsKind::TerrainToken => (e, [1.0, 1.0, 1.0, -1.0][e]),
    }
}

impl PolicyMirror {
    /// The mirror `spec`'s policy is averaged with (`[policy] mirror = "average"`), or `None` when
    /// the network runs alone: the one place that reads the setting.
    pub fn averaged_with(spec: &DeploySpec) -> Result<Option<Self>, MirrorError> {
        match spec.policy.mirror {
            super::MirrorMode::None => Ok(None),
            super::MirrorMode::Average => Self::from_spec(spec).map(Some),
        }
    }

    /// The mirrors of `spec`'s observation and action.
    pub fn from_spec(spec: &DeploySpec) -> Result<Self, MirrorError> {
        let p = &spec.policy;
        let n = p.joint_names.len();
        if n != p.joint_ids_map.len() || n != p.default_pose.len() {
            return Err(MirrorError::JointNames {
                expected: p.joint_ids_map.len(),
                found: n,
            });
        }
        let scale = p.action_scale.expand(n).unwrap_or_default();
        let mut joints = Vec::with_capacity(n);
        for (i, name) in p.joint_names.iter().enumerate() {
            let (partner, sign) = joint_partner(name);
            let j = p
                .joint_names
                .iter()
                .position(|x| *x == partner)
                .ok_or_else(|| MirrorError::NoPartner {
                    joint: name.clone(),
                    partner: partner.clone(),
                })?;
            // Targets are default + scale · action: the mirror holds only for a symmetric pose and scale.
            if (p.default_pose[i] - sign * p.default_pose[j]).abs() >= 1e-6 || scale.get(i) != scale.get(j) {
                return Err(MirrorError::Unmirrored {
                    joint: name.clone(),
                    partner,
                });
            }
            joints.push((j, sign));
        }
        // A policy-set clock's rate (the output after the joints) has no side: it mirrors to itself.
        let extra = spec.action_dim() - n;
        let action = SignedPermutation {
            source: joints.iter().map(|j| j.0).collect(),
            factor: joints.iter().map(|j| j.1).collect(),
        }
        .then(&SignedPermutation {
            source: (0..extra).collect(),
            factor: vec![1.0; extra],
        });

        // Each observation value: (term, frame, element) in the spec's layout.
        let terms = &spec.observation.terms;
        let dims: Vec<usize> = terms.iter().map(|t| t.kind.dim(n)).collect();
        let mut offsets = Vec::new(); // per term, per frame: the first index
        match spec.observation.history_layout {
            HistoryLayout::TermMajor => {
                let mut at = 0;
                for (t, term) in terms.iter().enumerate() {
                    offsets.push((0..term.history).map(|f| at + f * dims[t]).collect::<Vec<_>>());
                    at += term.history * dims[t];
                }
            }
            HistoryLayout::FrameMajor => {
                let h = terms.first().map_or(1, |t| t.history);
                let frame: usize = dims.iter().sum();
                let mut before = 0;
                for d in &dims {
                    offsets.push((0..h).map(|f| f * frame + before).collect());
                    before += d;
                }
            }
        }
        let total = spec.observation_dim();
        let mut obs = SignedPermutation {
            source: vec![usize::MAX; total],
            factor: vec![0.0; total],
        };
        for (t, term) in terms.iter().enumerate() {
            let scale = term.scale.expand(dims[t]).ok_or(MirrorError::ScaleLength { term: t })?;
            for &start in &offsets[t] {
                for e in 0..dims[t] {
                    let (src, sign) = term_mirror(term.kind, &joints, e);
                    if scale[src] == 0.0 && scale[e] != 0.0 {
                        return Err(MirrorError::ZeroScale { term: t, element: src });
                    }
                    let ratio = if scale[src] == 0.0 { 0.0 } else { scale[e] / scale[src] };
                    obs.source[start + e] = start + src;
                    obs.factor[start + e] = sign * ratio;
                }
            }
        }
        if obs.source.iter().any(|&s| s >= total) {
            return Err(MirrorError::Uncovered);
        }
        Ok(Self { obs, action })
    }
}
