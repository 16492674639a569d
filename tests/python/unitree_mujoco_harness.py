"""Unitree's own simulator, headless: unitree_mujoco's simulate_python with its bridge unmodified.

What this replaces of `unitree_mujoco.py`: only the viewer (there is no display here) and the
keyboard that works the elastic band. Everything that talks to the controller is Unitree's
`UnitreeSdk2Bridge` from ../shared/peers/unitree_mujoco/simulate_python, over unitree_sdk2py from
../shared/peers/unitree_sdk2_python, both read in place.

`config.py` is set as a user sets it for the G1 (scene, domain, interface, no gamepad, the band on),
with a 2 ms step. The loop is Unitree's SimulationThread: a real-time `mj_step` loop that applies
the band. The band holds the robot up (as a user hangs it in the viewer) until the controller has
commanded for `--release-after` seconds (its start-up ramp), then lets go, as pressing 9 does.

With `--lockstep` the physics is driven by the commands instead of the wall clock, as `g1-sim
--dds` drives its own: one 2 ms `mj_step` per command that arrives (the torque Unitree's
`LowCmdHandler` computed from it, held through the step, as in real time), then one `PublishLowState`
(Unitree's) of the new state; the bridge's own 2 ms `sim_lowstate` timer is stopped, since a second
publisher on a timer would break the one-to-one. The state is sent again when no command follows
within 20 ms (discovery swallows the first samples). g1fw ticks on the states (`--tick-on state`),
so a tick is one command is one physics step whatever the CPU's speed: Python's real-time loop
falls to 0.42-0.56 x real time on a slow CPU, and the peer walker then sees a slowed world and
trips (docs/robot.md). Times in the output are then simulated seconds.

With `--pad SCRIPT.json` a scripted gamepad stands in for the one pygame would find: the bridge's
own `SetupJoystick` and `PublishLowState` read it and write `wireless_remote` as they do for a real
pad, so g1fw's remote decoding meets Unitree's encoding (the `ScriptedPad` class says the format).

Prints one JSON line at the end: the pelvis trajectory (t, x, y, z at 10 Hz, t from the release),
when the first command came, how many physics steps ran and the real-time factor.
"""

import argparse
import json
import os
import sys
import threading
import time

here = os.path.dirname(os.path.abspath(__file__))
shared = os.environ.get("G1_SHARED") or os.path.join(here, "..", "..", "..", "shared")
sim_dir = os.path.join(shared, "peers", "unitree_mujoco", "simulate_python")
sys.path.insert(0, os.path.join(shared, "peers", "unitree_sdk2_python"))
sys.path.insert(0, sim_dir)

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("--domain", type=int, default=1)
ap.add_argument("--interface", default="lo")
ap.add_argument("--dt", type=float, default=0.002, help="config.SIMULATE_DT (Unitree's default is 0.005)")
ap.add_argument("--duration", type=float, default=30.0, help="wall seconds to run in all")
ap.add_argument("--release-after", type=float, default=0.8,
                help="seconds after the first command before the band lets go")
ap.add_argument("--idle-exit", type=float, default=1.5,
                help="exit this long after commands stop (once some came)")
ap.add_argument("--pad", metavar="SCRIPT.json",
                help="a gamepad that plays this script, read by the bridge's own joystick code (see below)")
ap.add_argument("--lockstep", action="store_true",
                help="one physics step per command, then the state (for g1fw --tick-on state)")
args = ap.parse_args()

import config  # noqa: E402  Unitree's config module, set as a user edits config.py

config.ROBOT = "g1"
config.ROBOT_SCENE = os.path.join(shared, "peers", "unitree_mujoco", "unitree_robots", "g1", "scene_29dof.xml")
config.DOMAIN_ID = args.domain
config.INTERFACE = args.interface
config.USE_JOYSTICK = 0
config.PRINT_SCENE_INFORMATION = False
config.ENABLE_ELASTIC_BAND = True
config.SIMULATE_DT = args.dt

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from unitree_sdk2py.core.channel import ChannelFactoryInitialize  # noqa: E402
from unitree_sdk2py_bridge import ElasticBand, UnitreeSdk2Bridge  # noqa: E402

mj_model = mujoco.MjModel.from_xml_path(config.ROBOT_SCENE)
mj_data = mujoco.MjData(mj_model)
mj_model.opt.timestep = config.SIMULATE_DT

band = ElasticBand()
band_link = mj_model.body("torso_link").id
# Hang the robot with its feet on the floor: the band's rest length so that it would carry the
# robot's whole weight with the pelvis (the band measures the pelvis, the free joint's position)
# just below its standing height of ~0.79 m.
mass = float(np.sum(mj_model.body_mass))
pelvis_z = 0.77
band.length = (band.point[2] - pelvis_z) - mass * 9.81 / band.stiffness

# The bridge publishes from the moment it is made; before any physics step its IMU quaternion is
# all zeros, which g1fw rightly refuses (invalid_imu). The viewer's launch computes the model once;
# without a viewer, do the same here.
mujoco.mj_forward(mj_model, mj_data)

locker = threading.Lock()


class CommandCountingBridge(UnitreeSdk2Bridge):
    """Unitree's bridge; its handler runs unchanged (under the lock the physics steps under) and the
    commands are counted, for `--lockstep`."""

    def __init__(self, model, data):
        self.commands = 0
        self.arrived = threading.Condition()
        super().__init__(model, data)

    def LowCmdHandler(self, msg):
        with locker:  # not while the main loop steps: the handler reads the state
            super().LowCmdHandler(msg)
        with self.arrived:
            self.commands += 1
            self.arrived.notify()


ChannelFactoryInitialize(config.DOMAIN_ID, config.INTERFACE)
bridge = CommandCountingBridge(mj_model, mj_data)


class ScriptedPad:
    """What `pygame.joystick.Joystick` gives the bridge, playing `--pad`'s script over simulated
    time (mj_data.time; with --lockstep, one 2 ms step per g1fw tick). The script is a list of
    `[t_s, {"hold": [names], "LX": v, "LY": v, "RX": v, "RY": v}]`, each entry holding until the
    next: names are the Xbox pad's (A B X Y LB RB SELECT START, the triggers LT RT, the D-pad up
    down left right), axes in pygame's convention (LY = -1 is the left stick pushed forward). The
    bridge turns them into `wireless_remote` with its own code (LT is the remote's L2, RB its R1)."""

    def __init__(self, script, axis_id, button_id):
        self.script = sorted(script, key=lambda e: e[0])
        self.axis_id, self.button_id = axis_id, button_id

    def init(self):
        pass

    def _now(self):
        entry = {}
        for t, e in self.script:
            if mj_data.time + 1e-9 >= t:
                entry = e
        return entry

    def get_axis(self, i):
        e = self._now()
        name = next(n for n, k in self.axis_id.items() if k == i)
        if name in ("LT", "RT"):
            return 1.0 if name in e.get("hold", []) else -1.0
        return float(e.get(name, 0.0))

    def get_button(self, i):
        name = next(n for n, k in self.button_id.items() if k == i)
        return int(name in self._now().get("hold", []))

    def get_hat(self, i):
        held = self._now().get("hold", [])
        return (int("right" in held) - int("left" in held), int("up" in held) - int("down" in held))


if args.pad:
    # Unitree's SetupJoystick, unmodified, finds this pad where pygame would find a real one.
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    import pygame  # noqa: E402

    with open(args.pad) as f:
        pad_script = json.load(f)
    pygame.joystick.get_count = lambda: 1
    pygame.joystick.Joystick = lambda device_id: pad
    pad = ScriptedPad(pad_script, {}, {})
    bridge.SetupJoystick(device_id=0, js_type="xbox")
    pad.axis_id, pad.button_id = bridge.axis_id, bridge.button_id

t_start = time.perf_counter()
first_cmd = None
last_active = None
released_at = None
traj = []
steps = 0
next_sample = 0.0
prev_ctrl = np.zeros(mj_model.nu)


def step_physics(now):
    """One `mj_step` with the band as Unitree's SimulationThread applies it; `now` is the time the
    release and the trajectory go by. Call with `locker` held."""
    global released_at, next_sample, steps
    if band.enable and first_cmd is not None and now - first_cmd >= args.release_after:
        band.enable = False
        released_at = now
    if band.enable:
        mj_data.xfrc_applied[band_link, :3] = band.Advance(mj_data.qpos[:3], mj_data.qvel[:3])
    else:
        mj_data.xfrc_applied[band_link, :3] = 0.0
    mujoco.mj_step(mj_model, mj_data)
    steps += 1
    if released_at is not None and now - released_at >= next_sample:
        traj.append([round(now - released_at, 3)] + [round(float(v), 4) for v in mj_data.qpos[:3]])
        next_sample += 0.1


RESEND_AFTER_S = 0.02
if args.lockstep:
    bridge.lowStateThread.Wait(1.0)  # the states go out below, one per physics step
    seen = 0
    last_command_wall = None
    bridge.PublishLowState()
    while time.perf_counter() - t_start < args.duration:
        with bridge.arrived:
            if bridge.commands == seen:
                bridge.arrived.wait(RESEND_AFTER_S)
            pending = bridge.commands - seen
        wall_now = time.perf_counter()
        if pending == 0:
            if last_command_wall is not None and wall_now - last_command_wall > args.idle_exit:
                break
            bridge.PublishLowState()  # not heard (discovery, a lost sample): send it again
            continue
        seen += pending
        last_command_wall = wall_now
        with locker:
            for _ in range(pending):  # commands that came together: one step each, the newest's torque
                now = steps * mj_model.opt.timestep
                if first_cmd is None:
                    first_cmd = now
                step_physics(now)
        bridge.PublishLowState()
else:
    # Unitree's SimulationThread: a 2 ms step in wall-clock time; the first command is the first
    # change of `ctrl`.
    while time.perf_counter() - t_start < args.duration:
        step_start = time.perf_counter()
        with locker:
            now = step_start - t_start
            ctrl = np.array(mj_data.ctrl)
            if np.any(ctrl != prev_ctrl):
                last_active = now
                if first_cmd is None:
                    first_cmd = now
            prev_ctrl = ctrl
            step_physics(now)
        if last_active is not None and time.perf_counter() - t_start - last_active > args.idle_exit:
            break
        wait = mj_model.opt.timestep - (time.perf_counter() - step_start)
        if wait > 0:
            time.sleep(wait)

wall = time.perf_counter() - t_start
print(json.dumps({
    "lockstep": args.lockstep,
    "first_command_s": first_cmd,
    "released_s": released_at,
    "physics_steps": steps,
    "real_time_factor": steps * mj_model.opt.timestep / wall,
    "trajectory": traj,
}), flush=True)
os._exit(0)  # the bridge's recurrent threads never stop on their own
