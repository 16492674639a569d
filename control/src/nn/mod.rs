//! Fixed-buffer neural-network executor for the control loop.
//!
//! A [`NetworkDesc`] (usually embedded in the TOML deploy spec) names the layers (Linear,
//! ELU/ReLU/Tanh, stateful LSTM, Conv2d) and the tensors of a safetensors weight file; [`Network::load`] validates the two against each other and
//! allocates every buffer up front, so [`Network::step`] — called at the policy rate inside the
//! real-time loop — never allocates, never panics, and is bit-reproducible across x86-64 and
//! aarch64 (see the `kernels` module docs for how).
//!
//! # Example
//!
//! The peer policy (Unitree G1 LSTM), as written in a deploy spec:
//!
//! ```
//! use control::nn::{LayerDesc, NetworkDesc};
//!
//! #[derive(serde::Deserialize)]
//! struct Policy {
//!     network: NetworkDesc,
//! }
//! #[derive(serde::Deserialize)]
//! struct Spec {
//!     policy: Policy,
//! }
//!
//! let spec: Spec = toml::from_str(r#"
//! [policy.network]
//! input = 47
//! layers = [
//!   { type = "lstm", weight_ih = "memory.weight_ih_l0", weight_hh = "memory.weight_hh_l0", bias_ih = "memory.bias_ih_l0", bias_hh = "memory.bias_hh_l0", initial_hidden = "hidden_state", initial_cell = "cell_state" },
//!   { type = "linear", weight = "actor.0.weight", bias = "actor.0.bias" },
//!   { type = "elu", alpha = 1.0 },
//!   { type = "linear", weight = "actor.2.weight", bias = "actor.2.bias" },
//! ]
//! "#).unwrap();
//! assert_eq!(spec.policy.network.layers[2], LayerDesc::Elu { alpha: 1.0 });
//!
//! // Then, once at startup:
//! fn run(desc: &NetworkDesc) -> Result<(), control::nn::NnError> {
//!     let mut net = control::nn::Network::load(desc, "policy.safetensors".as_ref())?;
//!     let (obs, mut action) = (vec![0.0f32; net.input_dim()], vec![0.0f32; net.output_dim()]);
//!     net.step(&obs, &mut action)?; // every control tick; state carries over
//!     Ok(())
//! }
//! # let _ = run;
//! ```
//!
//! A convolutional network (the terrain CNN) gives its input's image shape; activations are
//! CHW-flattened like PyTorch's `x.flatten()`, so a `linear` after a `conv2d` acts like
//! `nn.Flatten()` + `nn.Linear`:
//!
//! ```
//! let desc: control::nn::NetworkDesc = toml::from_str(r#"
//! input = 21600
//! input_shape = [6, 60, 60]
//! layers = [
//!   { type = "conv2d", weight = "conv1.weight", bias = "conv1.bias", stride = 2, padding = 1 },
//!   { type = "relu" },
//!   { type = "linear", weight = "fc.weight", bias = "fc.bias" },
//! ]
//! "#).unwrap();
//! assert_eq!(desc.input_shape, Some(vec![6, 60, 60]));
//! ```

mod desc;
mod error;
mod kernels;
mod layers;

pub use desc::{LayerDesc, NetworkDesc};

/// The executor's activation functions, for code that must compute exactly what it computes (the
/// trainer's LSTM replay).
pub mod activation {
    pub use super::kernels::{elu, sigmoid, tanh};
}
pub use error::{with_causes, NnError};

use layers::{Layer, TensorSource};
use safetensors::SafeTensors;
use sha2::{Digest, Sha256};
use std::fmt;
use std::path::Path;

/// Where a layer reads or writes its activation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Buf {
    Input,
    Ping,
    Pong,
    Output,
}

/// Lower-case hex SHA-256 of `bytes`: how weight files and specs are identified in logs and
/// replays ([`Network::weights_sha256`], the run metadata, `g1-train`'s parity fixtures).
pub fn sha256_hex(bytes: &[u8]) -> String {
    format!("{:x}", Sha256::digest(bytes))
}

/// A loaded network: packed weights, recurrent state and activation buffers. A clone is an
/// independent copy (its own state and buffers), cheaper than loading the weights again.
#[derive(Clone)]
pub struct Network {
    layers: Vec<Layer>,
    /// Per layer: the buffers it reads and writes, or `None` for a pass-through layer that is
    /// skipped (fixed at load; the last layer always writes `Output`).
    route: Vec<Option<(Buf, Buf)>>,
    /// `dims[0]` is the input width, `dims[i + 1]` the output width of layer `i`.
    dims: Vec<usize>,
    /// The same as shapes: `[n]` for vectors, `[C, H, W]` for images; product = `dims[i]`.
    shapes: Vec<Vec<usize>>,
    /// Ping-pong activation buffers, each as wide as the widest intermediate activation.
    ping: Vec<f32>,
    pong: Vec<f32>,
    params: usize,
    sha256: String,
}

/// Most elements one activation (the input, or any layer's output) may have: 64 MiB of f32. The
/// terrain CNN's largest is under 60,000.
pub const MAX_ACTIVATION: usize = 1 << 24;

/// Largest weight file read (the policies and the terrain CNN here are under 2 MB): a larger file
/// is refused before it is read, not held in memory whole.
pub const MAX_WEIGHTS_BYTES: u64 = 256 << 20;

impl Network {
    /// Reads and validates the weight file at `weights_path` against `desc` (at most
    /// [`MAX_WEIGHTS_BYTES`]).
    pub fn load(desc: &NetworkDesc, weights_path: &Path) -> Result<Network, NnError> {
        let bytes = crate::read_capped(weights_path, MAX_WEIGHTS_BYTES).map_err(|source| NnError::Io {
            path: weights_path.to_path_buf(),
            source,
        })?;
        Self::from_safetensors_bytes(desc, &bytes)
    }

    /// Like [`Network::load`], from the bytes of a safetensors file (tests, embedded weights).
    pub fn from_safetensors_bytes(desc: &NetworkDesc, bytes: &[u8]) -> Result<Network, NnError> {
        if desc.layers.is_empty() {
            return Err(NnError::NoLayers);
        }
        if desc.input == 0 {
            return Err(NnError::ZeroInput);
        }
        if desc.input > MAX_ACTIVATION {
            return Err(NnError::TooLarge {
                layer: "the network input".into(),
                elements: desc.input,
                max: MAX_ACTIVATION,
            });
        }
        let input_shape = match &desc.input_shape {
            None => vec![desc.input],
            Some(shape) => {
                let product = shape
                    .iter()
                    .try_fold(1usize, |a, &d| a.checked_mul(d))
                    .unwrap_or(usize::MAX);
                if product != desc.input || shape.is_empty() {
                    return Err(NnError::InputShape {
                        shape: shape.clone(),
                        product,
                        input: desc.input,
                    });
                }
                shape.clone()
            }
        };
        let st = SafeTensors::deserialize(bytes).map_err(|e| NnError::Format(safetensors_in_words(&e, bytes)))?;
        let mut layers = Vec::with_capacity(desc.layers.len());
        let mut dims = vec![desc.input];
        let mut shapes = vec![input_shape];
        let mut params = 0;
        let mut source_desc = "the network input".to_string();
        for (i, layer_desc) in desc.layers.iter().enumerate() {
            let src = TensorSource {
                st: &st,
                layer: format!("layers[{i}] ({})", layer_desc.kind()),
            };
            let (layer, shape, n) = src.build(layer_desc, &shapes[i], &source_desc)?;
            // Activations are allocated at load: bound them before (a chain of convolutions can
            // grow them far beyond the weight file's size).
            let width = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
            match width {
                Some(w) if w <= MAX_ACTIVATION => dims.push(w),
                _ => {
                    return Err(NnError::TooLarge {
                        layer: src.layer,
                        elements: width.unwrap_or(usize::MAX),
                        max: MAX_ACTIVATION,
                    })
                }
            }
            shapes.push(shape);
            params += n;
            layers.push(layer);
            source_desc = src.layer;
        }
        for i in 1..layers.len() {
            let (head, tail) = layers.split_at_mut(i);
            head[i - 1].fuse(&mut tail[0]);
        }
        // Layer i reads where the activation is and writes the other ping-pong buffer (the last
        // one writes the output); a pass-through layer leaves the activation where it is.
        let last = layers.len() - 1;
        let mut cur = Buf::Input;
        let route = layers
            .iter()
            .enumerate()
            .map(|(i, layer)| {
                if i == last {
                    Some((cur, Buf::Output))
                } else if layer.is_pass_through() {
                    None
                } else {
                    let to = if cur == Buf::Ping { Buf::Pong } else { Buf::Ping };
                    Some((std::mem::replace(&mut cur, to), to))
                }
            })
            .collect();
        let widest = dims[1..dims.len() - 1].iter().copied().max().unwrap_or(0);
        let sha256 = sha256_hex(bytes);
        Ok(Network {
            layers,
            route,
            dims,
            shapes,
            ping: vec![0.0; widest],
            pong: vec![0.0; widest],
            params,
            sha256,
        })
    }

    /// Length of the input slice [`Network::step`] expects.
    pub fn input_dim(&self) -> usize {
        self.dims[0]
    }

    /// Length of the output slice [`Network::step`] fills.
    pub fn output_dim(&self) -> usize {
        self.dims[self.dims.len() - 1]
    }

    /// Shape of the input: `input_shape` from the description, or `[input_dim]`.
    pub fn input_shape(&self) -> &[usize] {
        &self.shapes[0]
    }

    /// Shape of the activation after layer `i` (`[n]` or `[C, H, W]`), `None` past the end.
    pub fn layer_output_shape(&self, i: usize) -> Option<&[usize]> {
        self.shapes.get(i + 1).map(Vec::as_slice)
    }

    /// Number of learned parameters (weights and biases) read from the file.
    pub fn param_count(&self) -> usize {
        self.params
    }

    /// Lower-case hex SHA-256 of the weight file bytes, to log which policy is running.
    pub fn weights_sha256(&self) -> &str {
        &self.sha256
    }

    /// Runs every layer on the portable kernels even where the CPU offers a faster instruction
    /// set (AVX2 on x86-64). Results are bit-identical either way; benchmarks use this to show
    /// what a CPU without AVX2 (or an aarch64 board, which always runs the portable kernels) gets.
    #[doc(hidden)]
    pub fn use_portable_kernels(&mut self) {
        for layer in &mut self.layers {
            layer.use_portable_kernels();
        }
    }

    /// Restores all recurrent state (LSTM `h`, `c`) to its initial value (zeros, or the
    /// initial tensors named in the description).
    pub fn reset(&mut self) {
        for layer in &mut self.layers {
            layer.reset();
        }
    }

    /// Length of the recurrent state: `h` and `c` of every LSTM layer, in layer order.
    pub fn state_len(&mut self) -> usize {
        self.layers
            .iter_mut()
            .filter_map(Layer::state_parts)
            .map(|(h, c)| h.len() + c.len())
            .sum()
    }

    /// Copies the recurrent state into `out` (length [`Network::state_len`]): per LSTM layer `h`
    /// then `c`. The PPO trainer stores it at the start of each rollout to replay the sequence.
    pub fn read_state(&mut self, out: &mut [f32]) {
        let mut at = 0;
        for (h, c) in self.layers.iter_mut().filter_map(Layer::state_parts) {
            out[at..at + h.len()].copy_from_slice(h);
            at += h.len();
            out[at..at + c.len()].copy_from_slice(c);
            at += c.len();
        }
    }

    /// Sets the recurrent state from `state` (the layout of [`Network::read_state`]).
    pub fn write_state(&mut self, state: &[f32]) {
        let mut at = 0;
        for (h, c) in self.layers.iter_mut().filter_map(Layer::state_parts) {
            h.copy_from_slice(&state[at..at + h.len()]);
            at += h.len();
            c.copy_from_slice(&state[at..at + c.len()]);
            at += c.len();
        }
    }

    /// Runs one step: `output = net(input)`, advancing recurrent state.
    ///
    /// Allocates nothing. Fails only if a slice length differs from
    /// [`Network::input_dim`]/[`Network::output_dim`], in which case state is untouched.
    pub fn step(&mut self, input: &[f32], output: &mut [f32]) -> Result<(), NnError> {
        if input.len() != self.input_dim() {
            return Err(NnError::InputLen {
                expected: self.input_dim(),
                found: input.len(),
            });
        }
        if output.len() != self.output_dim() {
            return Err(NnError::OutputLen {
                expected: self.output_dim(),
                found: output.len(),
            });
        }
        for (i, (layer, route)) in self.layers.iter_mut().zip(&self.route).enumerate() {
            let Some((from, to)) = *route else {
                continue;
            };
            let (n_in, n_out) = (self.dims[i], self.dims[i + 1]);
            let (src, dst): (&[f32], &mut [f32]) = match (from, to) {
                (Buf::Input, Buf::Output) => (input, &mut *output),
                (Buf::Input, _) => (input, &mut self.ping[..n_out]),
                (Buf::Ping, Buf::Output) => (&self.ping[..n_in], &mut *output),
                (Buf::Ping, _) => (&self.ping[..n_in], &mut self.pong[..n_out]),
                (Buf::Pong, Buf::Output) => (&self.pong[..n_in], &mut *output),
                (Buf::Pong, _) | (Buf::Output, _) => (&self.pong[..n_in], &mut self.ping[..n_out]),
            };
            layer.forward(src, dst);
        }
        Ok(())
    }
}

impl fmt::Debug for Network {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Network")
            .field("shapes", &self.shapes)
            .field("params", &self.params)
            .field("weights_sha256", &self.sha256)
            .finish_non_exhaustive()
    }
}

/// A safetensors parse error in plain words, with the sizes that show it (the crate's own messages
/// are enum names such as `HeaderTooLarge` or `InvalidOffset("actor.0.bias")`).
pub fn safetensors_in_words(e: &safetensors::SafeTensorError, bytes: &[u8]) -> String {
    use safetensors::SafeTensorError as E;
    let header_len = bytes
        .get(..8)
        .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")));
    let size = format!("the file has {} bytes", bytes.len());
    let not_st = "this is not a safetensors file, or it is damaged";
    match e {
        E::HeaderTooSmall => format!("{not_st}: {size}, fewer than the 8 of a safetensors length prefix"),
        E::HeaderTooLarge | E::InvalidHeaderLength => match header_len {
            Some(n) => format!("{not_st}: its first 8 bytes say the header is {n} bytes long, and {size}"),
            None => format!("{not_st}: {size}"),
        },
        E::InvalidHeader => format!("{not_st}: the header is not UTF-8 text"),
        E::InvalidHeaderStart => format!("{not_st}: the header does not start with '{{'"),
        E::InvalidHeaderDeserialization | E::JsonError(_) => {
            format!("{not_st}: the header is not the JSON table of tensors safetensors expects")
        }
        E::TensorNotFound(name) => format!("there is no tensor named {name:?} in the file"),
        E::InvalidOffset(name) => format!(
            "tensor {name:?}: its data offsets in the header point outside the data ({size}): the file is truncated or damaged"
        ),
        E::TensorInvalidInfo | E::InvalidTensorView(..) => {
            "a tensor's shape and type do not match the size of its data: the file is damaged".into()
        }
        E::MetadataIncompleteBuffer => format!(
            "the tensors' data does not fill the file exactly ({size}): it is truncated or has bytes appended"
        ),
        E::ValidationOverflow => "a tensor's shape is so large that its size overflows: the file is damaged".into(),
        E::IoError(io) => io.to_string(),
    }
}

/// The recurrent state of every stateful layer, in order (nothing for a feed-forward network).
impl snapshot::Snapshot for Network {
    fn save(&self, out: &mut Vec<u8>) {
        for l in &self.layers {
            if let layers::Layer::Lstm(lstm) = l {
                lstm.save(out);
            }
        }
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        for l in &mut self.layers {
            if let layers::Layer::Lstm(lstm) = l {
                lstm.restore(input)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod safetensors_words {
    #[test]
    fn damaged_files_are_described_in_words() {
        let say = |bytes: &[u8]| match safetensors::SafeTensors::deserialize(bytes) {
            Err(e) => super::safetensors_in_words(&e, bytes),
            Ok(_) => panic!("accepted"),
        };
        assert!(say(b"abc").contains("the file has 3 bytes, fewer than the 8"));
        let mut huge = u64::MAX.to_le_bytes().to_vec();
        huge.extend_from_slice(b"{}");
        let s = say(&huge);
        assert!(
            s.contains("header is 18446744073709551615 bytes long, and the file has 10 bytes"),
            "{s}"
        );
        let mut header = br#"{"w":{"dtype":"F32","shape":[4],"data_offsets":[0,16]}}"#.to_vec();
        let mut file = (header.len() as u64).to_le_bytes().to_vec();
        file.append(&mut header);
        file.extend_from_slice(&[0u8; 8]); // half of the tensor's data
        let s = say(&file);
        assert!(!s.contains("InvalidOffset") && !s.contains("MetadataIncomplete"), "{s}");
        assert!(s.contains("truncated"), "{s}");
    }
}
