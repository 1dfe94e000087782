"""Writes a ROS 1 bag (dvs_msgs/EventArray on /dvs/events, geometry_msgs/PoseStamped on
/optitrack/pose) from a dataset folder, to try the real-data walkthrough without a recording:

    python docs/make_bag.py DATASET_DIR OUT.bag
"""

import sys
from pathlib import Path

from rosbags.rosbag1 import Writer

from evsplat.data.event_files import read_events
from evsplat.data.formats.rosbag import typestore
from evsplat.data.poses import matrix_to_quat, read_tum

EVENTS_PER_MESSAGE = 5000  # about what rpg_dvs_ros publishes

store = typestore(ros1=True)
T = store.types


def stamp(us: int):
    return T["builtin_interfaces/msg/Time"](sec=int(us) // 10**6, nanosec=int(us) % 10**6 * 1000)


def header(us: int, frame: str):
    return T["std_msgs/msg/Header"](seq=0, stamp=stamp(us), frame_id=frame)


ev = read_events(Path(sys.argv[1]) / "events.h5")  # a tiny dataset's events, whole
with Writer(sys.argv[2]) as bag:
    conn = bag.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
    for s in range(0, len(ev), EVENTS_PER_MESSAGE):
        e = ev.slice(s, min(s + EVENTS_PER_MESSAGE, len(ev)))
        events = [
            T["dvs_msgs/msg/Event"](x=int(x), y=int(y), ts=stamp(t), polarity=bool(p > 0))
            for x, y, t, p in zip(e.x, e.y, e.t, e.p)
        ]
        msg = T["dvs_msgs/msg/EventArray"](
            header=header(e.t[-1], "dvs"), height=ev.height, width=ev.width, events=events
        )
        bag.write(conn, int(e.t[-1]) * 1000, store.serialize_ros1(msg, "dvs_msgs/msg/EventArray"))
    pose_type = "geometry_msgs/msg/PoseStamped"
    pconn = bag.add_connection("/optitrack/pose", pose_type, typestore=store)
    for t, m in zip(*read_tum(f"{sys.argv[1]}/poses.txt")):
        q = matrix_to_quat(m[:3, :3])
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=m[0, 3], y=m[1, 3], z=m[2, 3]),
            orientation=T["geometry_msgs/msg/Quaternion"](w=q[0], x=q[1], y=q[2], z=q[3]),
        )
        msg = T[pose_type](header=header(t, "world"), pose=pose)
        bag.write(pconn, int(t) * 1000, store.serialize_ros1(msg, pose_type))
