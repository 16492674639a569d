//! One iteration's figures, as the runner logs them and the curves plot them.
use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::algo::UpdateStats;

/// One iteration's figures (history.json, curves.png).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct IterLog {
    pub iteration: usize,
    pub env_steps: u64,
    pub wall_s: f64,
    pub mean_reward_per_step: f64,
    pub episodes: usize,
    pub mean_episode_return: Option<f64>,
    pub success_rate: Option<f64>,
    /// The same for staircases up (straight and outdoor) and down, apart: together they hid that
    /// climbing failed where descending succeeded (histories before run 14 lack them).
    #[serde(default)]
    pub success_up: Option<f64>,
    #[serde(default)]
    pub success_down: Option<f64>,
    pub fall_rate: Option<f64>,
    /// Falls by cause, in the order of `env::FALL_CAUSES` (tilt, joint speed, base height, base
    /// angular speed; histories written before the last was added have three).
    #[serde(default)]
    pub fall_causes: Vec<usize>,
    pub mean_level: f64,
    /// Mean level of the environments whose column goes up, and down.
    #[serde(default)]
    pub level_up: Option<f64>,
    #[serde(default)]
    pub level_down: Option<f64>,
    /// Success of the assisted climbs (`--assist-share`; not in the rates above), and the strength
    /// assisted episodes started with this iteration (histories before 2026-12-02 lack them).
    #[serde(default)]
    pub success_assisted: Option<f64>,
    #[serde(default)]
    pub assist_strength: f64,
    pub env_steps_per_s: f64,
    pub learner_share: f64,
    /// Wall time of this iteration's rollouts (the slowest worker) and of the update, s. They
    /// overlap: the iteration takes about the longer of the two.
    #[serde(default)]
    pub rollout_s: f64,
    #[serde(default)]
    pub update_s: f64,
    pub update: UpdateStats,
    /// The mean return of this iteration's finished episodes split by reward term (the terms
    /// that are not zero; histories before it was added lack it): what the policy is paid for.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub return_by_term: BTreeMap<String, f64>,
}
