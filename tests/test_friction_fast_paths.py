"""The validation-free friction evaluations and the analytic Jacobians (dynid.model.friction's
module-level functions and force_function, dynid.estimation.friction_curves' curve_force,
curve_jacobian and projected_jacobian) and the simulation loops built on them: the fast paths
evaluate what the dataclasses and the loops they replaced evaluated (the same operations: equal to
rounding), and the analytic Jacobians are the derivatives (against central differences, with a
margin from the step)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy.optimize import least_squares

from conftest import seed
from dynid.estimation.friction_curves import (MODELS, _bounds, curve_force, curve_jacobian, fit_curve,
                                              projected_jacobian)
from dynid.model import load_robot
from dynid.model.friction import (CoulombViscous, FrictionMemory, FrictionModel, PowerLawViscous, SmoothStribeck,
                                  Stribeck, coulomb_viscous_force, force_function, power_law_force,
                                  smooth_stribeck_force, stribeck_force)
from dynid.simulation.control import JointPID, SerialPlant, simulate_control
from dynid.tolerances import scaled

EPS = np.finfo(float).eps
RTOL = 8 * EPS  # the same operations on the same operands: equal but for the last bits of a few roundings


def _close(a, b, rtol=RTOL):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * max(float(np.abs(b).max()), 1e-300))


def _velocities(rng, n=40, nj=6):
    """Signed velocities over four decades, with exact zeros (sign(0) = 0)."""
    v = rng.choice([-1.0, 1.0], size=(n, nj)) * 10 ** rng.uniform(-4, 0.5, size=(n, nj))
    v[::7] = 0.0
    return v


def _models(rng, nj=6):
    """One model per class with random per-joint coefficients (and one with scalars)."""
    u = lambda lo, hi: rng.uniform(lo, hi, nj)  # noqa: E731
    return {
        "coulomb_viscous": CoulombViscous(fc=u(0.5, 5), fv=u(0.5, 5), offset=u(-1, 1)),
        "coulomb_viscous_asym": CoulombViscous(fc=u(0.5, 5), fv=u(0.5, 5), fc_neg=-u(0.5, 5), fv_neg=u(0.5, 5)),
        "stribeck": Stribeck(fc=u(0.5, 5), fs=u(5, 8), fv=u(0.5, 5), vs=u(0.01, 0.1), delta=u(0.5, 2.5)),
        "stribeck_scalar": Stribeck(fc=3.0, fs=5.0, fv=4.0, vs=0.05),
        "power_law": PowerLawViscous(fc=u(0.5, 5), fv=u(0.5, 5), alpha=u(0.3, 1.5), offset=u(-1, 1)),
        "smooth_stribeck": SmoothStribeck(fc=u(0.5, 5), fs=u(5, 8), fv=u(0.5, 5), vs=u(0.01, 0.1), kv=u(50, 900),
                                          alpha=u(0.3, 1.5)),
        "smooth_stribeck_scalar": SmoothStribeck(fc=3.0, fs=5.0, fv=4.0, vs=0.05, kv=200.0, alpha=0.7),
    }


def _reference_force(m, v):
    """The dataclasses' formulas as they were written before the module-level functions (the
    reference of the identity)."""
    if isinstance(m, CoulombViscous):
        if m.fc_neg is None and m.fv_neg is None:
            return m.fc * np.sign(v) + m.fv * v + m.offset
        fc_neg = -m.fc if m.fc_neg is None else m.fc_neg
        fv_neg = m.fv if m.fv_neg is None else m.fv_neg
        return np.where(v > 0, m.fc + m.fv * v, 0.0) + np.where(v < 0, fc_neg + fv_neg * v, 0.0) + m.offset
    if isinstance(m, Stribeck):
        return (m.fc + (m.fs - m.fc) * np.exp(-np.abs(v / m.vs) ** m.delta)) * np.sign(v) + m.fv * v
    if isinstance(m, PowerLawViscous):
        s = np.sign(v)
        return m.fv * np.abs(v) ** m.alpha * s + m.fc * s + m.offset
    smooth = 2.0 / np.pi * np.arctan(m.kv * v)
    return (m.fc + (m.fs - m.fc) * np.exp(-((v / m.vs) ** 2))) * smooth + m.fv * np.abs(v) ** m.alpha * np.sign(v)


def test_the_dataclasses_evaluate_the_module_functions():
    rng = np.random.default_rng(seed(11))
    v = _velocities(rng)
    for name, m in _models(rng).items():
        _close(m.force(v), _reference_force(m, v))
        _close(m.force(v[3]), _reference_force(m, v[3][None]))  # one sample -> (1, n_joints)
    m = _models(rng)["smooth_stribeck"]
    _close(smooth_stribeck_force(v, m.fc, m.fs, m.fv, m.vs, m.kv, m.alpha), m.force(v))
    m = _models(rng)["stribeck"]
    _close(stribeck_force(v, m.fc, m.fs, m.fv, m.vs, m.delta), m.force(v))
    m = _models(rng)["power_law"]
    _close(power_law_force(v, m.fc, m.fv, m.alpha, m.offset), m.force(v))
    m = _models(rng)["coulomb_viscous_asym"]
    _close(coulomb_viscous_force(v, m.fc, m.fv, m.fc_neg, m.fv_neg), m.force(v))


class _Quadratic(FrictionModel):
    """A model force_function knows nothing about (evaluated through its force)."""

    def force(self, dq):
        dq = np.atleast_2d(dq)
        return 0.5 * dq * np.abs(dq)


def test_force_function_is_force_at_one_sample():
    rng = np.random.default_rng(seed(12))
    v = _velocities(rng)
    models = {**_models(rng), "custom": _Quadratic(),
              "memory": FrictionMemory(_models(rng)["smooth_stribeck"], time_constant=0.01)}
    for name, m in models.items():
        one = force_function(m)
        for row in v:
            _close(one(row), m.force(row)[0])
        if name != "custom":  # the evaluators are picklable (a plant may travel to a worker process)
            _close(pickle.loads(pickle.dumps(one))(v[1]), m.force(v[1])[0])


def test_curve_force_is_the_classes_force():
    """curve_force without constructing a model per call evaluates what the classes did."""
    rng = np.random.default_rng(seed(13))
    v = np.abs(_velocities(rng, 60, 1)[:, 0])
    for _ in range(5):
        p = {"fc": rng.uniform(0.5, 5), "fs": rng.uniform(5, 8), "fv": rng.uniform(0.5, 5),
             "vs": rng.uniform(0.01, 0.1), "kv": rng.uniform(50, 900), "alpha": rng.uniform(0.3, 1.5)}
        via = {"coulomb_viscous": CoulombViscous(fc=p["fc"], fv=p["fv"]),
               "stribeck": Stribeck(fc=p["fc"], fs=p["fs"], fv=p["fv"], vs=p["vs"], delta=2.0),
               "power_law": PowerLawViscous(fc=p["fc"], fv=p["fv"], alpha=p["alpha"]),
               "smooth_stribeck": SmoothStribeck(**p),
               "arctan_stribeck": SmoothStribeck(**{**p, "alpha": 1.0})}
        for model, m in via.items():
            x = [p[n] for n in MODELS[model]]
            _close(curve_force(model, x, v), m.force(v[:, None])[:, 0])
            _close(curve_force(model, dict(zip(MODELS[model], x)), v), m.force(v[:, None])[:, 0])


def _central(fun, x, i, h):
    up, dn = x.copy(), x.copy()
    up[i] += h
    dn[i] -= h
    return (fun(up) - fun(dn)) / (up[i] - dn[i])


def _check_jacobian(fun, jac, x, delta=1e-5):
    """``jac(x)`` against central differences of ``fun`` with relative steps ``delta`` and
    ``delta/2``: their difference measures the truncation error (O(h^2): the one of the half step
    is a third of it), plus the rounding of a central difference, eps |f| / h, with margins."""
    J = jac(x)
    for i in range(x.size):
        h = delta * max(abs(x[i]), 1e-8)
        d1, d2 = _central(fun, x, i, h), _central(fun, x, i, h / 2)
        fmax = max(float(np.abs(fun(x)).max()), 1e-300)
        tol = 2 * np.abs(d1 - d2) / 3 + 16 * EPS * fmax / (h / 2) + 1e-12 * np.abs(d2).max()
        err = np.abs(J[:, i] - d2)
        assert np.all(err <= tol), (i, float((err - tol).max()), float(err.max()))


@pytest.mark.parametrize("model", list(MODELS))
def test_curve_jacobian_is_the_derivative(model):
    rng = np.random.default_rng(seed(14))
    v = np.concatenate([-np.geomspace(1e-3, 2.0, 15), [0.0], np.geomspace(1e-3, 2.0, 15)])
    table = {"fc": (0.5, 5), "fs": (5, 8), "fv": (0.5, 5), "vs": (0.01, 0.1), "kv": (50, 900), "alpha": (0.3, 1.5)}
    for _ in range(4):
        x = np.array([rng.uniform(*table[n]) for n in MODELS[model]])
        _check_jacobian(lambda y: curve_force(model, y, v), lambda y: curve_jacobian(model, y, v), x)


def test_projected_jacobian_is_the_derivative():
    """The mechanism's joint fit: curves of three joints reaching four channels through P."""
    rng = np.random.default_rng(seed(15))
    model, n, nc, nj = "smooth_stribeck", 25, 4, 3
    p = len(MODELS[model])
    dq = rng.normal(scale=0.3, size=(n, nj))
    P = rng.normal(size=(n, nc, nj))
    r = rng.normal(size=(n, nc))
    w = np.broadcast_to(rng.uniform(0.5, 2.0, nc)[None, :], (n, nc))
    mask = rng.random((n, nc)) < 0.8

    def resid(x):
        F = np.column_stack([curve_force(model, x[j * p:(j + 1) * p], dq[:, j]) for j in range(nj)])
        return ((r - np.einsum("ncj,nj->nc", P, F)) * w)[mask]

    x = np.concatenate([[rng.uniform(0.5, 3), rng.uniform(3, 6), rng.uniform(0.5, 3), rng.uniform(0.02, 0.1),
                         rng.uniform(50, 500), rng.uniform(0.4, 1.2)] for _ in range(nj)])
    _check_jacobian(resid, lambda y: projected_jacobian(model, y, dq, P, w, mask), x)


@pytest.mark.numerics
@pytest.mark.parametrize("model", list(MODELS))
def test_the_analytic_jacobian_fit_reaches_the_finite_difference_fits_minimum(model):
    """fit_curve (analytic Jacobian) and least_squares with scipy's 2-point Jacobian, same data,
    start, bounds and tolerances, stop at the same minimum: costs equal to 1e4 x the stopping
    tolerance (relative), parameters within 1e-2 standard errors (a relative cost excess c
    moves a parameter by about sqrt(2 c dof) standard errors: 3e-4 for c = 1e-8, dof = 10)."""
    rng = np.random.default_rng(seed(16))
    truth = {"fc": 3.0, "fs": 5.0, "fv": 4.0, "vs": 0.05, "kv": 200.0, "alpha": 0.7}
    v = np.geomspace(0.003, 0.8, 16)
    sigma = np.full(v.size, 0.02)
    f = curve_force("smooth_stribeck", truth, v) + rng.normal(scale=0.02, size=v.size)
    first = fit_curve(model, v, f, sigma)
    lo, hi = _bounds(MODELS[model], v)
    fd = least_squares(lambda x: (curve_force(model, x, v) - f) / sigma, first.params, bounds=(lo, hi), method="trf",
                       x_scale="jac", xtol=scaled(1e-12), ftol=scaled(1e-12), gtol=scaled(1e-12),
                       max_nfev=2000 * lo.size)
    an = fit_curve(model, v, f, sigma, start=first.params)
    cost = 0.5 * np.sum(((curve_force(model, an.params, v) - f) / sigma) ** 2)
    assert abs(cost - fd.cost) <= 1e4 * scaled(1e-12) * fd.cost
    free = np.isfinite(an.std)
    assert np.all(np.abs(an.params - fd.x)[free] <= 1e-2 * an.std[free])


# ------------------------------------------------------------------ the simulation loops

def _old_acceleration(plant, q, dq, tau, friction=None):
    import pinocchio as pin

    f = plant.friction.force(dq)[0] if friction is None else np.asarray(friction, dtype=float)
    return pin.aba(plant.model, plant.data, q, dq, np.asarray(tau, dtype=float) - f).copy()


def _old_loop(plant, controller, reference, duration, dt, substeps):
    """simulate_control as it was written before the fast paths (the reference of the identity):
    RK4 on (q, v), or on (q, v, z) with the friction state, each part an array of its own."""
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    qr, dqr, ddqr = reference(t)
    q, v = np.array(qr[0]), np.array(dqr[0])
    nv = q.size
    Q, V, A, T = (np.empty((n, nv)) for _ in range(4))
    h = dt / substeps
    memory = isinstance(plant.friction, FrictionMemory)
    z = plant.friction.force(v)[0].copy() if memory else None
    for k in range(n):
        tau = np.asarray(controller(dt, q, v, (qr[k], dqr[k], ddqr[k])), dtype=float)
        Q[k], V[k], T[k] = q, v, tau
        A[k] = _old_acceleration(plant, q, v, tau, z)
        if k == n - 1:
            break
        for _ in range(substeps):
            if memory:
                def f(qq, vv, zz):
                    return vv, _old_acceleration(plant, qq, vv, tau, zz), plant.friction.rate(vv, zz)

                k1 = f(q, v, z)
                k2 = f(q + h / 2 * k1[0], v + h / 2 * k1[1], z + h / 2 * k1[2])
                k3 = f(q + h / 2 * k2[0], v + h / 2 * k2[1], z + h / 2 * k2[2])
                k4 = f(q + h * k3[0], v + h * k3[1], z + h * k3[2])
                q, v, z = (x + h / 6 * (a + 2 * b + 2 * c + d) for x, a, b, c, d in zip((q, v, z), k1, k2, k3, k4))
            else:
                def acc(a, b):
                    return _old_acceleration(plant, a, b, tau)

                a1 = acc(q, v)
                a2 = acc(q + h / 2 * v, v + h / 2 * a1)
                a3 = acc(q + h / 2 * (v + h / 2 * a1), v + h / 2 * a2)
                a4 = acc(q + h * (v + h / 2 * a2), v + h * a3)
                q, v = q + h * v + h**2 / 6 * (a1 + a2 + a3), v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
    return Q, V, A, T


@pytest.mark.parametrize("kind", ["memory", "smooth", "default"])
def test_simulate_control_integrates_what_the_plain_loop_integrated(kind):
    """The loops on a stacked state (q, v, z) with force_function's evaluator and the first stage
    taken from the logged acceleration integrate what the plain RK4 loop did: equal to rounding
    (the same operations), amplified at most mildly by 0.2 s of PID-controlled motion."""
    robot = load_robot("builtin:cobot6r")
    steady = SmoothStribeck(fc=[3.0, 2.5, 2.0, 1.0, 0.8, 0.6], fs=[4.0, 3.3, 2.6, 1.3, 1.0, 0.8],
                            fv=[4.0, 5.0, 3.0, 1.5, 1.2, 1.0], vs=0.08, kv=200.0, alpha=[0.7, 0.6, 0.8, 0.9, 0.7, 0.8])
    friction = {"memory": FrictionMemory(steady, 0.01), "smooth": steady, "default": None}[kind]
    plant = SerialPlant(robot, robot.nominal_parameters(), friction=friction)
    w, a = np.array([3.0, 2.5, 2.0, 3.5, 4.0, 5.0]), np.array([0.3, 0.2, 0.25, 0.4, 0.3, 0.5])

    def reference(t):
        t = np.asarray(t)[:, None]
        return a * np.sin(w * t), a * w * np.cos(w * t), -a * w * w * np.sin(w * t)

    gains = dict(kp=np.array([1500, 1800, 800, 180, 200, 110.0]), kd=np.array([50, 60, 27, 6, 7, 3.6]),
                 ki=np.array([1.5e4, 1.8e4, 8e3, 1.8e3, 2e3, 1.1e3]))
    m = simulate_control(plant, JointPID(**gains), reference, duration=0.2, dt=4e-3, substeps=4)
    old = _old_loop(plant, JointPID(**gains), reference, 0.2, 4e-3, 4)
    for new, ref in zip((m.q, m.dq, m.ddq, m.tau), old):
        _close(new, ref, rtol=1e3 * EPS)
