//! The terrain CNN on the robot: the exported network (`g1-train`, BatchNorm folded) run by the
//! fixed-buffer executor on a BEV grid, its seven outputs decoded by `estimator::terrain_cnn` —
//! the same decode the trainer scores with.
//!
//! The trained weights are part of the firmware ([`TerrainNet::embedded`]); a deploy spec can
//! point at other files (`[perception] terrain_weights`, `terrain_network`).
use std::path::Path;

use estimator::terrain_cnn::{decode, OUTPUTS};
use hal::TerrainToken;
use sensor_io::bev::{BevGrid, BEV_CELLS, BEV_CHANNELS};

use crate::nn::{Network, NetworkDesc, NnError};

/// Largest network description read (the deploy spec's own cap).
const MAX_DESC_BYTES: u64 = 1 << 20;

/// The committed, trained network (see `control/weights/README.md` for how it was made).
pub const EMBEDDED_WEIGHTS: &[u8] = include_bytes!("../weights/terrain_cnn.safetensors");
pub const EMBEDDED_DESC: &str = include_str!("../weights/terrain_cnn.toml");

/// Why a terrain network could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum TerrainNetError {
    #[error("reading terrain network description {path}")]
    ReadDesc {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
    #[error("terrain network description {origin}: {message}")]
    ParseDesc { origin: String, message: String },
    #[error("terrain network: {}", crate::nn::with_causes(.0))]
    Nn(NnError),
    #[error(
        "terrain network maps {input} inputs to {output} outputs; the firmware needs {} → {OUTPUTS} \
         (a 6×60×60 BEV grid to class logits, h, d and the yaw vector)",
        BEV_CHANNELS * BEV_CELLS * BEV_CELLS
    )]
    Shape { input: usize, output: usize },
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<NnError> for TerrainNetError {
    fn from(e: NnError) -> Self {
        TerrainNetError::Nn(e)
    }
}

/// A loaded terrain CNN and its output buffer.
pub struct TerrainNet {
    net: Network,
    out: [f32; OUTPUTS],
}

impl TerrainNet {
    /// The network built into the firmware.
    pub fn embedded() -> Result<Self, TerrainNetError> {
        let desc = parse_desc(EMBEDDED_DESC, "(embedded)")?;
        Self::new(Network::from_safetensors_bytes(&desc, EMBEDDED_WEIGHTS)?)
    }

    /// A network from a description (TOML, as `g1-train` writes it) and a safetensors file.
    pub fn load(desc_path: &Path, weights_path: &Path) -> Result<Self, TerrainNetError> {
        let read = |source| TerrainNetError::ReadDesc {
            path: desc_path.to_path_buf(),
            source,
        };
        // A description is a few hundred bytes; the spec's limit is ample.
        let bytes = crate::read_capped(desc_path, MAX_DESC_BYTES).map_err(read)?;
        let text =
            String::from_utf8(bytes).map_err(|e| read(std::io::Error::new(std::io::ErrorKind::InvalidData, e)))?;
        let desc = parse_desc(&text, &desc_path.display().to_string())?;
        Self::new(Network::load(&desc, weights_path)?)
    }

    fn new(net: Network) -> Result<Self, TerrainNetError> {
        if net.input_dim() != BEV_CHANNELS * BEV_CELLS * BEV_CELLS || net.output_dim() != OUTPUTS {
            return Err(TerrainNetError::Shape {
                input: net.input_dim(),
                output: net.output_dim(),
            });
        }
        Ok(Self {
            net,
            out: [0.0; OUTPUTS],
        })
    }

    /// Runs the CNN on `grid`; `heading_rad` becomes the flat token's yaw. `None` if the outputs
    /// are not finite (the caller keeps its last token). Allocates nothing.
    pub fn estimate(&mut self, grid: &BevGrid, heading_rad: f32) -> Option<TerrainToken> {
        self.net.step(&grid.data, &mut self.out).ok()?;
        decode(&self.out, heading_rad)
    }

    /// The raw outputs of the last [`TerrainNet::estimate`].
    pub fn outputs(&self) -> &[f32; OUTPUTS] {
        &self.out
    }

    /// SHA-256 of the weight bytes (for logs).
    pub fn weights_sha256(&self) -> &str {
        self.net.weights_sha256()
    }
}

fn parse_desc(text: &str, origin: &str) -> Result<NetworkDesc, TerrainNetError> {
    toml::from_str(text).map_err(|e| TerrainNetError::ParseDesc {
        origin: origin.to_string(),
        message: e.to_string(),
    })
}
