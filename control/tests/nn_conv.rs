//! `conv2d` in `control::nn`: conv chains against a naive reference (bit for bit), the terrain
//! CNN's shapes, load errors that say what to fix, and the description's TOML form.

use control::nn::{LayerDesc, Network, NetworkDesc, NnError};
use hal::XorShift64 as Rng;
use safetensors::tensor::{Dtype, TensorView};

/// `n` values uniform in [-scale, scale).
fn rand_vec(rng: &mut Rng, n: usize, scale: f32) -> Vec<f32> {
    (0..n).map(|_| scale * rng.signed()).collect()
}

/// Named f32 tensors, serialized to safetensors bytes.
#[derive(Default)]
struct File {
    tensors: Vec<(String, Vec<usize>, Vec<f32>)>,
}
impl File {
    fn add(&mut self, name: &str, shape: &[usize], data: Vec<f32>) {
        assert_eq!(shape.iter().product::<usize>(), data.len());
        self.tensors.push((name.into(), shape.to_vec(), data));
    }
    fn get(&self, name: &str) -> &[f32] {
        &self.tensors.iter().find(|t| t.0 == name).unwrap().2
    }
    fn bytes(&self) -> Vec<u8> {
        let raw: Vec<Vec<u8>> = self
            .tensors
            .iter()
            .map(|t| t.2.iter().flat_map(|v| v.to_le_bytes()).collect())
            .collect();
        let views: Vec<(&str, TensorView<'_>)> = self
            .tensors
            .iter()
            .zip(&raw)
            .map(|(t, d)| (t.0.as_str(), TensorView::new(Dtype::F32, t.1.clone(), d).unwrap()))
            .collect();
        safetensors::serialize(views, &None).unwrap()
    }
}

fn conv(name: &str, stride: usize, padding: usize) -> LayerDesc {
    LayerDesc::Conv2d {
        weight: format!("{name}.weight"),
        bias: format!("{name}.bias"),
        stride,
        padding,
    }
}

fn linear(name: &str) -> LayerDesc {
    LayerDesc::Linear {
        weight: format!("{name}.weight"),
        bias: format!("{name}.bias"),
    }
}

/// PyTorch `nn.Conv2d` literally: every tap in (ci, ky, kx) order, zeros for padding, each a
/// fused multiply-add (the executor's documented arithmetic).
fn ref_conv(
    x: &[f32],
    (cin, h, w): (usize, usize, usize),
    wt: &[f32],
    b: &[f32],
    (cout, kh, kw): (usize, usize, usize),
    s: usize,
    p: usize,
) -> (Vec<f32>, (usize, usize, usize)) {
    let (ho, wo) = ((h + 2 * p - kh) / s + 1, (w + 2 * p - kw) / s + 1);
    let mut y = vec![0.0f32; cout * ho * wo];
    for co in 0..cout {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = b[co];
                for ci in 0..cin {
                    for ky in 0..kh {
                        for kx in 0..kw {
                            let (iy, ix) = ((oy * s + ky) as isize - p as isize, (ox * s + kx) as isize - p as isize);
                            let v = if iy >= 0 && ix >= 0 && (iy as usize) < h && (ix as usize) < w {
                                x[(ci * h + iy as usize) * w + ix as usize]
                            } else {
                                0.0
                            };
                            acc = wt[((co * cin + ci) * kh + ky) * kw + kx].mul_add(v, acc);
                        }
                    }
                }
                y[(co * ho + oy) * wo + ox] = acc;
            }
        }
    }
    (y, (cout, ho, wo))
}

fn ref_relu(x: &mut [f32]) {
    for v in x {
        if *v < 0.0 {
            *v = 0.0;
        }
    }
}

/// `nn.Flatten` + `nn.Linear`: `b + sum_j W[r][j] x[j]` in order.
fn ref_linear(x: &[f32], w: &[f32], b: &[f32]) -> Vec<f32> {
    b.iter()
        .enumerate()
        .map(|(r, &br)| {
            let row = &w[r * x.len()..(r + 1) * x.len()];
            row.iter().zip(x).fold(br, |acc, (w, x)| acc + w * x)
        })
        .collect()
}

fn assert_bits(got: &[f32], want: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (a, e)) in got.iter().zip(want).enumerate() {
        assert_eq!(a.to_bits(), e.to_bits(), "{what}: element {i}: {a} vs {e}");
    }
}

/// The terrain CNN with random weights (same shapes and names as the real export).
fn terrain_cnn(rng: &mut Rng) -> (NetworkDesc, File) {
    let mut f = File::default();
    for (name, cout, cin) in [("conv1", 24, 6), ("conv2", 48, 24), ("conv3", 128, 48)] {
        let fan_in = (cin * 9) as f32;
        f.add(
            &format!("{name}.weight"),
            &[cout, cin, 3, 3],
            rand_vec(rng, cout * cin * 9, 1.0 / fan_in.sqrt()),
        );
        f.add(&format!("{name}.bias"), &[cout], rand_vec(rng, cout, 0.1));
    }
    f.add(
        "fc.weight",
        &[128, 8192],
        rand_vec(rng, 128 * 8192, 1.0 / 8192f32.sqrt()),
    );
    f.add("fc.bias", &[128], rand_vec(rng, 128, 0.1));
    f.add("head.weight", &[7, 128], rand_vec(rng, 7 * 128, 1.0 / 128f32.sqrt()));
    f.add("head.bias", &[7], rand_vec(rng, 7, 0.1));
    let desc = NetworkDesc {
        input: 21600,
        input_shape: Some(vec![6, 60, 60]),
        layers: vec![
            conv("conv1", 2, 1),
            LayerDesc::Relu,
            conv("conv2", 2, 1),
            LayerDesc::Relu,
            conv("conv3", 2, 1),
            LayerDesc::Relu,
            linear("fc"),
            LayerDesc::Relu,
            linear("head"),
        ],
    };
    (desc, f)
}

#[test]
fn terrain_cnn_shapes_and_output_match_reference() {
    let mut rng = Rng(0x007E_44A1);
    let (desc, f) = terrain_cnn(&mut rng);
    let mut net = Network::from_safetensors_bytes(&desc, &f.bytes()).unwrap();
    assert_eq!((net.input_dim(), net.output_dim()), (21600, 7));
    assert_eq!(net.input_shape(), &[6, 60, 60]);
    let shapes: Vec<&[usize]> = (0..9).map(|i| net.layer_output_shape(i).unwrap()).collect();
    assert_eq!(
        shapes,
        [
            &[24, 30, 30][..],
            &[24, 30, 30],
            &[48, 15, 15],
            &[48, 15, 15],
            &[128, 8, 8],
            &[128, 8, 8],
            &[128],
            &[128],
            &[7]
        ]
    );
    assert_eq!(net.layer_output_shape(9), None);
    let want_params = 24 * 6 * 9 + 24 + 48 * 24 * 9 + 48 + 128 * 48 * 9 + 128 + 128 * 8192 + 128 + 7 * 128 + 7;
    assert_eq!(net.param_count(), want_params);

    let x: Vec<f32> = rand_vec(&mut rng, 21600, 0.5).iter().map(|v| v + 0.2).collect();
    let (mut a, s) = ref_conv(
        &x,
        (6, 60, 60),
        f.get("conv1.weight"),
        f.get("conv1.bias"),
        (24, 3, 3),
        2,
        1,
    );
    ref_relu(&mut a);
    let (mut a, s) = ref_conv(&a, s, f.get("conv2.weight"), f.get("conv2.bias"), (48, 3, 3), 2, 1);
    ref_relu(&mut a);
    let (mut a, _) = ref_conv(&a, s, f.get("conv3.weight"), f.get("conv3.bias"), (128, 3, 3), 2, 1);
    ref_relu(&mut a);
    let mut a = ref_linear(&a, f.get("fc.weight"), f.get("fc.bias"));
    ref_relu(&mut a);
    let want = ref_linear(&a, f.get("head.weight"), f.get("head.bias"));
    let mut y = [0.0f32; 7];
    net.step(&x, &mut y).unwrap();
    assert_bits(&y, &want, "terrain cnn");
    // Stateless: the same input gives the same bits again.
    let mut y2 = [0.0f32; 7];
    net.step(&x, &mut y2).unwrap();
    assert_bits(&y2, &y, "second step");
    // The portable kernels (what aarch64 and CPUs without AVX2 run) give the same bits.
    net.use_portable_kernels();
    net.step(&x, &mut y2).unwrap();
    assert_bits(&y2, &y, "portable kernels");
}

#[test]
fn conv_relu_conv_linear_chain_matches_reference() {
    // Odd sizes, stride 1 and 2, padding 0/1/2, channel counts off the 8-lane panels.
    for (seed, (cin, h, w), (c1, k1, s1, p1), (c2, k2, s2, p2), n_out) in [
        (1, (3, 9, 7), (10, 3, 2, 1), (12, 2, 1, 0), 5),
        (2, (1, 5, 5), (1, 1, 1, 0), (3, 3, 1, 1), 1),
        (3, (7, 13, 6), (17, 5, 1, 2), (9, 3, 2, 1), 33),
        (4, (2, 4, 11), (33, 4, 3, 2), (8, 1, 1, 0), 8),
    ] {
        let mut rng = Rng(seed);
        let mut f = File::default();
        f.add(
            "a.weight",
            &[c1, cin, k1, k1],
            rand_vec(&mut rng, c1 * cin * k1 * k1, 0.5),
        );
        f.add("a.bias", &[c1], rand_vec(&mut rng, c1, 0.5));
        f.add(
            "b.weight",
            &[c2, c1, k2, k2],
            rand_vec(&mut rng, c2 * c1 * k2 * k2, 0.5),
        );
        f.add("b.bias", &[c2], rand_vec(&mut rng, c2, 0.5));
        let (ho1, wo1) = ((h + 2 * p1 - k1) / s1 + 1, (w + 2 * p1 - k1) / s1 + 1);
        let (ho2, wo2) = ((ho1 + 2 * p2 - k2) / s2 + 1, (wo1 + 2 * p2 - k2) / s2 + 1);
        let flat = c2 * ho2 * wo2;
        f.add("l.weight", &[n_out, flat], rand_vec(&mut rng, n_out * flat, 0.5));
        f.add("l.bias", &[n_out], rand_vec(&mut rng, n_out, 0.5));
        let desc = NetworkDesc {
            input: cin * h * w,
            input_shape: Some(vec![cin, h, w]),
            layers: vec![
                conv("a", s1, p1),
                LayerDesc::Relu,
                conv("b", s2, p2),
                LayerDesc::Relu,
                linear("l"),
            ],
        };
        let mut net = Network::from_safetensors_bytes(&desc, &f.bytes()).unwrap();
        assert_eq!(net.layer_output_shape(2).unwrap(), &[c2, ho2, wo2]);
        let mut y = vec![0.0f32; n_out];
        for trial in 0..5 {
            let x = rand_vec(&mut rng, cin * h * w, 2.0);
            let (mut a, s) = ref_conv(
                &x,
                (cin, h, w),
                f.get("a.weight"),
                f.get("a.bias"),
                (c1, k1, k1),
                s1,
                p1,
            );
            ref_relu(&mut a);
            let (mut a, _) = ref_conv(&a, s, f.get("b.weight"), f.get("b.bias"), (c2, k2, k2), s2, p2);
            ref_relu(&mut a);
            let want = ref_linear(&a, f.get("l.weight"), f.get("l.bias"));
            net.step(&x, &mut y).unwrap();
            assert_bits(&y, &want, &format!("chain seed {seed} trial {trial}"));
        }
    }
}

#[test]
fn conv_as_last_layer_and_after_elementwise() {
    // conv -> tanh keeps the image shape; the output is the CHW-flattened conv output.
    let mut rng = Rng(11);
    let mut f = File::default();
    f.add("c.weight", &[4, 2, 3, 3], rand_vec(&mut rng, 72, 0.5));
    f.add("c.bias", &[4], rand_vec(&mut rng, 4, 0.5));
    let desc = NetworkDesc {
        input: 2 * 6 * 5,
        input_shape: Some(vec![2, 6, 5]),
        layers: vec![LayerDesc::Relu, conv("c", 1, 1)],
    };
    let mut net = Network::from_safetensors_bytes(&desc, &f.bytes()).unwrap();
    assert_eq!(net.output_dim(), 4 * 6 * 5);
    let x = rand_vec(&mut rng, 60, 1.0);
    let mut xr = x.clone();
    ref_relu(&mut xr);
    let (want, _) = ref_conv(&xr, (2, 6, 5), f.get("c.weight"), f.get("c.bias"), (4, 3, 3), 1, 1);
    let mut y = vec![0.0; 120];
    net.step(&x, &mut y).unwrap();
    assert_bits(&y, &want, "relu -> conv");
}

#[test]
fn conv_relu_as_last_layers() {
    // The relu after a conv is applied by the conv's store; as the last layer it still writes the
    // output (NaN stays NaN, negative zero stays negative zero, like the separate layer).
    let mut rng = Rng(12);
    let mut f = File::default();
    f.add("c.weight", &[9, 2, 3, 3], rand_vec(&mut rng, 162, 0.5));
    f.add("c.bias", &[9], rand_vec(&mut rng, 9, 0.5));
    let desc = NetworkDesc {
        input: 2 * 5 * 7,
        input_shape: Some(vec![2, 5, 7]),
        layers: vec![conv("c", 2, 1), LayerDesc::Relu],
    };
    let mut net = Network::from_safetensors_bytes(&desc, &f.bytes()).unwrap();
    assert_eq!(net.layer_output_shape(1).unwrap(), &[9, 3, 4]);
    let mut x = rand_vec(&mut rng, 70, 1.0);
    x[3] = f32::NAN;
    let (mut want, _) = ref_conv(&x, (2, 5, 7), f.get("c.weight"), f.get("c.bias"), (9, 3, 3), 2, 1);
    ref_relu(&mut want);
    let mut y = vec![0.0; 9 * 12];
    net.step(&x, &mut y).unwrap();
    assert!(y.iter().any(|v| v.is_nan()) && y.contains(&0.0));
    for (i, (a, e)) in y.iter().zip(&want).enumerate() {
        assert!(
            a.to_bits() == e.to_bits() || (a.is_nan() && e.is_nan()),
            "element {i}: {a} vs {e}"
        );
    }
}

fn load_err(desc: &NetworkDesc, bytes: &[u8]) -> (NnError, String) {
    let e = Network::from_safetensors_bytes(desc, bytes).unwrap_err();
    let s = e.to_string();
    eprintln!("expected error: {s}");
    (e, s)
}

#[test]
fn conv_errors_say_what_to_fix() {
    let mut rng = Rng(3);
    let (mut desc, f) = terrain_cnn(&mut rng);
    let bytes = f.bytes();

    // No input_shape: suggests the square shape from the kernel's channel count.
    desc.input_shape = None;
    let (e, s) = load_err(&desc, &bytes);
    assert!(matches!(e, NnError::ConvShape { .. }), "{e:?}");
    assert!(
        s.contains("layers[0] (conv2d)") && s.contains("set input_shape = [6, 60, 60]"),
        "{s}"
    );

    // input_shape whose product is not `input`.
    desc.input_shape = Some(vec![6, 60, 61]);
    let (e, s) = load_err(&desc, &bytes);
    assert!(
        matches!(
            e,
            NnError::InputShape {
                product: 21960,
                input: 21600,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(s.contains("[6, 60, 61]") && s.contains("21600"), "{s}");
    desc.input_shape = Some(vec![]);
    assert!(matches!(load_err(&desc, &bytes).0, NnError::InputShape { .. }));
    desc.input_shape = Some(vec![usize::MAX, 3, 2]);
    assert!(matches!(load_err(&desc, &bytes).0, NnError::InputShape { .. }));

    // Channel mismatch: 6 x 60 x 60 laid out as 24 x 30 x 30.
    desc.input_shape = Some(vec![24, 30, 30]);
    let (e, s) = load_err(&desc, &bytes);
    assert!(matches!(e, NnError::ConvShape { .. }), "{e:?}");
    assert!(
        s.contains("expects 6 input channels") && s.contains("conv1.weight") && s.contains("[24, 30, 30]"),
        "{s}"
    );

    // Flat input that is not cin * side^2: a generic hint.
    let mut g = File::default();
    g.add("c.weight", &[2, 3, 3, 3], rand_vec(&mut rng, 54, 1.0));
    g.add("c.bias", &[2], rand_vec(&mut rng, 2, 1.0));
    g.add("l.weight", &[4, 10], rand_vec(&mut rng, 40, 1.0));
    g.add("l.bias", &[4], rand_vec(&mut rng, 4, 1.0));
    g.add("c3.weight", &[2, 3, 3], rand_vec(&mut rng, 18, 1.0));
    let gb = g.bytes();
    let net = |input, input_shape, layers| NetworkDesc {
        input,
        input_shape,
        layers,
    };
    let (_, s) = load_err(&net(30, None, vec![conv("c", 1, 0)]), &gb);
    assert!(s.contains("set input_shape = [3, H, W] with 3 * H * W = 30"), "{s}");

    // Conv after a linear layer: the activation is flat.
    let (e, s) = load_err(&net(10, None, vec![linear("l"), conv("c", 1, 0)]), &gb);
    assert!(matches!(e, NnError::ConvShape { .. }));
    assert!(
        s.contains("layers[1] (conv2d)") && s.contains("layers[0] (linear)") && s.contains("[4]"),
        "{s}"
    );

    // Kernel larger than the padded input.
    let (e, s) = load_err(&net(6, Some(vec![3, 2, 1]), vec![conv("c", 1, 0)]), &gb);
    assert!(matches!(e, NnError::ConvShape { .. }));
    assert!(
        s.contains("3x3 kernel") && s.contains("larger than the padded input 2x1"),
        "{s}"
    );
    // ... which padding fixes.
    let mut ok = Network::from_safetensors_bytes(&net(6, Some(vec![3, 2, 1]), vec![conv("c", 1, 1)]), &gb).unwrap();
    assert_eq!(ok.layer_output_shape(0).unwrap(), &[2, 2, 1]);
    ok.step(&[1.0; 6], &mut [0.0; 4]).unwrap();

    // Stride 0, absurd padding.
    let (e, s) = load_err(&net(27, Some(vec![3, 3, 3]), vec![conv("c", 0, 0)]), &gb);
    assert!(matches!(e, NnError::Param { .. }) && s.contains("stride"), "{s}");
    let (e, s) = load_err(&net(27, Some(vec![3, 3, 3]), vec![conv("c", 1, 3)]), &gb);
    assert!(matches!(e, NnError::Param { .. }) && s.contains("padding 3"), "{s}");

    // Weight not 4-D; bias of the wrong length.
    let (e, s) = load_err(
        &net(
            27,
            Some(vec![3, 3, 3]),
            vec![LayerDesc::Conv2d {
                weight: "c3.weight".into(),
                bias: "c.bias".into(),
                stride: 1,
                padding: 0,
            }],
        ),
        &gb,
    );
    assert!(
        matches!(e, NnError::Shape { .. }) && s.contains("[cout, cin, kh, kw]"),
        "{s}"
    );
    let (e, s) = load_err(
        &net(
            27,
            Some(vec![3, 3, 3]),
            vec![LayerDesc::Conv2d {
                weight: "c.weight".into(),
                bias: "l.bias".into(),
                stride: 1,
                padding: 0,
            }],
        ),
        &gb,
    );
    assert!(
        matches!(e, NnError::Shape { .. }) && s.contains("l.bias") && s.contains("[2]"),
        "{s}"
    );
}

#[test]
fn description_toml_round_trip() {
    let text = r#"
input = 21600
input_shape = [6, 60, 60]
layers = [
  { type = "conv2d", weight = "conv1.weight", bias = "conv1.bias", stride = 2, padding = 1 },
  { type = "relu" },
  { type = "conv2d", weight = "conv2.weight", bias = "conv2.bias" },
  { type = "linear", weight = "fc.weight", bias = "fc.bias" },
]
"#;
    let d: NetworkDesc = toml::from_str(text).unwrap();
    assert_eq!(d.input_shape, Some(vec![6, 60, 60]));
    assert_eq!(d.layers[0], conv("conv1", 2, 1));
    // Defaults: stride 1, padding 0.
    assert_eq!(d.layers[2], conv("conv2", 1, 0));
    let back: NetworkDesc = toml::from_str(&toml::to_string(&d).unwrap()).unwrap();
    assert_eq!(back, d);

    // Without input_shape: parses, and serializes without the key.
    let flat: NetworkDesc = toml::from_str("input = 3\nlayers = [{ type = \"relu\" }]").unwrap();
    assert_eq!(flat.input_shape, None);
    let s = toml::to_string(&flat).unwrap();
    assert!(!s.contains("input_shape"), "{s}");
    assert_eq!(toml::from_str::<NetworkDesc>(&s).unwrap(), flat);

    // Typos are still errors.
    let typo = "input = 3\ninput_shap = [3]\nlayers = [{ type = \"relu\" }]";
    assert!(toml::from_str::<NetworkDesc>(typo).is_err());
    let typo = "input = 3\nlayers = [{ type = \"conv2d\", weight = \"w\", bias = \"b\", strides = 2 }]";
    let e = toml::from_str::<NetworkDesc>(typo).unwrap_err().to_string();
    assert!(e.contains("strides"), "{e}");
}
