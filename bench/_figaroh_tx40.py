"""FIGAROH 1.0.2's TX40 identification, driven through its public API, for ``bench/vs_figaroh.py``.

This file runs in FIGAROH's own virtual environment (never in dynid's): ``vs_figaroh.py`` starts it
as a subprocess with that environment's interpreter. It is written against FIGAROH's API
(``figaroh.identification.base_identification.BaseIdentification``, ``figaroh.tools.robot``,
``figaroh.utils.config_migration``); it does what FIGAROH's published TX40 example does with its
1.0-era configuration, on the log and model in ``shared/data/tx40``:

* configuration: the shared legacy file ``figaroh_TX40_config.yaml`` converted to FIGAROH 1.0's
  unified format by FIGAROH's own migration function (``prepare`` mode, run once, not timed), with
  ``wls: true`` as FIGAROH's 1.0 TX40 configuration sets it;
* data: motor-side encoder angles -> joint angles through the reduction matrix with the coupled
  wrist (q_motor6 = N6 (q5 + q6)), q2 -= pi/2, q3 += pi/2; torques tau = N i with tau5 = N5 i5 + N6 i6;
* processing (FIGAROH's base class): median filter of width 5 and a 4th-order zero-phase Butterworth
  at the configured 100 Hz (FIGAROH 1.0 normalizes by the Nyquist frequency), ``np.gradient``
  derivatives, 5 x order = 20 samples trimmed at each end;
* fit: ``initialize`` then ``solve(decimate=True)`` with the example's defaults (decimation by 10
  with ``scipy.signal.decimate``, zero-column tolerance 1e-3), OLS refined by WLS (Gautier 1997);
  the coupled-wrist motor columns (Iam6, fvm6, fsm6) are not in the fit because FIGAROH 1.0.2's base
  class never calls the example's ``add_additional_parameters`` hook (nor does this driver);
* held-out data: FIGAROH's own validation path (``identif_config["validation_data_file"]``), here a
  row window of the same log, processed like the training rows and scored at the full 5 kHz.

Modes (argv): ``prepare DATA_DIR PREP_DIR`` writes the unified config and a geometry-free
copy of the URDF (its meshes are not shipped); ``identify DATA_DIR PREP_DIR OUT_DIR
--train A B --validate C D [--no-plots]`` identifies and writes ``OUT_DIR/figaroh_result.json``.
With plots, the figures FIGAROH draws are also written as PNG (under the Agg backend its
``plt.show()`` renders nothing, while dynid writes its plots to files: saving them makes both tools
render what they draw) and its HTML report is exported, as the example does by default; the run is
archived (``figaroh.tools.run_archive``) in both cases, as the example does by default. The example's
verification step is left out: its module is part of the examples repository, not of the wheel.
"""

from __future__ import annotations

import json
import sys
import time

T_START = time.perf_counter()

import numpy as np  # noqa: E402

JOINTS = ["joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6"]
COLUMNS = ["Joint_1", "Joint_2", "Joint_3", "Joint_4", "Joint_5", "Joint_6"]


def prepare(data_dir: str, out_dir: str) -> int:
    """Write ``OUT_DIR/figaroh_tx40.yaml`` (unified config) and ``OUT_DIR/tx40.urdf`` (no geometry)."""
    import xml.etree.ElementTree as ET

    import yaml
    from figaroh.utils.config_migration import convert_legacy_to_unified

    with open(f"{data_dir}/figaroh_TX40_config.yaml") as fh:
        legacy = yaml.safe_load(fh)
    doc = convert_legacy_to_unified(legacy, template="base")
    doc.pop("extends", None)  # the templates are not shipped with the wheel; "base" adds no defaults
    ident = doc["tasks"]["identification"]
    ident.setdefault("problem", {})["wls"] = True  # FIGAROH 1.0's TX40 configuration
    doc.setdefault("robot", {})["name"] = "staubli_tx40"
    joints = doc["robot"].setdefault("properties", {}).setdefault("joints", {})
    joints["active_joints"] = list(JOINTS)
    doc["tasks"].setdefault("calibration", {})["enabled"] = False
    with open(f"{out_dir}/figaroh_tx40.yaml", "w") as fh:
        yaml.safe_dump(doc, fh, sort_keys=False)
    # the shared URDF names meshes that are not shipped (FIGAROH's Robot always loads geometry):
    # drop <visual>/<collision>, which do not enter the dynamics
    tree = ET.parse(f"{data_dir}/tx40_mdh_modified.urdf")
    for link in tree.getroot().iter("link"):
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                link.remove(el)
    tree.write(f"{out_dir}/tx40.urdf")
    return 0


def identify(data_dir: str, prep_dir: str, out_dir: str, train: tuple[int, int], validate: tuple[int, int],
             plots: bool) -> int:
    import pandas as pd
    from figaroh.identification.base_identification import BaseIdentification
    from figaroh.tools.robot import load_robot
    from figaroh.tools.run_archive import archive_run, compute_run_dir

    t_import = time.perf_counter()

    class TX40(BaseIdentification):
        """TX40 specifics: motor-side data, coupled wrist, border trimming (see module docstring)."""

        def __init__(self, robot, config_file):
            super().__init__(robot, config_file)
            cfg = self.identif_config
            cfg["active_joints"] = list(JOINTS)
            jid = [self.model.getJointId(n) for n in JOINTS]
            cfg["act_Jid"] = jid
            cfg["act_J"] = [self.model.joints[i] for i in jid]
            cfg["act_idxq"] = [self.model.joints[i].idx_q for i in jid]
            cfg["act_idxv"] = [self.model.joints[i].idx_v for i in jid]
            cfg["idx_act_joints"] = [i - 1 for i in jid]
            self.filter_config = {
                "differentiation_method": "gradient",
                "filter_params": {"nbutter": 4, "f_butter": cfg.get("cut_off_frequency_butterworth", 100.0),
                                  "f_sample": 1.0 / cfg["ts"]},
            }
            self._log = None

        def _read(self):
            if self._log is None:
                pos = pd.read_csv(f"{data_dir}/pos_read_data.csv")[COLUMNS].to_numpy()
                cur = pd.read_csv(f"{data_dir}/curr_data.csv")[COLUMNS].to_numpy()
                self._log = (pos, cur)
            return self._log

        def load_trajectory_data(self, data_source=None):
            pos, cur = self._read()
            if data_source is not None:  # "A:B", the held-out row window
                a, b = (int(x) for x in data_source.split(":"))
                pos, cur = pos[a:b], cur[a:b]
            n = len(pos)
            return {"timestamps": (np.arange(n) * self.identif_config["ts"]).reshape(-1, 1),
                    "positions": pos, "velocities": None, "accelerations": None, "torques": cur}

        def process_kinematics_data(self, filter_config=None):
            n = np.asarray(self.identif_config["reduction_ratio"], float)
            motor_from_joint = np.diag(n)
            motor_from_joint[5, 4] = n[5]  # motor 6 turns with q5 + q6
            q = np.linalg.solve(motor_from_joint, self.raw_data["positions"].T).T
            q[:, 1] -= np.pi / 2
            q[:, 2] += np.pi / 2
            self.raw_data["positions"] = q
            self.filter_kinematics_data(self.filter_config)

        def process_torque_data(self, **kwargs):
            n = np.asarray(self.identif_config["reduction_ratio"], float)
            gain = np.diag(n)
            gain[4, 5] = n[5]  # motor 6's torque also acts on joint 5
            tau = self.raw_data["torques"] @ gain.T
            cut = 5 * self.filter_config["filter_params"]["nbutter"]
            self.processed_data["torques"] = tau[cut:-cut]
            for key in ("timestamps", "positions", "velocities", "accelerations"):
                self.processed_data[key] = self.processed_data[key][cut:-cut]
            return self.processed_data["torques"]

    robot = load_robot(f"{prep_dir}/tx40.urdf")
    tx = TX40(robot, f"{prep_dir}/figaroh_tx40.yaml")
    wls = bool(tx.identif_config.get("wls", False))
    tx.identif_config["validation_data_file"] = f"{validate[0]}:{validate[1]}"
    t0 = time.perf_counter()
    tx.initialize(truncate=train)
    t1 = time.perf_counter()
    tx.solve(decimate=True, plotting=plots, save_results=False, wls=wls, html_report=False)
    t2 = time.perf_counter()
    n_figures = 0
    if plots:
        import matplotlib.pyplot as plt

        for k in plt.get_fignums():
            plt.figure(k).savefig(f"{out_dir}/figaroh_figure_{k}.png")
            n_figures += 1
        plt.close("all")
    # the example's default outputs: its HTML report (with plots: dynid writes report.html only with
    # plots too) and the run archive (parameters, provenance, config snapshot: dynid always writes
    # result.json, params.csv, summary.txt)
    run_dir = compute_run_dir(tx, root=f"{out_dir}/runs")
    if plots:
        tx.export_html_report(output_path=str(run_dir / "report.html"))
    archive_run(tx, run_dir)
    t3 = time.perf_counter()
    val = tx.result.get("validation_metrics") or {}
    per_joint = val.get("per_joint", {})
    doc = {
        "n_base": len(tx.params_base),
        "base_parameters": {name: float(v) for name, v in zip(tx.params_base, tx.phi_base)},
        "wls": wls,
        "train_rows": list(train),
        "train_samples": int(tx.num_samples),
        "validation_source": val.get("validation_source"),
        "validation_samples": val.get("n_val_samples"),
        "rmse_per_joint": [per_joint[j]["rmse_identified"] for j in JOINTS] if per_joint else None,
        "fit_rmse": float(tx.rms_error),
        "condition_number": float(tx.result["condition number"]),
        "figures": n_figures,
        "timing_s": {"imports": t_import - T_START, "initialize": t1 - t0, "solve": t2 - t1, "plots_report_archive": t3 - t2},
    }
    with open(f"{out_dir}/figaroh_result.json", "w") as fh:
        json.dump(doc, fh)
    print("FIGAROH TX40: %d base parameters, held-out RMSE per joint [N*m] %s, import %.2f s, "
          "initialize %.2f s, solve %.2f s" % (doc["n_base"], doc["rmse_per_joint"], doc["timing_s"]["imports"],
                                              doc["timing_s"]["initialize"], doc["timing_s"]["solve"]))
    return 0


def main(argv: list[str]) -> int:
    if argv[:1] == ["prepare"] and len(argv) == 3:
        return prepare(argv[1], argv[2])
    if argv[:1] == ["identify"] and len(argv) in (10, 11):
        _, data_dir, prep_dir, out_dir, f1, a, b, f2, c, d, *rest = argv
        if f1 != "--train" or f2 != "--validate" or rest not in ([], ["--no-plots"]):
            raise SystemExit("usage: identify DATA_DIR PREP_DIR OUT_DIR --train A B --validate C D [--no-plots]")
        return identify(data_dir, prep_dir, out_dir, (int(a), int(b)), (int(c), int(d)), plots=not rest)
    raise SystemExit("usage: _figaroh_tx40.py prepare DATA_DIR PREP_DIR | identify ...")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
