"""Independent peer for the unitree_hg DDS samples: CycloneDDS's own serializer (cyclonedds.idl,
pure Python, not this project's code) with this file's own copy of the IDL, and Unitree's CRC as
unitree_sdk2py computes it (over the C memory layout, packed with struct).

  hg_cdr_peer.py check-cmd FILE       read a LowCmd_ CDR sample; print its fields and whether the
                                      CRC matches the C layout (JSON)
  hg_cdr_peer.py make-state SEED FILE write a LowState_ CDR sample with seeded values and a valid CRC;
                                      print its fields (JSON)
"""
import json
import random
import struct
import sys
from dataclasses import dataclass

import cyclonedds.idl.types as t
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import final


@dataclass
@final
class MotorCmd_(IdlStruct, typename="unitree_hg.msg.dds_.MotorCmd_"):
    mode: t.uint8
    q: t.float32
    dq: t.float32
    tau: t.float32
    kp: t.float32
    kd: t.float32
    reserve: t.uint32


@dataclass
@final
class LowCmd_(IdlStruct, typename="unitree_hg.msg.dds_.LowCmd_"):
    mode_pr: t.uint8
    mode_machine: t.uint8
    motor_cmd: t.array[MotorCmd_, 35]
    reserve: t.array[t.uint32, 4]
    crc: t.uint32


@dataclass
@final
class IMUState_(IdlStruct, typename="unitree_hg.msg.dds_.IMUState_"):
    quaternion: t.array[t.float32, 4]
    gyroscope: t.array[t.float32, 3]
    accelerometer: t.array[t.float32, 3]
    rpy: t.array[t.float32, 3]
    temperature: t.int16


@dataclass
@final
class MotorState_(IdlStruct, typename="unitree_hg.msg.dds_.MotorState_"):
    mode: t.uint8
    q: t.float32
    dq: t.float32
    ddq: t.float32
    tau_est: t.float32
    temperature: t.array[t.int16, 2]
    vol: t.float32
    sensor: t.array[t.uint32, 2]
    motorstate: t.uint32
    reserve: t.array[t.uint32, 4]


@dataclass
@final
class LowState_(IdlStruct, typename="unitree_hg.msg.dds_.LowState_"):
    version: t.array[t.uint32, 2]
    mode_pr: t.uint8
    mode_machine: t.uint8
    tick: t.uint32
    imu_state: IMUState_
    motor_state: t.array[MotorState_, 35]
    wireless_remote: t.array[t.uint8, 40]
    reserve: t.array[t.uint32, 4]
    crc: t.uint32


def crc32_core(words):
    """unitree_sdk2py/utils/crc.py: MSB-first, poly 0x04C11DB7, init 0xFFFFFFFF, no final xor."""
    crc = 0xFFFFFFFF
    poly = 0x04C11DB7
    for data in words:
        xbit = 1 << 31
        for _ in range(32):
            if crc & 0x80000000:
                crc = ((crc << 1) & 0xFFFFFFFF) ^ poly
            else:
                crc = (crc << 1) & 0xFFFFFFFF
            if data & xbit:
                crc ^= poly
            xbit >>= 1
    return crc


def crc_of(c_bytes):
    words = struct.unpack("<%dI" % (len(c_bytes) // 4), c_bytes)
    return crc32_core(words[:-1])


def pack_cmd(c):
    out = struct.pack("<2B2x", c.mode_pr, c.mode_machine)
    for m in c.motor_cmd:
        out += struct.pack("<B3x5fI", m.mode, m.q, m.dq, m.tau, m.kp, m.kd, m.reserve)
    return out + struct.pack("<5I", *c.reserve, c.crc)


def pack_state(s):
    i = s.imu_state
    out = struct.pack("<2I2B2xI", *s.version, s.mode_pr, s.mode_machine, s.tick)
    out += struct.pack("<13fh2x", *i.quaternion, *i.gyroscope, *i.accelerometer, *i.rpy, i.temperature)
    for m in s.motor_state:
        out += struct.pack("<B3x4f2hf2I5I", m.mode, m.q, m.dq, m.ddq, m.tau_est, *m.temperature, m.vol,
                           *m.sensor, m.motorstate, *m.reserve)
    return out + struct.pack("<40B5I", *s.wireless_remote, *s.reserve, s.crc)


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def main():
    if sys.argv[1] == "check-cmd":
        data = open(sys.argv[2], "rb").read()
        c = LowCmd_.deserialize(data)
        c_bytes = pack_cmd(c)
        assert len(c_bytes) == 1004, len(c_bytes)
        print(json.dumps({
            "header": data[:4].hex(),
            "len": len(data),
            "mode_pr": c.mode_pr,
            "mode_machine": c.mode_machine,
            "motors": [[m.mode, m.q, m.dq, m.tau, m.kp, m.kd] for m in c.motor_cmd],
            "crc": c.crc,
            "crc_ok": crc_of(c_bytes) == c.crc,
        }))
    elif sys.argv[1] == "make-state":
        rng = random.Random(int(sys.argv[2]))
        u = lambda a, b: f32(rng.uniform(a, b))
        s = LowState_(
            version=[1, 2], mode_pr=0, mode_machine=rng.randrange(1, 7), tick=rng.randrange(2**32),
            imu_state=IMUState_([u(-1, 1) for _ in range(4)], [u(-3, 3) for _ in range(3)],
                                [u(-20, 20) for _ in range(3)], [u(-3, 3) for _ in range(3)],
                                rng.randrange(-100, 100)),
            motor_state=[MotorState_(rng.randrange(2), u(-3, 3), u(-20, 20), u(-100, 100), u(-50, 50),
                                     [rng.randrange(20, 90), rng.randrange(20, 90)], u(20, 30),
                                     [rng.randrange(2**32), rng.randrange(2**32)], rng.randrange(2**32),
                                     [0, 0, 0, 0]) for _ in range(35)],
            wireless_remote=[rng.randrange(256) for _ in range(40)], reserve=[0, 0, 0, 0], crc=0)
        s.crc = crc_of(pack_state(s))
        data = s.serialize()
        open(sys.argv[3], "wb").write(data)
        print(json.dumps({
            "len": len(data),
            "mode_machine": s.mode_machine,
            "tick": s.tick,
            "quaternion": s.imu_state.quaternion,
            "gyroscope": s.imu_state.gyroscope,
            "imu_temperature": s.imu_state.temperature,
            "motors": [[m.mode, m.q, m.dq, m.tau_est, m.temperature[0], m.temperature[1]] for m in s.motor_state],
            "wireless_remote": s.wireless_remote,
            "crc": s.crc,
        }))
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
