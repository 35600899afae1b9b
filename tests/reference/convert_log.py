"""Independent reference: one ROS 2 bag (MCAP, as simulate_arm.py writes it) rewritten in the other forms real arms'
logs come in, message for message, by tools that are not dynforge's: a rosbag2 directory in sqlite3 storage (what
`ros2 bag record` writes on Humble), by the `rosbags` package, the CDR bytes as they are; and a table (CSV) of the
joint states, with motor currents instead of torques when gains are given, as RTDE or a lab logger writes them.

stdin (JSON):
  mcap     the bag read (its /joint_states and /robot_description); written instead, from the table, with "table"
  table    optional: {"path", "time": column, "joints": {name: [position, velocity, effort]}, "gains": {name: g}}
           (columns from 1, time in s, the effort times its gain): a headerless CSV read into joint states, which are
           written to "mcap" (by mcap_ros2) and to "db3"
  db3      optional: the rosbag2 directory to write
  csv      optional: the table to write: t [s], then per joint position, velocity (if logged), effort; a header row
  gains    optional: {joint: gain}: the table's effort column, and the db3 bag's effort, is effort / gain (a current)
  stale    optional: share of rows whose values are a stale copy of the row before (stamped at its own tick), as a
           logger stamping by its own thread writes them when the driver's sample has not changed yet
  skip     optional: share of rows left out (a missed tick)
  seed     of the rows chosen for stale and skip
stdout (JSON): {"rows": n, "stale": k, "skipped": k}.
"""
import json
import os
import sys

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def read(path):
    """The bag's messages: (topic, schema name, log time, raw CDR, decoded) in file order."""
    out = []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            out.append((channel.topic, schema.name, message.log_time, message.data, decoded))
    return out


def write_db3(messages, out, gains):
    """The messages as they are (their CDR bytes), or with gains, the joint states' efforts divided by them
    (deserialised and serialised again by rosbags' own CDR codec)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(out, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        connections = {}
        for topic, schema, time, data, _ in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, schema, typestore=store)
            if gains and topic == "/joint_states":
                msg = store.deserialize_cdr(data, schema)
                msg.effort = np.array([e / gains.get(n, 1.0) for n, e in zip(msg.name, msg.effort)])
                data = store.serialize_cdr(msg, schema)
            writer.write(connections[topic], time, data)


def write_csv(messages, req):
    rng = np.random.default_rng(req.get("seed", 0))
    states = [d for topic, _, _, _, d in messages if topic == "/joint_states"]
    names = list(states[0].name)
    gains = req.get("gains", {})
    header = ["t"]
    for n in names:
        header += [f"{n}.q"] + ([f"{n}.qd"] if len(states[0].velocity) else []) + [f"{n}.effort"]
    rows, stale, skipped = [], 0, 0
    for s in states:
        # From the first stamp in exact nanoseconds: 1.7e9 s as a double would round each time by ~1e-7 s.
        t = (s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec - 1_700_000_000_000_000_000) / 1e9
        row = [t]
        for k, n in enumerate(names):
            row += [s.position[k]] + ([s.velocity[k]] if len(s.velocity) else []) + [s.effort[k] / gains.get(n, 1.0)]
        if rows and rng.uniform() < req.get("skip", 0.0):
            skipped += 1
            continue
        if rows and rng.uniform() < req.get("stale", 0.0):
            stale += 1
            row = [t] + rows[-1][1:]
        rows.append(row)
    with open(req["csv"], "w") as f:
        f.write(",".join(header) + "\n")
        for row in rows:
            f.write(",".join(repr(float(v)) for v in row) + "\n")
    return len(rows), stale, skipped


def from_table(spec, mcap):
    """The table's rows as joint-state messages, written to the MCAP bag `mcap` by mcap_ros2's writer; the messages
    as `read` gives them."""
    import csv
    from mcap_ros2.writer import Writer as McapWriter

    names = list(spec["joints"])
    gains = spec.get("gains", {})
    definition = open(os.path.join(os.path.dirname(__file__), "..", "..", "proto", "src", "schemas",
                                   "sensor_msgs_JointState.ros2msg")).read()
    with open(mcap, "wb") as f:
        writer = McapWriter(f)
        schema = writer.register_msgdef("sensor_msgs/msg/JointState", definition)
        with open(spec["path"]) as table:
            for i, row in enumerate(csv.reader(table)):
                ns = round(float(row[spec["time"] - 1]) * 1e9)
                value = lambda c: float(row[c - 1])
                cols = [spec["joints"][n] for n in names]
                msg = {
                    "header": {"stamp": {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}, "frame_id": ""},
                    "name": names,
                    "position": [value(c[0]) for c in cols],
                    "velocity": [value(c[1]) for c in cols],
                    "effort": [value(c[2]) * gains.get(n, 1.0) for n, c in zip(names, cols)],
                }
                writer.write_message("/joint_states", schema, msg, log_time=ns, publish_time=ns, sequence=i)
        writer.finish()
    return read(mcap)


def main():
    req = json.load(sys.stdin)
    messages = from_table(req["table"], req["mcap"]) if req.get("table") else read(req["mcap"])
    result = {}
    if req.get("db3"):
        write_db3(messages, req["db3"], req.get("gains", {}))
    if req.get("csv"):
        result["rows"], result["stale"], result["skipped"] = write_csv(messages, req)
    json.dump(result, sys.stdout)


if __name__ == "__main__":
    main()
