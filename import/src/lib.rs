//! Bring your own policy: ONNX networks as rsl_rl, IsaacLab, unitree_rl_lab and mjlab export them,
//! converted into what `g1fw` runs ([`control::nn::NetworkDesc`] + safetensors). See [`onnx`].
pub mod onnx;
pub mod rl_lab;

pub use onnx::{import_bytes, import_file, ImportError, ImportedNetwork};
pub use rl_lab::{import_onnx_metadata, import_rl_lab, DeployError, RlLabImport, RlLabOptions};
