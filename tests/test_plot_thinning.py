"""Series thinning for plots (issue 20, item 8): no more points than the panel has pixels, and the
drawn envelope is the full series' (every pixel column's smallest and largest value kept, a spike
one sample wide included: a stride would drop it)."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.report.plots import _thin, _thin_edges


@pytest.mark.parametrize("n, n_px", [(100_003, 880), (24_750, 490), (5_000, 1_000), (1_001, 2_000), (7, 3)])
def test_thin_keeps_the_envelope_within_the_pixel_budget(n, n_px):
    rng = np.random.default_rng(n)
    x = np.linspace(0.0, 5.0, n)
    y = np.sin(2 * np.pi * 1.3 * x) + 0.05 * rng.standard_normal(n)
    spike = n // 3
    y[spike] = 40.0  # one sample
    tx, ty = _thin(x, y, n_px)
    if n <= n_px:
        assert tx is x and ty is y
        return
    assert tx.size <= n_px and tx.size == ty.size
    assert np.all(np.diff(tx) > 0)  # in time order, no repeats
    # every kept point is a sample of the series
    idx = np.searchsorted(x, tx)
    assert np.array_equal(x[idx], tx) and np.array_equal(y[idx], ty)
    # the envelope over any span of pixel columns is the full series': global and the spike
    assert ty.max() == y.max() == 40.0 and ty.min() == y.min()
    # per run of samples the thinning used, the extremes are kept exactly
    edges = _thin_edges(n, n_px)
    for b in range(0, edges.size - 1, max(1, (edges.size - 1) // 17)):
        seg = slice(edges[b], edges[b + 1])
        inside = (tx >= x[seg][0]) & (tx <= x[seg][-1])
        assert ty[inside].max() == y[seg].max() and ty[inside].min() == y[seg].min()


@pytest.mark.parametrize("n, n_px", [(1_463, 978), (24_749, 490), (100_003, 880)])
def test_thin_runs_cover_the_series_evenly(n, n_px):
    """No stretch of the series is drawn coarser than the rest: the runs differ in length by at
    most one sample, so two kept points are never more than two runs apart (runs of n // buckets
    with the rest in one run drew the last third of a 1 463-sample series as two points)."""
    edges = _thin_edges(n, n_px)
    runs = np.diff(edges)
    assert edges[0] == 0 and edges[-1] == n and runs.max() - runs.min() <= 1 and edges.size - 1 == n_px // 2
    x = np.arange(n, dtype=float)
    y = np.random.default_rng(1).standard_normal(n)
    tx, _ = _thin(x, y, n_px)
    assert np.diff(tx).max() <= 2 * runs.max() - 1 and tx[0] <= runs.max() - 1 and tx[-1] >= n - runs.max()
