#!/usr/bin/env python3
"""ONNX Runtime baseline for the terrain CNN, for firmware/benches/perception_frame.rs.

Builds an ONNX graph (Conv / Relu / Tanh / Elu / Flatten / Gemm) from a control::nn network
description (JSON, as serde writes a NetworkDesc) and the same safetensors weights, checks that
it reproduces a reference input/output pair computed by our executor (max abs diff <= --tol),
then times `InferenceSession.run` on one BEV with intra_op_num_threads=1 and with ORT's default threading,
and prints one JSON line:

  {"ort_version", "iters", "ref_max_abs_err",
   "single": {"median_us", "p99_us", "mean_us", "min_us", "threads"},
   "default": {... same ...}}

The reference file holds `input` (the network input, shaped as `input_shape` with a leading
batch axis) and `output` ([1, out]).
"""

import argparse
import json
import os
import sys

# Keep numpy's BLAS from spinning threads that would compete with the timed runs.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402  (after the thread env vars on purpose)
import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402
from onnx import TensorProto, helper, numpy_helper  # noqa: E402
from safetensors.numpy import load_file  # noqa: E402


def build_model(desc: dict, w: dict) -> onnx.ModelProto:
    """The network of `desc` (control::nn::NetworkDesc as JSON) as an ONNX graph, batch 1."""
    shape = list(desc.get("input_shape") or [desc["input"]])
    inits, nodes = [], []
    cur = "input"
    in_shape = [1] + shape

    def init(name: str, arr: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(np.ascontiguousarray(arr, dtype=np.float32), name))
        return name

    for i, layer in enumerate(desc["layers"]):
        kind = layer["type"]
        out = f"l{i}"
        if kind == "conv2d":
            wt, b = w[layer["weight"]], w[layer["bias"]].reshape(-1)
            s, p = int(layer.get("stride", 1)), int(layer.get("padding", 0))
            cout, cin, kh, kw = wt.shape
            assert len(shape) == 3 and shape[0] == cin, f"layer {i}: conv2d on shape {shape}, weight {wt.shape}"
            nodes.append(
                helper.make_node(
                    "Conv",
                    [cur, init(f"w{i}", wt), init(f"b{i}", b)],
                    [out],
                    kernel_shape=[kh, kw],
                    strides=[s, s],
                    pads=[p, p, p, p],
                )
            )
            shape = [cout, (shape[1] + 2 * p - kh) // s + 1, (shape[2] + 2 * p - kw) // s + 1]
        elif kind == "linear":
            if len(shape) != 1:
                flat = f"f{i}"
                nodes.append(helper.make_node("Flatten", [cur], [flat], axis=1))
                cur = flat
                shape = [int(np.prod(shape))]
            wt, b = w[layer["weight"]], w[layer["bias"]].reshape(-1)
            assert wt.shape[1] == shape[0], f"layer {i}: linear {wt.shape} on {shape}"
            nodes.append(helper.make_node("Gemm", [cur, init(f"w{i}", wt), init(f"b{i}", b)], [out], transB=1))
            shape = [wt.shape[0]]
        elif kind == "relu":
            nodes.append(helper.make_node("Relu", [cur], [out]))
        elif kind == "tanh":
            nodes.append(helper.make_node("Tanh", [cur], [out]))
        elif kind == "elu":
            nodes.append(helper.make_node("Elu", [cur], [out], alpha=float(layer["alpha"])))
        else:
            raise SystemExit(f"layer {i}: {kind} is not supported by this baseline")
        cur = out
    f32 = TensorProto.FLOAT
    graph = helper.make_graph(
        nodes,
        "terrain_cnn",
        [helper.make_tensor_value_info("input", f32, in_shape)],
        [helper.make_tensor_value_info(cur, f32, [1] + shape)],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def inference(model: onnx.ModelProto, single: bool) -> ort.InferenceSession:
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    if single:
        so.intra_op_num_threads = 1
        so.inter_op_num_threads = 1
        so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def time_runs(sess: ort.InferenceSession, x: np.ndarray, warmup: int, iters: int) -> dict:
    feed = {"input": x}
    run = sess.run
    clock = time.perf_counter_ns
    times = np.empty(iters, np.float64)
    for i in range(warmup + iters):
        t0 = clock()
        run(None, feed)
        t1 = clock()
        if i >= warmup:
            times[i - warmup] = (t1 - t0) / 1e3
    return {
        "median_us": float(np.median(times)),
        "p99_us": float(np.percentile(times, 99)),
        "mean_us": float(times.mean()),
        "min_us": float(times.min()),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--weights", type=Path, required=True, help="safetensors weights")
    ap.add_argument("--desc", type=Path, required=True, help="NetworkDesc as JSON")
    ap.add_argument("--ref", type=Path, required=True, help="safetensors with `input` and `output`")
    ap.add_argument("--iters", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--tol", type=float, default=1e-4)
    args = ap.parse_args()

    desc = json.loads(args.desc.read_text())
    weights = load_file(str(args.weights))
    ref = load_file(str(args.ref))
    model = build_model(desc, weights)
    x = ref["input"].astype(np.float32)
    want = ref["output"]

    single = inference(model, True)
    default = inference(model, False)
    errs = []
    for sess in (single, default):
        (got,) = sess.run(None, {"input": x})
        errs.append(float(np.abs(got.reshape(want.shape) - want).max()))
    max_err = max(errs)
    if not max_err <= args.tol:
        print(
            f"ORT graph does not reproduce our output: max abs err {max_err} > {args.tol}\n"
            f"ours: {want.reshape(-1)}\nORT:  {got.reshape(-1)}",
            file=sys.stderr,
        )
        return 1

    figures = {"single": time_runs(single, x, args.warmup, args.iters)}
    figures["single"]["threads"] = 1
    figures["default"] = time_runs(default, x, args.warmup, args.iters)
    figures["default"]["threads"] = "ORT default (intra_op_num_threads=0: one per physical core, %d CPUs)" % (
        os.cpu_count() or 0
    )
    print(
        json.dumps(
            {
                "ort_version": ort.__version__,
                "iters": args.iters,
                "ref_max_abs_err": max_err,
                **figures,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
