"""Reader of ROS bags: ``sensor_msgs/JointState`` topics of ROS 1 bags (``.bag``) and ROS 2 bags
(a bag folder with ``metadata.yaml``, or one ``.db3`` / ``.mcap`` storage file), through the
pure-Python ``rosbags`` library (extra ``[ros]``).

A JointState message carries a ``name`` array and the ``position``, ``velocity`` and ``effort``
arrays in the same order; the order may differ from message to message and from bag to bag, so
values are always picked by joint name. Time is the message's ``header.stamp`` (the instant the
driver sampled the joints) or, when asked, the bag's receive time (when the recorder got the
message). Every problem is an :class:`~dynid.errors.InputError` with a one-line message.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError, MissingExtraError
from dynid.io.readers import missing_names, nearest_names

__all__ = ["BAG_SUFFIXES", "JOINT_STATE", "BagReader"]

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
JOINT_STATE = "sensor_msgs/msg/JointState"
FIELDS = ("position", "velocity", "effort")


class _Topic:
    """The JointState messages of one topic: stamps (ns) and, per message, name -> index."""

    def __init__(self, header_ns: np.ndarray, receive_ns: np.ndarray, names: list[tuple[str, ...]],
                 values: dict[str, list[np.ndarray]]) -> None:
        self.header_ns = header_ns
        self.receive_ns = receive_ns
        self.names = names
        self.values = values


class BagReader:
    """Lazy reader of one ROS bag; each topic is decoded once, on first use.

    Parameters
    ----------
    path : path
        A ROS 1 ``.bag`` file, a ROS 2 bag folder, or a ROS 2 ``.db3`` or ``.mcap`` file.
    """

    kind = "bag"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise InputError(f"ROS bag not found: {self.path}")
        if self.path.is_dir() and self.path.suffix.lower() in BAG_SUFFIXES:
            raise InputError(f"{self.path} is a folder named like a bag file ({self.path.suffix}); rosbags reads that name "
                             "as a file: rename the ROS 2 bag folder")
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise InputError(f"{self.path} is a folder without metadata.yaml, not a ROS 2 bag")
        if self.path.is_file() and self.path.suffix.lower() not in BAG_SUFFIXES:
            raise InputError(f"{self.path}: not a ROS bag (use .bag, a ROS 2 bag folder, .db3 or .mcap)")
        self._topics: dict[str, _Topic] = {}
        self._sha256: str | None = None

    # ------------------------------------------------------------------ loading
    def _open(self):
        try:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise MissingExtraError("reading ROS bags needs rosbags: pip install 'dynid[ros]'") from None
        ros1 = self.path.suffix.lower() == ".bag"
        store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        return AnyReader([self.path], default_typestore=store)

    def _fail(self, exc: BaseException) -> InputError:
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return InputError(f"cannot read ROS bag {self.path}: {text}")

    def _load(self, topic: str) -> _Topic:
        if topic in self._topics:
            return self._topics[topic]
        reader = self._open()
        try:
            with reader:
                connections = [c for c in reader.connections if c.topic == topic]
                if not connections:
                    have = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
                    if not have:
                        raise InputError(f"{self.path.name}: the bag holds no topics (an empty bag)")
                    near = nearest_names(topic, sorted({c.topic for c in reader.connections}))
                    raise InputError(f"{self.path}: no topic {topic!r}"
                                     + (f" (nearest: {', '.join(repr(x) for x in near)})" if near else "")
                                     + f"; the bag has {', '.join(have)}")
                types = sorted({c.msgtype for c in connections})
                if types != [JOINT_STATE]:
                    raise InputError(f"{self.path.name}: topic {topic!r} carries {', '.join(types)}; dynid reads "
                                     f"{JOINT_STATE} (name, position, velocity, effort)")
                header, receive, names = [], [], []
                values: dict[str, list[np.ndarray]] = {f: [] for f in FIELDS}
                for conn, t_receive, raw in reader.messages(connections=connections):
                    msg = reader.deserialize(raw, conn.msgtype)
                    stamp = msg.header.stamp
                    header.append(int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec))
                    receive.append(int(t_receive))
                    names.append(tuple(msg.name))
                    for f in FIELDS:
                        values[f].append(np.asarray(getattr(msg, f), dtype=float))
        except InputError:
            raise
        except MissingExtraError:
            raise
        except Exception as exc:  # rosbags raises its own errors, OSError, KeyError, struct errors ...
            raise self._fail(exc) from None
        if not header:
            raise InputError(f"{self.path.name}: topic {topic!r} has no messages")
        out = _Topic(np.array(header, dtype=np.int64), np.array(receive, dtype=np.int64), names, values)
        self._topics[topic] = out
        return out

    # ------------------------------------------------------------------ access
    def stamps(self, topic: str, source: str) -> np.ndarray:
        """The messages' time in ns: ``source`` ``"header"`` (header.stamp) or ``"receive"`` (bag time)."""
        tp = self._load(topic)
        return tp.header_ns if source == "header" else tp.receive_ns

    def joints(self, topic: str, field: str, joints: Sequence[str]) -> FloatArray:
        """Float array (n_messages, len(joints)) of ``field`` (position, velocity or effort) of the named
        joints, picked by name in each message."""
        tp = self._load(topic)
        joints = list(joints)
        out = np.empty((len(tp.names), len(joints)))
        index_of: dict[tuple[str, ...], list[int]] = {}
        for k, (names, vals) in enumerate(zip(tp.names, tp.values[field])):
            idx = index_of.get(names)
            if idx is None:
                where = {n: i for i, n in enumerate(names)}
                missing = [j for j in joints if j not in where]
                if missing:
                    raise InputError(f"{self.path}: message {k + 1} of {topic!r} has no joint "
                                     f"{', '.join(repr(j) for j in missing)} ({missing_names(missing, names)}); "
                                     f"it names {list(names)}")
                idx = index_of[names] = [where[j] for j in joints]
            if vals.shape[0] != len(names):
                raise InputError(f"{self.path.name}: message {k + 1} of {topic!r} has {vals.shape[0]} {field} values "
                                 f"for {len(names)} joint names (the topic does not publish {field}?)")
            out[k] = vals[idx]
        return out

    def sha256(self) -> str:
        """SHA-256 of the bag (a folder: of its files' names and contents, in name order)."""
        if self._sha256 is None:
            h = hashlib.sha256()
            files = sorted(p for p in self.path.rglob("*") if p.is_file()) if self.path.is_dir() else [self.path]
            for p in files:
                if self.path.is_dir():
                    h.update(str(p.relative_to(self.path)).encode() + b"\0")
                with open(p, "rb") as fh:
                    for block in iter(lambda: fh.read(1 << 20), b""):
                        h.update(block)
            self._sha256 = h.hexdigest()
        return self._sha256
