"""Independent side of tests/tests/onnx_vs_onnxruntime.rs: random small policy MLPs built with
onnx.helper (no project code), run by onnxruntime.

  onnx_vs_onnxruntime.py DIR N SEED

writes DIR/<name>.onnx and prints JSON {"models": [...], "repro": {...}}. Each model: name, fault
(null for a well-formed model, else what was injected: an opset outside 7..28, a float64 or int64
constant in a float32 op, a constant that broadcasts the value to a matrix, a Reshape that moves
the features off the last axis), ort_error (null when onnxruntime loads and runs it), inputs and
outputs (one observation each, from onnxruntime) and out_shape. "repro" holds the three models of
the issue, with what onnxruntime does with each.
"""
import json
import sys

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

# Runtime refusals are expected and reported in the JSON; keep them off stderr.
ort.set_default_logger_severity(4)
STEPS = 8


def f32(name, a):
    return numpy_helper.from_array(np.asarray(a, dtype=np.float32), name)


class Builder:
    def __init__(self, rng, opset):
        self.rng, self.opset = rng, opset
        self.nodes, self.inits, self.k = [], [], 0

    def name(self, p):
        self.k += 1
        return f"{p}{self.k}"

    def const(self, a, dtype=np.float32):
        n = self.name("c")
        self.inits.append(numpy_helper.from_array(np.asarray(a, dtype=dtype), n))
        return n

    def ints(self, v):
        return self.const(np.array(v, dtype=np.int64), np.int64)

    def op(self, op, inputs, **attrs):
        out = self.name("v")
        self.nodes.append(helper.make_node(op, inputs, [out], name=self.name(op.lower() + "_"), **attrs))
        return out

    def axes_op(self, op, x, axes):
        if self.opset >= 13:
            return self.op(op, [x, self.ints(axes)])
        return self.op(op, [x], axes=axes)


def bias_shape(rng, n, allow_rank3):
    """A shape ONNX broadcasts against the [1, n] value without changing it."""
    shapes = [[n], [1, n], [1], []]
    if allow_rank3:
        shapes.append([1, 1, n])
    return shapes[rng.integers(len(shapes))]


def random_model(rng, path):
    fault = None
    if rng.random() < 0.3:
        fault = ["opset", "float64", "int64", "matrix_bias", "batch_bias", "reshape"][rng.integers(6)]
    opset = int(rng.choice([7, 9, 11, 13, 17, 21, 28]))
    if fault == "opset":
        opset = int(rng.choice([5, 6, 29, 99]))
    b = Builder(rng, opset)
    n_in = int(rng.integers(1, 17))
    sizes = [n_in] + [int(rng.integers(1, 17)) for _ in range(rng.integers(1, 5))]
    batch = "batch" if rng.random() < 0.5 else 1
    # The constants where a fault may go: (index in inits, the width it broadcasts against).
    spots = []
    x = "obs"
    if rng.random() < 0.5:  # an observation normaliser, kept by the exporter
        for op, lo, hi in [("Sub", -1.0, 1.0), ("Div", 0.5, 2.0), ("Mul", 0.5, 2.0)]:
            if rng.random() < 0.6:
                shape = bias_shape(rng, n_in, False)
                spots.append((len(b.inits), n_in))
                x = b.op(op, [x, b.const(rng.uniform(lo, hi, shape))])
    for i, (k, n) in enumerate(zip(sizes, sizes[1:])):
        last = i == len(sizes) - 2
        w = rng.normal(0, 1 / np.sqrt(k), (n, k))
        if rng.random() < 0.5:
            attrs = {}
            if rng.random() < 0.5:
                attrs["transB"] = 1
            else:
                w = w.T
            if rng.random() < 0.3:
                attrs["alpha"] = float(rng.uniform(0.5, 1.5))
                attrs["beta"] = float(rng.uniform(0.5, 1.5))
            inputs = [x, b.const(w)]
            if opset < 11 or rng.random() < 0.8:  # C is optional from opset 11
                spots.append((len(b.inits), n))
                inputs.append(b.const(rng.normal(0, 0.1, bias_shape(rng, n, False))))
            x = b.op("Gemm", inputs, **attrs)
        else:
            x = b.op("MatMul", [x, b.const(w.T)])
            spots.append((len(b.inits), n))
            x = b.op("Add", [x, b.const(rng.normal(0, 0.1, bias_shape(rng, n, False)))])
        if not last:
            r = rng.random()
            if r < 0.3:
                x = b.op("Elu", [x], alpha=float(rng.uniform(0.2, 2.0)))
            elif r < 0.6:
                x = b.op("Relu", [x])
            elif r < 0.9:
                x = b.op("Tanh", [x])
            s = rng.random()
            if s < 0.15:
                x = b.op("Identity", [x])
            elif s < 0.3:
                x = b.op("Flatten", [x], axis=1)
            elif s < 0.45:
                x = b.op("Reshape", [x, b.ints([1, -1])])
            elif s < 0.6:
                x = b.axes_op("Squeeze", b.axes_op("Unsqueeze", x, [0]), [0])
    if rng.random() < 0.5:  # an action scale; a rank-3 one makes the output [1, 1, n], same values
        spots.append((len(b.inits), sizes[-1]))
        x = b.op("Mul", [x, b.const(rng.uniform(0.5, 1.5, bias_shape(rng, sizes[-1], True)))])
    b.nodes.append(helper.make_node("Identity", [x], ["actions"], name="out"))

    wide = [s for s in spots if s[1] > 1]
    floats = [i for i, t in enumerate(b.inits) if t.data_type == TensorProto.FLOAT]
    if fault in ("float64", "int64"):
        i = floats[int(rng.integers(len(floats)))]
        t = b.inits[i]
        a = numpy_helper.to_array(t)
        a = a.astype(np.float64) if fault == "float64" else np.round(a * 3).astype(np.int64)
        b.inits[i] = numpy_helper.from_array(a, t.name)
    elif fault in ("matrix_bias", "batch_bias") and wide:
        i, n = wide[int(rng.integers(len(wide)))]
        t = b.inits[i]
        shape = [n, 1] if fault == "matrix_bias" else [2, n]
        b.inits[i] = f32(t.name, rng.normal(0, 0.5, shape))
    elif fault == "reshape" and sizes[1] > 1:
        # After the first layer: [1, n] → [n, 1].
        at = next(i for i, nd in enumerate(b.nodes) if nd.op_type in ("Gemm", "Add"))
        out = b.nodes[at].output[0]
        moved = b.op("Reshape", [out, b.ints([-1, 1])])
        reshape = b.nodes.pop()
        for nd in b.nodes:
            if out in nd.input:
                nd.input[list(nd.input).index(out)] = moved
        b.nodes.insert(at + 1, reshape)
    elif fault in ("matrix_bias", "batch_bias", "reshape"):
        fault = None  # nothing wide to fault
    g = helper.make_graph(b.nodes, "policy", [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [batch, n_in])],
                          [helper.make_tensor_value_info("actions", TensorProto.FLOAT, None)], b.inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", opset)])
    m.ir_version = 8
    onnx.save(m, path)
    return n_in, fault


def run(path, n_in, rng):
    try:
        s = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        ins, outs, shape = [], [], None
        for _ in range(STEPS):
            x = rng.normal(0, 1.5, (1, n_in)).astype(np.float32)
            (y,) = s.run(["actions"], {"obs": x})
            ins.append(x[0].tolist())
            outs.append(np.asarray(y, dtype=np.float64).ravel().tolist())
            shape = list(y.shape)
        return {"ort_error": None, "inputs": ins, "outputs": outs, "out_shape": shape}
    except Exception as e:  # onnxruntime's refusal, at load or at run
        return {"ort_error": str(e), "inputs": [], "outputs": [], "out_shape": None}


def repro(d, rng):
    """The issue's three models: opset 99, a float64 weight in a float32 Gemm, an Add bias of shape
    [h, 1] (h = 5)."""
    res = {}
    for name in ["opset99", "float64_gemm", "bias_h1"]:
        nodes = [helper.make_node("Gemm", ["obs", "w0", "b0"], ["h0"], name="actor.0", transB=1),
                 helper.make_node("Elu", ["h0"], ["a0"], name="actor.1"),
                 helper.make_node("MatMul", ["a0", "w1"], ["m1"], name="actor.2/MatMul"),
                 helper.make_node("Add", ["m1", "b1"], ["actions"], name="actor.2/Add")]
        w0 = rng.normal(0, 0.5, (5, 4))
        inits = [numpy_helper.from_array(w0.astype(np.float64 if name == "float64_gemm" else np.float32), "w0"),
                 f32("b0", rng.normal(0, 0.1, 5)), f32("w1", rng.normal(0, 0.5, (5, 5))),
                 f32("b1", rng.normal(0, 0.1, (5, 1) if name == "bias_h1" else 5))]
        g = helper.make_graph(nodes, name, [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, 4])],
                              [helper.make_tensor_value_info("actions", TensorProto.FLOAT, None)], inits)
        m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 99 if name == "opset99" else 17)])
        m.ir_version = 8
        onnx.save(m, f"{d}/{name}.onnx")
        res[name] = run(f"{d}/{name}.onnx", 4, rng)
    return res


def main():
    d, n, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    rng = np.random.default_rng(seed)
    models = []
    for i in range(n):
        path = f"{d}/m{i}.onnx"
        n_in, fault = random_model(rng, path)
        models.append({"name": f"m{i}", "fault": fault, **run(path, n_in, rng)})
    print(json.dumps({"models": models, "repro": repro(d, rng), "onnxruntime": ort.__version__}))


if __name__ == "__main__":
    main()
