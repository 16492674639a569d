"""Generates the small, seeded MLP used by specs/test/rl_lab_style.toml (a unitree_rl_lab-style
29-joint policy with 5-frame per-term history: 480 -> 32 -> 29). Output is committed; rerunning
gives the same bytes."""
import pathlib
import numpy as np
from safetensors.numpy import save_file

rng = np.random.default_rng(20261121)
out = pathlib.Path(__file__).resolve().parent.parent / "specs" / "test" / "mlp_480_29.safetensors"
tensors = {
    "actor.0.weight": (rng.standard_normal((32, 480)) * 0.05).astype(np.float32),
    "actor.0.bias": (rng.standard_normal(32) * 0.01).astype(np.float32),
    "actor.2.weight": (rng.standard_normal((29, 32)) * 0.1).astype(np.float32),
    "actor.2.bias": np.zeros(29, dtype=np.float32),
}
save_file(tensors, str(out), metadata={"purpose": "test fixture for history/joint-map layout; not a walking policy"})
print(out)
