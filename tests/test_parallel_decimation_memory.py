"""Parallel decimation streamed through the regressor (dynid.signals.streamed): equal to the
whole-signal zero-phase filtering, and a memory peak that does not grow with the training window
(issue 20, item 10: the TX40 identification held the whole window's full-rate regressor)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from dynid.dataset import Dataset
from dynid.model import load_robot, robot_base_parameters
from dynid.model.serial_dynamics import inverse_dynamics
from dynid.pipeline.identification import build_problem
from dynid.signals import decimation_filter, lowpass_sos
from dynid.signals.streamed import StreamedDecimation
from dynid.simulation import FourierTrajectory


def _signal(n: int, seed: int = 0) -> np.ndarray:
    """Random walks with sign jumps (the non-smooth Coulomb columns parallel decimation is for)."""
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.standard_normal((n, 5)), axis=0) + np.sign(rng.standard_normal((n, 5)))


@pytest.mark.parametrize("n, k, fs, block, out_rows", [
    (24750, 100, 5000.0, 3000, 5000),  # the TX40 configuration's filter (margin 4775 rows)
    (5000, 10, 1000.0, 37, 1000),      # blocks shorter than the padding carried over
    (2000, 4, 200.0, 500, 100),        # output chunks far shorter than the margin
    (300, 10, 1000.0, 28, 50),         # the whole signal inside one margin
])
def test_streamed_decimation_equals_whole_signal_filtering(n, k, fs, block, out_rows):
    """Fed block by block, the kept rows equal lowpass_sos(x)[::k] of the whole signal: the forward
    pass is the same recursion, the backward pass of a chunk starts ``margin`` rows late, a state
    mismatch decaying as rho^j (module docstring): below 1e-9 of the signal's range."""
    sos, margin = decimation_filter(k, fs)
    x = _signal(n)
    ref = lowpass_sos(x, sos)[::k]
    sd = StreamedDecimation(sos, n, k, margin, out_rows)
    chunks = [c for a in range(0, n, block) for c in sd.feed(x[a:a + block])]
    assert sd.done
    starts = [s for s, _, _ in chunks]
    assert starts == sorted(starts) and all(s % k == 0 for s in starts)
    got = np.concatenate([c[2] for c in chunks])
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * np.ptp(x))
    # the chunks whose backward pass reaches the padded end start where the whole signal's does
    s_last = chunks[-1][0]
    np.testing.assert_allclose(chunks[-1][2], ref[s_last // k:], rtol=0, atol=1e-12 * np.ptp(x))


def test_streamed_decimation_needs_the_padding_in_its_first_block():
    sos, margin = decimation_filter(10, 1000.0)
    sd = StreamedDecimation(sos, 1000, 10, margin, 100)
    with pytest.raises(ValueError, match="first block"):
        sd.feed(_signal(10))


ROBOT = load_robot("builtin:generic6r")
FS = 500.0


def _log(n: int) -> Dataset:
    rng = np.random.default_rng(3)
    lo, hi = ROBOT.position_limits()
    traj = FourierTrajectory.random(6, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    t = np.arange(n) / FS
    q, dq, ddq = traj.sample(t)
    tau = inverse_dynamics(ROBOT, ROBOT.nominal_parameters(), q, dq, ddq) + 0.1 * rng.standard_normal(q.shape)
    return Dataset(t=t, q=q, tau=tau, dq=dq, ddq=ddq)


def test_parallel_decimation_peak_does_not_grow_with_the_window():
    """The traced peak of compressing a parallel-decimated log (default chunk_size 20 000) at 4N is
    the peak at N plus at most 100 bytes a sample of the extra rows. What may grow: the decimated
    per-row quantities (inconsistency, 8 B per kept row, one row in k = 10). The whole-window
    version this replaces held the full-rate base regressor (6 x 58 columns, 2.8 kB a sample) and
    the filter's copies of it (~12 kB a sample). N = 8 000 already holds a full window (out_rows +
    margin + one block, about 4 500 rows here), so the window's own size is the same at both N."""
    base = robot_base_parameters(ROBOT)
    build_problem(ROBOT, base, _log(3000), parallel_decimate=10)  # imports outside the measurement
    peaks = {}
    for n in (8000, 32000):
        ds = _log(n)
        tracemalloc.start()
        try:
            problem = build_problem(ROBOT, base, ds, parallel_decimate=10)
            peaks[n] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert list(problem.n_obs) == [n // 10] * 6
    growth = (peaks[32000] - peaks[8000]) / 24000
    assert growth < 100.0, f"{growth:.1f} B per sample (peaks {peaks})"
