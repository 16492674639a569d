#!/usr/bin/env python3
"""ONNX Runtime baseline for the peer LSTM policy, for firmware/benches/policy_step.rs.

Builds an ONNX graph of LSTM(47->64) -> Linear(64->32) -> ELU -> Linear(32->12) from
policy.safetensors with onnx.helper, checks it reproduces golden_random actions (state carried
from zero) to 1e-4, then times one stateful `InferenceSession.run` per step on a single thread and prints
one JSON line: {"ort_version", "iters", "median_us", "p99_us", "mean_us", "golden_max_abs_err"}.

h/c are graph inputs and outputs so the caller carries state between calls, as the policy does.
"""

import argparse
import json
import os
import sys

# Keep numpy's BLAS from spinning threads that would compete with the timed single-thread run.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
import time
from pathlib import Path

import numpy as np  # noqa: E402  (after the thread env vars on purpose)
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper
from safetensors.numpy import load_file


def build_model(w: dict) -> onnx.ModelProto:
    w_ih = w["memory.weight_ih_l0"]  # [4H, in], PyTorch gate order i, f, g, o
    w_hh = w["memory.weight_hh_l0"]
    b_ih = w["memory.bias_ih_l0"]
    b_hh = w["memory.bias_hh_l0"]
    four_h, n_in = w_ih.shape
    hid = four_h // 4

    def iofc(t):  # PyTorch i,f,g,o -> ONNX i,o,f,c along the first axis
        i, f, g, o = np.split(t, 4, axis=0)
        return np.concatenate([i, o, f, g], axis=0)

    W = iofc(w_ih)[None].astype(np.float32)  # [1, 4H, in]
    R = iofc(w_hh)[None].astype(np.float32)  # [1, 4H, H]
    B = np.concatenate([iofc(b_ih), iofc(b_hh)])[None].astype(np.float32)  # [1, 8H]
    n_out = w["actor.2.weight"].shape[0]

    inits = [
        numpy_helper.from_array(W, "W"),
        numpy_helper.from_array(R, "R"),
        numpy_helper.from_array(B, "B"),
        numpy_helper.from_array(np.array([1, hid], dtype=np.int64), "flat_shape"),
        numpy_helper.from_array(w["actor.0.weight"].astype(np.float32), "A0w"),
        numpy_helper.from_array(w["actor.0.bias"].astype(np.float32), "A0b"),
        numpy_helper.from_array(w["actor.2.weight"].astype(np.float32), "A2w"),
        numpy_helper.from_array(w["actor.2.bias"].astype(np.float32), "A2b"),
    ]
    nodes = [
        helper.make_node(
            "LSTM",
            ["obs", "W", "R", "B", "", "h_in", "c_in"],
            ["", "h_out", "c_out"],
            hidden_size=hid,
        ),
        helper.make_node("Reshape", ["h_out", "flat_shape"], ["h_flat"]),
        helper.make_node("Gemm", ["h_flat", "A0w", "A0b"], ["z0"], transB=1),
        helper.make_node("Elu", ["z0"], ["e0"], alpha=1.0),
        helper.make_node("Gemm", ["e0", "A2w", "A2b"], ["action"], transB=1),
    ]
    f32 = TensorProto.FLOAT
    graph = helper.make_graph(
        nodes,
        "peer_lstm_policy",
        [
            helper.make_tensor_value_info("obs", f32, [1, 1, n_in]),
            helper.make_tensor_value_info("h_in", f32, [1, 1, hid]),
            helper.make_tensor_value_info("c_in", f32, [1, 1, hid]),
        ],
        [
            helper.make_tensor_value_info("action", f32, [1, n_out]),
            helper.make_tensor_value_info("h_out", f32, [1, 1, hid]),
            helper.make_tensor_value_info("c_out", f32, [1, 1, hid]),
        ],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", type=Path, required=True, help="peer_policy/unitree_g1_lstm folder")
    ap.add_argument("--iters", type=int, default=20000)
    ap.add_argument("--warmup", type=int, default=2000)
    args = ap.parse_args()

    weights = load_file(str(args.dir / "policy.safetensors"))
    golden = load_file(str(args.dir / "golden_random.safetensors"))
    model = build_model(weights)

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    sess = ort.InferenceSession(
        model.SerializeToString(), so, providers=["CPUExecutionProvider"]
    )

    hid = weights["memory.weight_hh_l0"].shape[1]
    obs = golden["obs"].astype(np.float32)
    want = golden["action"]
    h = np.zeros((1, 1, hid), np.float32)
    c = np.zeros((1, 1, hid), np.float32)
    max_err = 0.0
    for t in range(obs.shape[0]):
        a, h, c = sess.run(None, {"obs": obs[t].reshape(1, 1, -1), "h_in": h, "c_in": c})
        max_err = max(max_err, float(np.abs(a[0] - want[t]).max()))
    if not max_err <= 1e-4:
        print(f"ORT graph does not reproduce golden_random: max abs err {max_err}", file=sys.stderr)
        return 1

    rows = [o.reshape(1, 1, -1).copy() for o in obs]
    h = np.zeros((1, 1, hid), np.float32)
    c = np.zeros((1, 1, hid), np.float32)
    times = np.empty(args.iters, np.float64)
    run = sess.run
    clock = time.perf_counter_ns
    for i in range(args.warmup + args.iters):
        feed = {"obs": rows[i % len(rows)], "h_in": h, "c_in": c}
        t0 = clock()
        _, h, c = run(None, feed)
        t1 = clock()
        if i >= args.warmup:
            times[i - args.warmup] = (t1 - t0) / 1e3
    print(
        json.dumps(
            {
                "ort_version": ort.__version__,
                "iters": args.iters,
                "median_us": float(np.median(times)),
                "p99_us": float(np.percentile(times, 99)),
                "mean_us": float(times.mean()),
                "min_us": float(times.min()),
                "golden_max_abs_err": max_err,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
