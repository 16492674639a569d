//! Observation builder: turns sensor-derived signals into the policy's input vector exactly as the
//! deploy spec lays it out. All buffers are sized at construction; `build` allocates nothing.
use crate::spec::{DeploySpec, HistoryLayout, ObsKind};

/// Signals of one policy step, in policy joint order.
pub struct ObsInputs<'a> {
    pub gyro: [f32; 3],
    pub quat: [f32; 4],
    /// Clamped operator command (vx, vy, wz).
    pub command: [f32; 3],
    /// Joint positions relative to the default pose.
    pub joint_pos_rel: &'a [f32],
    pub joint_vel: &'a [f32],
    pub last_action: &'a [f32],
    /// Gait phase in [0, 1).
    pub phase: f32,
    /// The perception group's current terrain token.
    pub terrain: hal::TerrainToken,
}

struct Term {
    kind: ObsKind,
    dim: usize,
    scale: Vec<f32>,
    clip: Option<f32>,
    clip_before_scale: Option<[f32; 2]>,
    history: usize,
    /// Ring of `history` frames of `dim` values; `head` is the slot of the newest frame.
    ring: Vec<f32>,
    head: usize,
}

pub struct ObservationBuilder {
    terms: Vec<Term>,
    layout: HistoryLayout,
    dim: usize,
    /// False until the first frame: the first frame fills the whole history (IsaacLab's reset).
    primed: bool,
}

impl ObservationBuilder {
    pub fn new(spec: &DeploySpec) -> Self {
        let n = spec.num_joints();
        let terms = spec
            .observation
            .terms
            .iter()
            .map(|t| {
                let dim = t.kind.dim(n);
                Term {
                    kind: t.kind,
                    dim,
                    scale: t.scale.expand(dim).expect("validated by DeploySpec"),
                    clip: t.clip,
                    clip_before_scale: t.clip_before_scale,
                    history: t.history,
                    ring: vec![0.0; dim * t.history],
                    head: 0,
                }
            })
            .collect();
        Self {
            terms,
            layout: spec.observation.history_layout,
            dim: spec.observation_dim(),
            primed: false,
        }
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Forgets the history (the next frame fills it again).
    pub fn reset(&mut self) {
        self.primed = false;
    }

    /// Pushes one frame of signals and writes the full observation into `out` (length `dim()`).
    pub fn build(&mut self, x: &ObsInputs, out: &mut [f32]) {
        debug_assert_eq!(out.len(), self.dim);
        let gravity = estimator::projected_gravity(x.quat);
        let (s, c) = libm::sincosf(2.0 * std::f32::consts::PI * x.phase);
        for term in &mut self.terms {
            let slot = if self.primed { (term.head + 1) % term.history } else { 0 };
            let frame = &mut term.ring[slot * term.dim..(slot + 1) * term.dim];
            match term.kind {
                ObsKind::BaseAngVel => frame.copy_from_slice(&x.gyro),
                ObsKind::ProjectedGravity => frame.copy_from_slice(&gravity),
                ObsKind::VelocityCommand => frame.copy_from_slice(&x.command),
                ObsKind::JointPosRel => frame.copy_from_slice(x.joint_pos_rel),
                ObsKind::JointVel => frame.copy_from_slice(x.joint_vel),
                ObsKind::LastAction => frame.copy_from_slice(x.last_action),
                ObsKind::GaitPhase => frame.copy_from_slice(&[s, c]),
                ObsKind::TerrainToken => {
                    let z = &x.terrain;
                    frame.copy_from_slice(&[z.class.index() as f32, z.step_height_m, z.step_depth_m, z.yaw_rad])
                }
            }
            for (v, k) in frame.iter_mut().zip(&term.scale) {
                // IsaacLab clips the raw term, then scales; bounds validated (low <= high, not NaN).
                if let Some([lo, hi]) = term.clip_before_scale {
                    *v = v.max(lo).min(hi);
                }
                *v *= k;
                if let Some(clip) = term.clip {
                    *v = v.max(-clip).min(clip);
                }
            }
            if !self.primed {
                let (first, rest) = term.ring.split_at_mut(term.dim);
                for chunk in rest.chunks_exact_mut(term.dim) {
                    chunk.copy_from_slice(first);
                }
            }
            term.head = slot;
        }
        self.primed = true;

        match self.layout {
            HistoryLayout::TermMajor => {
                let mut at = 0;
                for term in &self.terms {
                    for age in (0..term.history).rev() {
                        let slot = (term.head + term.history - age) % term.history;
                        out[at..at + term.dim].copy_from_slice(&term.ring[slot * term.dim..(slot + 1) * term.dim]);
                        at += term.dim;
                    }
                }
            }
            HistoryLayout::FrameMajor => {
                let h = self.terms.first().map_or(1, |t| t.history);
                let mut at = 0;
                for age in (0..h).rev() {
                    for term in &self.terms {
                        let slot = (term.head + term.history - age) % term.history;
                        out[at..at + term.dim].copy_from_slice(&term.ring[slot * term.dim..(slot + 1) * term.dim]);
                        at += term.dim;
                    }
                }
            }
        }
    }
}

snapshot::snapshot_fields!(Term { ring, head });
snapshot::snapshot_fields!(ObservationBuilder { terms, primed });
