"""Writers of small ROS bags for the tests, with rosbags' own writers: a log table (t, q1, q2, tau1, tau2
of tests/_bad_inputs.py) as sensor_msgs/JointState messages of a ROS 1 bag (.bag), a ROS 2 bag folder
(sqlite3 or mcap storage) or one .mcap file."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

JOINT_STATE = "sensor_msgs/msg/JointState"
EPOCH_NS = 1_764_000_000_000_000_000  # header stamps are wall-clock times: 2025-11-24 in ns
JOINTS = ("shoulder", "slide")


def stamps_ns(t: np.ndarray) -> np.ndarray:
    """Header stamps of samples at ``t`` s (integer ns after EPOCH_NS)."""
    return EPOCH_NS + np.round(np.asarray(t) * 1e9).astype(np.int64)


class BagWriter:
    """One bag being written: ``kind`` "ros1" (a .bag file), "sqlite3" or "mcap" (a ROS 2 bag folder)."""

    def __init__(self, path: Path, kind: str) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.kind, self.path = kind, path
        self.store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
        if kind == "ros1":
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import Writer
            from rosbags.rosbag2.enums import StoragePlugin

            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=9, storage_plugin=plugin)
        self.writer.open()
        self.connections: dict[str, object] = {}

    def _serialize(self, msg, msgtype: str) -> bytes:
        if self.kind == "ros1":
            return self.store.serialize_ros1(msg, msgtype)
        return self.store.serialize_cdr(msg, msgtype)

    def connection(self, topic: str, msgtype: str = JOINT_STATE):
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        return self.connections[topic]

    def joint_state(self, topic: str, stamp_ns: int, names: Sequence[str], position=(), velocity=(), effort=(),
                    receive_ns: int | None = None) -> None:
        ty = self.store.types
        stamp = ty["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))
        header_type = ty["std_msgs/msg/Header"]
        fields = header_type.__dataclass_fields__
        header = header_type(**({"seq": 0} if "seq" in fields else {}), stamp=stamp, frame_id="")
        msg = ty[JOINT_STATE](header=header, name=list(names), position=np.asarray(position, dtype=float),
                              velocity=np.asarray(velocity, dtype=float), effort=np.asarray(effort, dtype=float))
        conn = self.connection(topic)
        self.writer.write(conn, int(stamp_ns if receive_ns is None else receive_ns), self._serialize(msg, JOINT_STATE))

    def float64(self, topic: str, stamp_ns: int, value: float) -> None:
        msgtype = "std_msgs/msg/Float64"
        conn = self.connection(topic, msgtype)
        self.writer.write(conn, int(stamp_ns), self._serialize(self.store.types[msgtype](data=float(value)), msgtype))

    def close(self) -> None:
        self.writer.close()


def write_table_bag(path: Path, kind: str, table: np.ndarray, *, effort_topic: str | None = None,
                    order: Callable[[int], Sequence[int]] = lambda k: (0, 1), extra_joint: bool = False,
                    latency_ns: int = 0, stamps: np.ndarray | None = None) -> Path:
    """``table`` (t, q1, q2, tau1, tau2) as JointState messages on /joint_states (efforts there too, or on
    ``effort_topic`` with the same stamps). ``order(k)``: the joint order of message k (names and values
    permuted alike); ``extra_joint``: every message also carries a gripper joint; ``latency_ns``: receive
    time = the sample's time + latency (whatever the stamp); ``stamps``: header stamps in ns (default :func:`stamps_ns` of t)."""
    w = BagWriter(path, kind)
    received = stamps_ns(table[:, 0])  # the recorder receives the messages in order
    stamps = received if stamps is None else stamps
    for k, row in enumerate(table):
        idx = list(order(k))
        names = [JOINTS[i] for i in idx] + (["gripper"] if extra_joint else [])
        q = [row[1 + i] for i in idx] + ([0.01 * k] if extra_joint else [])
        tau = [row[3 + i] for i in idx] + ([0.5] if extra_joint else [])
        recv = int(received[k]) + latency_ns
        if effort_topic is None:
            w.joint_state("/joint_states", int(stamps[k]), names, position=q, effort=tau, receive_ns=recv)
        else:
            w.joint_state("/joint_states", int(stamps[k]), names, position=q, receive_ns=recv)
            w.joint_state(effort_topic, int(stamps[k]), names, effort=tau, receive_ns=recv)
    w.close()
    return path
