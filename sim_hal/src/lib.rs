//! HAL implementations for simulation: the lock-stepped bridge protocol and its client.
pub mod bridge;
