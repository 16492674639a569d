#!/usr/bin/env python3
"""The python-can peer test: an independent implementation of docs/can.md that drives the real
processes on vcan (inside the HIL VM: run it through `cargo xtask hil`).

It imports no project code: the codec below is written from docs/can.md alone (and self-tested against
frames computed by hand from it), the bus layout is read from specs/can/*.toml, the gains from the
deploy spec and the joint ranges from the spec's MJCF, each with the standard library.

Runs (each its own g1-can-emu + g1fw pair, both buses recorded by candump):
  walk        a walk with --cmd 0.5,0,0: the bus layout (ids, DLCs, one command per motor per IMU
              sample, reply and IMU framing, sequences, decoded values within the spec's gains and
              the joint ranges), and the outcome (emulator: did not fall; firmware: policy, no trip);
  dlc3        a motor reply with DLC 3                      -> damping, malformed_frame
  bad_byte0   a motor reply whose byte 0 is another id      -> damping, malformed_frame
  foreign_id  a reply from an unconfigured node (0x142)     -> damping, malformed_frame
  flood       thousands of foreign frames, as fast as possible -> damping, malformed_frame
  silent      *exit motor mode* to one motor, which then goes silent -> damping, motor_silent; sent on
              the emulator's side of a can-gw gateway (vcan2/vcan3), so the firmware sees only the
              silence: on its own bus the frame is a second master's command, which is
  second_master  the same frame on the firmware's bus             -> damping, malformed_frame
Each fault is injected once the firmware runs its policy (after --inject-after IMU samples), and
after the trip every motor's command on the bus must have kp = 0 and kd > 0.

  peer_test.py --self-test     only the codec self-test (runs anywhere, no CAN needed)
  peer_test.py [--only walk,flood] [--walk-s 10] [--fault-s 2.5]
Environment: HIL_DIR (output directory), HIL_BIN_DIR (g1fw, g1-can-emu), HIL_WALK_S, HIL_PEER_ONLY,
HIL_FLOOD_FRAMES, HIL_MIN_TICKS_PER_S (subprocess timeouts assume the VM runs at least this fast).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import re
import signal
import struct
import subprocess
import sys
import time
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

# ------------------------------------------------------------------------------------------------
# Codec (docs/can.md, "Quantisation" and "Frames")
# ------------------------------------------------------------------------------------------------

ENTER = bytes.fromhex("FFFFFFFFFFFFFFFC")
EXIT = bytes.fromhex("FFFFFFFFFFFFFFFD")
ZERO = bytes.fromhex("FFFFFFFFFFFFFFFE")
SPECIALS = {ENTER: "enter", EXIT: "exit", ZERO: "zero"}
IMU_QUAT, IMU_GYRO, IMU_ACCEL = 0x081, 0x082, 0x083
REPLY_BASE = 0x100


def f32(x: float) -> float:
    """Rounds to the nearest f32 (the codec computes in f32)."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def to_uint(x: float, lo: float, hi: float, bits: int) -> int:
    """round((clamp(x, lo, hi) - lo) * (2^bits - 1) / (hi - lo)), in f32; NaN maps to the low end."""
    if math.isnan(x):
        x = lo
    x = f32(min(max(f32(x), lo), hi))
    scaled = f32(f32(f32(x - f32(lo)) * f32((1 << bits) - 1)) / f32(hi - lo))
    return int(math.floor(scaled + 0.5))  # round half away from zero (scaled >= 0); exact in f64


def to_float(u: int, lo: float, hi: float, bits: int) -> float:
    return f32(f32(lo) + f32(f32(u * f32(hi - lo)) / f32((1 << bits) - 1)))


@dataclass(frozen=True)
class Motor:
    slot: int
    bus: int
    id: int
    p_max: float
    v_max: float
    t_max: float
    kp_max: float
    kd_max: float

    def step(self, field_: str) -> float:
        """One quantisation step of a command field."""
        span, bits = {
            "p": (2 * self.p_max, 16),
            "v": (2 * self.v_max, 12),
            "t": (2 * self.t_max, 12),
            "kp": (self.kp_max, 12),
            "kd": (self.kd_max, 12),
        }[field_]
        return span / ((1 << bits) - 1)


def encode_command(m: Motor, p: float, v: float, kp: float, kd: float, t: float) -> bytes:
    pu = to_uint(p, -m.p_max, m.p_max, 16)
    vu = to_uint(v, -m.v_max, m.v_max, 12)
    kpu = to_uint(kp, 0.0, m.kp_max, 12)
    kdu = to_uint(kd, 0.0, m.kd_max, 12)
    tu = to_uint(t, -m.t_max, m.t_max, 12)
    return bytes(
        [pu >> 8, pu & 0xFF, vu >> 4, ((vu & 0xF) << 4) | (kpu >> 8), kpu & 0xFF, kdu >> 4, ((kdu & 0xF) << 4) | (tu >> 8), tu & 0xFF]
    )


def command_fields(d: bytes) -> tuple[int, int, int, int, int]:
    """(p, v, kp, kd, t) as raw unsigned integers."""
    return (
        (d[0] << 8) | d[1],
        (d[2] << 4) | (d[3] >> 4),
        ((d[3] & 0xF) << 8) | d[4],
        (d[5] << 4) | (d[6] >> 4),
        ((d[6] & 0xF) << 8) | d[7],
    )


def decode_command(m: Motor, d: bytes) -> dict:
    pu, vu, kpu, kdu, tu = command_fields(d)
    return {
        "p": to_float(pu, -m.p_max, m.p_max, 16),
        "v": to_float(vu, -m.v_max, m.v_max, 12),
        "kp": to_float(kpu, 0.0, m.kp_max, 12),
        "kd": to_float(kdu, 0.0, m.kd_max, 12),
        "t": to_float(tu, -m.t_max, m.t_max, 12),
        "raw": (pu, vu, kpu, kdu, tu),
    }


def encode_reply(m: Motor, p: float, v: float, t: float) -> bytes:
    pu = to_uint(p, -m.p_max, m.p_max, 16)
    vu = to_uint(v, -m.v_max, m.v_max, 12)
    tu = to_uint(t, -m.t_max, m.t_max, 12)
    return bytes([m.id, pu >> 8, pu & 0xFF, vu >> 4, ((vu & 0xF) << 4) | (tu >> 8), tu & 0xFF])


def decode_reply(m: Motor, d: bytes) -> dict:
    pu = (d[1] << 8) | d[2]
    vu = (d[3] << 4) | (d[4] >> 4)
    tu = ((d[4] & 0xF) << 8) | d[5]
    return {
        "id": d[0],
        "p": to_float(pu, -m.p_max, m.p_max, 16),
        "v": to_float(vu, -m.v_max, m.v_max, 12),
        "t": to_float(tu, -m.t_max, m.t_max, 12),
        "raw": (pu, vu, tu),
    }


def decode_imu(can_id: int, d: bytes) -> dict:
    if can_id == IMU_QUAT:
        w, x, y, z = struct.unpack(">hhhh", d)
        return {"q": tuple(c / 32767 for c in (w, x, y, z))}
    if can_id == IMU_GYRO:
        x, y, z, seq = struct.unpack(">hhhH", d)
        return {"gyro": (x * 0.001, y * 0.001, z * 0.001), "seq": seq}
    if can_id == IMU_ACCEL:
        x, y, z, seq = struct.unpack(">hhhH", d)
        return {"acc": (x * 0.005, y * 0.005, z * 0.005), "seq": seq}
    raise ValueError(f"0x{can_id:03X} is not an IMU id")


def self_test() -> list[str]:
    """Frames computed by hand from docs/can.md; returns what was checked."""
    m = Motor(slot=0, bus=0, id=1, p_max=12.5, v_max=48.0, t_max=88.0, kp_max=500.0, kd_max=10.0)
    done = []

    def eq(what, got, want):
        if got != want:
            raise AssertionError(f"codec self-test: {what}: got {got!r}, want {want!r}")
        done.append(what)

    hx = bytes.fromhex
    # p 0 -> (0 + 12.5) * 65535 / 25 = 32767.5 -> 32768 = 0x8000; v 0 -> 48 * 4095 / 96 = 2047.5 -> 0x800;
    # kp 200 -> 200 * 4095 / 500 = 1638 = 0x666; kd 2 -> 2 * 4095 / 10 = 819 = 0x333; t 0 -> 0x800.
    eq("command p0 v0 kp200 kd2 t0", encode_command(m, 0, 0, 200, 2, 0), hx("8000800666333800"))
    # damping: kp 0, kd 5 -> 2047.5 -> 0x800
    eq("command damping kd 5", encode_command(m, 0, 0, 0, 5, 0), hx("8000800000800800"))
    # p 1.0 -> 13.5 * 65535 / 25 = 35388.9 -> 35389 = 0x8A3D
    eq("command p 1.0", encode_command(m, 1.0, 0, 0, 0, 0)[:2], hx("8A3D"))
    eq("command all maxima", encode_command(m, 12.5, 48, 500, 10, 88), hx("FFFFFFFFFFFFFFFF"))
    eq("command all minima", encode_command(m, -12.5, -48, 0, 0, -88), hx("0000000000000000"))
    eq("command clamps out-of-range values", encode_command(m, 99, -99, 9999, -1, 1e9), hx("FFFF000FFF000FFF"))
    eq("NaN -> low end", to_uint(float("nan"), -12.5, 12.5, 16), 0)
    # the nibble packing: v 0xABC, kp 0xDEF, kd 0x123, t 0x456
    eq("command nibble layout", command_fields(hx("0000ABCDEF123456")), (0, 0xABC, 0xDEF, 0x123, 0x456))
    eq("reply id 1 p0 v0 t0", encode_reply(m, 0, 0, 0), hx("018000800800"))
    r = decode_reply(m, hx("018000800800"))
    eq("reply decode id", r["id"], 1)
    eq("reply decode p ~ 0", abs(r["p"]) < m.step("p"), True)
    eq("reply nibble layout", decode_reply(m, hx("05ABCDEF1234"))["raw"], (0xABCD, 0xEF1, 0x234))
    eq("quaternion identity", decode_imu(IMU_QUAT, hx("7FFF000000000000"))["q"], (1.0, 0.0, 0.0, 0.0))
    # gyro x -0.5 rad/s = -500 = 0xFE0C, seq 7; accel z 9.81 m/s^2 = 1962 = 0x07AA, seq 42
    g = decode_imu(IMU_GYRO, hx("FE0C000000000007"))
    eq("gyro x -0.5 rad/s, seq 7", (round(g["gyro"][0], 6), g["seq"]), (-0.5, 7))
    a = decode_imu(IMU_ACCEL, hx("000000000" + "7AA002A"))
    eq("accel z 9.81 m/s^2, seq 42", (round(a["acc"][2], 6), a["seq"]), (9.81, 42))
    eq("accel seq is unsigned", decode_imu(IMU_ACCEL, hx("000000000000FFFF"))["seq"], 65535)
    eq("special frames", [SPECIALS.get(hx(s)) for s in ("FFFFFFFFFFFFFFFC", "FFFFFFFFFFFFFFFD", "FFFFFFFFFFFFFFFE")],
       ["enter", "exit", "zero"])
    # round trip within half a step, random values in range
    rng = random.Random(7)
    worst = 0.0
    for _ in range(2000):
        p, v, t = rng.uniform(-12.5, 12.5), rng.uniform(-48, 48), rng.uniform(-88, 88)
        kp, kd = rng.uniform(0, 500), rng.uniform(0, 10)
        c = decode_command(m, encode_command(m, p, v, kp, kd, t))
        for k, x in (("p", p), ("v", v), ("kp", kp), ("kd", kd), ("t", t)):
            err = abs(c[k] - x) / m.step(k)
            worst = max(worst, err)
    eq("command round trip within half a step", worst <= 0.5 + 1e-3, True)
    return done


# ------------------------------------------------------------------------------------------------
# Configuration: the bus layout, the spec's gains, the joint ranges
# ------------------------------------------------------------------------------------------------

# unitree_hg motor slots of the G1 (the legs first), the joint names of the MJCF without `_joint`.
G1_SLOTS = [
    "left_hip_pitch", "left_hip_roll", "left_hip_yaw", "left_knee", "left_ankle_pitch", "left_ankle_roll",
    "right_hip_pitch", "right_hip_roll", "right_hip_yaw", "right_knee", "right_ankle_pitch", "right_ankle_roll",
    "waist_yaw", "waist_roll", "waist_pitch",
    "left_shoulder_pitch", "left_shoulder_roll", "left_shoulder_yaw", "left_elbow",
    "left_wrist_roll", "left_wrist_pitch", "left_wrist_yaw",
    "right_shoulder_pitch", "right_shoulder_roll", "right_shoulder_yaw", "right_elbow",
    "right_wrist_roll", "right_wrist_pitch", "right_wrist_yaw",
]  # fmt: skip


@dataclass
class Layout:
    interfaces: list[str]
    imu_bus: int
    motors: list[Motor]
    motor_timeout_ticks: int
    by_bus_id: dict = field(default_factory=dict)

    @staticmethod
    def load(path: Path) -> "Layout":
        c = tomllib.loads(path.read_text())
        motors = [
            Motor(m["slot"], m["bus"], m["id"], m["p_max"], m["v_max"], m["t_max"], m["kp_max"], m["kd_max"])
            for m in c["motor"]
        ]
        lay = Layout(c["interfaces"], c["imu"]["bus"], motors, c["motor_timeout_ticks"])
        lay.by_bus_id = {(m.bus, m.id): m for m in motors}
        if len(lay.by_bus_id) != len(motors):
            raise ValueError(f"{path}: a node id appears twice on one bus")
        return lay

    def command_order(self) -> list[tuple[int, int]]:
        """docs/can.md: one command per configured motor, buses in order, ids ascending."""
        return sorted(self.by_bus_id)

    def reply_order(self) -> list[tuple[int, int]]:
        """docs/can.md: the emulator answers bus 1's motors first, then bus 0's (ids ascending)."""
        return sorted(self.by_bus_id, key=lambda k: (-k[0], k[1]))


@dataclass
class Gains:
    """Per slot: the (kp, kd) pairs the spec allows on the bus."""
    allowed: dict[int, list[tuple[str, float, float]]]
    damping_kd: float

    @staticmethod
    def load(spec_path: Path, layout: Layout) -> "Gains":
        s = tomllib.loads(spec_path.read_text())
        names = [n.removesuffix("_joint") for n in s["policy"]["joint_names"]]
        allowed: dict[int, list] = {}
        damp = float(s["safety"]["damping_kd"])
        for m in layout.motors:
            name = G1_SLOTS[m.slot]
            pairs = [("damping", 0.0, damp)]
            if name in names:
                i = names.index(name)
                pairs.append(("policy", float(s["policy"]["kp"][i]), float(s["policy"]["kd"][i])))
                st = s.get("startup", {})
                if "kp" in st:
                    pairs.append(("startup", float(st["kp"][i]), float(st["kd"][i])))
            allowed[m.slot] = pairs
        return Gains(allowed, damp)


def vm_can_config(path: Path, out: Path, tick_timeout_ms: int) -> Path:
    """A copy of the bus layout with a longer wall-clock `tick_timeout_ms`: the VM is not real time
    (stalls of 0.4-0.6 s between an IMU sample and the next were seen on a loaded 2-core host, which
    the robot's 250 ms would turn into a hal_fault). Everything counted in ticks stays as it is."""
    text = path.read_text()
    new, n = re.subn(r"(?m)^(\s*tick_timeout_ms\s*=\s*)\d+", lambda m: f"{m.group(1)}{tick_timeout_ms}", text)
    if n != 1:
        raise ValueError(f"{path}: expected one `tick_timeout_ms = N` line, found {n}")
    dst = out / path.name
    dst.write_text(new)
    if tomllib.loads(new)["tick_timeout_ms"] != tick_timeout_ms:
        raise ValueError(f"{dst}: tick_timeout_ms was not replaced")
    print(f"[peer] bus layout {path} with tick_timeout_ms = {tick_timeout_ms} (wall clock; the VM is not real time)")
    return dst


def joint_ranges(spec_path: Path) -> dict[str, tuple[float, float]]:
    s = tomllib.loads(spec_path.read_text())
    mjcf = (spec_path.parent / s["estimator"]["model"]).resolve()
    out = {}
    for j in ET.parse(mjcf).getroot().iter("joint"):
        if j.get("range") and j.get("name"):
            lo, hi = (float(x) for x in j.get("range").split())
            out[j.get("name").removesuffix("_joint")] = (lo, hi)
    if not out:
        raise ValueError(f"{mjcf}: no joint ranges found")
    return out


# ------------------------------------------------------------------------------------------------
# Recording (candump -L on every interface) and the recorded frames
# ------------------------------------------------------------------------------------------------


@dataclass
class Frame:
    n: int  # position in the recording (all interfaces, in the order the kernel delivered them)
    bus: int
    id: int
    data: bytes
    motor_side: bool = False  # seen on the emulator's side of a gateway, not on the firmware's bus


def parse_candump(path: Path, interfaces: list[str], motor_side: list[str] = ()) -> tuple[list[Frame], list[str]]:
    """candump -L lines `(ts) vcan0 123#DEADBEEF`; anything else (drop notices) is returned apart.
    `motor_side`: the emulator's interfaces when a gateway separates them from `interfaces`."""
    bus_of = {name: (i, False) for i, name in enumerate(interfaces)}
    bus_of.update({name: (i, True) for i, name in enumerate(motor_side)})
    frames, other = [], []
    with open(path) as f:
        for line in f:
            parts = line.split()
            if len(parts) != 3 or not parts[0].startswith("(") or "#" not in parts[2]:
                if line.strip():
                    other.append(line.strip())
                continue
            where = bus_of.get(parts[1])
            if where is None:
                continue  # not one of ours
            ident, _, data = parts[2].partition("#")
            if data.startswith("#") or data.startswith("R"):
                other.append(line.strip())  # CAN FD or remote frame: not in docs/can.md
                continue
            frames.append(Frame(len(frames), where[0], int(ident, 16), bytes.fromhex(data), where[1]))
    return frames, other


@dataclass
class Tick:
    """Frames between IMU sample k's accelerometer frame and sample k+1's (tick k's commands and
    the replies to them)."""
    k: int
    start: int  # Frame.n of the accelerometer frame that opened it
    commands: list = field(default_factory=list)  # (Frame, Motor)
    replies: list = field(default_factory=list)  # (Frame, Motor)
    other: list = field(default_factory=list)  # Frames


@dataclass
class Recording:
    frames: list[Frame]
    notes: list[str]
    startup: Tick  # before IMU sample 0 (k = -1)
    ticks: list[Tick]
    imu: list[list[Frame]]  # per sample: the IMU frames that made it up
    foreign: list[Frame]

    def tick_of(self, frame_n: int) -> int:
        """The tick a frame was seen in (-1: before IMU sample 0)."""
        k = -1
        for t in self.ticks:
            if t.start > frame_n:
                break
            k = t.k
        return k


def segment(frames: list[Frame], notes: list[str], lay: Layout) -> Recording:
    startup = Tick(-1, -1)
    ticks: list[Tick] = []
    cur = startup
    imu: list[list[Frame]] = []
    pending_imu: list[Frame] = []
    foreign: list[Frame] = []
    base_seq = None
    for fr in frames:
        if fr.motor_side:
            continue  # the firmware's view only
        if fr.bus == lay.imu_bus and fr.id in (IMU_QUAT, IMU_GYRO, IMU_ACCEL):
            pending_imu.append(fr)
            if fr.id == IMU_ACCEL and len(fr.data) == 8:
                seq = struct.unpack(">H", fr.data[6:8])[0]
                if base_seq is None:
                    base_seq = seq
                    k = 0
                else:
                    # unwrap the 16-bit sequence against the previous tick
                    prev = ticks[-1].k
                    k = prev + ((seq - (prev + base_seq)) & 0xFFFF)
                cur = Tick(k, fr.n)
                ticks.append(cur)
                imu.append(pending_imu)
                pending_imu = []
            continue
        m = lay.by_bus_id.get((fr.bus, fr.id))
        if m is not None:
            cur.commands.append((fr, m))
            continue
        if REPLY_BASE <= fr.id < REPLY_BASE + 0x80:
            m = lay.by_bus_id.get((fr.bus, fr.id - REPLY_BASE))
            if m is not None:
                cur.replies.append((fr, m))
                continue
        cur.other.append(fr)
        foreign.append(fr)
    return Recording(frames, notes, startup, ticks, imu, foreign)


# ------------------------------------------------------------------------------------------------
# Checks on a recording
# ------------------------------------------------------------------------------------------------


@dataclass
class Check:
    name: str
    ok: bool
    detail: str = ""
    ticks_to_damping: int | None = None
    wall_s: float | None = None
    reason: str = ""


def fmt_frame(fr: Frame, lay: Layout) -> str:
    return f"{lay.interfaces[fr.bus]} {fr.id:03X}#{fr.data.hex().upper()} (frame {fr.n})"


def check_layout(rec: Recording, lay: Layout, gains: Gains, ranges: dict, exclude_last: bool = True,
                 fw_ticks: int | None = None) -> list[Check]:
    out: list[Check] = []
    n_motors = len(lay.motors)
    full = rec.ticks[:-1] if exclude_last else rec.ticks  # the last sample may have no commands yet
    if fw_ticks is not None:
        # After its last tick the firmware damps on its own clock for --end-damping (docs/robot.md),
        # not one round per IMU sample: the per-sample checks stop at its last tick.
        full = [t for t in full if t.k < fw_ticks]

    # sniffer health
    drops = [n for n in rec.notes if "DROP" in n.upper()]
    out.append(Check("sniffer lost no frames", not drops, drops[0] if drops else f"{len(rec.frames)} frames recorded"))

    # ids
    bad = rec.foreign
    out.append(Check(
        "ids: only the layout's command/reply ids and 0x081-0x083 on the IMU bus",
        not bad, f"{len(bad)} foreign, first {fmt_frame(bad[0], lay)}" if bad else
        f"bus ids {', '.join(lay.interfaces[b] + ':' + ','.join(str(i) for (bb, i) in lay.command_order() if bb == b) for b in range(len(lay.interfaces)))}"))

    # DLCs and reply byte 0
    wrong = []
    for t in [rec.startup] + rec.ticks:
        wrong += [(fr, "command DLC") for fr, _ in t.commands if len(fr.data) != 8]
        wrong += [(fr, "reply DLC") for fr, _ in t.replies if len(fr.data) != 6]
        wrong += [(fr, "reply byte 0") for fr, m in t.replies if len(fr.data) >= 1 and fr.data[0] != m.id]
    wrong += [(fr, "IMU DLC") for s in rec.imu for fr in s if len(fr.data) != 8]
    out.append(Check("DLC 8 commands, DLC 6 replies with byte 0 = id, DLC 8 IMU", not wrong,
                     f"{len(wrong)} wrong, first {wrong[0][1]}: {fmt_frame(wrong[0][0], lay)}" if wrong else ""))

    # start-up: one enter per motor, answered, then IMU sample 0
    enters = [m for fr, m in rec.startup.commands if SPECIALS.get(fr.data) == "enter"]
    others = [fr for fr, m in rec.startup.commands if SPECIALS.get(fr.data) != "enter"]
    ok = sorted((m.bus, m.id) for m in enters) == lay.command_order() and not others and len(rec.startup.replies) == n_motors
    out.append(Check("start-up: one enter-motor-mode per motor, each answered, then IMU sample 0", ok,
                     f"{len(enters)} enters, {len(others)} other commands, {len(rec.startup.replies)} replies before sample 0"))

    # one command per motor per IMU sample, in order; one reply per motor per tick, in order
    order, rorder = lay.command_order(), lay.reply_order()
    bad_count, bad_order, bad_reply, bad_rorder = [], [], [], []
    for t in full:
        got = [(m.bus, m.id) for _, m in t.commands]
        if sorted(got) != order:
            bad_count.append(t)
        elif got != order:
            bad_order.append(t)
        rgot = [(m.bus, m.id) for _, m in t.replies]
        if sorted(rgot) != sorted(rorder):
            bad_reply.append(t)
        elif rgot != rorder:
            bad_rorder.append(t)
    def first(ts, what):
        if not ts:
            return f"{len(full)} ticks"
        t = ts[0]
        return f"{len(ts)} of {len(full)} ticks; first: tick {t.k} has {what(t)}"
    out.append(Check("exactly one command per motor per IMU sample", not bad_count,
                     first(bad_count, lambda t: f"{len(t.commands)} commands")))
    out.append(Check("commands: buses in order, ids ascending", not bad_order,
                     first(bad_order, lambda t: str([(m.bus, m.id) for _, m in t.commands]))))
    out.append(Check("one reply per motor per tick, before the next IMU sample", not bad_reply,
                     first(bad_reply, lambda t: f"{len(t.replies)} replies")))
    out.append(Check("replies: bus 1 first, then bus 0, ids ascending", not bad_rorder,
                     first(bad_rorder, lambda t: str([(m.bus, m.id) for _, m in t.replies]))))

    # IMU: quaternion, gyro, accel per sample; sequences equal and increasing
    bad_imu = []
    for i, s in enumerate(rec.imu):
        ids = [fr.id for fr in s]
        if ids != [IMU_QUAT, IMU_GYRO, IMU_ACCEL] or any(len(fr.data) != 8 for fr in s):
            bad_imu.append(f"sample {i}: ids {[hex(x) for x in ids]}")
            continue
        g, a, q = decode_imu(IMU_GYRO, s[1].data), decode_imu(IMU_ACCEL, s[2].data), decode_imu(IMU_QUAT, s[0].data)
        if g["seq"] != a["seq"] or a["seq"] != i & 0xFFFF:
            bad_imu.append(f"sample {i}: gyro seq {g['seq']}, accel seq {a['seq']}")
        norm = math.sqrt(sum(c * c for c in q["q"]))
        if abs(norm - 1.0) > 0.01:
            bad_imu.append(f"sample {i}: |q| = {norm:.4f}")
    out.append(Check("IMU: 0x081, 0x082, 0x083 per sample, sequences equal and k mod 2^16, |q| = 1", not bad_imu,
                     f"{len(bad_imu)} bad, first {bad_imu[0]}" if bad_imu else f"{len(rec.imu)} samples"))

    # decoded commands: gains one of the spec's pairs, v = t = 0, positions within the joint range
    bad_gain, bad_vt, bad_pos = [], [], []
    modes_seen: dict[str, int] = {}
    for t in full:
        for fr, m in motor_commands(t):
            c = decode_command(m, fr.data)
            match = [name for name, kp, kd in gains.allowed[m.slot]
                     if abs(c["kp"] - kp) <= m.step("kp") and abs(c["kd"] - kd) <= m.step("kd")]
            if not match:
                bad_gain.append((t.k, m, c))
            else:
                modes_seen[match[0]] = modes_seen.get(match[0], 0) + 1
            if abs(c["v"]) > m.step("v") or abs(c["t"]) > m.step("t"):
                bad_vt.append((t.k, m, c))
            name = G1_SLOTS[m.slot]
            lo, hi = ranges[name]
            if c["kp"] > 0 and not (lo - m.step("p") <= c["p"] <= hi + m.step("p")):
                bad_pos.append((t.k, m, c, lo, hi))
    def desc(x):
        k, m, c = x[:3]
        return (f"tick {k} {G1_SLOTS[m.slot]}: p {c['p']:.3f} v {c['v']:.3f} kp {c['kp']:.2f} kd {c['kd']:.3f} "
                f"t {c['t']:.3f}")
    out.append(Check("commands: (kp, kd) one of the spec's pairs (start-up, policy, damping)", not bad_gain,
                     f"{len(bad_gain)} off, first {desc(bad_gain[0])}" if bad_gain else
                     ", ".join(f"{k} {v}" for k, v in sorted(modes_seen.items()))))
    out.append(Check("commands: velocity and feed-forward torque 0 (PD targets only)", not bad_vt,
                     f"{len(bad_vt)} off, first {desc(bad_vt[0])}" if bad_vt else ""))
    out.append(Check("commands: position targets within the joint ranges of the MJCF", not bad_pos,
                     f"{len(bad_pos)} outside, first {desc(bad_pos[0])} range [{bad_pos[0][3]}, {bad_pos[0][4]}]"
                     if bad_pos else ""))

    # decoded replies: positions within the joint range (MuJoCo limits are soft: 0.1 rad margin)
    bad_r, sat = [], 0
    for t in full:
        for fr, m in t.replies:
            if len(fr.data) != 6:
                continue
            r = decode_reply(m, fr.data)
            lo, hi = ranges[G1_SLOTS[m.slot]]
            if not (lo - 0.1 <= r["p"] <= hi + 0.1):
                bad_r.append(f"tick {t.k} {G1_SLOTS[m.slot]}: p {r['p']:.3f} outside [{lo}, {hi}]")
            sat += sum(1 for u in r["raw"][1:] if u in (0, 4095))
    out.append(Check("replies: positions within the joint ranges", not bad_r,
                     f"{len(bad_r)} outside, first {bad_r[0]}" if bad_r else f"{sat} saturated v/t fields"))
    return out


def motor_commands(t: Tick) -> list:
    """Tick `t`'s MIT commands (DLC 8, not a special frame): (Frame, Motor)."""
    return [(fr, m) for fr, m in t.commands if len(fr.data) == 8 and not SPECIALS.get(fr.data)]


def damped(fr: Frame) -> bool:
    """A damping command: kp = 0 and kd > 0 (raw fields)."""
    _, _, kpu, kdu, _ = command_fields(fr.data)
    return kpu == 0 and kdu > 0


def damping_after(rec: Recording, trip_tick: int, k_inj: int, lay: Layout) -> tuple[bool, str, int | None]:
    """Every motor's every command from tick `trip_tick` on has kp = 0 and kd > 0. Returns (ok,
    detail, the first tick from which every command on the bus is damping, counted from k_inj)."""
    last_not = None
    bad = []
    cmds_after = 0
    for t in rec.ticks:
        if t.k < k_inj:
            continue
        cmds = motor_commands(t)
        if not cmds:
            continue
        if len(cmds) != len(lay.motors) or not all(damped(fr) for fr, _ in cmds):
            last_not = t.k
        if t.k >= trip_tick:
            cmds_after += len(cmds)
            bad += [f"tick {t.k} {G1_SLOTS[m.slot]} kp {command_fields(fr.data)[2]} kd {command_fields(fr.data)[3]} (raw)"
                    for fr, m in cmds if not damped(fr)]
    first_damped = k_inj if last_not is None else last_not + 1
    if cmds_after == 0:
        return False, f"no commands on the bus at or after tick {trip_tick}", None
    if bad:
        return False, f"{len(bad)} non-damping commands after tick {trip_tick}, first {bad[0]}", None
    return True, f"{cmds_after} commands from tick {trip_tick} on all kp 0, kd > 0", first_damped


# ------------------------------------------------------------------------------------------------
# Running the processes
# ------------------------------------------------------------------------------------------------


class Failed(Exception):
    pass


def raw_receivers() -> int:
    try:
        return sum(1 for line in open("/proc/net/can/rcvlist_all") if line.rstrip().endswith(" raw"))
    except OSError:
        return 0


def ticks_per_s_floor() -> float:
    return float(os.environ.get("HIL_MIN_TICKS_PER_S", "15"))  # the slowest the VM is allowed to be


class Run:
    """One g1-can-emu + g1fw pair with candump recording both buses. A context manager: every child
    is killed (its whole process group) on the way out."""

    def __init__(self, name: str, out: Path, lay: Layout, args, gateway: bool = False):
        """gateway: the emulator gets its own buses (vcan2, vcan3, ...), joined to the firmware's by
        can-gw, so a test can send to the motors without the firmware seeing it."""
        self.name, self.lay, self.args = name, lay, args
        n = len(lay.interfaces)
        self.emu_ifaces = [f"vcan{n + i}" for i in range(n)] if gateway else list(lay.interfaces)
        self.gateway = gateway
        self.dir = out / name
        self.dir.mkdir(parents=True, exist_ok=True)
        self.procs: list[tuple[str, subprocess.Popen]] = []
        self.dump = self.dir / "candump.log"
        self.bin = Path(os.environ.get("HIL_BIN_DIR", REPO / "target/release"))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.gateway:
            subprocess.run(["cangw", "-F"], check=False, timeout=30)
        for name, p in reversed(self.procs):
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + 10
        for name, p in self.procs:
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                p.wait()
        return False

    def spawn(self, name: str, argv: list[str], stdout=None) -> subprocess.Popen:
        log = open(self.dir / f"{name}.log", "w") if stdout is None else stdout
        p = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT if stdout is None else open(self.dir / f"{name}.err", "w"),
                             stdin=subprocess.DEVNULL, cwd=REPO, start_new_session=True)
        self.procs.append((name, p))
        return p

    def tail(self, name: str, n: int = 15) -> str:
        try:
            lines = (self.dir / f"{name}.log").read_text(errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(f"    {name}| {l}" for l in lines[-n:])

    def start_sniffer(self):
        if self.gateway:
            for fw_if, emu_if in zip(self.lay.interfaces, self.emu_ifaces):
                if not Path(f"/sys/class/net/{emu_if}").exists():
                    raise Failed(f"{emu_if} is missing: scripts/hil/guest_init.sh creates vcan0..vcan3")
                # firmware -> motors: everything; motors -> firmware: what motors and the IMU send
                # (replies 0x100-0x17F, IMU 0x080-0x083), so a test's command on the motor side stays
                # there. -e: echo the routed frames (needed on vcan); the hop limit (1) stops loops.
                rules = [(fw_if, emu_if, None), (emu_if, fw_if, "100:780"), (emu_if, fw_if, "080:7FC")]
                for src, dst, filt in rules:
                    argv = ["cangw", "-A", "-s", src, "-d", dst, "-e"] + (["-f", filt] if filt else [])
                    subprocess.run(argv, check=True, timeout=30)
        before = raw_receivers()
        # -r: an 8 MiB receive buffer (vcan has no flow control); -d: report drops in the log
        self.spawn("candump", ["candump", "-L", "-d", "-r", str(8 << 20), "any"], stdout=open(self.dump, "w"))
        wait_for(lambda: raw_receivers() > before, 30, "candump to bind its socket")

    def start_emu(self, report: Path, extra: list[str] = ()):
        ready = self.dir / "emu.ready"
        exe = self.bin / "g1-can-emu"
        if not exe.is_file():
            raise Failed(f"{exe} not found: build it (cargo build --release -p sim_hal --bins) or run via `cargo xtask hil`")
        self.emu = self.spawn("emu", [str(exe), "--can", ",".join(self.emu_ifaces), "--can-config", str(self.args.can_config),
                                      "--model", "g1-12dof", "--report", str(report), "--ready-file", str(ready),
                                      "--idle-timeout-s", "3", *extra])
        wait_for(lambda: ready.exists() or self.emu.poll() is not None, 180, "g1-can-emu to be ready")
        if self.emu.poll() is not None:
            raise Failed(f"g1-can-emu exited with {self.emu.returncode} before it was ready\n{self.tail('emu')}")

    def start_fw(self, duration: float, report: Path, cmd: str = "0,0,0", schedule: Path | None = None):
        exe = self.bin / "g1fw"
        self.fw_duration = duration
        # An operated run: passive at start, stepped by the schedule's requests.
        how = ["--operated", "--cmd-schedule", str(schedule)] if schedule else ["--cmd", cmd]
        self.fw = self.spawn("fw", [str(exe), "run", "--can", ",".join(self.lay.interfaces), "--can-config",
                                    str(self.args.can_config), "--spec", str(self.args.spec), "--duration", str(duration),
                                    *how, "--report", str(report), "--startup-timeout", "120"])

    def wait_fw(self) -> int:
        timeout = 120 + self.fw_duration * 500 / ticks_per_s_floor()
        try:
            return self.fw.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise Failed(f"g1fw did not finish within {timeout:.0f} s (HIL_MIN_TICKS_PER_S={ticks_per_s_floor()})\n{self.tail('fw')}")

    def finish(self) -> Recording:
        try:
            self.emu.wait(timeout=60)
        except subprocess.TimeoutExpired:
            raise Failed(f"g1-can-emu did not exit within 60 s of the firmware\n{self.tail('emu')}")
        time.sleep(0.2)
        for name, p in self.procs:
            if name == "candump" and p.poll() is None:
                p.send_signal(signal.SIGINT)
                p.wait(timeout=10)
        frames, notes = parse_candump(self.dump, self.lay.interfaces, self.emu_ifaces if self.gateway else [])
        return segment(frames, notes, self.lay)


def wait_for(pred, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise Failed(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.05)


def load_json(path: Path, who: str) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise Failed(f"{who} wrote no readable report {path}: {e}")


def imu_waiter(lay: Layout):
    import can

    return can.Bus(interface="socketcan", channel=lay.interfaces[lay.imu_bus],
                   can_filters=[{"can_id": IMU_ACCEL, "can_mask": 0x7FF, "extended": False}])


def wait_imu_samples(bus, n: int, fw: subprocess.Popen, timeout: float) -> int:
    """Counts accelerometer frames (each closes an IMU sample) until n; returns the last sequence."""
    deadline = time.monotonic() + timeout
    got, seq = 0, -1
    while got < n:
        if time.monotonic() > deadline:
            raise Failed(f"saw only {got} of {n} IMU samples in {timeout:.0f} s")
        if fw.poll() is not None:
            raise Failed(f"g1fw exited ({fw.returncode}) after {got} IMU samples, before the injection")
        m = bus.recv(timeout=0.5)
        if m is not None:
            got += 1
            seq = struct.unpack(">H", bytes(m.data[6:8]))[0]
    return seq


# ------------------------------------------------------------------------------------------------
# The runs
# ------------------------------------------------------------------------------------------------


def run_walk(args, lay, gains, ranges, out) -> list[Check]:
    t0 = time.monotonic()
    with Run("walk", out, lay, args) as r:
        r.start_sniffer()
        r.start_emu(r.dir / "emu.json")
        r.start_fw(args.walk_s, r.dir / "fw.json", cmd=args.walk_cmd)
        rc = r.wait_fw()
        rec = r.finish()
        wall = time.monotonic() - t0
        emu = load_json(r.dir / "emu.json", "g1-can-emu")
        fw = load_json(r.dir / "fw.json", "g1fw")
    checks = check_layout(rec, lay, gains, ranges, fw_ticks=int(fw.get("ticks", 0)))
    for c in checks:
        c.name = "walk/layout: " + c.name
    mode = str(fw.get("final_mode", ""))
    trip = fw.get("trip")
    # No fall while the policy ran; the end's damping lets the robot sink afterwards.
    fell_at = emu.get("fell_at_s")
    fell = fell_at is not None and fell_at < float(fw.get("time_s", 0.0))
    end_damping = fw.get("end_damping") or {}
    ok = (not fell and mode.lower().startswith("policy") and trip is None and rc == 0
          and end_damping.get("sent", 0) >= 1 and end_damping.get("failed", 1) == 0)
    n = len(rec.ticks)
    checks.append(Check(
        f"walk {args.walk_s:g} s at --cmd {args.walk_cmd}: no fall under the policy, no trip, damping after the end", ok,
        f"fell under the policy {fell} (emulator fell_at_s {fell_at}), end damping {end_damping}, "
        f"base_z_min {emu.get('base_z_min')}, distance_x {emu.get('distance_x_m')}, "
        f"final_mode {mode!r}, trip {trip}, g1fw exit {rc}; {n} IMU samples, {n / wall:.0f} ticks/s wall",
        wall_s=wall, reason=(trip or {}).get("reason", "") if isinstance(trip, dict) else ""))
    return checks


OPERATED_SCHEDULE = "0.5 stand_up\n1.2 walk\n1.22 0.4 0 0\n4.0 0 0 0\n4.8 stand\n5.45 sit_down\n"
# (to, source, tick) of each change of state the schedule makes (ramp 0.5 s + hold 0.1 s, sit 0.5 s).
OPERATED_CHANGES = [("startup", "schedule", 250), ("stand", "ramp", 550), ("policy", "schedule", 600),
                    ("startup", "schedule", 2400), ("stand", "ramp", 2700), ("sit_down", "schedule", 2725),
                    ("passive", "ramp", 2975)]


def run_operated(args, lay, out) -> list[Check]:
    """The operated state machine over vcan, as on the robot (`g1fw run --operated`): damping on
    the wire until the operator's stand-up, then driven, walking, standing, sitting down and
    damping again from the end of the sit-down ramp; the report names every change."""
    t0 = time.monotonic()
    with Run("operated", out, lay, args) as r:
        schedule = r.dir / "ops.txt"
        schedule.write_text(OPERATED_SCHEDULE)
        r.start_sniffer()
        r.start_emu(r.dir / "emu.json")
        r.start_fw(6.0, r.dir / "fw.json", schedule=schedule)
        rc = r.wait_fw()
        rec = r.finish()
        wall = time.monotonic() - t0
        fw = load_json(r.dir / "fw.json", "g1fw")
        emu = load_json(r.dir / "emu.json", "g1-can-emu")
    problems = []
    changes = [(c.get("to"), c.get("source"), c.get("tick")) for c in fw.get("transitions", [])]
    if changes != [tuple(c) for c in OPERATED_CHANGES]:
        problems.append(f"report transitions {changes}, expected {OPERATED_CHANGES}")
    if fw.get("trip") is not None or rc != 0 or str(fw.get("final_mode")) != "Passive":
        problems.append(f"trip {fw.get('trip')}, final_mode {fw.get('final_mode')}, g1fw exit {rc}")
    # On the wire (decoded here): every command damping while passive, none while driven.
    stand_up, passive = OPERATED_CHANGES[0][2], OPERATED_CHANGES[-1][2]
    wrong = []
    for t in rec.ticks:
        want_damped = t.k < stand_up or t.k >= passive
        for fr, m in motor_commands(t):
            if damped(fr) != want_damped:
                wrong.append((t.k, G1_SLOTS[m.slot], command_fields(fr.data)[2:4]))
    if wrong:
        problems.append(f"{len(wrong)} commands on the wire not as the state asks, first {wrong[:3]}")
    fell_at = emu.get("fell_at_s")
    if fell_at is not None and fell_at < passive * 0.002:
        problems.append(f"the robot fell at {fell_at} s, before the run was passive")
    detail = "; ".join(problems) if problems else (
        f"{len(changes)} changes as scheduled; damping on the wire before tick {stand_up} and from tick {passive}, "
        f"driven between; distance_x {emu.get('distance_x_m')}; g1fw exit {rc}")
    return [Check("operated: passive, stand-up, walk, stand, sit-down over CAN", not problems, detail, wall_s=wall)]


@dataclass
class Fault:
    name: str
    what: str
    expect: str  # the trip reason docs/can.md names
    inject: callable  # (can module, buses by index, layout) -> None
    is_injected: callable  # Frame -> bool: recognises the injected frames in the recording
    gateway: bool = False  # inject on the emulator's side of a can-gw gateway (the firmware does not see it)


def fault_list(lay: Layout) -> list[Fault]:
    def motor(bus, slot_name):
        for m in lay.motors:
            if m.bus == bus and G1_SLOTS[m.slot] == slot_name:
                return m
        return [m for m in lay.motors if m.bus == bus][0]

    knee0 = motor(0, "left_knee")
    hip1 = motor(1, "right_hip_yaw")
    knee1 = motor(1, "right_knee")
    configured = {m.id for m in lay.motors}
    foreign_node = next(i for i in range(0x42, 0x80) if i not in configured)
    flood_n = int(os.environ.get("HIL_FLOOD_FRAMES", "5000"))

    def send(can, bus, can_id, data):
        bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    def flood(can, buses, lay):
        b = buses[lay.imu_bus]
        sent, full = 0, 0
        for i in range(flood_n):
            msg = can.Message(arbitration_id=0x200 + (i & 0xFF), data=i.to_bytes(4, "big") * 2, is_extended_id=False)
            while True:
                try:
                    b.send(msg)
                    sent += 1
                    break
                except can.CanOperationError:  # ENOBUFS: the queue is full, try again
                    full += 1
                    if full > 100_000:
                        raise Failed(f"flood: the bus stayed full after {sent} frames")
        return f"{sent} frames 0x200-0x2FF on {lay.interfaces[lay.imu_bus]}"

    return [
        Fault("dlc3", f"reply 0x{0x100 + knee0.id:03X} (left_knee) with DLC 3 on {lay.interfaces[0]}", "malformed_frame",
              lambda can, buses, lay: send(can, buses[0], 0x100 + knee0.id, bytes([knee0.id, 0x80, 0x00])),
              lambda fr: fr.bus == 0 and fr.id == 0x100 + knee0.id and len(fr.data) == 3),
        Fault("bad_byte0", f"reply 0x{0x100 + hip1.id:03X} (right_hip_yaw) with byte 0 = 0x{hip1.id + 2:02X} on {lay.interfaces[1]}",
              "malformed_frame",
              lambda can, buses, lay: send(can, buses[1], 0x100 + hip1.id, bytes([hip1.id + 2, 0x80, 0x00, 0x80, 0x08, 0x00])),
              lambda fr: fr.bus == 1 and fr.id == 0x100 + hip1.id and len(fr.data) == 6 and fr.data[0] != hip1.id),
        Fault("foreign_id", f"reply from unconfigured node 0x{foreign_node:02X} (id 0x{0x100 + foreign_node:03X}) on {lay.interfaces[0]}",
              "malformed_frame",
              lambda can, buses, lay: send(can, buses[0], 0x100 + foreign_node, bytes([foreign_node, 0x80, 0x00, 0x80, 0x08, 0x00])),
              lambda fr: fr.id == 0x100 + foreign_node),
        Fault("flood", f"{flood_n} foreign frames as fast as python-can sends them on the IMU bus", "malformed_frame",
              flood, lambda fr: 0x200 <= fr.id <= 0x2FF),
        # The motor drops out: *exit motor mode* reaches it through a gateway the firmware is behind,
        # so the firmware sees only the silence.
        Fault("silent", f"exit motor mode to bus 1 node {knee1.id} (right_knee) on the motor side of a gateway; "
              "it goes silent", "motor_silent",
              lambda can, buses, lay: send(can, buses[1], knee1.id, EXIT),
              lambda fr: fr.motor_side and fr.bus == 1 and fr.id == knee1.id and fr.data == EXIT, gateway=True),
        # The same frame on the firmware's own bus: a command id from someone else is a second master.
        Fault("second_master", f"exit motor mode to {lay.interfaces[1]} node {knee1.id} (right_knee) on the "
              "firmware's bus: a second master", "malformed_frame",
              lambda can, buses, lay: send(can, buses[1], knee1.id, EXIT),
              lambda fr: fr.bus == 1 and fr.id == knee1.id and fr.data == EXIT),
    ]


def run_fault(f: Fault, args, lay, out) -> Check:
    import can

    t0 = time.monotonic()
    with Run(f.name, out, lay, args, gateway=f.gateway) as r:
        r.start_sniffer()
        r.start_emu(r.dir / "emu.json")
        waiter = imu_waiter(lay)
        # senders only: a filter nobody matches keeps their receive queues empty
        buses = [can.Bus(interface="socketcan", channel=i, can_filters=[{"can_id": 0x7FF, "can_mask": 0x7FF, "extended": False}])
                 for i in r.emu_ifaces]
        try:
            r.start_fw(args.fault_s, r.dir / "fw.json", cmd=args.walk_cmd)
            seq = wait_imu_samples(waiter, args.inject_after, r.fw, timeout=120 + args.inject_after / ticks_per_s_floor())
            note = f.inject(can, buses, lay)
        finally:
            waiter.shutdown()
            for b in buses:
                b.shutdown()
        rc = r.wait_fw()
        rec = r.finish()
        wall = time.monotonic() - t0
        fw = load_json(r.dir / "fw.json", "g1fw")
        emu = load_json(r.dir / "emu.json", "g1-can-emu")

    injected = [fr for fr in rec.frames if f.is_injected(fr)]
    if not injected:
        return Check(f"fault {f.name}: {f.what}", False, "the injected frame is not in the recording", wall_s=wall)
    k_inj = rec.tick_of(injected[0].n)
    trip = fw.get("trip")
    mode = str(fw.get("final_mode", ""))
    reason = trip.get("reason", "") if isinstance(trip, dict) else ""
    trip_tick = trip.get("tick") if isinstance(trip, dict) else None
    problems = []
    if not mode.lower().startswith("damping"):
        problems.append(f"final_mode {mode!r}, not damping")
    if trip_tick is None:
        problems.append("no trip in the firmware report")
    elif trip_tick < k_inj:
        problems.append(f"tripped at tick {trip_tick}, before the injection at tick {k_inj}")
    if reason.split(" ")[0] != f.expect:
        problems.append(f"trip reason {reason!r}, docs/can.md says {f.expect}")
    ok_bus, bus_detail, first_damped = damping_after(rec, trip_tick if trip_tick is not None else k_inj, k_inj, lay)
    if not ok_bus:
        problems.append("bus: " + bus_detail)
    extra = []
    if f.name in ("silent", "second_master"):
        ex = injected[0]
        late = [fr for fr in rec.frames
                if fr.n > ex.n and fr.bus == ex.bus and fr.id == 0x100 + ex.id and fr.motor_side == ex.motor_side]
        # docs/can.md: every special frame in motor mode is answered once; after exit the motor is silent
        if len(late) > 1:
            problems.append(f"the motor answered {len(late)} times after exit motor mode (docs: once, then silent)")
        extra.append(f"{len(late)} reply after exit motor mode")
    if f.name == "silent":
        if trip_tick is not None:
            extra.append(f"silent for {trip_tick - k_inj} ticks before the trip (motor_timeout_ticks {lay.motor_timeout_ticks})")
    if f.name == "flood":
        extra.append(f"{len(injected)} of the flood frames recorded")
    ttd = (first_damped - k_inj) if first_damped is not None else None
    return Check(
        f"fault {f.name}: {f.what}", not problems,
        "; ".join(problems) if problems else
        f"injected at tick {k_inj} (IMU seq {seq} seen), trip at tick {trip_tick}: {reason}; {bus_detail}"
        + ("; " + "; ".join(extra) if extra else "") + f"; g1fw exit {rc}, emulator fell {emu.get('fell')}",
        ticks_to_damping=ttd, wall_s=wall, reason=reason)


def run_imu_off(args, lay, out) -> list[Check]:
    """The IMU stops (g1-can-emu --imu-off) while the motors keep answering: the firmware's tick
    never comes again, so after tick_timeout_ms it damps every motor once and ends (docs/can.md)."""
    off_s = args.inject_after * 0.002
    t0 = time.monotonic()
    with Run("imu_off", out, lay, args) as r:
        r.start_sniffer()
        r.start_emu(r.dir / "emu.json", extra=["--imu-off", f"{off_s}"])
        r.start_fw(args.fault_s, r.dir / "fw.json", cmd=args.walk_cmd)
        rc = r.wait_fw()
        rec = r.finish()
        wall = time.monotonic() - t0
        fw = load_json(r.dir / "fw.json", "g1fw")
    name = f"fault imu_off: the IMU loses power after sample {args.inject_after}, the motors keep answering"
    problems = []
    last_sample = rec.ticks[-1].k if rec.ticks else None
    if last_sample != args.inject_after:
        problems.append(f"the last IMU sample on the bus is {last_sample}, expected {args.inject_after}")
    trip = fw.get("trip") if isinstance(fw.get("trip"), dict) else {}
    if trip.get("reason") != "hal_fault" or trip.get("tick") != args.inject_after + 1:
        problems.append(f"trip {trip or None}, docs/can.md says hal_fault at the tick that never came "
                        f"({args.inject_after + 1})")
    end = str(fw.get("end", ""))
    if "HAL failure" not in end or "the IMU stopped" not in end:
        problems.append(f"report end {end!r} does not say the IMU stopped")
    if rc != 3:
        problems.append(f"g1fw exit {rc}, expected 3 (a trip)")
    # On the wire, after the last IMU sample: that sample's tick, one damping command per motor at
    # once, then the end's damping rounds (--end-damping, docs/robot.md), every one a damping command.
    cmds = motor_commands(rec.ticks[-1]) if rec.ticks else []
    n = len(lay.motors)
    rounds = int((fw.get("end_damping") or {}).get("sent", 0))
    last = cmds[n:]
    slots = sorted(m.slot for _, m in last[:n])
    if len(cmds) != (2 + rounds) * n:
        problems.append(f"{len(cmds)} commands after the last IMU sample, expected {(2 + rounds) * n} "
                        f"(that sample's tick, one damping command per motor, then {rounds} end-damping rounds)")
    elif rounds < 1:
        problems.append("no damping after the end (report end_damping.sent is 0)")
    elif slots != sorted(m.slot for m in lay.motors) or not all(damped(fr) for fr, _ in last):
        problems.append(f"the commands after that tick are not all damping: "
                        f"{[(G1_SLOTS[m.slot], command_fields(fr.data)[2:4]) for fr, m in last[:n]]}")
    detail = "; ".join(problems) if problems else (
        f"last IMU sample {last_sample}; trip {trip.get('reason')} at tick {trip.get('tick')}; then "
        f"{len(last)} damping commands (kp 0, kd > 0), one per motor; g1fw exit {rc}: {end}")
    return [Check(name, not problems, detail, wall_s=wall, reason=trip.get("reason", ""))]


# ------------------------------------------------------------------------------------------------


def print_table(checks: list[Check]):
    w = max(len(c.name) for c in checks)
    w = min(w, 100)
    print(f"\n{'check':<{w}}  result  ticks to damping  wall s")
    print("-" * (w + 34))
    for c in checks:
        ttd = "" if c.ticks_to_damping is None else str(c.ticks_to_damping)
        wall = "" if c.wall_s is None else f"{c.wall_s:.1f}"
        print(f"{c.name[:w]:<{w}}  {'PASS' if c.ok else 'FAIL':<6}  {ttd:>16}  {wall:>6}")
    print()
    for c in checks:
        if c.detail:
            print(f"{'ok  ' if c.ok else 'FAIL'} {c.name}: {c.detail}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--self-test", action="store_true", help="only the codec self-test (no CAN needed)")
    ap.add_argument("--only", default=os.environ.get("HIL_PEER_ONLY", ""),
                    help="comma-separated runs: walk,operated,dlc3,bad_byte0,foreign_id,flood,silent,second_master,imu_off "
                         "(default: all)")
    ap.add_argument("--can-config", type=Path, default=REPO / "specs/can/g1_12dof.toml")
    ap.add_argument("--spec", type=Path, default=REPO / "specs/peer/unitree_g1_lstm.toml")
    ap.add_argument("--walk-s", type=float, default=float(os.environ.get("HIL_WALK_S", "11")),
                    help="g1fw --duration of the walk (incl. the 0.6 s start-up ramp and hold)")
    ap.add_argument("--walk-cmd", default="0.5,0,0")
    ap.add_argument("--fault-s", type=float, default=2.5, help="g1fw --duration of each fault run")
    ap.add_argument("--inject-after", type=int, default=500,
                    help="IMU samples before a fault is injected (the policy engages at 0.6 s = 300)")
    ap.add_argument("--tick-timeout-ms", type=int, default=int(os.environ.get("HIL_TICK_TIMEOUT_MS", "2000")),
                    help="the layout's wall-clock tick_timeout_ms for these runs (the VM stalls for 0.5 s at times)")
    ap.add_argument("--out", type=Path, default=Path(os.environ.get("HIL_DIR", "/tmp")) / "peer")
    args = ap.parse_args()

    t0 = time.monotonic()
    done = self_test()
    print(f"[peer] codec self-test: {len(done)} checks passed (frames computed by hand from docs/can.md)")
    if args.self_test:
        return 0

    if not Path("/sys/class/net/vcan0").exists():
        print("[peer] FAIL: no vcan0 here. The peer test runs inside the HIL VM: `cargo xtask hil`", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    args.can_config = vm_can_config(args.can_config, args.out, args.tick_timeout_ms)
    lay = Layout.load(args.can_config)
    lay.interfaces = [f"vcan{i}" for i in range(len(lay.interfaces))]
    gains = Gains.load(args.spec, lay)
    ranges = joint_ranges(args.spec)
    faults = fault_list(lay)
    names = ["walk", "operated"] + [f.name for f in faults] + ["imu_off"]
    only = [s for s in args.only.split(",") if s]
    unknown = [s for s in only if s not in names]
    if unknown:
        print(f"[peer] FAIL: unknown run(s) {unknown}; known: {names}", file=sys.stderr)
        return 2
    selected = only or names
    if only:
        print(f"[peer] NOTE: running only {selected} (--only / HIL_PEER_ONLY); the rest is NOT tested")

    checks = [Check(f"codec self-test ({len(done)} hand-computed frames and properties)", True)]
    for name in selected:
        t = time.monotonic()
        print(f"[peer] run {name} ...", flush=True)
        try:
            if name == "walk":
                res = run_walk(args, lay, gains, ranges, args.out)
            elif name == "operated":
                res = run_operated(args, lay, args.out)
            elif name == "imu_off":
                res = run_imu_off(args, lay, args.out)
            else:
                res = [run_fault(next(f for f in faults if f.name == name), args, lay, args.out)]
        except Failed as e:
            res = [Check(f"{name}", False, str(e), wall_s=time.monotonic() - t)]
        for c in res:
            print(f"[peer]   {'ok  ' if c.ok else 'FAIL'} {c.name}" + (f" ({c.detail})" if not c.ok else ""), flush=True)
        print(f"[peer] run {name}: {time.monotonic() - t:.1f} s", flush=True)
        checks += res

    print_table(checks)
    (args.out / "results.json").write_text(json.dumps([c.__dict__ for c in checks], indent=1))
    failed = [c for c in checks if not c.ok]
    print(f"[peer] {len(checks) - len(failed)} of {len(checks)} checks passed in {time.monotonic() - t0:.1f} s"
          f"; recordings and logs in {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
