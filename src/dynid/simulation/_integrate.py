"""One step of classical Runge–Kutta 4 for :math:`\\ddot q = f(q, \\dot q)` (the held torque is
inside ``f``), shared by the serial and the closed-loop simulators."""

from __future__ import annotations

from collections.abc import Callable

from dynid._typing import FloatArray


def rk4_step(acc: Callable[[FloatArray, FloatArray], FloatArray], q: FloatArray, v: FloatArray, h: float,
             k1: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Positions and velocities after ``h`` seconds (RK4 on the first-order system (q, v)).
    ``k1``: ``acc(q, v)`` when the caller has it already (the acceleration logged at a control
    instant is the first stage of the hold's first step).

    The stages' velocities :math:`v + \\tfrac h2 k_1` and :math:`v + \\tfrac h2 k_2` are also the
    next stages' position slopes; each is formed once (the same operations: the same result to
    the last bit as forming them twice)."""
    k1 = acc(q, v) if k1 is None else k1
    h2 = h / 2
    v2 = v + h2 * k1
    k2 = acc(q + h2 * v, v2)
    v3 = v + h2 * k2
    k3 = acc(q + h2 * v2, v3)
    k4 = acc(q + h * v3, v + h * k3)
    return q + h * v + h**2 / 6 * (k1 + k2 + k3), v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
