//! placeholder
#[derive(Debug, thiserror::Error)]
#[error("x")]
pub struct BridgeError;
pub struct BridgeHal;
