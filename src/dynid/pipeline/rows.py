"""Regression rows and their compression (issue 35: the pipeline split by concern): the base-regressor rows of a
processed log chunk by chunk (:func:`_chunks`, Gautier's parallel decimation), the row selection (:func:`row_mask`)
and the per-channel QR factors (:func:`build_problem`, :func:`_compress`) that experiments are stacked from
(:mod:`dynid.pipeline.experiments`). Re-exported by :mod:`dynid.pipeline.identification`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.dataset import Dataset
from dynid.errors import ConfigError, IdentifiabilityError, InputError
from dynid.estimation import ProblemBuilder, RegressionProblem
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import Rows, System, as_system
from dynid.pipeline.data import preprocess, reversal_keep, velocity_mask
from dynid.signals import decimation_filter


Progress = Callable[[str, int, int], None]
"""``progress(task, done, total)``: called as long work advances (the CLI draws a bar)."""

def _no_progress(task: str, done: int, total: int) -> None:
    return None


@dataclasses.dataclass(frozen=True)
class Chunk:
    """Base-regressor rows of a chunk: ``W`` (n, n_ch, r), measured outputs ``y`` (n, n_ch), the
    actuator velocities ``dq`` (n, n_a) (row selection, Stribeck friction) and the inconsistency of
    redundant actuator positions (n,)."""

    W: FloatArray
    y: FloatArray
    dq: FloatArray
    inconsistency: FloatArray
    joint_dq: FloatArray | None = None  # velocities of all joints of a mechanism (passive row selection)
    reversal: np.ndarray | None = None  # (n, n_a) rows farther than processing.reversal_guard from a reversal
    Ga: FloatArray | None = None  # (n, n_a, n_u) a redundant mechanism's actuator velocity map
    tau: FloatArray | None = None  # (n, n_a) measured actuator forces (with Ga: the other view of the outputs)


def _chunks(system: System, base: BaseParameters, ds: Dataset, force_model: str | None, *, parallel_decimate: int = 1,
            chunk_size: int = 20000, progress: Progress = _no_progress, task: str = "compress",
            periodic=None, reversal_guard: float | None = None,
            min_velocity: tuple[float, ...] | None = None, keep: np.ndarray | None = None,
            joint_q: FloatArray | None = None, project: FloatArray | None = None,
            tap: Callable[[int, int, FloatArray, Any], None] | None = None,
            torques: Callable[[FloatArray, FloatArray, FloatArray], FloatArray] | None = None) -> Iterator[Chunk]:
    """Yield the rows of ``ds`` chunk by chunk, at full rate or parallel-decimated.

    Parallel decimation (Gautier 1997; FIGAROH's TX40 pipeline): each column of the base
    regressor and each measured output are low-passed by the same zero-phase filter and one
    sample in ``k`` is kept, so forces and model see identical filtering even where the
    regressor is non-smooth (Coulomb ``sign`` columns). The rows are streamed through the filter
    (:func:`_parallel_chunks`): the backward pass of a chunk runs 15 filter time constants past it,
    which makes the result equal to whole-signal filtering to ~1e-12 without ever holding the full
    regressor. Full-rate chunks hold at most :data:`CHUNK_BYTES` of regressor rows (fewer rows than
    ``chunk_size`` where the rows are wide). ``periodic`` with ``domain = "pose"``: the whole averaged period
    at once through the platform pose (paper 004 §3.3).

    ``reversal_guard`` [s]: each chunk carries :func:`~dynid.pipeline.data.reversal_keep` of its
    rows, computed on the whole log (a reversal near a chunk boundary counts on both sides), around
    the reversals and the samples slower than ``min_velocity``. ``keep`` (n, n_a): a row selection
    decided beforehand, carried the same way instead (maximum likelihood keeps one selection for
    every candidate cut-off).

    ``joint_q`` (n, n_v): all joint positions of a mechanism where known (a simulated motion,
    :mod:`dynid.pipeline.control_loop`), the starting points of its position solve.

    ``project`` (r, m): the chunks carry ``W @ project`` (n, n_ch, m) instead of the base regressor,
    for a caller that needs only ``m`` combinations of its columns (the drive gains: the nominal
    torques, ``m = 1``). Decimated, the product is formed at full rate and then filtered: the filter
    is linear, so this is the filtered regressor times ``project`` to rounding, at the cost of
    filtering ``m`` columns per channel instead of ``r``.

    ``torques(q, dq, ddq)`` (n, n_ch): a serial arm only (its rows are the joint torques, ``y`` the
    measured efforts as given): the chunks carry these torques (n, n_ch, 1) in place of the
    regressor, which is not computed. The drive gains need the nominal torques ``W beta_nom`` alone,
    and pinocchio's RNEA gives them at about a third of the regressor's cost
    (:func:`~dynid.model.serial_dynamics.inverse_dynamics`; equal to rounding, bench/README.md "Cold
    start, fourth pass").

    ``tap(a, b, W, rows)``: parallel decimation only, called with every full-rate block (input rows
    ``a:b``, its base regressor ``W`` and the :class:`~dynid.model.system.Rows`) before it is
    filtered: what a caller needs at the full rate of the same rows, without computing them again
    (the held-out scores at the log's rate, :func:`~dynid.pipeline.validation.score_held_out`). The
    blocks are those of the full-rate chunks (:data:`CHUNK_BYTES`), so ``W`` is what they would give.
    """
    if periodic is not None and periodic.domain == "pose":
        if reversal_guard is not None:
            raise ConfigError("processing.reversal_guard applies to the time-domain processing, not to processing.periodic")
        r, dq = system.pose_rows(ds.q, ds.tau, 1.0 / float(np.median(np.diff(ds.t))), periodic.cutoff_hz, force_model)
        progress(task, ds.n_samples, ds.n_samples)
        Wb = base.regressor(r.W)
        yield Chunk(Wb if project is None else Wb @ project, r.y, dq, r.inconsistency, r.joint_dq)
        return
    if ds.dq is None or ds.ddq is None:
        raise InputError("the dataset has no velocities/accelerations; preprocess it first")
    if torques is not None and (system.kind != "serial" or project is not None or tap is not None):
        raise ValueError("torques: a serial arm's chunks only, without project or tap")
    n = ds.n_samples
    size = max(1, int(chunk_size) if system.max_chunk is None else min(int(chunk_size), system.max_chunk))
    rows = system.rows(force_model)
    guard = None if reversal_guard is None else reversal_keep(ds.dq, ds.t, reversal_guard, min_velocity)
    if keep is not None:
        guard = np.asarray(keep, dtype=bool)
    if parallel_decimate <= 1:
        n_ch = len(system.channel_names(force_model))
        size = min(size, max(512, CHUNK_BYTES // (8 * n_ch * (base.n_standard + base.n_base))))  # bounded memory
        for a in range(0, n, size):
            b = min(a + size, n)
            if torques is not None:
                r, Wb = _torque_rows(torques, ds, a, b)
            else:
                r = rows(ds.q[a:b], ds.dq[a:b], ds.ddq[a:b], ds.tau[a:b], a, **({} if joint_q is None else {"joint_q": joint_q[a:b]}))
                Wb = base.regressor(r.W)
            yield Chunk(Wb if project is None else Wb @ project, r.y, ds.dq[a:b], r.inconsistency, r.joint_dq,
                        None if guard is None else guard[a:b], r.Ga, None if r.Ga is None else ds.tau[a:b])
            progress(task, b, n)
        return
    k = parallel_decimate
    sos, margin = decimation_filter(k, ds.fs)
    if n <= 2 * k:
        raise InputError(f"{n} samples are too few to decimate by {k}")
    yield from _parallel_chunks(system, base, ds, force_model, k, sos, margin, size, rows, guard, joint_q,
                                progress, task, project, tap, torques)


def _torque_rows(torques: Callable[[FloatArray, FloatArray, FloatArray], FloatArray], ds: Dataset, a: int,
                 b: int) -> tuple[Rows, FloatArray]:
    """A serial arm's rows ``a:b`` with ``torques`` in place of the regressor (``_chunks``' ``torques``):
    the measured efforts as they are (what ``_SerialRows`` gives) and the torques as one column a channel."""
    r = Rows(W=None, y=np.asarray(ds.tau[a:b], dtype=float), inconsistency=np.zeros(b - a))
    return r, np.asarray(torques(ds.q[a:b], ds.dq[a:b], ds.ddq[a:b]), dtype=float)[:, :, None]


CHUNK_BYTES = 8 * 2**20
"""Bytes of full-rate regressor rows parallel decimation computes at once (:func:`_parallel_chunks`);
the rows it holds, ``out_rows + margin`` of the packed columns, follow from it."""


def _parallel_chunks(system: System, base: BaseParameters, ds: Dataset, force_model: str | None, k: int,
                     sos: FloatArray, margin: int, size: int, rows, guard: np.ndarray | None,
                     joint_q: FloatArray | None, progress: Progress, task: str,
                     project: FloatArray | None = None,
                     tap: Callable[[int, int, FloatArray, Any], None] | None = None,
                     torques: Callable[[FloatArray, FloatArray, FloatArray], FloatArray] | None = None) -> Iterator[Chunk]:
    """The parallel-decimated chunks of :func:`_chunks`, streamed (:class:`~dynid.signals.streamed.StreamedDecimation`):
    the base-regressor rows, outputs and velocities are computed in blocks of about
    :data:`CHUNK_BYTES`, packed side by side as the columns of one signal, low-passed and decimated
    together; the whole-window full-rate regressor ``(n, n_ch, r)`` is never held, only a window
    of ``out_rows + margin`` rows. Equal to the whole-signal filtering to rounding (the module
    docstring of :mod:`dynid.signals.streamed` bounds the difference). The quantities that are not
    filtered (position inconsistency, a redundant mechanism's ``G_a``, the row selection ``guard``)
    are taken at the kept rows."""
    from dynid.signals.streamed import StreamedDecimation

    n = ds.n_samples
    n_ch, r, n_std = len(system.channel_names(force_model)), base.n_base, base.n_standard
    block = min(size, max(4 * k, CHUNK_BYTES // (8 * n_ch * (n_std + r))))
    m = 1 if torques is not None else r if project is None else project.shape[1]  # columns per channel that are filtered
    block = max(block, min(n, 3 * (2 * sos.shape[0] + 1) + 1))  # the first block holds the odd extension
    packed = None  # (start, stop) of each field in the packed columns
    stream = None
    n_out = -(-n // k)
    sampled: dict[str, np.ndarray] = {}

    def take(name: str, a: int, values: np.ndarray | None) -> None:
        if values is None:
            return
        if name not in sampled:
            sampled[name] = np.empty((n_out,) + values.shape[1:], dtype=values.dtype)
        first = -(-a // k) * k
        sampled[name][first // k:first // k + len(values[first - a::k])] = values[first - a::k]

    for a in range(0, n, block):
        b = min(a + block, n)
        if torques is not None:
            rr, Wb = _torque_rows(torques, ds, a, b)
        else:
            rr = rows(ds.q[a:b], ds.dq[a:b], ds.ddq[a:b], ds.tau[a:b], a, **({} if joint_q is None else {"joint_q": joint_q[a:b]}))
            Wb = base.regressor(rr.W)
        if tap is not None:
            tap(a, b, Wb, rr)
        fields = {"W": Wb if project is None else Wb @ project, "y": rr.y, "dq": ds.dq[a:b], "joint_dq": rr.joint_dq,
                  "tau": None if rr.Ga is None else ds.tau[a:b]}
        fields = {key: np.asarray(v, dtype=float).reshape(b - a, -1) for key, v in fields.items() if v is not None}
        if packed is None:
            edges = np.cumsum([0] + [v.shape[1] for v in fields.values()])
            packed = {key: (int(edges[i]), int(edges[i + 1])) for i, key in enumerate(fields)}
            row_bytes = 8 * int(edges[-1])
            out_rows = max(margin, min(size, CHUNK_BYTES // row_bytes))
            stream = StreamedDecimation(sos, n, k, margin, out_rows)
        x = np.concatenate(list(fields.values()), axis=1)
        take("inconsistency", a, rr.inconsistency)
        take("Ga", a, rr.Ga)
        take("guard", a, None if guard is None else guard[a:b])
        del rr, fields, Wb
        for s, e, out in stream.feed(x):
            i0, i1 = s // k, s // k + out.shape[0]
            cut = {key: out[:, lo:hi] for key, (lo, hi) in packed.items()}
            yield Chunk(cut["W"].reshape(-1, n_ch, m), cut["y"], cut["dq"], sampled["inconsistency"][i0:i1],
                        cut.get("joint_dq"), sampled["guard"][i0:i1] if "guard" in sampled else None,
                        sampled["Ga"][i0:i1] if "Ga" in sampled else None, cut.get("tau"))
            progress(task, e, n)
        del x


def row_mask(system: System, force_model: str | None, dq: FloatArray, min_velocity: tuple[float, ...] | None,
             joint_dq: FloatArray | None = None,
             min_velocity_passive: float | None = None, reversal: np.ndarray | None = None) -> FloatArray | None:
    """Rows kept by ``processing.min_velocity`` (None: all): per actuator equation where the
    equations are the actuators' own, else (projected equations of a redundant mechanism) the
    whole samples in which every actuator is at least that fast, broadcast to the channels. A full noise covariance across channels (Gauss–Markov) takes per-equation rows:
    each sample is whitened with the covariance of the channels it keeps.

    ``min_velocity_passive`` (mechanisms): the whole samples in which a passive joint with Coulomb
    friction (:meth:`~dynid.model.system.ClosedLoopSystem.passive_friction_joints`) is slower are
    left out too: its friction reaches every equation through the loops, and where it sticks or
    reverses its force is whatever holds it, which no friction model describes.

    ``reversal`` (n, n_a): the rows farther than ``processing.reversal_guard`` from a reversal of
    each actuator (:attr:`Chunk.reversal`), combined with ``min_velocity`` by the same rule."""
    mask = velocity_mask(dq, min_velocity)
    if reversal is not None:
        mask = reversal if mask is None else mask & reversal
    if mask is not None and not system.channels_are_actuators(force_model):
        mask = mask.all(axis=1)
    if min_velocity_passive is None or joint_dq is None:
        return mask
    joints = list(system.passive_friction_joints())
    moving = np.all(np.abs(joint_dq[:, joints]) >= min_velocity_passive, axis=1)
    if mask is None:
        return moving
    return mask & (moving[:, None] if mask.ndim == 2 else moving)


def build_problem(robot, base: BaseParameters, ds: Dataset, *, force_model: str | None = None,
                  min_velocity: tuple[float, ...] | None = None, parallel_decimate: int = 1, chunk_size: int = 20000,
                  progress: Progress = _no_progress, meta: dict[str, Any] | None = None, cross: bool = False,
                  periodic=None, min_velocity_passive: float | None = None,
                  reversal_guard: float | None = None) -> RegressionProblem:
    """Compress a processed actuator-space dataset chunk by chunk (never the full regressor).

    ``robot``: a :class:`~dynid.model.system.System` or a model. ``min_velocity`` drops the rows
    where an actuator's (filtered) velocity is below the threshold [rad/s or m/s]: Coulomb friction
    is ill-defined there (:func:`row_mask`); ``reversal_guard`` [s] drops the rows that close to a
    reversal of the actuator (:func:`~dynid.pipeline.data.reversal_keep`).
    """
    return _compress(as_system(robot), base, ds, force_model=force_model, min_velocity=min_velocity,
                     parallel_decimate=parallel_decimate, chunk_size=chunk_size, progress=progress, meta=meta,
                     cross=cross, periodic=periodic, min_velocity_passive=min_velocity_passive,
                     reversal_guard=reversal_guard)[0]


def _compress(system: System, base: BaseParameters, ds: Dataset, *, force_model, min_velocity, parallel_decimate,
              chunk_size, progress, meta, cross, periodic, min_velocity_passive=None,
              blocks=None, reversal_guard: float | None = None,
              keep: np.ndarray | None = None, source: Iterator[Chunk] | None = None,
              check: bool = True) -> tuple[RegressionProblem, float]:
    """:func:`build_problem` and the largest inconsistency of redundant actuator positions; ``check``:
    refuse a row selection that leaves no more equations than base parameters (off for a segment of
    the log, :func:`~dynid.pipeline.identification._decide_structure`); ``blocks``
    (a :class:`~dynid.estimation.block_covariance.BlockBuilder`) also gets every chunk and its rows.
    ``source``: the chunks themselves (the streamed identification, :mod:`dynid.pipeline.streaming`;
    ``ds`` is then unused)."""
    builder = ProblemBuilder(base.names, system.channel_names(force_model), cross=cross)
    worst = 0.0
    if source is None:
        source = _chunks(system, base, ds, force_model, parallel_decimate=parallel_decimate, chunk_size=chunk_size,
                         progress=progress, periodic=periodic, reversal_guard=reversal_guard,
                         min_velocity=min_velocity, keep=keep)
    for c in source:
        mask = row_mask(system, force_model, c.dq, min_velocity, joint_dq=c.joint_dq,
                        min_velocity_passive=min_velocity_passive, reversal=c.reversal)
        if mask is not None and mask.ndim == 1:
            builder.add(c.W[mask], c.y[mask])
        else:
            builder.add(c.W, c.y, mask)
        if blocks is not None:
            blocks.add(c.W, c.y, mask)
        worst = max(worst, float(c.inconsistency.max(initial=0.0)))
        del c  # the next chunk's rows are built without this one's alive beside them
    problem = builder.build(expressions=base.expressions(), standard=system.standard_map(base), meta=meta or {})
    selection = [k for k, v in (("min_velocity", min_velocity), ("min_velocity_passive", min_velocity_passive),
                                ("reversal_guard", reversal_guard)) if v is not None]
    if check and selection and problem.n_total <= base.n_base:
        rule = "whole samples (every actuator)" if not system.channels_are_actuators(force_model) else "per equation"
        raise IdentifiabilityError(
            f"data: the row selection ({', '.join('processing.' + k for k in selection)}; {rule}) keeps "
            f"{problem.n_total} equations for {base.n_base} base parameters; lower the thresholds or record a "
            "motion with fewer slow stretches and reversals")
    return problem, worst


def _model_rows(system: System, base: BaseParameters, params: FloatArray, ds: Dataset,
                chunk_size: int) -> tuple[FloatArray, FloatArray]:
    """(measured, predicted) joint torques of a processed serial-robot Dataset at every sample."""
    meas, pred = [], []
    for c in _chunks(system, base, ds, None, chunk_size=chunk_size):
        meas.append(c.y)
        pred.append(c.W @ params)
    return np.concatenate(meas), np.concatenate(pred)
