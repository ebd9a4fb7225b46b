"""Structural reduction (issue 17, item 3): identical kinematic chains share parameters
(:mod:`dynid.model.reduction`), and the hexapod under the papers' two assumptions has exactly the
10 rigid-body parameters of paper 002's Table 1 + 14 friction terms (paper 004, Table II)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import seed
from dynid._files import save_npz
from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError
from dynid.model.base_parameters import perturb_bodies
from dynid.model.closed_loop import actuator_forces, actuator_regressor, random_consistent_states
from dynid.model.loading import load_model
from dynid.model.loop_kinematics import POSITION_TOL
from dynid.model.robots import build_mechanism, hexapod
from dynid.model.system import as_system
from dynid.pipeline import identify
from dynid.pipeline.simulate import run_simulation
from dynid.tolerances import scaled

LEGS = [f"P{j}" for j in range(1, 7)]


@pytest.fixture(scope="module")
def hexa():
    return as_system(hexapod.build())


@pytest.fixture(scope="module")
def paper(hexa):
    system = hexa.with_structure("paper")
    return system, system.base_parameters()


def test_paper_structure_is_table1_plus_friction(hexa, paper):
    system, base = paper
    red = system.reduction
    rigid = base.independent < red.n_body_params
    assert base.n_base == 24 and int(rigid.sum()) == 10
    assert set(np.array(base.names)[rigid]) == set(hexapod.TABLE1_NAMES)
    assert list(np.array(base.names)[~rigid]) == list(hexa.model.parameter_names[hexa.model.n_body_params:])
    beta = base.from_standard(system.nominal_parameters())
    names = list(base.names)
    # p1..p10 a priori of paper 002 Table 2 (p5 with paper 004's sign); K comes from a least-squares
    # fit on unit-norm columns, so agreement is to rounding (1e-9 relative)
    np.testing.assert_allclose([beta[names.index(n)] for n in hexapod.TABLE1_NAMES], hexapod.A_PRIORI, rtol=1e-9)
    friction = {**{f"fc_P{j + 1}": v for j, v in enumerate(hexapod.FRICTION["fc"])},
                **{f"fv_P{j + 1}": v for j, v in enumerate(hexapod.FRICTION["fv"])},
                "fc_alpha": hexapod.FRICTION["fc_alpha"], "fc_beta": hexapod.FRICTION["fc_beta"]}
    assert {n: beta[names.index(n)] for n in friction} == pytest.approx(friction, rel=1e-12)
    # the same ten by paper 002's Table 1 formulas on the full standard vector (an independent route)
    np.testing.assert_allclose(hexapod.table1_parameters(system.expand_parameters(system.nominal_parameters())),
                               hexapod.A_PRIORI, rtol=1e-12)
    # identical struts alone: 13 per strut group + 10 for the platform group (module docstring)
    tied = hexa.with_structure("identical_chains").base_parameters()
    assert tied.n_base == 37
    assert hexa.base_parameters().n_base == 102  # the default stays the full model


@pytest.mark.numerics
def test_reduced_rows_reproduce_the_full_inverse_dynamics(hexa, paper):
    """``rows @ psi`` == pinocchio RNEA of the full tree with ``pi = T psi``, projected (virtual power)."""
    system, base = paper
    mech, red = hexa.model, system.reduction
    nominal = mech.nominal_parameters()
    # the nominal model satisfies both assumptions: T T^+ pi = pi (to the rounding of the mean over six struts)
    np.testing.assert_allclose(system.expand_parameters(system.nominal_parameters()), nominal, rtol=1e-14, atol=0)
    # assembled configurations along a smooth platform path (the rows warm-start the loops sample after sample),
    # random actuator velocities and accelerations
    rng = np.random.default_rng(seed(3))
    s = np.linspace(0.0, 2 * np.pi, 25)[:, None]
    poses = hexapod.HOME + np.array([0.05, -0.04, 0.08, 0.1, -0.12, 0.15]) * np.sin(s + np.arange(6))
    state = mech.states(hexapod.inverse_kinematics(poses), rng.standard_normal((25, 6)), 3 * rng.standard_normal((25, 6)))
    act = list(mech.actuated)
    rows = system.rows(None)(state.q[:, act], state.dq[:, act], state.ddq[:, act], np.zeros((25, 6)))
    assert rows.W.shape == (25, 6, red.n_params)
    # a second parameter vector that satisfies the assumptions: tied bodies perturbed together
    rng = np.random.default_rng(seed(4))
    psi = perturb_bodies(system.nominal_parameters(), system.body_blocks(), 0.2, rng)
    psi[red.zero] = 0.0
    # the two routes meet at the loop closures' Gauss-Newton position solve, which stops at POSITION_TOL
    # (dynid.tolerances scale): the forces differ by about that times their sensitivity to the positions
    # (9e-14 of max |tau| at scale 1, where the solve's last step is quadratically small; 7e-10 at 10 and
    # 100, 2.6e-7 at 1000: 1e-9 alone held to 1.5x at scale 10). 1e-9 for the rounding, 10 x the tolerance
    rel = 1e-9 + 10 * scaled(POSITION_TOL)
    for vec in (system.nominal_parameters(), psi):
        tau = actuator_forces(mech, system.expand_parameters(vec), state)
        scale = np.abs(tau).max()
        np.testing.assert_allclose(rows.W @ vec, tau, atol=rel * scale)
        np.testing.assert_allclose(base.regressor(rows.W) @ base.from_standard(vec), tau, atol=rel * scale)
    # the regressor of the full model times T is the reduced one
    full = actuator_regressor(mech, state).W
    np.testing.assert_allclose(full @ red.T, rows.W, atol=1e-12 * np.abs(full).max())


@pytest.mark.numerics
def test_physically_consistent_fit_keeps_the_symmetric_zeros(hexa, paper):
    """The SDP works on psi: every tied body's pseudo-inertia is PSD and the zeros stay zero.

    Margins: PhysicalLS checks its solution's constraints after the solve and widens its buffer until
    they hold as stated (dynid.estimation.physical), whatever Clarabel's tolerances: the bounds below
    are the constraints themselves, with 1e-6 relative for the rounding of eigvalsh; the zeros come out
    exactly 0 (1e-9 of max |pi| allowed)."""
    from dynid.estimation import RegressionProblem
    from dynid.estimation.physical import PhysicalConstraints, PhysicalLS
    from dynid.model.base_parameters import pseudo_inertia

    system, base = paper
    state = random_consistent_states(hexa.model, 40, np.random.default_rng(seed(2)))
    W = base.regressor(actuator_regressor(hexa.model, state).W @ system.reduction.T)
    y = W @ base.from_standard(system.nominal_parameters()) + 5.0 * np.random.default_rng(seed(3)).standard_normal(W.shape[:2])
    smap = system.standard_map(base)
    prob = RegressionProblem.from_arrays(W, y, base.names, list(system.actuator_names), standard=smap)
    res = PhysicalLS(weighting="wls", constraints=PhysicalConstraints(margin=1e-6)).fit(prob)
    pi = np.array([res.solver["standard_params"][n] for n in smap.standard_names])
    assert len(smap.body_blocks) == 4 and smap.zero.size == 21  # platform, ring, stator, slider; 6 + 3 x 5 zeros
    assert min(np.linalg.eigvalsh(pseudo_inertia(pi[b]))[0] for b in smap.body_blocks) >= 1e-6 * (1 - 1e-6)
    assert np.abs(pi[smap.zero]).max() <= 1e-9 * np.abs(pi).max()
    assert np.all(pi[smap.nonnegative] >= 0)


def test_builtin_symmetry():
    rps = as_system(build_mechanism("rps3"))
    # the three legs are identical bodies in their own frames: 25 rigid-body base parameters become 15
    base = rps.with_structure("identical_chains").base_parameters()
    red = rps.with_structure("identical_chains").reduction
    assert int(np.sum(base.independent < red.n_body_params)) == 15 and base.n_base == 24
    with pytest.raises(ConfigError, match="declares no symmetric-body simplification"):
        rps.with_structure("paper")
    # shang2dof (paper 001, Table 3): a_i, b_i, c_i of chain 1 differ from those of chains 2 and 3, which are
    # equal: the description declares nothing, detection ties chains 2 and 3 only ...
    shang = as_system(build_mechanism("shang2dof"))
    assert shang.with_structure("identical_chains").reduction.chains == ((("qa2", "qb2"), ("qa3", "qb3")),)
    # ... and tying chain 1 by hand is refused: its bodies differ in the nominal model
    with pytest.raises(ConfigError, match="joint 'qa2' does not match joint 'qa1' .*their bodies differ") as err:
        shang.with_structure("identical_chains", ((("qa1", "qb1"), ("qa2", "qb2")),))
    assert "\n" not in str(err.value)
    fivebar = as_system(build_mechanism("fivebar"))
    with pytest.raises(ConfigError, match="declares no identical chains and none are found"):
        fivebar.with_structure("identical_chains")


@pytest.mark.parametrize("chains, message", [
    ([["a1", "b1", "P1"], ["a2", "b2", "Q2"]], r"\['Q2'\] are not joints of 'hexapod'"),
    ([["a1", "b1", "P1"], ["a2", "b2"]], "has 2 joints, chain"),
    ([["a1", "b1", "P1"], ["b2", "a2", "P2"]], "joint 'b2' does not match joint 'a1' .*joint types or axes differ \\(JointModelRX against JointModelRY\\)"),
    ([["a1", "b1", "P1"], ["a1", "b2", "P2"]], "joint 'a1' is in more than one chain"),
])
def test_bad_chains_are_one_line_config_errors(hexa, chains, message):
    with pytest.raises(ConfigError, match=message) as err:
        hexa.with_structure("identical_chains", (tuple(tuple(c) for c in chains),))
    assert "\n" not in str(err.value)


def test_structure_keys_in_the_config(tmp_path):
    sig = {"position": {"columns": ["q"]}, "effort": {"columns": ["tau"]}}
    base = {"robot": {"model": "builtin:hexapod"}, "data": {"file": "x.csv", "sample_rate_hz": 100.0, **sig},
            "validation": {"file": "y.csv"}}
    cfg = parse_config({**base, "identification": {"identical_chains": [["a1", "b1", "P1"], ["a2", "b2", "P2"]]}}, tmp_path)
    assert cfg.identification.structure == "identical_chains"
    assert cfg.identification.identical_chains == ((("a1", "b1", "P1"), ("a2", "b2", "P2")),)
    groups = [[["a1", "b1"], ["a2", "b2"]], [["P1"], ["P2"]]]
    cfg = parse_config({**base, "identification": {"structure": "paper", "identical_chains": groups}}, tmp_path)
    assert cfg.identification.identical_chains == ((("a1", "b1"), ("a2", "b2")), (("P1",), ("P2",)))
    assert parse_config(base, tmp_path).identification.structure == "auto"  # chosen from the data (parallel robots)
    for ident, message in (({"structure": "tied"}, "structure"),
                           ({"structure": "full", "identical_chains": [["a1"], ["a2"]]}, "needs identification.structure"),
                           ({"structure": "tied", "identical_chains": [["a1"], ["a2"]]}, "'auto', 'full'"),
                           ({"identical_chains": [["a1", "b1"]]}, "at least two chains"),
                           ({"identical_chains": [["a1", 3], ["a2", "b2"]]}, "a chain is a list of joint names")):
        with pytest.raises(ConfigError, match=message):
            parse_config({**base, "identification": ident}, tmp_path)
    serial = {**base, "robot": {"model": "builtin:puma560"}}
    with pytest.raises(ConfigError, match="serial robot"):
        as_system(load_model("builtin:puma560")).with_structure("identical_chains")
    assert parse_config({**serial, "identification": {"structure": "paper"}}, tmp_path).identification.structure == "paper"


def _log(d, name: str, seed: int):
    sim = run_simulation(parse_simulate_config({
        "robot": {"model": "builtin:hexapod"},  # the nominal model: six identical, symmetric struts
        "trajectory": {"coordinates": "task", "kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3,
                       "fill": 0.15, "max_velocity": 0.3, "max_acceleration": 3.0, "seed": seed},
        "control": {"rate_hz": 250, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
    }, d))
    m = sim.motion
    act = list(load_model("builtin:hexapod").actuated)
    rng = np.random.default_rng(seed)
    cols = {"t": m.t}
    for k, leg in enumerate(LEGS):
        j = act[k]
        cols[f"q_{leg}"], cols[f"dq_{leg}"], cols[f"ddq_{leg}"] = m.q[:, j], m.dq[:, j], m.ddq[:, j]
        cols[f"tau_{leg}"] = m.tau_a[:, k] + 2.0 * rng.standard_normal(m.t.size)
    save_npz(d / f"{name}.npz", cols)
    return sim


@pytest.mark.numerics
def test_identification_recovers_the_24_parameters(tmp_path):
    """A virtual hexapod whose truth satisfies both assumptions (the nominal model), exact states and
    2 N of white force noise: WLS of the 24 parameters is unbiased with the covariance it reports, so
    each |estimate - truth| / std is |N(0, 1)|; 4.5 bounds the largest of 24 with probability 1 - 1.6e-4."""
    sim = _log(tmp_path, "log", seed(1))
    n = sim.motion.t.size
    sig = lambda p, unit, **kw: {"columns": [f"{p}_{leg}" for leg in LEGS], "unit": unit, **kw}  # noqa: E731
    doc = {
        "robot": {"model": "builtin:hexapod"},
        "data": {"file": str(tmp_path / "log.npz"), "time": {"column": "t"}, "position": sig("q", "m"),
                 "velocity": sig("dq", "m"), "acceleration": sig("ddq", "m"), "effort": sig("tau", "N", kind="torque"),
                 "rows": [0, 3 * n // 4]},
        "validation": {"rows": [3 * n // 4, n]},
        "processing": {"derivatives": "measured", "trim_samples": 0},
        "identification": {"method": "wls", "structure": "paper"},
        "output": {"plots": False},
    }
    out = identify(parse_config(doc, tmp_path))
    res = out.result
    assert len(res.names) == 24 and set(hexapod.TABLE1_NAMES) <= set(res.names)
    truth = out.base.from_standard(out.system.reduce_parameters(np.asarray(sim.truth["true_parameters"])))
    z = (res.params - truth) / res.bse
    assert np.all(np.abs(z) < 4.5), dict(zip(res.names, np.round(z, 2)))
    assert out.system.structure == "paper" and res.provenance["robot"]["parameter_structure"]["structure"] == "paper"
