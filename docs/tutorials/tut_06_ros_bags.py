"""
Logs recorded as ROS bags
=========================

A robot running ROS records its joints as ``sensor_msgs/JointState`` messages, and ``rosbag
record`` (ROS 1) or ``ros2 bag record`` (ROS 2) writes them to a bag. dynid reads such bags
directly with the pure-Python ``rosbags`` package (the ``[ros]`` extra, which ``make setup``
installs): no ROS installation is needed (:doc:`/guide/data` lists every option).

This tutorial writes the 10 s log of ``examples/serial_arm`` into a ROS 2 bag, as a robot's driver
would have published it (positions, velocities and efforts on ``/joint_states``, each message with
its joint names and a header stamp), identifies the arm from the bag, and checks that the
estimate is the one the CSV log gives.
"""

# %%
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import dynid


def find_examples() -> Path:
    here = Path(globals().get("__file__", Path.cwd() / "x")).resolve().parent
    for folder in (here, *here.parents):
        if (folder / "examples" / "serial_arm").is_dir():
            return folder / "examples"
    raise FileNotFoundError("examples/ of the dynid checkout")


ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(dynid.__file__).parents[1]),
                                                    os.environ.get("PYTHONPATH", "")])}


def run(*args: str, cwd: Path) -> None:
    print("$ dynid", " ".join(args))
    proc = subprocess.run([sys.executable, "-m", "dynid.cli", *args], cwd=cwd, env=ENV,
                          capture_output=True, text=True)
    print(proc.stdout + proc.stderr)
    proc.check_returncode()


work = Path(tempfile.mkdtemp(prefix="dynid-tutorial-")) / "serial_arm"
shutil.copytree(find_examples() / "serial_arm", work, ignore=shutil.ignore_patterns("id", "sim", "design"))

# %%
# A bag as a driver writes it
# ---------------------------
# The CSV log has a time column and one column per joint and signal. A ROS driver publishes the
# same samples as JointState messages: the joint names in ``name``, their values in ``position``,
# ``velocity`` and ``effort`` (SI units), the sampling instant in ``header.stamp``. The joint order
# inside a message is the driver's: here it changes from message to message, which dynid handles
# (it looks every joint up by name).
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_typestore

log = np.genfromtxt(work / "log.csv", delimiter=",", names=True)
joints = ["yaw", "shoulder", "elbow"]
store = get_typestore(Stores.ROS2_HUMBLE)
JointState, Header, Time = (store.types[k] for k in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                      "builtin_interfaces/msg/Time"))
start_ns = 1_764_000_000_000_000_000  # stamps are wall-clock times
with Writer(work / "run_ros2", version=9, storage_plugin=StoragePlugin.MCAP) as bag:
    conn = bag.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
    for k, row in enumerate(log):
        order = joints if k % 2 == 0 else joints[::-1]
        stamp = start_ns + int(round(row["t"] * 1e9))
        msg = JointState(header=Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=""),
                         name=order,
                         position=np.array([row[f"q_{j}"] for j in order]),
                         velocity=np.zeros(0), effort=np.array([row[f"tau_{j}"] for j in order]))
        bag.write(conn, stamp, store.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
print(sorted(p.name for p in (work / "run_ros2").iterdir()))

# %%
# A configuration that reads the bag
# ----------------------------------
# ``file`` names the bag (a ROS 2 bag folder here; a ROS 1 ``.bag``, an ``.mcap`` or a ``.db3`` file
# work alike), ``topic`` the JointState topic, and ``columns`` are joint names. Time comes from
# the header stamps (``time = "receive"`` takes the bag's receive times instead). The validation
# window is a range of messages. The rest is the configuration ``dynid init`` writes for the CSV
# log (the first tutorial), so the two runs differ only in how the log is read.
run("init", "arm3.urdf", "log.csv", "--out", "csv.toml", cwd=work)
import re

csv_toml = (work / "csv.toml").read_text()
data_table = re.search(r"^\[data\].*?(?=^\[validation\])", csv_toml, re.S | re.M).group(0)
rows = re.search(r"^rows = .*$", data_table, re.M).group(0)  # the training messages, as init chose them
bag_data = f"""[data]                                         # the training log: a ROS 2 bag
file = "run_ros2"
topic = "/joint_states"
{rows}
position = {{ columns = ["yaw", "shoulder", "elbow"] }}   # joint names, looked up in each message
effort = {{ columns = ["yaw", "shoulder", "elbow"], kind = "torque", unit = "N*m" }}

"""
bag_toml = csv_toml.replace(data_table, bag_data)
(work / "bag.toml").write_text(bag_toml)
print(bag_toml[bag_toml.index("[data]"):bag_toml.index("[processing]")])

# %%
# Identify from the bag and from the CSV log
# ------------------------------------------
run("identify", "bag.toml", "--out", "id_bag", "-q", cwd=work)
run("identify", "csv.toml", "--out", "id_csv", "-q", cwd=work)
from_bag = json.loads((work / "id_bag" / "result.json").read_text())
from_csv = json.loads((work / "id_csv" / "result.json").read_text())

# %%
# ``result.json`` records where every signal came from: the bag, its topics and the time source.
source = from_bag["provenance"]["training_data"]
print({k: source[k] for k in ("ros_topics", "time_source", "window")})

# %%
# The same samples give the same estimate: the largest difference, in standard deviations of the
# estimate, is at the level of the rounding of the stamps (ns) and of the CSV's digits.
diff = max(abs(a["value"] - b["value"]) / b["std"] for a, b in zip(from_bag["params"], from_csv["params"]))
print(f"{len(from_bag['params'])} base parameters; largest difference {diff:.2e} standard deviations")
assert diff < 1e-6  # the same float64 samples; the stamps' ns rounding moves the estimate by ~1e-12 sd
summary = (work / "id_bag" / "summary.txt").read_text().splitlines()
first = next(k for k, line in enumerate(summary) if "held-out" in line.lower())
print("\n".join(summary[first:first + 20]))

shutil.rmtree(work.parent)
