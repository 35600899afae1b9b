"""Independent reference: decodes a shard with the official MCAP readers (mcap + mcap-ros2-support) and prints a
JSON digest: header profile, per-topic counts and schemas, every joint-state sample, the URDF and the metadata."""
import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def main() -> None:
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        out = {
            "profile": header.profile,
            "library": header.library,
            "message_count": summary.statistics.message_count,
            "schemas": sorted((s.name, s.encoding) for s in summary.schemas.values()),
            "compression": sorted({c.compression for c in summary.chunk_indexes}),
            "joint_states": [],
            "robot_description": None,
            "metadata": {m.name: dict(m.metadata) for m in reader.iter_metadata()},
        }
        for schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=True):
            if channel.topic == "/joint_states":
                out["joint_states"].append({
                    "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                    "log_time": message.log_time,
                    "name": list(msg.name),
                    "position": list(msg.position),
                    "velocity": list(msg.velocity),
                    "effort": list(msg.effort),
                })
            elif channel.topic == "/robot_description":
                out["robot_description"] = msg.data
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
