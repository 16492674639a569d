//! Serde-deserializable description of a network: which layers, in which order, and which
//! tensors of the weight file feed them. Layer shapes come from the weight file, never from here,
//! so the description cannot silently disagree with the weights; the only shape given here is how
//! the flat input is laid out as an image (`input_shape`), which convolutions need.

use serde::{Deserialize, Serialize};

/// A feed-forward chain of layers applied to an input vector of length `input`.
///
/// Designed to sit inside a TOML deploy spec; see the module docs for the exact form.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkDesc {
    /// Length of the input vector (the observation); checked against the first layer's weights.
    pub input: usize,
    /// The input's image shape `[C, H, W]` (product = `input`), stored CHW-flattened exactly as
    /// PyTorch's `x.flatten()`. Needed when the first shaped layer is a [`LayerDesc::Conv2d`];
    /// absent for vector inputs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input_shape: Option<Vec<usize>>,
    /// Layers applied in order; the output of the last one is the network output.
    pub layers: Vec<LayerDesc>,
}

/// One layer of a [`NetworkDesc`]. Tensor fields name tensors in the safetensors file.
///
/// Tagged by `type` (snake_case) so each layer is a self-describing TOML table; unknown keys are
/// rejected so a typo in an optional field (e.g. `initial_hiden`) is an error, not a silent default.
/// New layer kinds (BatchNorm, pooling, ...) are added as new variants.
///
/// Activations carry a shape: `[n]` for vectors, `[C, H, W]` for images (from
/// [`NetworkDesc::input_shape`] or a `conv2d`), always stored CHW-flattened. Element-wise layers
/// keep the shape; `linear` and `lstm` consume the flat vector (like `nn.Flatten` first) and
/// produce `[out]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum LayerDesc {
    /// `y = W x + b`, PyTorch `nn.Linear` layout: `weight` is `[out, in]`, `bias` is `[out]`.
    Linear { weight: String, bias: String },
    /// `x > 0 ? x : alpha * (exp(x) - 1)`.
    Elu { alpha: f32 },
    /// `max(x, 0)`.
    Relu,
    /// `tanh(x)`.
    Tanh,
    /// Single-layer stateful PyTorch `nn.LSTM` (gate order i, f, g, o; both bias vectors).
    ///
    /// `weight_ih` is `[4H, in]`, `weight_hh` is `[4H, H]`, biases `[4H]`. Output is `h` (length
    /// `H`). `h`/`c` carry over between [`crate::nn::Network::step`] calls; `reset()` restores
    /// them to `initial_hidden`/`initial_cell` (any shape with `H` elements) or to zeros.
    Lstm {
        weight_ih: String,
        weight_hh: String,
        bias_ih: String,
        bias_hh: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        initial_hidden: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        initial_cell: Option<String>,
    },
    /// 2-D convolution, PyTorch `nn.Conv2d` layout with square stride and zero padding:
    /// `weight` is `[cout, cin, kh, kw]`, `bias` is `[cout]`. Input `[cin, H, W]`, output
    /// `[cout, (H + 2 padding - kh) / stride + 1, (W + 2 padding - kw) / stride + 1]`.
    /// (Fold BatchNorm into `weight`/`bias` before export.)
    Conv2d {
        weight: String,
        bias: String,
        #[serde(default = "one")]
        stride: usize,
        #[serde(default)]
        padding: usize,
    },
}

fn one() -> usize {
    1
}

impl LayerDesc {
    /// Short kind name used in error messages.
    pub fn kind(&self) -> &'static str {
        match self {
            LayerDesc::Linear { .. } => "linear",
            LayerDesc::Elu { .. } => "elu",
            LayerDesc::Relu => "relu",
            LayerDesc::Tanh => "tanh",
            LayerDesc::Lstm { .. } => "lstm",
            LayerDesc::Conv2d { .. } => "conv2d",
        }
    }
}
