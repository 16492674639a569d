//! Errors of the network executor. Load errors name the layer and tensor and say what was
//! expected versus found, because they are read by someone fixing a deploy spec or weight file.

use std::path::PathBuf;
use thiserror::Error;

/// Everything that can go wrong loading or stepping a [`crate::nn::Network`].
#[derive(Debug, Error)]
pub enum NnError {
    #[error("cannot read weight file {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("weight file is not valid safetensors: {0}")]
    Format(String),
    #[error("network description has no layers")]
    NoLayers,
    #[error("network input dimension must be > 0")]
    ZeroInput,
    #[error(
        "input_shape {shape:?} has {product} elements, but input = {input}: the shape must be \
         [C, H, W] (or any shape) whose product is input"
    )]
    InputShape {
        shape: Vec<usize>,
        product: usize,
        input: usize,
    },
    #[error("{layer}: tensor `{tensor}` ({role}) not found in weight file (available: {available})")]
    MissingTensor {
        layer: String,
        role: &'static str,
        tensor: String,
        available: String,
    },
    #[error("{layer}: tensor `{tensor}` ({role}) has dtype {found}, expected F32")]
    Dtype {
        layer: String,
        role: &'static str,
        tensor: String,
        found: String,
    },
    #[error("{layer}: tensor `{tensor}` ({role}) has shape {found:?}, expected {expected}")]
    Shape {
        layer: String,
        role: &'static str,
        tensor: String,
        expected: String,
        found: Vec<usize>,
    },
    #[error("{layer}: tensor `{tensor}` ({role}) contains a non-finite value at flat index {index}")]
    NonFinite {
        layer: String,
        role: &'static str,
        tensor: String,
        index: usize,
    },
    #[error(
        "{layer}: expects input dimension {expected} (from tensor `{tensor}`), \
         but {source_desc} produces {found}"
    )]
    InputDim {
        layer: String,
        tensor: String,
        expected: usize,
        found: usize,
        source_desc: String,
    },
    #[error("{layer}: invalid parameter: {message}")]
    Param { layer: String, message: String },
    /// A convolution's input or geometry does not fit (no image shape, channels, kernel size).
    #[error("{layer}: {message}")]
    ConvShape { layer: String, message: String },
    #[error("{layer}: {elements} elements is more than the {max} an activation may have")]
    TooLarge { layer: String, elements: usize, max: usize },
    #[error("step: input slice has length {found}, network input dimension is {expected}")]
    InputLen { expected: usize, found: usize },
    #[error("step: output slice has length {found}, network output dimension is {expected}")]
    OutputLen { expected: usize, found: usize },
}

/// `e` and each of its causes, joined by ": " (the OS reason of an I/O error is a cause, said once).
pub fn with_causes(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        s.push_str(": ");
        s.push_str(&c.to_string());
        cause = c.source();
    }
    s
}
