"""Independent writer: a ROS 2-style bag written with the official Python `mcap` + `mcap-ros2-support` packages, the
way `ros2 bag record /joint_states` would store a real robot's log. stdin (JSON): {"path", "joint_state_schema",
"urdf", "messages": [{"t_ns", "name", "position", "velocity", "effort"}]}. /robot_description is written first."""
import json
import sys

from mcap_ros2.writer import Writer

STRING_SCHEMA = "string data\n"


def main() -> None:
    req = json.load(sys.stdin)
    with open(req["path"], "wb") as f:
        writer = Writer(f)
        js = writer.register_msgdef("sensor_msgs/msg/JointState", req["joint_state_schema"])
        text = writer.register_msgdef("std_msgs/msg/String", STRING_SCHEMA)
        first = req["messages"][0]["t_ns"]
        writer.write_message("/robot_description", text, {"data": req["urdf"]}, log_time=first, publish_time=first)
        for seq, m in enumerate(req["messages"]):
            t = m["t_ns"]
            msg = {
                "header": {"stamp": {"sec": t // 1_000_000_000, "nanosec": t % 1_000_000_000}, "frame_id": ""},
                "name": m["name"],
                "position": m["position"],
                "velocity": m["velocity"],
                "effort": m["effort"],
            }
            writer.write_message("/joint_states", js, msg, log_time=t, publish_time=t, sequence=seq)
        writer.finish()


if __name__ == "__main__":
    main()
