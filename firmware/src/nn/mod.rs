//! Fixed-buffer neural-network executor for the control loop.
//!
//! A [`NetworkDesc`] (usually embedded in the TOML deploy spec) names the layers and the tensors
//! of a safetensors weight file; [`Network::load`] validates the two against each other and
//! allocates every buffer up front, so [`Network::step`] — called at the policy rate inside the
//! real-time loop — never allocates, never panics, and is bit-reproducible across x86-64 and
//! aarch64 (see the `kernels` module docs for how).
//!
//! # Example
//!
//! The peer policy (Unitree G1 LSTM), as written in a deploy spec:
//!
//! ```
//! use firmware::nn::{LayerDesc, NetworkDesc};
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
//! fn run(desc: &NetworkDesc) -> Result<(), firmware::nn::NnError> {
//!     let mut net = firmware::nn::Network::load(desc, "policy.safetensors".as_ref())?;
//!     let (obs, mut action) = (vec![0.0f32; net.input_dim()], vec![0.0f32; net.output_dim()]);
//!     net.step(&obs, &mut action)?; // every control tick; state carries over
//!     Ok(())
//! }
//! # let _ = run;
//! ```

mod desc;
mod error;
mod kernels;
mod layers;

pub use desc::{LayerDesc, NetworkDesc};
pub use error::NnError;

use layers::{Layer, TensorSource};
use safetensors::SafeTensors;
use sha2::{Digest, Sha256};
use std::fmt;
use std::path::Path;

/// A loaded network: packed weights, recurrent state and activation buffers.
pub struct Network {
    layers: Vec<Layer>,
    /// `dims[0]` is the input width, `dims[i + 1]` the output width of layer `i`.
    dims: Vec<usize>,
    /// Ping-pong activation buffers, each as wide as the widest intermediate activation.
    ping: Vec<f32>,
    pong: Vec<f32>,
    params: usize,
    sha256: String,
}

impl Network {
    /// Reads and validates the weight file at `weights_path` against `desc`.
    pub fn load(desc: &NetworkDesc, weights_path: &Path) -> Result<Network, NnError> {
        let bytes = std::fs::read(weights_path).map_err(|source| NnError::Io {
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
        let st = SafeTensors::deserialize(bytes).map_err(|e| NnError::Format(e.to_string()))?;
        let mut layers = Vec::with_capacity(desc.layers.len());
        let mut dims = vec![desc.input];
        let mut params = 0;
        let mut source_desc = "the network input".to_string();
        for (i, layer_desc) in desc.layers.iter().enumerate() {
            let src = TensorSource {
                st: &st,
                layer: format!("layers[{i}] ({})", layer_desc.kind()),
            };
            let input = dims[i];
            let (layer, n) = src.build(layer_desc, input, &source_desc)?;
            dims.push(layer.output_dim(input));
            params += n;
            layers.push(layer);
            source_desc = src.layer;
        }
        let widest = dims[1..dims.len() - 1].iter().copied().max().unwrap_or(0);
        let sha256 = Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect();
        Ok(Network {
            layers,
            dims,
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

    /// Number of learned parameters (weights and biases) read from the file.
    pub fn param_count(&self) -> usize {
        self.params
    }

    /// Lower-case hex SHA-256 of the weight file bytes, to log which policy is running.
    pub fn weights_sha256(&self) -> &str {
        &self.sha256
    }

    /// Restores all recurrent state (LSTM `h`, `c`) to its initial value (zeros, or the
    /// initial tensors named in the description).
    pub fn reset(&mut self) {
        for layer in &mut self.layers {
            layer.reset();
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
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter_mut().enumerate() {
            let (n_in, n_out) = (self.dims[i], self.dims[i + 1]);
            // Layer i writes ping if i is even, pong if odd; the last layer writes `output`.
            let (src, dst): (&[f32], &mut [f32]) = match (i == 0, i == last, i % 2 == 0) {
                (true, true, _) => (input, &mut *output),
                (true, false, _) => (input, &mut self.ping[..n_out]),
                (false, true, true) => (&self.pong[..n_in], &mut *output),
                (false, true, false) => (&self.ping[..n_in], &mut *output),
                (false, false, true) => (&self.pong[..n_in], &mut self.ping[..n_out]),
                (false, false, false) => (&self.ping[..n_in], &mut self.pong[..n_out]),
            };
            layer.forward(src, dst);
        }
        Ok(())
    }
}

impl fmt::Debug for Network {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Network")
            .field("dims", &self.dims)
            .field("params", &self.params)
            .field("weights_sha256", &self.sha256)
            .finish_non_exhaustive()
    }
}
