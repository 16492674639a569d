//! Symmetry augmentation (IsaacLab ships it for the G1; rsl_rl's `use_data_augmentation`): each
//! transition is also learned mirrored, which doubles the data per simulated step. The mirror of
//! the observation and action is the firmware's own ([`control::spec::mirror`]), built from the deploy
//! spec; the critic's privileged inputs add their own mirror after it.
use control::spec::mirror::PolicyMirror;
pub use control::spec::mirror::SignedPermutation;
use control::spec::DeploySpec;

/// The mirrors of one spec: actor observation, critic observation, action.
#[derive(Clone, Debug, PartialEq)]
pub struct Mirror {
    pub obs: SignedPermutation,
    pub critic: SignedPermutation,
    pub action: SignedPermutation,
}

impl Mirror {
    /// The mirrors of `spec`'s observation and action; `critic_extra` is the mirror of the
    /// privileged inputs the critic sees after the observation (`env::critic_extra_mirror`).
    pub fn from_spec(spec: &DeploySpec, critic_extra: &SignedPermutation) -> anyhow::Result<Self> {
        let PolicyMirror { obs, action } = PolicyMirror::from_spec(spec)?;
        let critic = obs.clone().then(critic_extra);
        Ok(Self { obs, critic, action })
    }
}
