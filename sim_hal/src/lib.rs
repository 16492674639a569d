//! HAL implementations for simulation and the bench: the lock-stepped bridge protocol and its
//! client, and the CAN bench (SocketCAN HAL, motor emulator logic; the G1 itself speaks DDS,
//! `robot_io::dds`).
pub mod bridge;
pub mod can;
