"""The irreducible part of a cold ``dynid identify`` of the TX40 log, as one fresh process
(``bench/vs_figaroh.py --floor``: measured in the same rounds as FIGAROH, as a fraction of its wall).

What any identification of this log in Python with these libraries must do, and nothing else:

* start the interpreter and import what the run needs: numpy, pinocchio, ``scipy.linalg`` (the base
  parameters' QR), ``scipy.signal`` (the Butterworth filter; its ``__init__`` imports every submodule,
  bench/README.md "Cold start, fourth pass"), and with ``--plots`` matplotlib's ``Figure`` and Agg canvas
  (the least that draws a PNG);
* read the two logs (positions and currents, 45 000 rows x 6 columns each) with ``numpy.loadtxt``,
  the parser dynid's reader uses for a plain CSV file (:meth:`dynid.io.readers.TableReader._plain_csv`);
* load the URDF into pinocchio and call ``computeJointTorqueRegressor`` once per sample of the
  training rows (0-24 750) and of the held-out rows (29 250-45 000), on the log's joint positions
  (motor angles over the gear ratios) with central-difference velocities and accelerations: one
  regressor per sample, the physics itself (the cost of a call does not depend on the values).

Not included: the filter, the decimation, the least squares, the validation's products, the outputs
and any figure: so this is a lower bound of a run, not a run.

Run: ``python bench/_cold_floor.py DATA_DIR [--plots]``; prints one JSON line (its own stage times).
"""

from __future__ import annotations

import json
import sys
import time

t0 = time.perf_counter()
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402
import scipy.linalg  # noqa: E402,F401
import scipy.signal  # noqa: E402,F401

if "--plots" in sys.argv:
    import matplotlib.figure  # noqa: F401
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
t_import = time.perf_counter()

TRAIN, VALIDATE = (0, 24750), (29250, 45000)
GEAR = np.array([32.0, 32.0, 45.0, -48.0, 45.0, 32.0])  # examples/tx40/identify.toml (coupling left out: same cost)
FS = 5000.0


def main() -> None:
    data = sys.argv[1]
    pos = np.loadtxt(f"{data}/pos_read_data.csv", dtype=float, delimiter=",", comments=None, ndmin=2, skiprows=1,
                     encoding="utf-8")
    cur = np.loadtxt(f"{data}/curr_data.csv", dtype=float, delimiter=",", comments=None, ndmin=2, skiprows=1,
                     encoding="utf-8")
    t_read = time.perf_counter()
    model = pin.buildModelFromUrdf(f"{data}/tx40_mdh_modified.urdf")
    d = model.createData()
    q = pos / GEAR
    dq = np.gradient(q, 1.0 / FS, axis=0)
    ddq = np.gradient(dq, 1.0 / FS, axis=0)
    jtr = pin.computeJointTorqueRegressor
    n = 0
    for a, b in (TRAIN, VALIDATE):
        for i in range(a, b):
            jtr(model, d, q[i], dq[i], ddq[i])
        n += b - a
    t_reg = time.perf_counter()
    print(json.dumps({"import_s": t_import - t0, "read_s": t_read - t_import, "regressor_s": t_reg - t_read,
                      "samples": n, "rows": [int(pos.shape[0]), int(cur.shape[0])]}))


if __name__ == "__main__":
    main()
