"""Independent side of the ONNX import test: builds policy networks the way exporters write them
(onnx.helper, seeded weights; no project code) and runs them with onnxruntime.

  onnx_models.py DIR [PEER_SAFETENSORS]

writes DIR/<name>.onnx and prints JSON {name: {"inputs": [[...]...], "outputs": [[...]...]}} with K
steps per model (recurrent models are fed their own state back, from zeros), plus
DIR/softmax.onnx (an op the importer must refuse) and DIR/truncated.onnx.
"""
import json
import sys

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

K = 24
rng = np.random.default_rng(20261124)


def const(name, a):
    return numpy_helper.from_array(np.asarray(a, dtype=np.float32), name)


def vinfo(name, shape):
    return helper.make_tensor_value_info(name, TensorProto.FLOAT, shape)


def save(model, path):
    onnx.checker.check_model(model)
    onnx.save(model, path)


def mlp(path):
    """rsl_rl-style MLP with a kept normaliser (Sub/Div), Gemm (transB 1 and 0, alpha/beta),
    MatMul + Add, Elu / Relu / Tanh, and an action scale (Mul)."""
    n_in = 24
    nodes = [
        helper.make_node("Sub", ["obs", "mean"], ["n0"], name="normalizer_sub"),
        helper.make_node("Div", ["n0", "std"], ["n1"], name="normalizer_div"),
        helper.make_node("Gemm", ["n1", "w0", "b0"], ["h0"], name="actor.0", transB=1),
        helper.make_node("Elu", ["h0"], ["a0"], name="actor.1", alpha=1.0),
        helper.make_node("MatMul", ["a0", "w1"], ["h1"], name="actor.2/MatMul"),
        helper.make_node("Add", ["h1", "b1"], ["h1b"], name="actor.2/Add"),
        helper.make_node("Relu", ["h1b"], ["a1"], name="actor.3"),
        helper.make_node("Gemm", ["a1", "w2", "b2"], ["h2"], name="actor.4", alpha=0.5, beta=2.0),
        helper.make_node("Tanh", ["h2"], ["a2"], name="actor.5"),
        helper.make_node("Identity", ["a2"], ["a3"], name="id"),
        helper.make_node("Gemm", ["a3", "w3", "b3"], ["h3"], name="actor.6", transB=1),
        helper.make_node("Mul", ["h3", "scale"], ["actions"], name="action_scale"),
    ]
    inits = [
        const("mean", rng.normal(0, 1, n_in)),
        const("std", rng.uniform(0.5, 2.0, n_in)),
        const("w0", rng.normal(0, 0.3, (32, n_in))),
        const("b0", rng.normal(0, 0.1, 32)),
        const("w1", rng.normal(0, 0.3, (32, 16))),
        const("b1", rng.normal(0, 0.1, 16)),
        const("w2", rng.normal(0, 0.3, (16, 12))),
        const("b2", rng.normal(0, 0.1, 12)),
        const("w3", rng.normal(0, 0.3, (8, 12))),
        const("b3", rng.normal(0, 0.1, 8)),
        const("scale", rng.uniform(0.5, 1.5, 8)),
    ]
    g = helper.make_graph(nodes, "mlp", [vinfo("obs", [1, n_in])], [vinfo("actions", [1, 8])], inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)], producer_name="onnx_models.py")
    helper.set_model_props(m, {"joint_names": "a,b,c", "action_scale": "0.25"})
    save(m, path)
    return n_in, None


def lstm_graph(name, n_in, hidden, w, r, b, head, mean=None):
    """The recurrent export: obs [1, in], h_in / c_in [1, 1, H] → LSTM → Squeeze → MLP head;
    outputs actions, h_out, c_out."""
    nodes, inits = [], [const("W", w), const("R", r), const("B", b)]
    x = "obs"
    if mean is not None:
        nodes.append(helper.make_node("Sub", ["obs", "mean"], ["obs_n"], name="normalizer"))
        inits.append(const("mean", mean))
        x = "obs_n"
    inits.append(numpy_helper.from_array(np.array([0], dtype=np.int64), "ax0"))
    inits.append(numpy_helper.from_array(np.array([0, 1], dtype=np.int64), "ax01"))
    nodes += [
        helper.make_node("Unsqueeze", [x, "ax0"], ["x3"], name="unsqueeze"),
        helper.make_node("LSTM", ["x3", "W", "R", "B", "", "h_in", "c_in"], ["Y", "h_out", "c_out"],
                         name="memory", hidden_size=hidden),
        helper.make_node("Squeeze", ["Y", "ax01"], ["y"], name="squeeze"),
    ]
    cur = "y"
    for i, (kind, *t) in enumerate(head):
        out = "actions" if i == len(head) - 1 else f"m{i}"
        if kind == "gemm":
            inits += [const(f"hw{i}", t[0]), const(f"hb{i}", t[1])]
            nodes.append(helper.make_node("Gemm", [cur, f"hw{i}", f"hb{i}"], [out], name=f"actor.{i}", transB=1))
        else:
            nodes.append(helper.make_node("Elu", [cur], [out], name=f"actor.{i}", alpha=1.0))
        cur = out
    n_out = [t for k, *t in head if k == "gemm"][-1][0].shape[0]
    g = helper.make_graph(nodes, name,
                          [vinfo("obs", [1, n_in]), vinfo("h_in", [1, 1, hidden]), vinfo("c_in", [1, 1, hidden])],
                          [vinfo("actions", [1, n_out]), vinfo("h_out", [1, 1, hidden]), vinfo("c_out", [1, 1, hidden])],
                          inits)
    return helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)], producer_name="onnx_models.py")


def lstm(path):
    n_in, h = 10, 6
    head = [("gemm", rng.normal(0, 0.4, (4, h)), rng.normal(0, 0.1, 4)), ("elu",),
            ("gemm", rng.normal(0, 0.4, (3, 4)), rng.normal(0, 0.1, 3))]
    m = lstm_graph("lstm", n_in, h, rng.normal(0, 0.4, (1, 4 * h, n_in)), rng.normal(0, 0.4, (1, 4 * h, h)),
                   rng.normal(0, 0.2, (1, 8 * h)), head, mean=rng.normal(0, 0.5, n_in))
    save(m, path)
    return n_in, h


def peer(path, st_path):
    """Unitree's G1 LSTM walker (PyTorch weights) re-exported to ONNX: gate blocks reordered from
    PyTorch's i, f, g, o to ONNX's i, o, f, c, as torch.onnx.export does."""
    from safetensors.numpy import load_file
    t = load_file(st_path)
    wih, whh = t["memory.weight_ih_l0"], t["memory.weight_hh_l0"]
    h = whh.shape[1]

    def onnx_order(a):
        i, f, g, o = np.split(a, 4, axis=0)
        return np.concatenate([i, o, f, g], axis=0)

    b = np.concatenate([onnx_order(t["memory.bias_ih_l0"]), onnx_order(t["memory.bias_hh_l0"])])[None, :]
    head = [("gemm", t["actor.0.weight"], t["actor.0.bias"]), ("elu",), ("gemm", t["actor.2.weight"], t["actor.2.bias"])]
    m = lstm_graph("peer", wih.shape[1], h, onnx_order(wih)[None], onnx_order(whh)[None], b, head)
    save(m, path)
    return wih.shape[1], h


MJLAB_JOINTS = [f"{side}_{j}_joint" for j in ["hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll"]
                for side in ["left", "right"]]


def mjlab_meta(path, joints=MJLAB_JOINTS):
    """An MLP (45 → 12) with its deploy data in metadata_props, as mjlab's exporter attaches it:
    comma-separated lists in the policy's joint order (here left/right interleaved)."""
    n_in = 3 + 3 + 3 + 12 * 3
    nodes = [
        helper.make_node("Gemm", ["obs", "w0", "b0"], ["h0"], name="actor.0", transB=1),
        helper.make_node("Elu", ["h0"], ["a0"], name="actor.1"),
        helper.make_node("Gemm", ["a0", "w1", "b1"], ["actions"], name="actor.2", transB=1),
    ]
    inits = [const("w0", rng.normal(0, 0.3, (16, n_in))), const("b0", rng.normal(0, 0.1, 16)),
             const("w1", rng.normal(0, 0.3, (12, 16))), const("b1", rng.normal(0, 0.1, 12))]
    g = helper.make_graph(nodes, "mjlab", [vinfo("obs", [1, n_in])], [vinfo("actions", [1, 12])], inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)], producer_name="onnx_models.py")
    kp = [100.0 + 10 * i for i in range(12)]
    kd = [2.0 + 0.5 * i for i in range(12)]
    pos = [round(-0.3 + 0.05 * i, 3) for i in range(12)]
    csv = lambda v: ",".join(f"{x:.3f}" for x in v)
    helper.set_model_props(m, {
        "run_path": "test/run", "joint_names": ",".join(joints), "joint_stiffness": csv(kp),
        "joint_damping": csv(kd), "default_joint_pos": csv(pos), "command_names": "twist",
        "observation_names": "base_ang_vel,projected_gravity,command,joint_pos,joint_vel,actions",
        "action_scale": "0.5"})
    save(m, path)


def rl_lab_29(d):
    """The shape of unitree_rl_lab's official G1 29-dof velocity export: deploy.yaml (IsaacLab joint
    order mapped to SDK slots, SDK-order gains with arm kd 10, 6 terms × 5 frames = 480 inputs,
    clips) + an MLP 480 → 512 → 256 → 128 → 29 with ELU (seeded weights)."""
    ids = [0, 6, 12, 1, 7, 13, 2, 8, 14, 3, 9, 15, 22, 4, 10, 16, 23, 5, 11, 17, 24, 18, 25, 19, 26, 20, 27, 21, 28]
    kp = [100, 100, 100, 150, 40, 40] * 2 + [200] * 3 + [40] * 14
    kd = [2, 2, 2, 4, 2, 2] * 2 + [5] * 3 + [10] * 14
    pos = [-0.1, -0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.3, 0.3, 0.3, -0.2, -0.2, 0.25, -0.25,
           0.0, 0.0, 0.0, 0.0, 0.97, 0.97, 0.15, -0.15, 0.0, 0.0, 0.0, 0.0]
    fl = lambda v: "[" + ", ".join(f"{float(x)}" for x in v) + "]"
    term = lambda name, scale, clip="null", params="{}": (
        f"  {name}:\n    params: {params}\n    clip: {clip}\n    scale: {fl(scale)}\n    history_length: 5\n")
    text = (f"joint_ids_map: {ids}\nstep_dt: 0.02\nstiffness: {fl(kp)}\ndamping: {fl(kd)}\n"
            f"default_joint_pos: {fl(pos)}\n"
            "commands:\n  base_velocity:\n    ranges:\n      lin_vel_x: [-0.5, 1.0]\n      lin_vel_y: [-0.3, 0.3]\n"
            "      ang_vel_z: [-0.2, 0.2]\n      heading: null\n"
            f"actions:\n  JointPositionAction:\n    clip: null\n    joint_names: [.*]\n    scale: {fl([0.25] * 29)}\n"
            f"    offset: {fl(pos)}\n    joint_ids: null\n"
            "observations:\n"
            + term("base_ang_vel", [0.2] * 3, clip="[-100.0, 100.0]")
            + term("projected_gravity", [1.0] * 3)
            + term("keyboard_velocity_commands", [1.0] * 3, params="{command_name: base_velocity}")
            + term("joint_pos_rel", [1.0] * 29)
            + term("joint_vel_rel", [0.05] * 29, clip="[-50.0, 50.0]")
            + term("last_action", [1.0] * 29))
    open(f"{d}/rl_lab_29.yaml", "w").write(text)
    sizes = [480, 512, 256, 128, 29]
    nodes, inits, cur = [], [], "obs"
    for i in range(4):
        inits += [const(f"w{i}", rng.normal(0, 1 / np.sqrt(sizes[i]), (sizes[i + 1], sizes[i]))),
                  const(f"b{i}", rng.normal(0, 0.05, sizes[i + 1]))]
        out = "actions" if i == 3 else f"h{i}"
        nodes.append(helper.make_node("Gemm", [cur, f"w{i}", f"b{i}"], [out], name=f"actor.{2 * i}", transB=1))
        cur = out
        if i < 3:
            nodes.append(helper.make_node("Elu", [cur], [f"e{i}"], name=f"actor.{2 * i + 1}"))
            cur = f"e{i}"
    g = helper.make_graph(nodes, "rl_lab_29", [vinfo("obs", [1, 480])], [vinfo("actions", [1, 29])], inits)
    save(helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)]), f"{d}/rl_lab_29.onnx")
    return 480, None


def peer_deploy(path):
    """The peer walker's deployment data written as unitree_rl_lab writes deploy.yaml: gains in SDK
    motor order (29 on the G1), pose and action data in policy order (the 12 leg joints)."""
    legs_kp, legs_kd = [100, 100, 100, 150, 40, 40] * 2, [2, 2, 2, 4, 2, 2] * 2
    arm_kp = [100, 100, 50, 50, 40, 40, 40]
    stiffness = legs_kp + [300] * 3 + arm_kp * 2
    damping = legs_kd + [20] * 3 + [2] * 14
    default = [-0.1, 0.0, 0.0, 0.3, -0.2, 0.0] * 2
    fl = lambda v: "[" + ", ".join(f"{float(x)}" for x in v) + "]"
    text = f"""joint_ids_map: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]
step_dt: 0.02
stiffness: {fl(stiffness)}
damping: {fl(damping)}
default_joint_pos: {fl(default)}
commands:
  base_velocity:
    ranges:
      lin_vel_x: [-0.8, 0.8]
      lin_vel_y: [-0.5, 0.5]
      ang_vel_z: [-1.57, 1.57]
      heading: null
actions:
  JointPositionAction:
    clip: null
    joint_names: [.*]
    scale: {fl([0.25] * 12)}
    offset: {fl(default)}
    joint_ids: null
observations:
  base_ang_vel:
    params: {{}}
    clip: null
    scale: [0.25, 0.25, 0.25]
    history_length: 1
  projected_gravity:
    params: {{}}
    clip: null
    scale: [1.0, 1.0, 1.0]
    history_length: 1
  velocity_commands:
    params: {{command_name: base_velocity}}
    clip: null
    scale: [2.0, 2.0, 0.25]
    history_length: 1
  joint_pos_rel:
    params: {{}}
    clip: null
    scale: {fl([1.0] * 12)}
    history_length: 1
  joint_vel_rel:
    params: {{}}
    clip: null
    scale: {fl([0.05] * 12)}
    history_length: 1
  last_action:
    params: {{}}
    clip: null
    scale: {fl([1.0] * 12)}
    history_length: 1
  gait_phase:
    params: {{period: 0.8}}
    clip: null
    scale: [1.0, 1.0]
    history_length: 1
"""
    open(path, "w").write(text)


def run(path, n_in, hidden):
    s = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    ins, outs = [], []
    hs = np.zeros((1, 1, hidden), np.float32) if hidden else None
    cs = np.zeros((1, 1, hidden), np.float32) if hidden else None
    for _ in range(K):
        x = rng.normal(0, 1, (1, n_in)).astype(np.float32)
        feed = {"obs": x}
        if hidden:
            feed.update({"h_in": hs, "c_in": cs})
            y, hs, cs = s.run(["actions", "h_out", "c_out"], feed)
        else:
            (y,) = s.run(["actions"], feed)
        ins.append(x[0].tolist())
        outs.append(y[0].tolist())
    return {"inputs": ins, "outputs": outs}


def main():
    d = sys.argv[1]
    res = {}
    for name, build in [("mlp", mlp), ("lstm", lstm)]:
        n_in, h = build(f"{d}/{name}.onnx")
        res[name] = run(f"{d}/{name}.onnx", n_in, h)
    rl_lab_29(d)
    res["rl_lab_29"] = run(f"{d}/rl_lab_29.onnx", 480, None)
    if len(sys.argv) > 2:
        n_in, h = peer(f"{d}/peer.onnx", sys.argv[2])
        res["peer"] = run(f"{d}/peer.onnx", n_in, h)
        peer_deploy(f"{d}/deploy.yaml")
    mjlab_meta(f"{d}/mjlab.onnx")
    mjlab_meta(f"{d}/mjlab_bad.onnx", MJLAB_JOINTS[:11] + ["left_tail_joint"])
    # An op the importer must refuse by name.
    m = onnx.load(f"{d}/mlp.onnx")
    m.graph.node[6].op_type = "Softmax"
    m.graph.node[6].name = "actor.3.softmax"
    onnx.save(m, f"{d}/softmax.onnx")
    # LSTM features the importer cannot represent, each refused by name (onnxruntime runs them, and
    # importing them without would silently compute other outputs).
    for variant in ["peephole", "clip", "activations", "input_forget", "reverse"]:
        m = onnx.load(f"{d}/lstm.onnx")
        node = next(n for n in m.graph.node if n.op_type == "LSTM")
        if variant == "peephole":
            m.graph.initializer.append(const("P", rng.normal(0, 0.3, (1, 3 * 6))))
            while len(node.input) < 8:
                node.input.append("")
            node.input[7] = "P"
        elif variant == "clip":
            node.attribute.append(helper.make_attribute("clip", 3.0))
        elif variant == "activations":
            node.attribute.append(helper.make_attribute("activations", ["Sigmoid", "Tanh", "Relu"]))
        elif variant == "input_forget":
            node.attribute.append(helper.make_attribute("input_forget", 1))
        else:
            node.attribute.append(helper.make_attribute("direction", "reverse"))
        onnx.save(m, f"{d}/lstm_{variant}.onnx")
    data = open(f"{d}/mlp.onnx", "rb").read()
    open(f"{d}/truncated.onnx", "wb").write(data[: len(data) // 2])
    print(json.dumps(res))


if __name__ == "__main__":
    main()
