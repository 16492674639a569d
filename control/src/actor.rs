//! The policy as a deploy spec runs it: its network alone, or (`[policy] mirror = "average"`) the
//! mean of the network's action and the mirror image of its action on the mirrored observation,
//! the second run keeping its own recurrent state. The controller and the trainer's rollouts both
//! step this type, so what trains is what runs.
use crate::nn::{Network, NnError};
use crate::spec::mirror::{MirrorError, PolicyMirror};
use crate::spec::DeploySpec;

/// The network run a second time on the mirror image of each observation; buffers allocated once,
/// so a step allocates nothing.
#[derive(Clone)]
struct MirroredTwin {
    mirror: PolicyMirror,
    net: Network,
    obs: Vec<f32>,
    raw: Vec<f32>,
    action: Vec<f32>,
}

/// A spec's policy: the network and, with `mirror = "average"`, its mirrored twin.
#[derive(Clone)]
pub struct Actor {
    net: Network,
    twin: Option<MirroredTwin>,
}

impl Actor {
    /// The policy `spec` describes, with `net` as its network (its input and output sizes are the
    /// caller's to check against the spec).
    pub fn new(spec: &DeploySpec, net: Network) -> Result<Self, MirrorError> {
        let twin = PolicyMirror::averaged_with(spec)?.map(|mirror| {
            let n = mirror.action.len();
            MirroredTwin {
                obs: vec![0.0; mirror.obs.len()],
                raw: vec![0.0; n],
                action: vec![0.0; n],
                net: net.clone(),
                mirror,
            }
        });
        Ok(Self { net, twin })
    }

    /// The network (the twin runs the same weights).
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// The mirror the twin runs with, if any.
    pub fn mirror(&self) -> Option<&PolicyMirror> {
        self.twin.as_ref().map(|t| &t.mirror)
    }

    pub fn input_dim(&self) -> usize {
        self.net.input_dim()
    }

    pub fn output_dim(&self) -> usize {
        self.net.output_dim()
    }

    /// One policy step: `action = policy(obs)`, advancing the recurrent state(s). Allocates nothing.
    pub fn step(&mut self, obs: &[f32], action: &mut [f32]) -> Result<(), NnError> {
        self.net.step(obs, action)?;
        if let Some(t) = self.twin.as_mut() {
            t.mirror.obs.apply(obs, &mut t.obs);
            t.net.step(&t.obs, &mut t.raw)?;
            t.mirror.action.apply(&t.raw, &mut t.action);
            for (a, m) in action.iter_mut().zip(&t.action) {
                *a = 0.5 * (*a + m);
            }
        }
        Ok(())
    }

    /// Recurrent state back to its start (the twin's too).
    pub fn reset(&mut self) {
        self.net.reset();
        if let Some(t) = self.twin.as_mut() {
            t.net.reset();
        }
    }

    /// Length of the recurrent state: the network's, then the twin's ([`Network::state_len`] each).
    pub fn state_len(&mut self) -> usize {
        self.net.state_len() + self.twin.as_mut().map_or(0, |t| t.net.state_len())
    }

    /// Copies the recurrent state into `out` (length [`Actor::state_len`]): the network's, then the twin's.
    pub fn read_state(&mut self, out: &mut [f32]) {
        let n = self.net.state_len();
        self.net.read_state(&mut out[..n]);
        if let Some(t) = self.twin.as_mut() {
            t.net.read_state(&mut out[n..]);
        }
    }

    /// Sets the recurrent state from `state` (the layout of [`Actor::read_state`]).
    pub fn write_state(&mut self, state: &[f32]) {
        let n = self.net.state_len();
        self.net.write_state(&state[..n]);
        if let Some(t) = self.twin.as_mut() {
            t.net.write_state(&state[n..]);
        }
    }

    /// Swaps in other weights (same description), keeping the recurrent state.
    pub fn set_weights(&mut self, net: &Network) {
        let mut state = vec![0.0; self.state_len()];
        self.read_state(&mut state);
        self.net = net.clone();
        if let Some(t) = self.twin.as_mut() {
            t.net = net.clone();
        }
        self.write_state(&state);
    }
}

/// The network's recurrent state, and its mirrored twin's.
impl snapshot::Snapshot for Actor {
    fn save(&self, out: &mut Vec<u8>) {
        self.net.save(out);
        if let Some(t) = &self.twin {
            t.net.save(out);
        }
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        self.net.restore(input)?;
        if let Some(t) = &mut self.twin {
            t.net.restore(input)?;
        }
        Ok(())
    }
}
