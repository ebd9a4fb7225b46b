"""Base parameters: counts, regrouping identity, determinism, maps, names."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.model import load_robot, regressor, robot_base_parameters
from dynid.model.base_parameters import random_states

EXTRA_SETS = {"inertial": (), "with Ia": ("Ia",), "with Ia+fv+fc+offset": ("Ia", "fv", "fc", "offset")}


@pytest.mark.parametrize("name", ["puma560", "generic6r"])
@pytest.mark.parametrize("extras,expected", [((), 36), (("Ia",), 40), (("Ia", "fv", "fc", "offset"), 58)])
def test_counts_6r(name, extras, expected):
    base = robot_base_parameters(load_robot(f"builtin:{name}", extras=extras))
    assert base.n_base == expected


@pytest.mark.parametrize("extras,expected", [((), 43), (("Ia",), 48), (("Ia", "fv", "fc", "offset"), 69)])
def test_counts_kuka_lwr4(shared, extras, expected):
    robot = load_robot(str(shared("kuka_lwr4", "kuka_lwr4.urdf")), extras=extras)
    assert robot.dof == 7
    assert robot_base_parameters(robot).n_base == expected


@pytest.mark.parametrize("name", ["puma560", "generic6r"])
def test_base_regressor_reproduces_full_regressor(name):
    robot = load_robot(f"builtin:{name}")
    base = robot_base_parameters(robot)
    rng = np.random.default_rng(123)  # other states than those used to compute the base
    lo, hi = robot.position_limits()
    q, dq, ddq = random_states(lo, hi, 50, rng)
    Y = regressor(robot, q, dq, ddq)
    for _ in range(3):
        pi = rng.normal(size=robot.n_standard_params)
        beta = base.from_standard(pi)
        full = Y @ pi
        np.testing.assert_allclose(base.regressor(Y) @ beta, full, atol=1e-9 * np.abs(full).max())


def test_deterministic_and_named_in_natural_order():
    robot = load_robot("builtin:puma560")
    a, b = robot_base_parameters(robot), robot_base_parameters(robot)
    assert a.names == b.names and np.array_equal(a.K, b.K)
    assert list(a.independent) == sorted(a.independent)
    # classical grouping: the first link's rotor inertia and distal masses regroup into Izz1
    expr = dict(zip(a.names, a.expressions()))
    assert expr["Izz1"].startswith("Izz1 + Iyy2") and "Ia1" in expr["Izz1"]
    assert "0.4318*m3" in expr["mx2"]  # a2 = 0.4318 m
    assert "Ia1" not in a.names and "m1" not in a.names


def test_to_standard_maps_back_and_is_closest_to_reference():
    robot = load_robot("builtin:generic6r")
    base = robot_base_parameters(robot)
    ref = robot.nominal_parameters()
    rng = np.random.default_rng(5)
    beta = base.from_standard(ref) + rng.normal(scale=1e-2, size=base.n_base)
    pi = base.to_standard(beta, reference=ref)
    np.testing.assert_allclose(base.from_standard(pi), beta, atol=1e-10)
    # any other standard vector with the same base parameters is further from the reference
    null = np.linalg.svd(base.B)[2][base.n_base :]
    other = pi + null.T @ rng.normal(size=null.shape[0])
    np.testing.assert_allclose(base.from_standard(other), beta, atol=1e-9)
    assert np.linalg.norm(other - ref) > np.linalg.norm(pi - ref)


def test_coupled_wrist_adds_three_independent_motor_terms():
    from dynid.model import Coupling, Transmission

    plain = robot_base_parameters(load_robot("builtin:puma560"))
    tr = Transmission.from_ratios([32, 32, 45, -48, 45, 32], [Coupling(6, (5, 6))])
    coupled = robot_base_parameters(load_robot("builtin:puma560", transmission=tr))
    assert coupled.n_base == plain.n_base + 3
    assert {"Iam6", "fvm6", "fcm6"} <= set(coupled.names)


def test_too_small_a_sample_is_doubled_until_the_regrouping_holds_on_fresh_states():
    """Two states of a 6R arm give 12 equations for 84 parameters: the regrouping found there fails
    on fresh states, and the sample is doubled (2 -> 32 at most) until the base is the full one."""
    robot = load_robot("builtin:puma560")
    full = robot_base_parameters(robot)
    small = robot_base_parameters(robot, n_samples=2)
    assert small.n_samples > 2 and small.names == full.names
    # K solves the same triangular system from two samples: each to eps x cond(R11) (~1e3 for the
    # PUMA's base columns), so 1e-6 relative is a margin of 1e6 over the rounding
    np.testing.assert_allclose(small.K, full.K, rtol=1e-6, atol=1e-9 * np.abs(full.K).max())
