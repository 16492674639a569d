//! HAL implementations for simulation and the bench: the lock-stepped bridge protocol and its
//! client, and the G1 on CAN (SocketCAN HAL, motor emulator logic).
pub mod bridge;
pub mod can;
