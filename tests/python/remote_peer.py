"""Independent peer for the wireless remote's 40 bytes: unitree_sdk2py's own `utils/joystick.py`
(`Joystick.combine`, the writer unitree_mujoco's bridge mirrors, and `Joystick.extract`, the reader),
loaded from ../shared/peers. Its module imports pygame at the top for its gamepad subclass; a stub
stands in, as nothing used here touches it.

  remote_peer.py make SEED N      N random readings written by combine(): buttons, sticks, bytes (JSON)
  remote_peer.py read HEX...      each 40-byte reading (hex) read by extract(): its buttons (JSON)
"""
import importlib.util
import json
import pathlib
import random
import sys
import types

sys.modules.setdefault("pygame", types.ModuleType("pygame"))
PEER = pathlib.Path(__file__).resolve().parents[3] / "shared/peers/unitree_sdk2_python/unitree_sdk2py/utils/joystick.py"
spec = importlib.util.spec_from_file_location("unitree_joystick", PEER)
joystick = importlib.util.module_from_spec(spec)
spec.loader.exec_module(joystick)

BUTTONS = ["LT", "RT", "back", "start", "LB", "RB", "left", "down", "right", "up", "Y", "X", "B", "A"]


def make(seed, n):
    rng = random.Random(seed)
    out = []
    for _ in range(n):
        js = joystick.Joystick()
        pressed = {b: rng.random() < 0.3 for b in BUTTONS}
        for b, p in pressed.items():
            getattr(js, b).data = int(p)
        sticks = {a: rng.uniform(-1, 1) for a in ["lx", "ly", "rx", "ry"]}
        for a, v in sticks.items():
            getattr(js, a).data = v
        out.append({"buttons": pressed, "sticks": sticks, "bytes": list(js.combine())})
    return out


def read(hexes):
    out = []
    for h in hexes:
        js = joystick.Joystick()
        js.extract(list(bytes.fromhex(h)))
        out.append({b: bool(getattr(js, b).pressed) for b in BUTTONS})
    return out


if __name__ == "__main__":
    if sys.argv[1] == "make":
        print(json.dumps(make(int(sys.argv[2]), int(sys.argv[3]))))
    else:
        print(json.dumps(read(sys.argv[2:])))
