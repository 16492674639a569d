//! What onnxruntime refuses, or computes as something other than one vector, the importer refuses
//! with an error naming the node or initializer: an opset outside [`policy_import::onnx::OPSETS`],
//! a float64 constant in a float32 op, and a constant that broadcasts the value to a matrix. Each
//! refusal is next to the same model with the one fault removed, which imports: the refusal comes
//! from the fault. (That onnxruntime refuses or broadcasts these models as said is checked against
//! onnxruntime itself in `tests/tests/onnx_vs_onnxruntime.rs`.)
use policy_import::onnx::proto::*;
use prost::Message;

fn init(name: &str, dims: &[i64], dtype: tensor_proto::DataType) -> TensorProto {
    let n: i64 = dims.iter().product();
    let raw: Vec<u8> = match dtype {
        tensor_proto::DataType::Double => (0..n)
            .flat_map(|i| (0.1 * (i % 7) as f64 - 0.3).to_le_bytes())
            .collect(),
        tensor_proto::DataType::Int64 => (0..n).flat_map(|i| (i % 3).to_le_bytes()).collect(),
        _ => (0..n)
            .flat_map(|i| (0.1 * (i % 7) as f32 - 0.3).to_le_bytes())
            .collect(),
    };
    TensorProto {
        name: Some(name.into()),
        dims: dims.to_vec(),
        data_type: Some(dtype as i32),
        raw_data: Some(raw),
        ..Default::default()
    }
}

fn f32s(name: &str, dims: &[i64]) -> TensorProto {
    init(name, dims, tensor_proto::DataType::Float)
}

fn i64s(name: &str, values: &[i64]) -> TensorProto {
    TensorProto {
        name: Some(name.into()),
        dims: vec![values.len() as i64],
        data_type: Some(tensor_proto::DataType::Int64 as i32),
        raw_data: Some(values.iter().flat_map(|v| v.to_le_bytes()).collect()),
        ..Default::default()
    }
}

fn value(name: &str, dims: &[i64], elem_type: i32) -> ValueInfoProto {
    ValueInfoProto {
        name: Some(name.into()),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: Some(elem_type),
                shape: Some(TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|&d| tensor_shape_proto::Dimension {
                            value: Some(tensor_shape_proto::dimension::Value::DimValue(d)),
                            ..Default::default()
                        })
                        .collect(),
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

fn node(op: &str, name: &str, inputs: &[&str], out: &str, ints: &[(&str, i64)]) -> NodeProto {
    NodeProto {
        op_type: Some(op.into()),
        name: Some(name.into()),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![out.into()],
        attribute: ints
            .iter()
            .map(|&(n, i)| AttributeProto {
                name: Some(n.into()),
                i: Some(i),
                r#type: Some(attribute_proto::AttributeType::Int as i32),
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    }
}

const FLOAT: i32 = tensor_proto::DataType::Float as i32;
const DOUBLE: i32 = tensor_proto::DataType::Double as i32;

/// obs [1, 4] → nodes → actions, at `opset`.
fn model(nodes: Vec<NodeProto>, inits: Vec<TensorProto>, opset: i64) -> ModelProto {
    ModelProto {
        ir_version: Some(8),
        opset_import: vec![OperatorSetIdProto {
            domain: Some(String::new()),
            version: Some(opset),
        }],
        graph: Some(GraphProto {
            name: Some("policy".into()),
            node: nodes,
            initializer: inits,
            input: vec![value("obs", &[1, 4], FLOAT)],
            output: vec![value("actions", &[1, 3], FLOAT)],
            ..Default::default()
        }),
        ..Default::default()
    }
}

/// rsl_rl's shape: Gemm (transB) → Elu → MatMul + Add, with a hidden width of 5.
fn mlp(w0: TensorProto, bias: TensorProto, opset: i64) -> ModelProto {
    model(
        vec![
            node("Gemm", "actor.0", &["obs", "w0", "b0"], "h0", &[("transB", 1)]),
            node("Elu", "actor.1", &["h0"], "a0", &[]),
            node("MatMul", "actor.2/MatMul", &["a0", "w1"], "m1", &[]),
            node("Add", "actor.2/Add", &["m1", "b1"], "actions", &[]),
        ],
        vec![w0, f32s("b0", &[5]), f32s("w1", &[5, 3]), bias],
        opset,
    )
}

fn import(m: &ModelProto) -> Result<policy_import::ImportedNetwork, String> {
    policy_import::import_bytes(&m.encode_to_vec()).map_err(|e| e.to_string())
}

fn refused(m: &ModelProto) -> String {
    match import(m) {
        Ok(_) => panic!("imported a model onnxruntime would refuse or compute otherwise"),
        Err(e) => e,
    }
}

#[test]
fn an_opset_outside_the_supported_range_is_refused() {
    let ok = |opset| mlp(f32s("w0", &[5, 4]), f32s("b1", &[3]), opset);
    for opset in [7, 17, 28] {
        import(&ok(opset)).unwrap_or_else(|e| panic!("opset {opset}: {e}"));
    }
    let (lo, hi) = (policy_import::onnx::OPSETS.start(), policy_import::onnx::OPSETS.end());
    assert_eq!((*lo, *hi), (7, 28));
    for opset in [99, 29, 6, 1] {
        let e = refused(&ok(opset));
        assert!(
            e.contains(&format!("opset {opset}")) && e.contains("7 to 28") && e.contains("re-export"),
            "{e}"
        );
    }
    // No default-domain opset at all (only another domain's).
    let mut m = ok(17);
    m.opset_import[0].domain = Some("com.microsoft".into());
    let e = refused(&m);
    assert!(e.contains("no opset for the default ONNX domain"), "{e}");
    // An op of another domain that shares a default op's name.
    let mut m = ok(17);
    m.graph.as_mut().unwrap().node[1].domain = Some("com.microsoft".into());
    let e = refused(&m);
    assert!(e.contains("actor.1") && e.contains("domain 'com.microsoft'"), "{e}");
}

#[test]
fn a_float64_initializer_in_a_float32_gemm_is_refused() {
    import(&mlp(f32s("w0", &[5, 4]), f32s("b1", &[3]), 17)).expect("the float32 model imports");
    let e = refused(&mlp(
        init("w0", &[5, 4], tensor_proto::DataType::Double),
        f32s("b1", &[3]),
        17,
    ));
    assert!(
        e.contains("'w0'") && e.contains("float64") && e.contains("actor.0") && e.contains("float32"),
        "{e}"
    );
    // A float64 bias of the Add, and an int64 one.
    let e = refused(&mlp(
        f32s("w0", &[5, 4]),
        init("b1", &[3], tensor_proto::DataType::Double),
        17,
    ));
    assert!(
        e.contains("'b1'") && e.contains("float64") && e.contains("actor.2/Add"),
        "{e}"
    );
    let e = refused(&mlp(
        f32s("w0", &[5, 4]),
        init("b1", &[3], tensor_proto::DataType::Int64),
        17,
    ));
    assert!(e.contains("'b1'") && e.contains("int64"), "{e}");
    // A whole float64 graph: the executor computes float32.
    let mut m = mlp(f32s("w0", &[5, 4]), f32s("b1", &[3]), 17);
    m.graph.as_mut().unwrap().input = vec![value("obs", &[1, 4], DOUBLE)];
    let e = refused(&m);
    assert!(e.contains("'obs'") && e.contains("float64"), "{e}");
    let mut m = mlp(f32s("w0", &[5, 4]), f32s("b1", &[3]), 17);
    m.graph.as_mut().unwrap().output = vec![value("actions", &[1, 3], DOUBLE)];
    assert!(refused(&m).contains("'actions'"));
}

#[test]
fn a_bias_that_broadcasts_to_a_matrix_is_refused() {
    // The per-output biases ONNX broadcasts to the [1, 3] value unchanged: imported as one bias.
    for dims in [&[3][..], &[1, 3], &[1, 1, 3], &[1], &[]] {
        let net =
            import(&mlp(f32s("w0", &[5, 4]), f32s("b1", dims), 17)).unwrap_or_else(|e| panic!("bias {dims:?}: {e}"));
        assert_eq!(net.output_dim, 3);
        let b = &net.tensors.iter().find(|(n, _)| n == "l2.bias").unwrap().1.data;
        let v: Vec<f32> = f32s("b1", dims)
            .raw_data
            .unwrap()
            .chunks_exact(4)
            .map(|x| f32::from_le_bytes(x.try_into().unwrap()))
            .collect();
        let expect = if v.len() == 1 { vec![v[0]; 3] } else { v };
        assert_eq!(b, &expect, "bias {dims:?}");
    }
    // [3, 1]: onnxruntime makes the [1, 3] value a [3, 3] matrix.
    let e = refused(&mlp(f32s("w0", &[5, 4]), f32s("b1", &[3, 1]), 17));
    assert!(
        e.contains("actor.2/Add")
            && e.contains("'b1'")
            && e.contains("[3, 1]")
            && e.contains("[3, 3]")
            && e.contains("[1, 3]"),
        "{e}"
    );
    // A batch of biases, and a width that does not broadcast at all.
    let e = refused(&mlp(f32s("w0", &[5, 4]), f32s("b1", &[2, 3]), 17));
    assert!(e.contains("[2, 3]") && e.contains("not one vector"), "{e}");
    let e = refused(&mlp(f32s("w0", &[5, 4]), f32s("b1", &[2]), 17));
    assert!(e.contains("does not broadcast"), "{e}");
    // Gemm's C broadcasts one way only, to [1, out].
    let gemm_c = |dims: &[i64]| {
        model(
            vec![node(
                "Gemm",
                "actor.0",
                &["obs", "w0", "c"],
                "actions",
                &[("transB", 1)],
            )],
            vec![f32s("w0", &[3, 4]), f32s("c", dims)],
            17,
        )
    };
    import(&gemm_c(&[1, 3])).expect("C [1, 3]");
    for dims in [&[3, 1][..], &[1, 1, 3], &[2, 3], &[2]] {
        let e = refused(&gemm_c(dims));
        assert!(
            e.contains("actor.0")
                && e.contains("'c'")
                && e.contains("does not broadcast one way to Gemm's output [1, 3]"),
            "{e}"
        );
    }
    // The normaliser before the first layer follows the same rule.
    let norm = |dims: &[i64]| {
        model(
            vec![
                node("Sub", "normalizer", &["obs", "mean"], "n0", &[]),
                node("Gemm", "actor.0", &["n0", "w0", "b0"], "actions", &[("transB", 1)]),
            ],
            vec![f32s("mean", dims), f32s("w0", &[3, 4]), f32s("b0", &[3])],
            17,
        )
    };
    import(&norm(&[1, 4])).expect("mean [1, 4]");
    let e = refused(&norm(&[4, 1]));
    assert!(
        e.contains("normalizer") && e.contains("'mean'") && e.contains("[4, 4]"),
        "{e}"
    );
}

/// Shape ops that would move the features off the last axis, where a later [1, n] bias would then
/// broadcast to a matrix too.
#[test]
fn shape_ops_that_move_the_features_are_refused() {
    let with = |shape_node: NodeProto, extra: Vec<TensorProto>| {
        let mut inits = vec![f32s("w0", &[3, 4]), f32s("b0", &[3])];
        inits.extend(extra);
        model(
            vec![
                shape_node,
                node("Gemm", "actor.0", &["s", "w0", "b0"], "actions", &[("transB", 1)]),
            ],
            inits,
            17,
        )
    };
    import(&with(
        node("Reshape", "reshape", &["obs", "shape"], "s", &[]),
        vec![i64s("shape", &[1, -1])],
    ))
    .expect("Reshape to [1, -1]");
    import(&with(
        node("Reshape", "reshape", &["obs", "shape"], "s", &[]),
        vec![i64s("shape", &[0, 4])],
    ))
    .expect("Reshape to [0, 4]");
    let e = refused(&with(
        node("Reshape", "reshape", &["obs", "shape"], "s", &[]),
        vec![i64s("shape", &[4, 1])],
    ));
    assert!(e.contains("reshape") && e.contains("[4, 1]"), "{e}");
    let e = refused(&with(
        node("Unsqueeze", "unsq", &["obs", "ax"], "s", &[]),
        vec![i64s("ax", &[-1])],
    ));
    assert!(e.contains("unsq") && e.contains("after the features"), "{e}");
    import(&with(node("Flatten", "flat", &["obs"], "s", &[]), vec![])).expect("Flatten axis 1");
    let e = refused(&with(node("Flatten", "flat", &["obs"], "s", &[("axis", 2)]), vec![]));
    assert!(e.contains("flat") && e.contains("[n, 1]"), "{e}");
    let e = refused(&with(
        node("Squeeze", "sq", &["obs", "ax"], "s", &[]),
        vec![i64s("ax", &[1])],
    ));
    assert!(e.contains("sq") && e.contains("not of size 1"), "{e}");
    // Axes as an attribute where opset 13+ takes an input.
    let mut sq = node("Squeeze", "sq", &["obs"], "s", &[]);
    sq.attribute.push(AttributeProto {
        name: Some("axes".into()),
        ints: vec![0],
        r#type: Some(attribute_proto::AttributeType::Ints as i32),
        ..Default::default()
    });
    let e = refused(&with(sq, vec![]));
    assert!(e.contains("attribute 'axes' at opset 17"), "{e}");
    // A fixed batch of several observations.
    let mut m = with(node("Identity", "id", &["obs"], "s", &[]), vec![]);
    import(&m).expect("Identity");
    m.graph.as_mut().unwrap().input = vec![value("obs", &[2, 4], FLOAT)];
    let e = refused(&m);
    assert!(e.contains("[2, 4]") && e.contains("one observation"), "{e}");
}
