"""The [robot], [data] and [validation] tables of an identify config for a simulated
``builtin:cobot6r`` pair of logs ``train/log.csv`` and ``val/log.csv`` (``dynid simulate`` column
names), as a ``str.format`` template piece (braces doubled), shared by the tests that identify such
twins."""

COBOT_LOGS = """[robot]
model = "builtin:cobot6r"

[data]
file = "train/log.csv"
time = {{ column = "t", unit = "s" }}
position = {{ columns = ["q_joint_1", "q_joint_2", "q_joint_3", "q_joint_4", "q_joint_5", "q_joint_6"], unit = "rad" }}
effort = {{ columns = ["tau_joint_1", "tau_joint_2", "tau_joint_3", "tau_joint_4", "tau_joint_5", "tau_joint_6"], unit = "N*m", kind = "torque" }}

[validation]
file = "val/log.csv"
"""

PUMA_DOC = {
    "robot": {"model": "builtin:puma560"},
    "data": {"file": "x.csv", "sample_rate_hz": 100.0, "rows": [0, 10], "position": {"columns": list("abcdef")},
             "effort": {"columns": list("ghijkl")}},
    "validation": {"rows": [10, 20]},
}
"""A minimal identify document (parsed, never run) for config-error tests."""
