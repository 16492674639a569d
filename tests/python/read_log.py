#!/usr/bin/env python3
"""Independent reader for g1fw MCAP logs (the `mcap` and `mcap-ros2-support` packages, not our
Rust code). Prints one JSON object: messages per topic, tick range, decoded samples, whether the
file ended early. Works on crash-truncated files: it streams records and stops at the damage.

Usage: read_log.py LOG.mcap
"""
import json
import sys

from mcap.reader import NonSeekingReader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory


def main(path):
    out = {"topics": {}, "metadata": {}, "low_state_ticks": [], "truncated": None,
           "low_state_sample": None, "low_cmd_sample": None, "safety_events": [], "json_ok": True}
    ros2 = Ros2DecoderFactory()
    decoders = {}
    with open(path, "rb") as f:
        reader = NonSeekingReader(f)
        try:
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                t = channel.topic
                out["topics"][t] = out["topics"].get(t, 0) + 1
                if channel.message_encoding == "cdr":
                    dec = decoders.get(channel.id)
                    if dec is None:
                        dec = decoders[channel.id] = ros2.decoder_for("cdr", schema)
                    msg = dec(message.data)
                    if t == "/hal/low_state":
                        out["low_state_ticks"].append(msg.tick)
                        if out["low_state_sample"] is None:
                            out["low_state_sample"] = {"tick": msg.tick, "time_ns": msg.time_ns,
                                                       "status": msg.status, "received": msg.received,
                                                       "len": len(msg.data)}
                    elif t == "/hal/low_cmd" and out["low_cmd_sample"] is None:
                        out["low_cmd_sample"] = {"tick": msg.tick, "sent": msg.sent, "len": len(msg.data)}
                elif channel.message_encoding == "json":
                    try:
                        obj = json.loads(message.data)
                    except ValueError:
                        out["json_ok"] = False
                        continue
                    if t == "/safety/event":
                        out["safety_events"].append(obj)
                    if schema is None or schema.encoding != "jsonschema":
                        out["json_ok"] = False
        except Exception as e:  # truncated or damaged tail: report, keep what was read
            out["truncated"] = f"{type(e).__name__}: {e}"
    # Metadata: a second pass over records (the run metadata is written before any chunk).
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:
                if type(record).__name__ == "Metadata":
                    out["metadata"][record.name] = sorted(record.metadata.keys())
                if type(record).__name__ == "Chunk":
                    break
        except Exception:
            pass
    ticks = out.pop("low_state_ticks")
    out["ticks"] = len(ticks)
    out["first_tick"] = ticks[0] if ticks else None
    out["last_tick"] = ticks[-1] if ticks else None
    out["contiguous"] = all(b == a + 1 for a, b in zip(ticks, ticks[1:]))
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
