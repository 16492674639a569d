//! Wire codecs for the G1's devices. Pure functions from bytes to `hal` types and back: no I/O, no
//! allocation, and every malformed input is an error value, never a panic.
pub mod bev;
pub mod bev_memory;
pub mod can;
pub mod livox;
pub mod unitree_hg;
