//! An ONNX policy network → the firmware's [`NetworkDesc`] and its tensors.
//!
//! Parsed with prost from ONNX's own protobuf definition. The graph must be a chain from the
//! observation input to the first graph output, of the ops rsl_rl, IsaacLab, unitree_rl_lab and mjlab
//! exports contain:
//! - `Gemm` (`transB` either way, `alpha`, `beta`), or `MatMul` (+ `Add` of a constant): `linear`;
//! - `Elu`, `Relu`, `Tanh`: the same activations; `Identity`, `Squeeze`, `Unsqueeze`, `Reshape`,
//!   `Flatten`: nothing (the executor works on flat vectors);
//! - `Sub`/`Div`/`Mul`/`Add` with a constant before the first layer (an observation normaliser,
//!   kept or folded by the exporter): folded into that layer's weights; after a `linear`: folded
//!   into it (action scaling);
//! - `LSTM` (forward, one layer, default activations; gates reordered from ONNX's i, o, f, c to the
//!   executor's PyTorch order i, f, g, o), with its state as graph inputs (`h_in`, `c_in`: the
//!   executor carries it between steps from zeros) or constants (the initial state).
//!
//! Anything else is refused by name, with the node's name and position.
//!
//! Nothing onnxruntime refuses is imported, and nothing is imported as other than what onnxruntime
//! computes:
//! - the default domain's opset must lie in [`OPSETS`], and every node be in that domain;
//! - everything the chain computes is float32: the graph's inputs and outputs and every constant a
//!   node computes with (a float64 weight in a float32 `Gemm` is a type error in onnxruntime);
//!   int64 only for shapes and axes;
//! - constants broadcast by ONNX's (numpy's) rules against the chain value, which at batch 1 is one
//!   vector along its last axis: a constant of shape `[]`, `[1]`, `[n]`, `[1, n]` (or more leading
//!   1s) keeps it one, anything else (`[n, 1]` makes an `[n, n]` matrix) is refused, as are shape
//!   ops that would move the features off the last axis.
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use control::nn::{LayerDesc, NetworkDesc};
use prost::Message;

#[allow(clippy::all, clippy::pedantic, missing_docs)]
pub mod proto {
    include!(concat!(env!("OUT_DIR"), "/onnx.rs"));
}

use proto::{tensor_proto::DataType, ModelProto, NodeProto, TensorProto};

/// Largest ONNX file read (a policy MLP is a few MB; a larger file is not a policy).
pub const MAX_ONNX_BYTES: u64 = 256 << 20;

/// Opsets of the default ONNX domain imported. From 7: before it `Add`/`Sub`/`Mul`/`Div` and
/// `Gemm`'s C broadcast by a `broadcast` attribute, not numpy's rules. To 28: the newest
/// onnxruntime 1.32 loads (it refuses newer ones); none of the ops above changed after opset 25.
pub const OPSETS: std::ops::RangeInclusive<i64> = 7..=28;

#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The OS's reason is the source (printed once by `{:#}` chains).
    #[error("cannot read {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {bytes} bytes is more than the {max} an ONNX policy may have")]
    TooLarge { path: PathBuf, bytes: u64, max: u64 },
    #[error(
        "{path}: not a readable ONNX model ({why}); is the file complete (a truncated download?) and an .onnx export?"
    )]
    Decode { path: PathBuf, why: String },
    #[error(
        "unsupported ONNX op '{op}' (node '{node}', #{index} of the graph); supported: Gemm, MatMul, Add, Sub, Mul, \
         Div, Elu, Relu, Tanh, Identity, Squeeze, Unsqueeze, Reshape, Flatten, LSTM"
    )]
    UnsupportedOp { op: String, node: String, index: usize },
    #[error("node '{node}' (#{index}, {op}): {why}")]
    BadNode {
        op: String,
        node: String,
        index: usize,
        why: String,
    },
    #[error("{0}")]
    Graph(String),
    #[error("tensor '{name}': {why}")]
    Tensor { name: String, why: String },
}

/// A constant of the graph, as f32.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    pub dims: Vec<usize>,
    pub data: Vec<f32>,
}

/// The recurrent state's graph inputs and outputs (the executor keeps the state itself).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RecurrentIo {
    pub hidden: usize,
    pub h_in: Option<String>,
    pub c_in: Option<String>,
}

/// What the import produced.
#[derive(Clone, Debug)]
pub struct ImportedNetwork {
    pub desc: NetworkDesc,
    /// Tensors named by `desc`, in order of appearance.
    pub tensors: Vec<(String, Tensor)>,
    pub input_name: String,
    pub output_name: String,
    pub output_dim: usize,
    pub recurrent: Option<RecurrentIo>,
    /// `metadata_props` of the model (deploy data some exporters put there).
    pub metadata: Vec<(String, String)>,
    /// One line per graph node: what became of it.
    pub trace: Vec<String>,
}

/// Reads and converts `path`.
pub fn import_file(path: &Path) -> Result<ImportedNetwork, ImportError> {
    // The firmware's capped read: refused from its size, and a growing file or a device is still
    // read only up to the limit.
    let data = input_file::read_capped(path, MAX_ONNX_BYTES).map_err(|source| ImportError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    import_bytes_at(&data, path)
}

/// Converts the bytes of an ONNX model (at most [`MAX_ONNX_BYTES`]).
pub fn import_bytes(data: &[u8]) -> Result<ImportedNetwork, ImportError> {
    import_bytes_at(data, Path::new("<bytes>"))
}

/// `path` names the model in errors.
fn import_bytes_at(data: &[u8], path: &Path) -> Result<ImportedNetwork, ImportError> {
    if data.len() as u64 > MAX_ONNX_BYTES {
        return Err(ImportError::TooLarge {
            path: path.to_path_buf(),
            bytes: data.len() as u64,
            max: MAX_ONNX_BYTES,
        });
    }
    let model = ModelProto::decode(data).map_err(|e| ImportError::Decode {
        path: path.to_path_buf(),
        why: e.to_string(),
    })?;
    convert(&model).map_err(|e| match e {
        ImportError::Graph(why) => ImportError::Graph(format!("{}: {why}", path.display())),
        e => e,
    })
}

/// Fuzz harness (the `onnx_import` cargo-fuzz target and the stable `fuzz_smoke` test): a model
/// that imports writes a network table and weights that the firmware loads into a network of the
/// same shape, and that network steps.
#[doc(hidden)]
pub fn fuzz_onnx(data: &[u8]) {
    let Ok(net) = import_bytes(data) else {
        return;
    };
    let table = net.spec_table().expect("the table of an imported network serialises");
    #[derive(serde::Deserialize)]
    struct Wrap {
        policy: P,
    }
    #[derive(serde::Deserialize)]
    struct P {
        network: NetworkDesc,
    }
    let back: Wrap = toml::from_str(&table).expect("the network table parses back");
    assert_eq!(back.policy.network, net.desc);
    let Ok(weights) = net.safetensors_bytes() else {
        return;
    };
    let mut loaded = control::nn::Network::from_safetensors_bytes(&net.desc, &weights)
        .unwrap_or_else(|e| panic!("an imported network does not load: {e}"));
    assert_eq!(loaded.output_dim(), net.output_dim);
    let input = vec![0.5f32; loaded.input_dim()];
    let mut output = vec![0.0f32; loaded.output_dim()];
    loaded.step(&input, &mut output).expect("steps");
}

fn tensor_of(t: &TensorProto) -> Result<Tensor, ImportError> {
    let name = t.name.clone().unwrap_or_default();
    let bad = |why: String| ImportError::Tensor {
        name: name.clone(),
        why,
    };
    let dims: Vec<usize> = t
        .dims
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| bad(format!("negative dimension {d}"))))
        .collect::<Result<_, _>>()?;
    let n = dims
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|&n| n <= (MAX_ONNX_BYTES / 4) as usize)
        .ok_or_else(|| bad(format!("shape {dims:?} is too large")))?;
    if t.data_location == Some(proto::tensor_proto::DataLocation::External as i32) {
        return Err(bad(
            "its data is in an external file; re-export with the weights inside the .onnx".into(),
        ));
    }
    let dt = t.data_type.unwrap_or(0);
    let data: Vec<f32> = if dt == DataType::Float as i32 {
        match &t.raw_data {
            Some(raw) if !raw.is_empty() => {
                if raw.len() != n * 4 {
                    return Err(bad(format!("{} raw bytes for {n} floats", raw.len())));
                }
                raw.chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect()
            }
            _ => t.float_data.clone(),
        }
    } else if dt == DataType::Double as i32 {
        match &t.raw_data {
            Some(raw) if !raw.is_empty() => raw
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
                .collect(),
            _ => t.double_data.iter().map(|&v| v as f32).collect(),
        }
    } else if dt == DataType::Int64 as i32 {
        // Shapes and axes (Reshape, Squeeze): kept as numbers, never used as weights.
        match &t.raw_data {
            Some(raw) if !raw.is_empty() => raw
                .chunks_exact(8)
                .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
                .collect(),
            _ => t.int64_data.iter().map(|&v| v as f32).collect(),
        }
    } else {
        return Err(bad(format!(
            "data type {dt} is not float32 (1), float64 (11) or int64 (7)"
        )));
    };
    if data.len() != n {
        return Err(bad(format!("{} values for shape {dims:?}", data.len())));
    }
    Ok(Tensor { dims, data })
}

fn attr_f(node: &NodeProto, name: &str, default: f32) -> f32 {
    node.attribute
        .iter()
        .find(|a| a.name.as_deref() == Some(name))
        .and_then(|a| a.f)
        .unwrap_or(default)
}

fn attr_i(node: &NodeProto, name: &str, default: i64) -> i64 {
    node.attribute
        .iter()
        .find(|a| a.name.as_deref() == Some(name))
        .and_then(|a| a.i)
        .unwrap_or(default)
}

fn attr_s(node: &NodeProto, name: &str) -> Option<String> {
    node.attribute
        .iter()
        .find(|a| a.name.as_deref() == Some(name))
        .and_then(|a| a.s.as_ref())
        .map(|s| String::from_utf8_lossy(s).into_owned())
}

/// A linear layer being built: `[out][in]` row-major, and its bias.
struct Linear {
    out: usize,
    inp: usize,
    w: Vec<f32>,
    b: Vec<f32>,
}

enum Built {
    Linear(Linear),
    Act(LayerDesc),
    Lstm {
        hidden: usize,
        inp: usize,
        w_ih: Vec<f32>,
        w_hh: Vec<f32>,
        b_ih: Vec<f32>,
        b_hh: Vec<f32>,
        h0: Option<Vec<f32>>,
        c0: Option<Vec<f32>>,
    },
}

/// A shape as ONNX prints it; `?` for a size not known here.
fn shape_str(dims: &[Option<usize>]) -> String {
    let d: Vec<String> = dims
        .iter()
        .map(|d| d.map_or("?".to_string(), |d| d.to_string()))
        .collect();
    format!("[{}]", d.join(", "))
}

/// The chain value's shape: `rank` axes (2 when not known), all of size 1 but the last, `width`.
fn value_shape(width: Option<usize>, rank: Option<usize>) -> Vec<Option<usize>> {
    let r = rank.unwrap_or(2);
    let mut d = vec![Some(1); r.saturating_sub(1)];
    if r > 0 {
        d.push(width);
    }
    d
}

/// `c` combined element-wise with the chain value (`width` wide, `rank` axes) by ONNX's (numpy's)
/// broadcasting: its values along the value's axis, or why the result is not one vector. Only a
/// constant whose axes but the last are all 1, and whose last is 1 or `width`, keeps it one; an
/// `[n, 1]` bias would make an `[n, n]` matrix, which the executor's flat vector cannot be.
fn broadcast(c: &Tensor, width: Option<usize>, rank: Option<usize>, what: &str) -> Result<Vec<f32>, String> {
    let k = c.dims.last().copied().unwrap_or(1);
    let lead_ones = c.dims.iter().rev().skip(1).all(|&d| d == 1);
    if lead_ones {
        match width {
            Some(n) if k == n => return Ok(c.data.clone()),
            Some(n) if k == 1 => return Ok(vec![c.data[0]; n]),
            None if k == 1 => {
                return Err(format!(
                    "{what} is a single value but the width it applies to is not known here; declare the input's shape"
                ))
            }
            None => return Ok(c.data.clone()),
            Some(_) => {}
        }
    }
    // What numpy makes of it, for the message.
    let x = value_shape(width, rank);
    let cd: Vec<Option<usize>> = c.dims.iter().map(|&d| Some(d)).collect();
    let r = x.len().max(cd.len());
    let pad = |v: &[Option<usize>]| {
        let mut p = vec![Some(1); r - v.len()];
        p.extend_from_slice(v);
        p
    };
    let (xp, cp) = (pad(&x), pad(&cd));
    let mut out = Vec::with_capacity(r);
    for (a, b) in xp.iter().zip(&cp) {
        out.push(match (a, b) {
            (Some(1), b) => *b,
            (a, Some(1)) => *a,
            (Some(a), Some(b)) if a == b => Some(*a),
            (None, b) => *b,
            _ => {
                return Err(format!(
                    "{what} of shape {} does not broadcast against the value's shape {} (ONNX/numpy broadcasting; \
                     onnxruntime refuses it); give it shape [{n}] or [1, {n}]",
                    shape_str(&cd),
                    shape_str(&x),
                    n = width.map_or("n".into(), |n| n.to_string()),
                ))
            }
        });
    }
    Err(format!(
        "{what} of shape {} broadcasts the value of shape {} to {} (ONNX/numpy broadcasting, as onnxruntime \
         computes it), not one vector of {} values: the executor cannot compute that; give it shape \
         [{n}] or [1, {n}] if it is a per-output bias or scale",
        shape_str(&cd),
        shape_str(&x),
        shape_str(&out),
        width.map_or("the same".into(), |n| n.to_string()),
        n = width.map_or("n".into(), |n| n.to_string()),
    ))
}

/// An ONNX data type by name, for messages.
fn dtype_name(dt: i32) -> String {
    match DataType::try_from(dt) {
        Ok(DataType::Float) => "float32".into(),
        Ok(DataType::Double) => "float64".into(),
        Ok(DataType::Float16) => "float16".into(),
        Ok(DataType::Int64) => "int64".into(),
        Ok(DataType::Int32) => "int32".into(),
        Ok(d) => d.as_str_name().to_lowercase(),
        Err(_) => format!("data type {dt}"),
    }
}

/// The element type a graph input or output declares, if it declares one.
fn elem_type(v: &proto::ValueInfoProto) -> Option<i32> {
    match v.r#type.as_ref()?.value.as_ref()? {
        proto::type_proto::Value::TensorType(t) => t.elem_type,
        _ => None,
    }
}

/// The default domain's opset, refused outside [`OPSETS`] (as onnxruntime refuses one newer than it
/// knows, and older ones broadcast by other rules).
fn default_opset(model: &ModelProto) -> Result<i64, ImportError> {
    let versions: Vec<i64> = model
        .opset_import
        .iter()
        .filter(|o| matches!(o.domain.as_deref(), None | Some("") | Some("ai.onnx")))
        .map(|o| o.version.unwrap_or(0))
        .collect();
    let (lo, hi) = (OPSETS.start(), OPSETS.end());
    match versions.as_slice() {
        [v] if OPSETS.contains(v) => Ok(*v),
        [v] => Err(ImportError::Graph(format!(
            "opset {v} of the default ONNX domain (opset_import) is outside the {lo} to {hi} this importer \
             implements (onnxruntime loads no opset newer than {hi}); re-export with an opset in that range, \
             e.g. torch.onnx.export(..., opset_version=17)"
        ))),
        [] => Err(ImportError::Graph(format!(
            "the model declares no opset for the default ONNX domain (opset_import), so its ops have no \
             defined meaning; re-export with an opset from {lo} to {hi}"
        ))),
        many => Err(ImportError::Graph(format!(
            "the model declares the default ONNX domain's opset {} times ({many:?}); re-export it",
            many.len()
        ))),
    }
}

/// The graph's parts the walk reads.
struct Graph<'a> {
    g: &'a proto::GraphProto,
    consts: HashMap<String, Tensor>,
    /// Each constant's ONNX data type (float32 where a node computes with it).
    dtypes: HashMap<String, i32>,
    users: HashMap<&'a str, Vec<usize>>,
    input_name: String,
    output_name: String,
    /// Graph inputs after the observation: the recurrent state, carried by the executor.
    state_inputs: Vec<String>,
    declared_input: Option<usize>,
    /// Axes of the observation input, when it declares its shape.
    declared_rank: Option<usize>,
    /// The default domain's opset (where `Squeeze`/`Unsqueeze` take their axes from).
    opset: i64,
}

fn convert(model: &ModelProto) -> Result<ImportedNetwork, ImportError> {
    let opset = default_opset(model)?;
    let graph = read_graph(model, opset)?;
    let walk = walk_chain(&graph)?;
    assemble(model, graph, walk)
}

/// Constants, the observation input and its declared width, the output, and who uses each value.
fn read_graph(model: &ModelProto, opset: i64) -> Result<Graph<'_>, ImportError> {
    let g = model
        .graph
        .as_ref()
        .ok_or_else(|| ImportError::Graph("the model has no graph".into()))?;
    let mut consts: HashMap<String, Tensor> = HashMap::new();
    let mut dtypes: HashMap<String, i32> = HashMap::new();
    for t in &g.initializer {
        let name = t.name.clone().unwrap_or_default();
        consts.insert(name.clone(), tensor_of(t)?);
        dtypes.insert(name, t.data_type.unwrap_or(0));
    }
    for n in &g.node {
        if n.op_type.as_deref() == Some("Constant") {
            if let (Some(out), Some(t)) = (n.output.first(), n.attribute.iter().find_map(|a| a.t.as_ref())) {
                consts.insert(out.clone(), tensor_of(t)?);
                dtypes.insert(out.clone(), t.data_type.unwrap_or(0));
            }
        }
    }
    let inputs: Vec<&proto::ValueInfoProto> = g
        .input
        .iter()
        .filter(|i| !consts.contains_key(i.name.as_deref().unwrap_or("")))
        .collect();
    let obs = inputs
        .first()
        .ok_or_else(|| ImportError::Graph("the graph has no input".into()))?;
    let input_name = obs.name.clone().unwrap_or_default();
    // The executor computes in float32: a graph of another type would be imported as something else.
    for (v, what) in inputs
        .iter()
        .map(|v| (*v, "input"))
        .chain(g.output.iter().map(|v| (v, "output")))
    {
        if let Some(t) = elem_type(v).filter(|&t| t != DataType::Float as i32) {
            return Err(ImportError::Graph(format!(
                "the graph {what} '{}' is {}, but the executor computes in float32; re-export the policy in \
                 float32 (e.g. `policy.float()` before `torch.onnx.export`)",
                v.name.as_deref().unwrap_or(""),
                dtype_name(t)
            )));
        }
    }
    // The observation input's shape, when the export states it: a named (batch) size is None.
    let dims: Option<Vec<Option<usize>>> = obs
        .r#type
        .as_ref()
        .and_then(|t| match &t.value {
            Some(proto::type_proto::Value::TensorType(tt)) => tt.shape.as_ref(),
            _ => None,
        })
        .map(|s| {
            s.dim
                .iter()
                .map(|d| match d.value {
                    Some(proto::tensor_shape_proto::dimension::Value::DimValue(v)) => usize::try_from(v).ok(),
                    _ => None,
                })
                .collect()
        });
    let declared_input = dims.as_ref().and_then(|d| d.last().copied().flatten());
    let declared_rank = dims.as_ref().map(Vec::len);
    // The executor steps one observation: a fixed batch of several would be another computation.
    if let Some(d) = &dims {
        if d.iter().rev().skip(1).any(|&d| d.is_some_and(|d| d != 1)) {
            return Err(ImportError::Graph(format!(
                "the input '{input_name}' has shape {}: the executor runs one observation at a time; export \
                 it with batch size 1 or a named batch dimension",
                shape_str(d)
            )));
        }
    }
    // The importer allocates vectors of this width (a broadcast normaliser); a declared shape is
    // not yet checked against any weight.
    if let Some(n) = declared_input.filter(|&n| n > control::nn::MAX_ACTIVATION) {
        return Err(ImportError::Graph(format!(
            "the input '{input_name}' declares {n} values, more than the {} the executor takes",
            control::nn::MAX_ACTIVATION
        )));
    }
    let output_name = g
        .output
        .first()
        .and_then(|o| o.name.clone())
        .ok_or_else(|| ImportError::Graph("the graph has no output".into()))?;
    let state_inputs: Vec<String> = inputs[1..].iter().filter_map(|i| i.name.clone()).collect();

    let mut users: HashMap<&str, Vec<usize>> = HashMap::new();
    for (i, n) in g.node.iter().enumerate() {
        for inp in &n.input {
            if !inp.is_empty() && !consts.contains_key(inp) {
                users.entry(inp.as_str()).or_default().push(i);
            }
        }
    }

    Ok(Graph {
        g,
        consts,
        dtypes,
        users,
        input_name,
        output_name,
        state_inputs,
        declared_input,
        declared_rank,
        opset,
    })
}

/// Walks the chain from the observation input to the output, node by node.
fn walk_chain(graph: &Graph) -> Result<Walk, ImportError> {
    let (g, users, input_name, output_name) = (graph.g, &graph.users, &graph.input_name, &graph.output_name);
    let mut walk = Walk {
        width: graph.declared_input,
        rank: graph.declared_rank,
        ..Walk::default()
    };
    let mut cur = input_name.clone();
    let mut visited = vec![false; g.node.len()];
    while &cur != output_name {
        let us = users.get(cur.as_str()).cloned().unwrap_or_default();
        let idx = match us.as_slice() {
            [i] => *i,
            [] => {
                return Err(ImportError::Graph(format!(
                "value '{cur}' leads nowhere: the chain from '{input_name}' does not reach the output '{output_name}'"
            )))
            }
            many => {
                return Err(ImportError::Graph(format!(
                    "value '{cur}' feeds {} nodes ({}): only a chain from the observation to the action is supported",
                    many.len(),
                    many.iter()
                        .map(|&i| g.node[i].name.clone().unwrap_or_default())
                        .collect::<Vec<_>>()
                        .join(", ")
                )))
            }
        };
        if std::mem::replace(&mut visited[idx], true) {
            return Err(ImportError::Graph(format!("the graph loops at node #{idx}")));
        }
        let node = &g.node[idx];
        let at = At {
            node,
            idx,
            op: node.op_type.clone().unwrap_or_default(),
            name: node.name.clone().unwrap_or_default(),
            cur: &cur,
            consts: &graph.consts,
            dtypes: &graph.dtypes,
            opset: graph.opset,
        };
        let (op, name) = (at.op.as_str(), at.name.as_str());
        // Another domain's op of the same name (com.microsoft's, a custom one) means something else.
        if let Some(d) = node.domain.as_deref().filter(|d| !d.is_empty() && *d != "ai.onnx") {
            return Err(at.bad(format!(
                "the op is from domain '{d}', not the default ONNX domain this importer implements"
            )));
        }
        let mut next = node.output.first().cloned().unwrap_or_default();
        match op {
            "Identity" | "Squeeze" | "Unsqueeze" | "Reshape" | "Flatten" => {
                walk.shape_only(&at)?;
                walk.trace
                    .push(format!("#{idx} {op} '{name}': shape only, nothing to compute"));
            }
            "Sub" | "Add" | "Mul" | "Div" => walk.elementwise(&at)?,
            "Gemm" | "MatMul" => walk.linear(&at)?,
            "Elu" | "Relu" | "Tanh" => walk.activation(&at)?,
            "LSTM" => next = walk.lstm(&at, graph)?,
            _ => {
                return Err(ImportError::UnsupportedOp {
                    op: op.to_string(),
                    node: name.to_string(),
                    index: idx,
                })
            }
        }
        if next.is_empty() {
            return Err(ImportError::Graph(format!("node #{idx} has no output")));
        }
        cur = next;
    }
    Ok(walk)
}

/// The network description and its tensors from what the walk built.
fn assemble(model: &ModelProto, graph: Graph, walk: Walk) -> Result<ImportedNetwork, ImportError> {
    let Walk {
        built,
        width,
        recurrent,
        trace,
        ..
    } = walk;
    let Graph {
        input_name,
        output_name,
        ..
    } = graph;
    if built.is_empty() {
        return Err(ImportError::Graph(
            "the graph computes nothing (no linear or LSTM layer)".into(),
        ));
    }
    let input = match built.first() {
        Some(Built::Linear(l)) => l.inp,
        Some(Built::Lstm { inp, .. }) => *inp,
        _ => return Err(ImportError::Graph("the first layer is an activation".into())),
    };
    let mut layers = Vec::new();
    let mut tensors = Vec::new();
    for (i, b) in built.into_iter().enumerate() {
        match b {
            Built::Linear(l) => {
                let (w, bias) = (format!("l{i}.weight"), format!("l{i}.bias"));
                tensors.push((
                    w.clone(),
                    Tensor {
                        dims: vec![l.out, l.inp],
                        data: l.w,
                    },
                ));
                tensors.push((
                    bias.clone(),
                    Tensor {
                        dims: vec![l.out],
                        data: l.b,
                    },
                ));
                layers.push(LayerDesc::Linear { weight: w, bias });
            }
            Built::Act(a) => layers.push(a),
            Built::Lstm {
                hidden,
                inp,
                w_ih,
                w_hh,
                b_ih,
                b_hh,
                h0,
                c0,
            } => {
                let n = |s: &str| format!("l{i}.{s}");
                tensors.push((
                    n("weight_ih"),
                    Tensor {
                        dims: vec![4 * hidden, inp],
                        data: w_ih,
                    },
                ));
                tensors.push((
                    n("weight_hh"),
                    Tensor {
                        dims: vec![4 * hidden, hidden],
                        data: w_hh,
                    },
                ));
                tensors.push((
                    n("bias_ih"),
                    Tensor {
                        dims: vec![4 * hidden],
                        data: b_ih,
                    },
                ));
                tensors.push((
                    n("bias_hh"),
                    Tensor {
                        dims: vec![4 * hidden],
                        data: b_hh,
                    },
                ));
                let mut state = |s: &str, v: Option<Vec<f32>>| {
                    v.map(|data| {
                        tensors.push((
                            n(s),
                            Tensor {
                                dims: vec![hidden],
                                data,
                            },
                        ));
                        n(s)
                    })
                };
                let initial_hidden = state("initial_hidden", h0);
                let initial_cell = state("initial_cell", c0);
                layers.push(LayerDesc::Lstm {
                    weight_ih: n("weight_ih"),
                    weight_hh: n("weight_hh"),
                    bias_ih: n("bias_ih"),
                    bias_hh: n("bias_hh"),
                    initial_hidden,
                    initial_cell,
                });
            }
        }
    }
    // The firmware refuses non-finite weights; say so here, where the cause (a NaN initializer, or
    // a normaliser with a zero std folded in) can still be named.
    for (name, t) in &tensors {
        if let Some(i) = t.data.iter().position(|v| !v.is_finite()) {
            return Err(ImportError::Tensor {
                name: name.clone(),
                why: format!(
                    "value {} at flat index {i} is not finite (a NaN or infinite constant, or a normaliser dividing by zero)",
                    t.data[i]
                ),
            });
        }
    }
    Ok(ImportedNetwork {
        desc: NetworkDesc {
            input,
            input_shape: None,
            layers,
        },
        tensors,
        input_name,
        output_name,
        output_dim: width.unwrap_or(0),
        recurrent,
        metadata: model
            .metadata_props
            .iter()
            .map(|p| (p.key.clone().unwrap_or_default(), p.value.clone().unwrap_or_default()))
            .collect(),
        trace,
    })
}

/// What the walk along the chain from the observation to the action has built so far.
#[derive(Default)]
struct Walk {
    built: Vec<Built>,
    /// Observation normaliser before the first layer: x' = a ⊙ x + b.
    pre: Option<(Vec<f32>, Vec<f32>)>,
    /// The chain value's last axis: the executor's vector. Every other axis has size 1 at batch 1
    /// (kept so by refusing what would change it).
    width: Option<usize>,
    /// How many axes the chain value has, when known (broadcasting and axis numbers depend on it).
    rank: Option<usize>,
    recurrent: Option<RecurrentIo>,
    trace: Vec<String>,
}

/// One node on the chain, with the value that flows into it.
struct At<'a> {
    node: &'a proto::NodeProto,
    idx: usize,
    op: String,
    name: String,
    cur: &'a str,
    consts: &'a HashMap<String, Tensor>,
    dtypes: &'a HashMap<String, i32>,
    opset: i64,
}

impl At<'_> {
    fn bad(&self, why: String) -> ImportError {
        ImportError::BadNode {
            op: self.op.clone(),
            node: self.name.clone(),
            index: self.idx,
            why,
        }
    }

    /// Input `k`, which must be a constant (an initializer), of any type.
    fn konst_any(&self, k: usize) -> Result<(&str, &Tensor), ImportError> {
        let n = self.node.input.get(k).filter(|s| !s.is_empty());
        n.and_then(|n| self.consts.get(n).map(|t| (n.as_str(), t)))
            .ok_or_else(|| self.bad(format!("input {k} must be a constant (an initializer)")))
    }

    /// Input `k`, a float32 constant: what the node computes with.
    fn konst(&self, k: usize) -> Result<&Tensor, ImportError> {
        let (n, t) = self.konst_any(k)?;
        self.float32(n)?;
        Ok(t)
    }

    /// Refuses constant `n` unless float32: every value on the chain is (onnxruntime refuses an op
    /// whose inputs differ in type, and importing a float64 weight would round it silently).
    fn float32(&self, n: &str) -> Result<(), ImportError> {
        match self.dtypes.get(n).copied() {
            Some(t) if t != DataType::Float as i32 => Err(self.bad(format!(
                "initializer '{n}' is {}, but this node computes in float32 (the observation is float32): \
                 onnxruntime refuses the type mismatch; re-export with float32 weights (e.g. `policy.float()` \
                 before `torch.onnx.export`)",
                dtype_name(t)
            ))),
            _ => Ok(()),
        }
    }

    /// Input `k`, an int64 constant (a shape or axes).
    fn ints(&self, k: usize) -> Result<Vec<i64>, ImportError> {
        let (n, t) = self.konst_any(k)?;
        match self.dtypes.get(n).copied() {
            Some(t) if t != DataType::Int64 as i32 => {
                Err(self.bad(format!("input {k} '{n}' is {}, where ONNX takes int64", dtype_name(t))))
            }
            // Read as f32 (exact to 2^24, more than any width here).
            _ => Ok(t.data.iter().map(|&v| v as i64).collect()),
        }
    }

    /// The axes of `Squeeze`/`Unsqueeze`: an attribute before opset 13, input 1 from it.
    fn axes(&self) -> Result<Option<Vec<i64>>, ImportError> {
        let input = self.node.input.get(1).filter(|s| !s.is_empty());
        let attr = self.node.attribute.iter().find(|a| a.name.as_deref() == Some("axes"));
        match (self.opset >= 13, input, attr) {
            (true, _, Some(_)) => Err(self.bad(format!(
                "attribute 'axes' at opset {}: since opset 13 the axes are input 1",
                self.opset
            ))),
            (false, Some(_), _) => Err(self.bad(format!(
                "axes as input 1 at opset {}: before opset 13 they are the attribute 'axes'",
                self.opset
            ))),
            (true, Some(_), None) => self.ints(1).map(Some),
            (true, None, None) => Ok(None),
            (false, None, a) => Ok(a.map(|a| a.ints.clone())),
        }
    }

    /// Which input of a binary element-wise node is the constant.
    fn other_index(&self) -> usize {
        if self.node.input.first().map(String::as_str) == Some(self.cur) {
            1
        } else {
            0
        }
    }

    /// The constant operand of a binary element-wise node.
    fn other_const(&self) -> Result<&Tensor, ImportError> {
        self.konst(self.other_index())
    }

    fn other_name(&self) -> &str {
        self.node.input.get(self.other_index()).map_or("", String::as_str)
    }
}

impl Walk {
    /// A constant `Sub`/`Add`/`Mul`/`Div`: into the observation normaliser before the first layer, or
    /// into the linear layer before it.
    fn elementwise(&mut self, at: &At) -> Result<(), ImportError> {
        let (node, idx, op, name) = (at.node, at.idx, at.op.as_str(), at.name.as_str());
        let bad = |why: String| at.bad(why);
        let Walk {
            built,
            pre,
            width,
            rank,
            trace,
            ..
        } = self;
        let c = at.other_const()?;
        let what = format!("the constant '{}'", at.other_name());
        if (op == "Sub" || op == "Div") && node.input.first().map(String::as_str) != Some(at.cur) {
            return Err(bad(
                "the constant comes first (c − x, c / x): not an affine normaliser".into()
            ));
        }
        match built.last_mut() {
            None => {
                let v = broadcast(c, *width, *rank, &what).map_err(bad)?;
                *width = Some(v.len());
                let (a, b) = pre.get_or_insert_with(|| (vec![1.0; v.len()], vec![0.0; v.len()]));
                if a.len() != v.len() {
                    return Err(bad(format!("{} values against a normaliser of {}", v.len(), a.len())));
                }
                for i in 0..v.len() {
                    match op {
                        "Sub" => b[i] -= v[i],
                        "Add" => b[i] += v[i],
                        "Mul" => {
                            a[i] *= v[i];
                            b[i] *= v[i]
                        }
                        _ => {
                            a[i] /= v[i];
                            b[i] /= v[i]
                        }
                    }
                }
                trace.push(format!(
                    "#{idx} {op} '{name}': observation normaliser, folded into the first layer"
                ));
            }
            Some(Built::Linear(l)) => {
                let v = broadcast(c, Some(l.out), *rank, &what).map_err(bad)?;
                for (o, &c) in v.iter().enumerate() {
                    match op {
                        "Add" => l.b[o] += c,
                        "Sub" => l.b[o] -= c,
                        "Mul" | "Div" => {
                            let f = if op == "Mul" { c } else { 1.0 / c };
                            l.b[o] *= f;
                            for w in &mut l.w[o * l.inp..(o + 1) * l.inp] {
                                *w *= f;
                            }
                        }
                        _ => unreachable!(),
                    }
                }
                trace.push(format!("#{idx} {op} '{name}': folded into the linear layer before it"));
            }
            Some(_) => {
                return Err(bad(
                    "an element-wise constant after an activation or LSTM cannot be folded into a linear layer".into(),
                ))
            }
        }
        // numpy broadcasting: the result has as many axes as the larger operand.
        *rank = rank.map(|r| r.max(c.dims.len()));
        Ok(())
    }

    /// `Gemm` or `MatMul` (+ bias): a linear layer, the pending normaliser folded in.
    fn linear(&mut self, at: &At) -> Result<(), ImportError> {
        let (node, idx, op, name) = (at.node, at.idx, at.op.as_str(), at.name.as_str());
        let bad = |why: String| at.bad(why);
        let Walk {
            built,
            pre,
            width,
            rank,
            trace,
            ..
        } = self;
        let w = at.konst(1)?;
        if w.dims.len() != 2 {
            return Err(bad(format!("weight of shape {:?}, expected 2-D", w.dims)));
        }
        if op == "Gemm" && attr_i(node, "transA", 0) != 0 {
            return Err(bad(
                "transA = 1 (the observation transposed) is not a policy layer".into()
            ));
        }
        let trans_b = op == "Gemm" && attr_i(node, "transB", 0) != 0;
        let (inp, out) = if trans_b {
            (w.dims[1], w.dims[0])
        } else {
            (w.dims[0], w.dims[1])
        };
        let alpha = if op == "Gemm" { attr_f(node, "alpha", 1.0) } else { 1.0 };
        let beta = if op == "Gemm" { attr_f(node, "beta", 1.0) } else { 1.0 };
        let mut l = Linear {
            out,
            inp,
            w: vec![0.0; out * inp],
            b: vec![0.0; out],
        };
        for o in 0..out {
            for i in 0..inp {
                let v = if trans_b {
                    w.data[o * inp + i]
                } else {
                    w.data[i * out + o]
                };
                l.w[o * inp + i] = alpha * v;
            }
        }
        if op == "Gemm" && node.input.len() > 2 && !node.input[2].is_empty() {
            let c = at.konst(2)?;
            // C broadcasts one way only, to Gemm's output [M, N] = [1, out].
            let k = c.dims.last().copied().unwrap_or(1);
            if c.dims.len() > 2 || c.dims.len() == 2 && c.dims[0] != 1 || k != 1 && k != out {
                return Err(bad(format!(
                    "the bias C '{}' of shape {:?} does not broadcast one way to Gemm's output [1, {out}] \
                     (onnxruntime refuses it, or computes a batch of outputs); give it shape [{out}]",
                    node.input[2], c.dims
                )));
            }
            let v = broadcast(c, Some(out), Some(2), "C").map_err(bad)?;
            for (b, c) in l.b.iter_mut().zip(&v) {
                *b = beta * c;
            }
        }
        if let Some(wd) = *width {
            if wd != inp {
                return Err(bad(format!("takes {inp} inputs but receives {wd}")));
            }
        }
        fold_pre(pre, inp, &mut l.w, &mut l.b, out).map_err(bad)?;
        *width = Some(out);
        // Gemm's output is [M, N]; MatMul by a 2-D weight keeps the axes of its input.
        if op == "Gemm" {
            *rank = Some(2);
        }
        trace.push(format!("#{idx} {op} '{name}': linear {inp} → {out}"));
        built.push(Built::Linear(l));
        Ok(())
    }

    /// `Identity`, `Squeeze`, `Unsqueeze`, `Reshape`, `Flatten`: the values stay, the axes change.
    /// Refused where the features would leave the last axis (the executor's vector is that axis), or
    /// where onnxruntime fails on the shape.
    fn shape_only(&mut self, at: &At) -> Result<(), ImportError> {
        let op = at.op.as_str();
        if op == "Identity" {
            return Ok(());
        }
        let bad = |why: String| at.bad(why);
        let width = self.width;
        let shape = shape_str(&value_shape(width, self.rank));
        // Moving the features off the last axis only matters when there are several.
        let several = width != Some(1);
        let Some(r) = self.rank else {
            return match op {
                "Squeeze" if at.axes()?.is_none() => {
                    self.rank = width.map(|n| usize::from(n != 1));
                    Ok(())
                }
                _ => Err(bad(
                    "the observation input declares no shape, so where this puts the features cannot be \
                     checked; export the input with its shape ([1, n])"
                        .into(),
                )),
            };
        };
        // An axis number in [-len, len) as a position.
        let axis = |a: i64, len: usize| -> Result<usize, ImportError> {
            let l = len as i64;
            if (-l..l).contains(&a) {
                Ok(a.rem_euclid(l.max(1)) as usize)
            } else {
                Err(bad(format!("axis {a} is outside a value of {len} axes")))
            }
        };
        let positions = |axes: &[i64], len: usize| -> Result<Vec<usize>, ImportError> {
            let mut p = axes.iter().map(|&a| axis(a, len)).collect::<Result<Vec<_>, _>>()?;
            p.sort_unstable();
            if p.windows(2).any(|w| w[0] == w[1]) {
                return Err(bad(format!("axes {axes:?} repeat an axis")));
            }
            Ok(p)
        };
        self.rank = Some(match op {
            "Squeeze" => match at.axes()? {
                None => usize::from(several),
                Some(axes) => {
                    let p = positions(&axes, r)?;
                    if several && p.last() == Some(&(r - 1)) {
                        return Err(bad(format!(
                            "squeezes axis {} of the value {shape}, the features, which is not of size 1 \
                             (onnxruntime fails on it)",
                            r - 1
                        )));
                    }
                    r - p.len()
                }
            },
            "Unsqueeze" => {
                let axes = at.axes()?.ok_or_else(|| bad("no axes".into()))?;
                let len = r + axes.len();
                let p = positions(&axes, len)?;
                if several && p.last() == Some(&(len - 1)) {
                    return Err(bad(format!(
                        "adds an axis after the features of the value {shape}: they would no longer be the \
                         last axis, which the executor's vector is"
                    )));
                }
                len
            }
            "Flatten" => {
                let a = attr_i(at.node, "axis", 1);
                let l = r as i64;
                if !(-l..=l).contains(&a) {
                    return Err(bad(format!("axis {a} is outside a value of {r} axes")));
                }
                if several && a.rem_euclid(l + 1) == l {
                    return Err(bad(format!(
                        "axis {a} flattens the value {shape} to a column [n, 1]: the features would no \
                         longer be the last axis, which the executor's vector is"
                    )));
                }
                2
            }
            _ => self.reshape(at, r, &shape)?,
        });
        Ok(())
    }

    /// `Reshape` to a constant shape (0 copies the input's size there, -1 is inferred); the new rank.
    fn reshape(&mut self, at: &At, r: usize, shape: &str) -> Result<usize, ImportError> {
        let bad = |why: String| at.bad(why);
        let target = at.ints(1)?;
        if at.konst_any(1)?.1.dims.len() != 1 {
            return Err(bad("the shape input is not 1-D".into()));
        }
        let allowzero = attr_i(at.node, "allowzero", 0) != 0;
        let mut out: Vec<Option<usize>> = Vec::with_capacity(target.len());
        let mut inferred = None;
        for (i, &s) in target.iter().enumerate() {
            out.push(match s {
                -1 if inferred.is_none() => {
                    inferred = Some(i);
                    None
                }
                0 if !allowzero && i < r => {
                    if i + 1 == r {
                        self.width
                    } else {
                        Some(1)
                    }
                }
                s if s > 0 => Some(usize::try_from(s).unwrap_or(usize::MAX)),
                _ => {
                    return Err(bad(format!(
                        "shape {target:?}: not a reshape of {shape} the importer follows"
                    )))
                }
            });
        }
        // Every other axis has size 1, so the value has `width` elements.
        if let (Some(i), Some(n)) = (inferred, self.width) {
            let rest = out
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .try_fold(1usize, |a, (_, d)| d.and_then(|d| a.checked_mul(d)));
            out[i] = match rest {
                Some(p) if p > 0 && n % p == 0 => Some(n / p),
                _ => return Err(bad(format!("shape {target:?} does not fit the {n} values of {shape}"))),
            };
        }
        let last = out.last().copied().unwrap_or(Some(1));
        let leading_ones = out.iter().rev().skip(1).all(|&d| d == Some(1));
        match (leading_ones, last, self.width) {
            (true, Some(k), Some(n)) if k == n => {}
            (true, Some(k), None) => self.width = Some(k),
            (true, None, None) => {}
            _ => {
                return Err(bad(format!(
                    "reshapes the value {shape} to {}: the features must stay one vector along the last axis, \
                     which the executor's vector is",
                    shape_str(&out)
                )))
            }
        }
        Ok(out.len())
    }

    /// `Elu`, `Relu` or `Tanh`.
    fn activation(&mut self, at: &At) -> Result<(), ImportError> {
        let (node, idx, op, name) = (at.node, at.idx, at.op.as_str(), at.name.as_str());
        let bad = |why: String| at.bad(why);
        let Walk { built, pre, trace, .. } = self;
        if pre.is_some() && built.is_empty() {
            return Err(bad(
                "an activation directly on the normalised observation is not supported".into(),
            ));
        }
        let layer = match op {
            "Elu" => {
                // The executor refuses a non-finite alpha; name the node here.
                let alpha = attr_f(node, "alpha", 1.0);
                if !alpha.is_finite() {
                    return Err(bad(format!("alpha {alpha} is not finite")));
                }
                LayerDesc::Elu { alpha }
            }
            "Relu" => LayerDesc::Relu,
            _ => LayerDesc::Tanh,
        };
        trace.push(format!("#{idx} {op} '{name}': activation"));
        built.push(Built::Act(layer));
        Ok(())
    }

    /// One forward `LSTM`, gates reordered from ONNX's i, o, f, c to PyTorch's i, f, g, o; returns
    /// the value the chain goes on with (Y or Y_h).
    fn lstm(&mut self, at: &At, graph: &Graph) -> Result<String, ImportError> {
        let (node, idx, name) = (at.node, at.idx, at.name.as_str());
        let bad = |why: String| at.bad(why);
        let Walk {
            built,
            pre,
            width,
            rank,
            recurrent,
            trace,
            ..
        } = self;
        let (consts, users, output_name, state_inputs) =
            (at.consts, &graph.users, &graph.output_name, &graph.state_inputs);
        let hidden = lstm_hidden_size(at)?;
        let (w, r) = (at.konst(1)?, at.konst(2)?);
        if w.dims.len() != 3 || w.dims[0] != 1 || w.dims[1] != 4 * hidden {
            return Err(bad(format!(
                "W has shape {:?}, expected [1, {}, in]",
                w.dims,
                4 * hidden
            )));
        }
        if r.dims != [1, 4 * hidden, hidden] {
            return Err(bad(format!(
                "R has shape {:?}, expected [1, {}, {hidden}]",
                r.dims,
                4 * hidden
            )));
        }
        let inp = w.dims[2];
        if let Some(wd) = *width {
            if wd != inp {
                return Err(bad(format!("takes {inp} inputs but receives {wd}")));
            }
        }
        let bias: Vec<f32> = match node.input.get(3).filter(|s| !s.is_empty()) {
            Some(_) => {
                let b = at.konst(3)?;
                if b.dims != [1, 8 * hidden] {
                    return Err(bad(format!("B has shape {:?}, expected [1, {}]", b.dims, 8 * hidden)));
                }
                b.data.clone()
            }
            None => vec![0.0; 8 * hidden],
        };
        if node
            .input
            .get(4)
            .is_some_and(|s| !s.is_empty() && !consts.contains_key(s))
        {
            return Err(bad(
                "sequence_lens from a graph input: step-by-step execution has none".into()
            ));
        }
        // ONNX gate blocks i, o, f, c → PyTorch i, f, g, o.
        let reorder = |src: &[f32], cols: usize| -> Vec<f32> {
            let mut out = Vec::with_capacity(src.len());
            for blk in [0usize, 2, 3, 1] {
                out.extend_from_slice(&src[blk * hidden * cols..(blk + 1) * hidden * cols]);
            }
            out
        };
        let mut w_ih = reorder(&w.data, inp);
        let w_hh = reorder(&r.data, hidden);
        let mut b_ih = reorder(&bias[..4 * hidden], 1);
        let b_hh = reorder(&bias[4 * hidden..], 1);
        fold_pre(pre, inp, &mut w_ih, &mut b_ih, 4 * hidden).map_err(bad)?;
        let mut rec = RecurrentIo {
            hidden,
            ..Default::default()
        };
        let state = |k: usize, slot: &mut Option<String>| -> Result<Option<Vec<f32>>, ImportError> {
            match node.input.get(k).filter(|s| !s.is_empty()) {
                None => Ok(None),
                Some(s) if state_inputs.contains(s) => {
                    *slot = Some(s.clone());
                    Ok(None)
                }
                Some(s) => match consts.get(s) {
                    Some(t) if t.dims == [1, 1, hidden] => at.float32(s).map(|()| Some(t.data.clone())),
                    Some(t) => Err(bad(format!("initial state '{s}' has shape {:?}, not [1, 1, {hidden}]", t.dims))),
                    None => Err(bad(format!(
                        "initial state '{s}' is computed in the graph (a multi-layer state sliced from one input?): not supported"
                    ))),
                },
            }
        };
        let h0 = state(5, &mut rec.h_in)?;
        let c0 = state(6, &mut rec.c_in)?;
        if recurrent.is_some() {
            return Err(bad("a second LSTM: only one recurrent layer is supported".into()));
        }
        *recurrent = Some(rec);
        // Y (all steps) or Y_h (the last): the same vector for one step.
        let next = match (node.output.first(), node.output.get(1)) {
            (Some(y), _) if !y.is_empty() && users.contains_key(y.as_str()) || Some(y) == Some(output_name) => {
                y.clone()
            }
            (_, Some(yh)) if !yh.is_empty() => yh.clone(),
            _ => return Err(bad("neither Y nor Y_h is used".into())),
        };
        *width = Some(hidden);
        // Y is [seq, directions, batch, hidden], Y_h [directions, batch, hidden].
        *rank = Some(if node.output.first() == Some(&next) { 4 } else { 3 });
        trace.push(format!(
            "#{idx} LSTM '{name}': lstm {inp} → {hidden} (gates reordered i,o,f,c → i,f,g,o)"
        ));
        built.push(Built::Lstm {
            hidden,
            inp,
            w_ih,
            w_hh,
            b_ih,
            b_hh,
            h0,
            c0,
        });
        Ok(next)
    }
}

/// The LSTM's hidden size, after refusing what the firmware's LSTM does not compute (another
/// direction or layout, coupled gates, peepholes, custom activations or clipping).
fn lstm_hidden_size(at: &At) -> Result<usize, ImportError> {
    let node = at.node;
    let bad = |why: String| at.bad(why);
    let hidden = usize::try_from(attr_i(node, "hidden_size", 0)).unwrap_or(0);
    if hidden == 0 {
        return Err(bad("no hidden_size".into()));
    }
    // 8 · hidden values (both biases) must fit an activation; checked before any
    // arithmetic on it.
    if hidden > control::nn::MAX_ACTIVATION / 8 {
        return Err(bad(format!(
            "hidden_size {hidden} is more than the {} an LSTM here may have",
            control::nn::MAX_ACTIVATION / 8
        )));
    }
    if let Some(d) = attr_s(node, "direction").filter(|d| d != "forward") {
        return Err(bad(format!("direction '{d}': only forward LSTMs run step by step")));
    }
    if attr_i(node, "layout", 0) != 0 {
        return Err(bad("layout = 1 (batch-major) is not supported".into()));
    }
    if attr_i(node, "input_forget", 0) != 0 {
        return Err(bad(
            "input_forget = 1 (coupled input and forget gates) is not supported: the firmware's LSTM has independent gates".into(),
        ));
    }
    if node.input.get(7).is_some_and(|s| !s.is_empty()) {
        return Err(bad(
            "peephole weights (input P) are not supported: the firmware's LSTM has no peepholes, and without them it would compute other outputs".into(),
        ));
    }
    let custom = ["clip", "activations", "activation_alpha", "activation_beta"];
    if let Some(a) = node
        .attribute
        .iter()
        .filter_map(|a| a.name.as_deref())
        .find(|n| custom.contains(n))
    {
        return Err(bad(format!(
            "attribute '{a}' is not supported: the firmware's LSTM uses the default sigmoid and tanh, without cell clipping"
        )));
    }
    Ok(hidden)
}

/// Folds the pending normaliser `x' = a ⊙ x + b` into a layer `y = W x' + c`:
/// `W'[o][i] = W[o][i]·a[i]`, `c'[o] = c[o] + Σ_i W[o][i]·b[i]`.
fn fold_pre(
    pre: &mut Option<(Vec<f32>, Vec<f32>)>,
    inp: usize,
    w: &mut [f32],
    bias: &mut [f32],
    out: usize,
) -> Result<(), String> {
    let Some((a, b)) = pre.take() else { return Ok(()) };
    if a.len() != inp {
        return Err(format!(
            "the normaliser has {} values but the layer takes {inp}",
            a.len()
        ));
    }
    for o in 0..out {
        let row = &mut w[o * inp..(o + 1) * inp];
        let mut shift = 0.0f64;
        for i in 0..inp {
            shift += row[i] as f64 * b[i] as f64;
            row[i] *= a[i];
        }
        bias[o] += shift as f32;
    }
    Ok(())
}

impl ImportedNetwork {
    /// The network as a deploy spec's `[policy.network]` table.
    pub fn spec_table(&self) -> Result<String, ImportError> {
        let body =
            toml::to_string(&self.desc).map_err(|e| ImportError::Graph(format!("writing the network table: {e}")))?;
        Ok(format!(
            "[policy.network]\n{}",
            body.replace("[[layers]]", "[[policy.network.layers]]")
        ))
    }

    /// The tensors as a safetensors file.
    pub fn safetensors_bytes(&self) -> Result<Vec<u8>, ImportError> {
        let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = self
            .tensors
            .iter()
            .map(|(n, t)| {
                (
                    n.clone(),
                    t.dims.clone(),
                    t.data.iter().flat_map(|v| v.to_le_bytes()).collect(),
                )
            })
            .collect();
        let views: Vec<(String, safetensors::tensor::TensorView<'_>)> = bytes
            .iter()
            .map(|(n, d, b)| {
                safetensors::tensor::TensorView::new(safetensors::Dtype::F32, d.clone(), b)
                    .map(|v| (n.clone(), v))
                    .map_err(|e| ImportError::Tensor {
                        name: n.clone(),
                        why: e.to_string(),
                    })
            })
            .collect::<Result<_, _>>()?;
        safetensors::serialize(views, &None).map_err(|e| ImportError::Graph(format!("writing safetensors: {e}")))
    }
}
