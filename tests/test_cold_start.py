"""A cold ``dynid identify`` does no work twice and imports nothing it does not use (issue 37, item 5).

* Base parameters: computed once per model (serial arm) or system (mechanism: its structure) and
  settings in a run (:func:`dynid.model.system.cached_base_parameters`), never reused for another
  model: a Coulomb width so large that the smooth sign is linear in the velocity makes the Coulomb
  columns the viscous ones, and that model must get its own, smaller base; a mechanism's tied
  structure its own. ``identification.structure = "auto"`` computes the full and the tied model's
  base once each (it computed the chosen one a third time).
* Streamed parallel decimation skips the regressor columns that are exactly zero: its output is
  that of filtering every column, bit for bit, and equals whole-signal filtering.
* A serial-arm identify never imports numba (a dependency for the closed-chain kernels only), and
  with plots never matplotlib.pyplot: its two figures are drawn on a ``Figure`` with its own Agg
  canvas (:func:`dynid.report.plots._agg_figure`), whose pixels equal those of the same figure made
  through pyplot, as they were before.
* The drive-gain pass of a serial arm takes the nominal torques from RNEA instead of computing the
  regressor a second time over the training rows: the same decimated torques to rounding.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dynid.model.system as system_mod
from conftest import seed
from dynid.model.base_parameters import robot_base_parameters
from dynid.model.loading import load_robot
from dynid.model.mechanism_io import load_mechanism
from dynid.model.system import as_system
from dynid.signals import decimation_filter, lowpass_sos
from dynid.signals.streamed import StreamedDecimation

REPO = Path(__file__).resolve().parents[1]
ARM = REPO / "examples" / "serial_arm"


def _counting(monkeypatch, name: str) -> list:
    """Count the calls of ``dynid.model.system.<name>`` (the computation behind ``base_parameters``)."""
    calls: list = []
    orig = getattr(system_mod, name)

    def counted(*args, **kwargs):
        calls.append(args[0])
        return orig(*args, **kwargs)

    monkeypatch.setattr(system_mod, name, counted)
    return calls


def test_serial_base_parameters_once_per_model_never_for_another(monkeypatch):
    calls = _counting(monkeypatch, "robot_base_parameters")
    robot = load_robot(str(ARM / "arm3.urdf"), extras=("Ia", "fv", "fc"))
    arm = as_system(robot)
    first = arm.base_parameters()
    assert arm.base_parameters() is first and as_system(robot).base_parameters() is first and len(calls) == 1
    # other settings are another entry, with the content a direct computation gives (deterministic)
    other = arm.base_parameters(seed=3)
    direct = robot_base_parameters(robot, seed=3)
    assert len(calls) == 2 and other is not first
    assert other.names == direct.names and np.array_equal(other.K, direct.K)
    # Coulomb width w = 1e6 rad/s: random_states draws velocities N(0, 2^2), |v| < 12 for all 600
    # values but with probability ~1e-6, and erf(v / (sqrt(2) w)) = sqrt(2/pi) v/w (1 - v^2/(6 w^2) + ...)
    # departs from the viscous column v by at most 144/6e12 = 2.4e-11 relative: far below the rank
    # tolerance 1e-8, so the Coulomb terms are not identifiable and regroup with the viscous ones (3
    # base parameters fewer). w = 1e-3 rad/s: the smooth sign is a step, as independent as sign(v).
    linear = arm.with_coulomb_width([1e6] * 3).base_parameters()
    step = arm.with_coulomb_width([1e-3] * 3).base_parameters()
    assert len(calls) == 4
    assert first.n_base == step.n_base == linear.n_base + 3
    assert {"fc1", "fc2", "fc3"} <= set(first.names) and not {"fc1", "fc2", "fc3"} & set(linear.names)


def test_mechanism_structure_keeps_its_own_base(monkeypatch):
    calls = _counting(monkeypatch, "mechanism_base_parameters")
    full = as_system(load_mechanism("builtin:rps3"))
    tied = full.with_structure("identical_chains")
    b_full, b_tied = full.base_parameters(), tied.base_parameters()
    assert full.base_parameters() is b_full and tied.base_parameters() is b_tied and len(calls) == 2
    # three identical legs tied: one parameter set per leg body instead of three (34 -> 24 here)
    assert b_tied.n_base < b_full.n_base and b_tied.n_standard < b_full.n_standard


def _rps3_log(tmp_path, mech) -> None:
    """Forces of the actuated slides along a smooth motion (three sines per slide), the regressor times
    the description's parameters plus 0.05 N noise, 100 Hz."""
    from dynid.model.closed_loop import actuator_regressor

    rng = np.random.default_rng(seed(37))
    n, fs = 1500, 100.0
    t = np.arange(n) / fs
    act = list(mech.actuated)
    w = 2 * np.pi * np.array([0.3, 0.7, 1.1])
    amp = rng.uniform(0.01, 0.02, (len(act), 3))
    ph = rng.uniform(0, 2 * np.pi, (len(act), 3))
    arg = w * t[:, None, None] + ph
    qa = mech.q_ref[act] + np.sum(amp * np.sin(arg), axis=2)
    state = mech.states(mech.solve_positions(qa), np.sum(amp * w * np.cos(arg), axis=2),
                        -np.sum(amp * w**2 * np.sin(arg), axis=2))
    tau = actuator_regressor(mech, state).W @ mech.nominal_parameters() + 0.05 * rng.standard_normal((n, len(act)))
    names = [mech.pin_model.names[j + 1] for j in act]
    head = ["t"] + [f"q_{a}" for a in names] + [f"tau_{a}" for a in names]
    np.savetxt(tmp_path / "log.csv", np.c_[t, state.q[:, act], tau], delimiter=",", header=",".join(head), comments="")
    q_cols = ", ".join(f'"q_{a}"' for a in names)
    f_cols = ", ".join(f'"tau_{a}"' for a in names)
    (tmp_path / "auto.toml").write_text(f"""[robot]
model = "builtin:rps3"
[data]
file = "log.csv"
time = {{ column = "t", unit = "s" }}
rows = [0, 1200]
position = {{ columns = [{q_cols}], unit = "m" }}
effort = {{ columns = [{f_cols}], unit = "N", kind = "torque" }}
[validation]
rows = [1200, 1500]
[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4, filter_effort = false }}
[identification]
method = "ols"
structure = "auto"
[output]
plots = false
""")


def test_structure_decision_computes_each_base_once(monkeypatch, tmp_path):
    from dynid.config import load_config
    from dynid.pipeline.identification import identify

    mech = load_mechanism("builtin:rps3")
    _rps3_log(tmp_path, mech)
    calls = _counting(monkeypatch, "mechanism_base_parameters")
    out = identify(load_config(tmp_path / "auto.toml"))
    # the full and the tied model's base, once each: the chosen one is not computed a third time
    assert out.structure["mode"] == "auto" and len(calls) == 2
    chosen = as_system(mech).with_structure(out.structure["chosen"])
    assert out.base.names == chosen.base_parameters().names


class _EveryColumn(StreamedDecimation):
    """The streamed decimation as it was before the skip: every column filtered from the start."""

    def _forward(self, x, zi):
        self._live[:] = True
        y, self._state = self._sosfilt(self.sos, x, axis=0, zi=zi)
        return y


@pytest.mark.parametrize("zero_from", [0, 700])
def test_streamed_decimation_skips_zero_columns_bit_for_bit(zero_from):
    """Columns zero throughout, and one zero until row ``zero_from``: the output equals, bit for bit,
    that of filtering every column (the recursion of zero input from the zero state is zero), and
    whole-signal zero-phase filtering to the streamed module's bound (1e-9 of the signal's range, as
    tests/test_parallel_decimation_memory.py checks it)."""
    rng = np.random.default_rng(seed(38))
    n, k = 3000, 10
    sos, margin = decimation_filter(k, 1000.0)
    x = np.cumsum(rng.standard_normal((n, 6)), axis=0)
    x[:, [1, 4]] = 0.0  # structurally zero
    x[:zero_from, 2] = 0.0  # zero, then live

    def stream(cls) -> np.ndarray:
        s = cls(sos, n, k, margin, 400)
        parts = []
        for a in range(0, n, 500):
            parts += [o for _, _, o in s.feed(x[a:a + 500])]
        assert s.done
        return np.concatenate(parts)

    got = stream(StreamedDecimation)
    assert np.array_equal(got, stream(_EveryColumn))
    assert not np.any(got[:, [1, 4]])
    whole = lowpass_sos(x, sos)[::k]
    np.testing.assert_allclose(got, whole, rtol=0, atol=1e-9 * np.ptp(x))


@pytest.mark.parametrize("plots", [False, True])
def test_serial_identify_does_not_import_numba(tmp_path, plots):
    """The shipped serial example's log through ``dynid identify`` in a fresh interpreter: no numba,
    and with plots (both figures written) no matplotlib.pyplot."""
    (tmp_path / "identify.toml").write_text(f"""[robot]
model = "{(ARM / 'arm3.urdf').as_posix()}"
extras = ["Ia", "fv", "fc"]
[data]
file = "{(ARM / 'log.csv').as_posix()}"
time = {{ column = "t", unit = "s" }}
rows = [0, 750]
position = {{ columns = ["q_yaw", "q_shoulder", "q_elbow"], unit = "rad" }}
effort = {{ columns = ["tau_yaw", "tau_shoulder", "tau_elbow"], unit = "N*m", kind = "torque" }}
[validation]
rows = [750, 1001]
[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4, filter_effort = false }}
[identification]
method = "ols"
[output]
plots = {'true' if plots else 'false'}
""")
    code = ("import sys, json\nfrom dynid.cli import main\n"
            f"rc = main(['identify', {str(tmp_path / 'identify.toml')!r}, '--out', {str(tmp_path / 'out')!r}, '-q'])\n"
            "print(json.dumps({'rc': rc, 'numba': sorted(m for m in sys.modules if m.split('.')[0] == 'numba'), "
            "'pyplot': 'matplotlib.pyplot' in sys.modules, 'agg': 'matplotlib.backends.backend_agg' in sys.modules}))")
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"), DYNID_PLOT_WORKER="0")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert res["rc"] == 0 and (tmp_path / "out" / "result.json").exists()
    assert res["numba"] == [], f"a serial-arm identify imported {res['numba']}"
    if plots:  # the figures were drawn (by Agg), without pyplot
        assert res["agg"] and not res["pyplot"]
        assert (tmp_path / "out" / "validation.png").exists() and (tmp_path / "out" / "processing.png").exists()


def test_agg_figure_draws_what_pyplot_drew(tmp_path, monkeypatch):
    """plot_validation on its pyplot-free figure against the same function with the figure made by
    ``pyplot.figure`` (the route before): the decoded PNGs are equal pixel for pixel. Both render the
    same artists with the same rcParams through the same Agg renderer in this process, so equality is
    exact on any machine (only the PNG's zlib level differs, and PNG is lossless)."""
    pytest.importorskip("matplotlib")
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from PIL import Image
    from types import SimpleNamespace

    import dynid.report.plots as plots

    rng = np.random.default_rng(seed(39))
    n, c = 3000, 3
    t = np.arange(n) / 500.0
    meas = np.cumsum(rng.standard_normal((n, c)), axis=0)
    pred = meas + 0.3 * rng.standard_normal((n, c))
    err = meas - pred
    rmse = np.sqrt(np.mean(err**2, axis=0))
    metrics = SimpleNamespace(measured=meas, predicted=pred, t=t, channel_names=[f"j{k}" for k in range(c)], rmse=rmse,
                              rel_rmse_pct=100 * rmse / np.sqrt(np.mean(meas**2, axis=0)), label="held-out")
    plots.plot_validation(metrics, tmp_path / "agg.png")
    made = []

    def via_pyplot(**kwargs):
        made.append(plt.figure(**kwargs))
        return made[-1]

    monkeypatch.setattr(plots, "_agg_figure", via_pyplot)
    plots.plot_validation(metrics, tmp_path / "pyplot.png")
    plt.close(made[0])
    a, b = (np.asarray(Image.open(tmp_path / f"{k}.png")) for k in ("agg", "pyplot"))
    assert a.shape == b.shape and np.array_equal(a, b)


def test_drive_gain_torques_by_rnea_equal_the_regressor_route():
    """The drive-gain pass's nominal torques by pinocchio's RNEA (``_chunks(torques=...)``,
    :func:`dynid.pipeline.drive_gains.estimate_drive_gains` on a serial arm) against the base regressor
    times the nominal base parameters (``project=``, what it filtered before), both parallel-decimated:
    a 6R arm with the TX40's coupled wrist, rotor inertia, viscous and smooth Coulomb friction and
    offsets, every joint extra non-zero (the coupled motor's own are 0 in the description). The measured efforts and velocities are the same bits; the
    torques agree to rounding."""
    from dynid.model.serial_dynamics import inverse_dynamics
    from dynid.model.transmission import Transmission
    from dynid.pipeline.rows import _chunks
    from dynid.dataset import Dataset

    C = np.diag([32.0, 32.0, 45.0, -48.0, 45.0, 32.0])
    C[5, 4] = 32.0  # motor 6 turns with joints 5 and 6 (examples/tx40/identify.toml)
    extras = {"Ia": [0.3, 0.3, 0.1, 0.03, 0.03, 0.02], "fv": [2.0, 2.0, 1.0, 0.5, 0.5, 0.3],
              "fc": [1.5, 1.5, 1.0, 0.4, 0.4, 0.2], "offset": [0.1, -0.2, 0.05, 0.03, 0.02, -0.01]}
    robot = load_robot("builtin:generic6r", extras=("Ia", "fv", "fc", "offset"), nominal_extras=extras,
                       transmission=Transmission(matrix=C, drive_gains=np.ones(6), position_offset=np.zeros(6)))
    system = as_system(robot).with_coulomb_width([0.05] * 6)
    base = system.base_parameters()
    nom = system.nominal_parameters()
    nb = robot.layout.n_body_params
    assert robot.layout.coupled_motors and np.count_nonzero(nom[nb:nb + 24]) == 24
    rng = np.random.default_rng(seed(40))
    n, fs = 3000, 1000.0
    t = np.arange(n) / fs
    w = 2 * np.pi * np.array([0.2, 0.5, 0.9])
    amp, ph = rng.uniform(0.2, 0.6, (6, 3)), rng.uniform(0, 2 * np.pi, (6, 3))
    arg = w * t[:, None, None] + ph
    q = np.sum(amp * np.sin(arg), axis=2)
    dq = np.sum(amp * w * np.cos(arg), axis=2)
    ddq = -np.sum(amp * w**2 * np.sin(arg), axis=2)
    ds = Dataset(t=t, q=q, tau=rng.standard_normal((n, 6)), dq=dq, ddq=ddq)

    def run(**way):
        cs = list(_chunks(system, base, ds, None, parallel_decimate=10, chunk_size=700, **way))
        return [np.concatenate([getattr(c, f) for c in cs]) for f in ("W", "y", "dq")]

    W_rnea, y_rnea, dq_rnea = run(torques=lambda q, dq, ddq: inverse_dynamics(system.model, nom, q, dq, ddq))
    W_reg, y_reg, dq_reg = run(project=base.from_standard(nom)[:, None])
    assert W_rnea.shape == W_reg.shape == (n // 10, 6, 1)
    assert np.array_equal(y_rnea, y_reg) and np.array_equal(dq_rnea, dq_reg)
    # per sample, RNEA and the regressor's product agree to a few ulp of the torques (float64, 6e-16
    # relative measured on the TX40); the base projection W_std pi = W_b beta holds to rounding times
    # the base map's conditioning, and the decimation filter is linear with a gain of order one:
    # 1e-9 of the largest torque leaves a factor 1e6 for that conditioning
    scale = np.abs(W_reg).max()
    assert scale > 1.0 and np.max(np.abs(W_rnea - W_reg)) <= 1e-9 * scale
