"""Fleets of robots (``dynid fleet``): many robots x many logs identified in parallel on Dask, then
pooled per robot and compared over the fleet (spread, outliers, drift).

Modules: :mod:`~dynid.fleet.jobs` (one log, on a worker), :mod:`~dynid.fleet.run` (the Dask run),
:mod:`~dynid.fleet.statistics` (fusion, spread, outliers, trend, change point),
:mod:`~dynid.fleet.analysis` (the fleet from the logs), :mod:`~dynid.fleet.output` (files, report).
"""
