//! The stair-climbing policy: PPO on vectorised in-process MuJoCo environments of the G1, with the
//! firmware's own observation, action and network code (`g1-train ppo`).
//!
//! - [`env`]: one environment (reset, step: simulator, randomisation, privileged token).
//! - [`reward`]: every reward term and weight.
//! - [`curriculum`]: terrain columns, levels and the worlds drawn for them.
//! - [`assist`]: a decaying helping hand on the base for climbs the policy cannot yet do
//!   (`--assist-share`).
//! - [`termination`]: when an episode ends early (the supervisor's walls, a base too low).
//! - [`policy`]: the actor (the spec's layers: the peer walker's LSTM, or an MLP over a short
//!   history) and critic in candle; export.
//! - [`checkpoint`]: the whole run in one file (weights, optimizers, normaliser, counters, streams).
//! - [`chunks`]: a run's table of chunks (each invocation that trained it).
//! - [`critic_file`]: the critic, its normaliser and the action noise, saved beside each actor.
//! - [`elu_op`]: ELU as one op with a one-loop backward.
//! - [`matmul`]: strided matrix products on the calling thread (the fused ops' kernel).
//! - [`mlp_update`]: the whole PPO step of a feed-forward actor and critic over preallocated
//!   buffers (forward, losses, backward, gradient clip, Adam) without a tensor graph.
//! - [`lstm_op`]: the LSTM's recurrence over a sequence as one op with a hand-written backward.
//! - [`symmetry`]: the G1's left–right mirror, for data augmentation.
//! - [`stair_turn`]: commanded turns off a staircase's axis (`--stair-turns`).
//! - [`rollout`]: environments stepping the actor with exploration noise.
//! - [`adam`]: Adam with its moments in the open (checkpoints hold them).
//! - [`algo`]: rollout storage, GAE and the PPO update.
//! - [`runner`]: the loop (a pipeline of rollout and update on worker threads), checkpoints, curves.
//! - [`iter_log`]: one iteration's figures.
//! - [`in_env`]: an actor evaluated in the training environment itself, one level at a time.
//! - [`judge`]: checkpoints judged through `g1fw eval` (a fixed set of staircases and a flat run).
//! - [`widen`]: a wider actor that computes what the narrow one did (`g1-train widen-actor`).
//! - [`average`]: the weighted average of snapshots of one fine-tune (`g1-train average-actors`).
//! - [`success_curve`]: stair success through `g1fw eval` against env steps, and per riser height
//!   against the paper (`g1-train success-curve`).
pub mod adam;
pub mod algo;
pub mod assist;
pub mod average;
pub mod checkpoint;
pub mod chunks;
pub mod critic_file;
pub mod curriculum;
pub mod elu_op;
pub mod env;
pub mod in_env;
pub mod iter_log;
pub mod judge;
pub mod lstm_op;
pub mod matmul;
pub mod mlp_update;
pub mod policy;
pub mod reward;
pub mod rollout;
pub mod runner;
pub mod stair_turn;
pub mod success_curve;
pub mod symmetry;
pub mod termination;
pub mod widen;
