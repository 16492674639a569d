//! Loaded layers: weights packed for [`PackedMatrix::matvec`] and [`PackedConv::forward`], state
//! and scratch buffers allocated once at load so that `forward` never allocates.

use super::desc::LayerDesc;
use super::error::NnError;
use super::kernels::{elu, sigmoid, tanh, ConvGeom, Isa, PackedConv, PackedMatrix};
use safetensors::{Dtype, SafeTensors};

/// A loaded layer. Element-wise layers carry no weights; their shape is the previous shape.
#[derive(Clone)]
pub(crate) enum Layer {
    Linear(PackedMatrix),
    Elu {
        alpha: f32,
    },
    Relu,
    Tanh,
    Lstm(Box<Lstm>),
    Conv2d(Box<PackedConv>),
    /// A `relu` whose work the preceding `conv2d` does while storing ([`Layer::fuse`]): passes
    /// its input through (the executor skips it unless it is the last layer, then it copies).
    FusedRelu,
}

/// Stateful single-layer LSTM. `W_ih` and `W_hh` are packed side by side into one
/// `[4H, in + H]` matrix applied to `xh = [x, h]`, with `bias_ih + bias_hh` pre-summed, so a
/// step is one matrix-vector product. `h` lives in the tail of `xh`, so no copy is needed.
#[derive(Clone)]
pub(crate) struct Lstm {
    input: usize,
    hidden: usize,
    w: PackedMatrix,
    xh: Vec<f32>,
    c: Vec<f32>,
    gates: Vec<f32>,
    h0: Vec<f32>,
    c0: Vec<f32>,
}

impl Lstm {
    fn reset(&mut self) {
        self.xh[self.input..].copy_from_slice(&self.h0);
        self.c.copy_from_slice(&self.c0);
    }

    /// PyTorch `nn.LSTM` cell: gates `[i, f, g, o]` (each `H`), `c = f*c + i*g`, `h = o*tanh(c)`.
    fn forward(&mut self, x: &[f32], y: &mut [f32]) {
        let h_len = self.hidden;
        self.xh[..self.input].copy_from_slice(x);
        self.w.matvec(&self.xh, &mut self.gates);
        let (gi, rest) = self.gates.split_at(h_len);
        let (gf, rest) = rest.split_at(h_len);
        let (gg, go) = rest.split_at(h_len);
        let h = &mut self.xh[self.input..];
        for (k, c) in self.c.iter_mut().enumerate() {
            let i = sigmoid(gi[k]);
            let f = sigmoid(gf[k]);
            let g = tanh(gg[k]);
            let o = sigmoid(go[k]);
            let c_new = f * *c + i * g;
            *c = c_new;
            h[k] = o * tanh(c_new);
        }
        y.copy_from_slice(h);
    }
}

impl Layer {
    /// Output shape given the input shape (CHW for images, `[n]` for vectors).
    fn output_shape(&self, input: &[usize]) -> Vec<usize> {
        match self {
            Layer::Linear(m) => vec![m.rows()],
            Layer::Lstm(l) => vec![l.hidden],
            Layer::Conv2d(c) => {
                let g = c.geom();
                vec![g.cout, g.ho(), g.wo()]
            }
            Layer::Elu { .. } | Layer::Relu | Layer::Tanh | Layer::FusedRelu => input.to_vec(),
        }
    }

    /// Fuses `next` into `self` where that is exact: a `relu` after a `conv2d` is applied by
    /// the convolution's store, and `next` becomes [`Layer::FusedRelu`]. Returns whether it did.
    pub(crate) fn fuse(&mut self, next: &mut Layer) -> bool {
        match (self, &*next) {
            (Layer::Conv2d(c), Layer::Relu) => {
                c.fuse_relu();
                *next = Layer::FusedRelu;
                true
            }
            _ => false,
        }
    }

    /// True for layers the executor skips (their output is their input).
    pub(crate) fn is_pass_through(&self) -> bool {
        matches!(self, Layer::FusedRelu)
    }

    /// Makes convolutions and matrix products use the portable kernels even where AVX2 is
    /// available (benchmarks and tests compare the two; results are bit-identical).
    pub(crate) fn use_portable_kernels(&mut self) {
        match self {
            Layer::Conv2d(c) => c.set_isa(Isa::Portable),
            Layer::Linear(m) => m.set_isa(Isa::Portable),
            Layer::Lstm(l) => l.w.set_isa(Isa::Portable),
            Layer::Elu { .. } | Layer::Relu | Layer::Tanh | Layer::FusedRelu => {}
        }
    }

    /// Recurrent state of this layer (`h` then `c` of an LSTM; empty for stateless layers).
    pub(crate) fn state_parts(&mut self) -> Option<(&mut [f32], &mut [f32])> {
        match self {
            Layer::Lstm(l) => {
                let input = l.input;
                Some((&mut l.xh[input..], &mut l.c))
            }
            _ => None,
        }
    }

    /// Restores recurrent state to its initial value; no-op for stateless layers.
    pub(crate) fn reset(&mut self) {
        if let Layer::Lstm(l) = self {
            l.reset();
        }
    }

    /// `y = layer(x)`; slice lengths were fixed at load time.
    #[inline]
    pub(crate) fn forward(&mut self, x: &[f32], y: &mut [f32]) {
        match self {
            Layer::Linear(m) => m.matvec(x, y),
            Layer::Elu { alpha } => {
                let alpha = *alpha;
                for (yi, &xi) in y.iter_mut().zip(x) {
                    *yi = elu(xi, alpha);
                }
            }
            Layer::Relu => {
                for (yi, &xi) in y.iter_mut().zip(x) {
                    // Not f32::max: keep NaN visible instead of turning it into 0.
                    *yi = if xi < 0.0 { 0.0 } else { xi };
                }
            }
            Layer::Tanh => {
                for (yi, &xi) in y.iter_mut().zip(x) {
                    *yi = tanh(xi);
                }
            }
            Layer::Lstm(l) => l.forward(x, y),
            Layer::Conv2d(c) => c.forward(x, y),
            Layer::FusedRelu => y.copy_from_slice(x),
        }
    }
}

/// Reads tensors for one layer, turning every problem into an [`NnError`] that names the layer.
pub(crate) struct TensorSource<'a, 'b> {
    pub(crate) st: &'b SafeTensors<'a>,
    pub(crate) layer: String,
}

/// A tensor converted to f32 with its shape.
pub(crate) struct Tensor {
    pub(crate) name: String,
    pub(crate) shape: Vec<usize>,
    pub(crate) data: Vec<f32>,
}

impl TensorSource<'_, '_> {
    fn get(&self, role: &'static str, name: &str) -> Result<Tensor, NnError> {
        let view = self.st.tensor(name).map_err(|_| {
            let mut names: Vec<&str> = self.st.names().into_iter().map(String::as_str).collect();
            names.sort_unstable();
            NnError::MissingTensor {
                layer: self.layer.clone(),
                role,
                tensor: name.to_string(),
                available: names.join(", "),
            }
        })?;
        if view.dtype() != Dtype::F32 {
            return Err(NnError::Dtype {
                layer: self.layer.clone(),
                role,
                tensor: name.to_string(),
                found: format!("{:?}", view.dtype()),
            });
        }
        let shape = view.shape().to_vec();
        // safetensors validated that the byte length matches the shape; data may be unaligned.
        let data: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if let Some(index) = data.iter().position(|v| !v.is_finite()) {
            return Err(NnError::NonFinite {
                layer: self.layer.clone(),
                role,
                tensor: name.to_string(),
                index,
            });
        }
        Ok(Tensor {
            name: name.to_string(),
            shape,
            data,
        })
    }

    fn shape_err(&self, role: &'static str, t: &Tensor, expected: String) -> NnError {
        NnError::Shape {
            layer: self.layer.clone(),
            role,
            tensor: t.name.clone(),
            expected,
            found: t.shape.clone(),
        }
    }

    /// A 2-D tensor with non-zero dimensions; returns `(rows, cols)`.
    fn matrix(&self, role: &'static str, name: &str, what: &str) -> Result<Tensor, NnError> {
        let t = self.get(role, name)?;
        match t.shape[..] {
            [r, c] if r > 0 && c > 0 => Ok(t),
            _ => Err(self.shape_err(role, &t, format!("a 2-D {what} matrix"))),
        }
    }

    /// A tensor with exactly `n` elements and shape `[n]` or `[1, .., 1, n]`.
    fn vector(&self, role: &'static str, name: &str, n: usize) -> Result<Tensor, NnError> {
        let t = self.get(role, name)?;
        let ok = t.shape.last() == Some(&n) && t.shape.iter().rev().skip(1).all(|&d| d == 1);
        if ok {
            Ok(t)
        } else {
            Err(self.shape_err(role, &t, format!("[{n}] (or [1, .., 1, {n}])")))
        }
    }

    fn input_check(&self, t: &Tensor, expected: usize, found: usize, source_desc: &str) -> Result<(), NnError> {
        if expected == found {
            Ok(())
        } else {
            Err(NnError::InputDim {
                layer: self.layer.clone(),
                tensor: t.name.clone(),
                expected,
                found,
                source_desc: source_desc.to_string(),
            })
        }
    }

    fn conv_err(&self, message: String) -> NnError {
        NnError::ConvShape {
            layer: self.layer.clone(),
            message,
        }
    }

    /// Builds a `conv2d` for the activation `shape` produced by `source_desc`.
    fn conv2d(
        &self,
        weight: &str,
        bias: &str,
        stride: usize,
        padding: usize,
        shape: &[usize],
        source_desc: &str,
    ) -> Result<(Layer, usize), NnError> {
        let w = self.get("weight", weight)?;
        let (cout, cin, kh, kw) = match w.shape[..] {
            [o, i, h, k] if o > 0 && i > 0 && h > 0 && k > 0 => (o, i, h, k),
            _ => {
                return Err(self.shape_err(
                    "weight",
                    &w,
                    "a 4-D [cout, cin, kh, kw] kernel (PyTorch nn.Conv2d layout)".into(),
                ))
            }
        };
        if stride == 0 {
            return Err(NnError::Param {
                layer: self.layer.clone(),
                message: "stride must be >= 1, found 0".into(),
            });
        }
        if padding >= kh.max(kw) {
            return Err(NnError::Param {
                layer: self.layer.clone(),
                message: format!(
                    "padding {padding} must be smaller than the {kh}x{kw} kernel (more padding only adds \
                     outputs that see nothing but zeros)"
                ),
            });
        }
        let (c, h, wd) = match shape[..] {
            [c, h, wd] => (c, h, wd),
            [n] if source_desc == "the network input" => {
                let fits = |s: &usize| {
                    s.checked_mul(*s)
                        .and_then(|v| v.checked_mul(cin))
                        .is_some_and(|v| v <= n)
                };
                let side = (1..=n).take_while(fits).last().unwrap_or(0);
                let hint = if side > 0 && side * side * cin == n {
                    format!("set input_shape = [{cin}, {side}, {side}]")
                } else {
                    format!("set input_shape = [{cin}, H, W] with {cin} * H * W = {n}")
                };
                return Err(self.conv_err(format!(
                    "conv2d needs a [C,H,W] input, but the network input is a flat vector of {n}: \
                     {hint} in the network description"
                )));
            }
            _ => {
                return Err(self.conv_err(format!(
                    "conv2d needs a [C,H,W] input, but {source_desc} produces shape {shape:?} (linear and \
                     lstm produce flat vectors; only conv2d and element-wise layers keep an image shape)"
                )))
            }
        };
        if c != cin {
            return Err(self.conv_err(format!(
                "expects {cin} input channels (tensor `{weight}` has shape {:?}), but {source_desc} \
                 produces shape [{c}, {h}, {wd}]",
                w.shape
            )));
        }
        let (hp, wp) = (h + 2 * padding, wd + 2 * padding);
        if kh > hp || kw > wp {
            return Err(self.conv_err(format!(
                "the {kh}x{kw} kernel (tensor `{weight}`) is larger than the padded input {hp}x{wp} \
                 ({source_desc} produces [{c}, {h}, {wd}], padding {padding})"
            )));
        }
        let b = self.vector("bias", bias, cout)?;
        let g = ConvGeom {
            cin,
            h,
            w: wd,
            cout,
            kh,
            kw,
            stride,
            pad: padding,
        };
        let n = w.data.len() + b.data.len();
        Ok((
            Layer::Conv2d(Box::new(PackedConv::pack(g, &w.data, &b.data, Isa::detect()))),
            n,
        ))
    }

    /// Builds the layer for `desc`, given the activation `shape` produced by `source_desc`
    /// (`[n]` for vectors, `[C, H, W]` for images). Returns it with its output shape and the
    /// number of learned parameters as stored in the file (weights and biases; LSTM initial
    /// states are buffers, not parameters, matching PyTorch's `parameters()`).
    pub(crate) fn build(
        &self,
        desc: &LayerDesc,
        shape: &[usize],
        source_desc: &str,
    ) -> Result<(Layer, Vec<usize>, usize), NnError> {
        let (layer, n) = self.build_layer(desc, shape, source_desc)?;
        let out = layer.output_shape(shape);
        Ok((layer, out, n))
    }

    fn build_layer(&self, desc: &LayerDesc, shape: &[usize], source_desc: &str) -> Result<(Layer, usize), NnError> {
        let input: usize = shape.iter().product();
        Ok(match desc {
            LayerDesc::Linear { weight, bias } => {
                let w = self.matrix("weight", weight, "[out, in]")?;
                let (rows, cols) = (w.shape[0], w.shape[1]);
                self.input_check(&w, cols, input, source_desc)?;
                let b = self.vector("bias", bias, rows)?;
                let n = w.data.len() + b.data.len();
                (Layer::Linear(PackedMatrix::pack(&w.data, &b.data, rows, cols)), n)
            }
            LayerDesc::Elu { alpha } => {
                if !alpha.is_finite() {
                    return Err(NnError::Param {
                        layer: self.layer.clone(),
                        message: format!("alpha must be finite, found {alpha}"),
                    });
                }
                (Layer::Elu { alpha: *alpha }, 0)
            }
            LayerDesc::Relu => (Layer::Relu, 0),
            LayerDesc::Tanh => (Layer::Tanh, 0),
            LayerDesc::Lstm {
                weight_ih,
                weight_hh,
                bias_ih,
                bias_hh,
                initial_hidden,
                initial_cell,
            } => {
                let wih = self.matrix("weight_ih", weight_ih, "[4*hidden, in]")?;
                let (four_h, n_in) = (wih.shape[0], wih.shape[1]);
                if four_h % 4 != 0 {
                    return Err(self.shape_err(
                        "weight_ih",
                        &wih,
                        "[4*hidden, in] (first dimension a multiple of 4)".into(),
                    ));
                }
                let hidden = four_h / 4;
                self.input_check(&wih, n_in, input, source_desc)?;
                let whh = self.matrix("weight_hh", weight_hh, "[4*hidden, hidden]")?;
                if whh.shape[..] != [four_h, hidden] {
                    return Err(self.shape_err(
                        "weight_hh",
                        &whh,
                        format!("[{four_h}, {hidden}] (hidden = {hidden} from weight_ih)"),
                    ));
                }
                let bih = self.vector("bias_ih", bias_ih, four_h)?;
                let bhh = self.vector("bias_hh", bias_hh, four_h)?;
                let state = |role, name: &Option<String>| match name {
                    Some(n) => self.vector(role, n, hidden).map(|t| t.data),
                    None => Ok(vec![0.0; hidden]),
                };
                let h0 = state("initial_hidden", initial_hidden)?;
                let c0 = state("initial_cell", initial_cell)?;

                let cols = n_in + hidden;
                let mut w = Vec::with_capacity(four_h * cols);
                for r in 0..four_h {
                    w.extend_from_slice(&wih.data[r * n_in..(r + 1) * n_in]);
                    w.extend_from_slice(&whh.data[r * hidden..(r + 1) * hidden]);
                }
                let b: Vec<f32> = bih.data.iter().zip(&bhh.data).map(|(a, b)| a + b).collect();
                let mut lstm = Lstm {
                    input: n_in,
                    hidden,
                    w: PackedMatrix::pack(&w, &b, four_h, cols),
                    xh: vec![0.0; cols],
                    c: vec![0.0; hidden],
                    gates: vec![0.0; four_h],
                    h0,
                    c0,
                };
                lstm.reset();
                let n = wih.data.len() + whh.data.len() + bih.data.len() + bhh.data.len();
                (Layer::Lstm(Box::new(lstm)), n)
            }
            LayerDesc::Conv2d {
                weight,
                bias,
                stride,
                padding,
            } => self.conv2d(weight, bias, *stride, *padding, shape, source_desc)?,
        })
    }
}

/// An LSTM's recurrent state: `h` (the tail of `xh`) and `c`.
impl snapshot::Snapshot for Lstm {
    fn save(&self, out: &mut Vec<u8>) {
        self.xh[self.input..].save(out);
        self.c.save(out);
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        let at = self.input;
        self.xh[at..].restore(input)?;
        self.c.restore(input)
    }
}
