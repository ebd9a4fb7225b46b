"""Dataset: validation of inputs, read-only arrays, windows, sampling rate."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynid.dataset import Dataset
from dynid.errors import InputError


def make(n=10, dt=0.25, n_q=2, **kw):
    t = np.arange(n) * dt  # 0.25 s: exact binary times
    q = np.column_stack([np.sin(t + j) for j in range(n_q)])
    tau = 2.0 * q
    args = dict(t=t, q=q, tau=tau)
    args.update(kw)
    return Dataset(**args)


class TestShapes:
    def test_one_dimensional_channels_become_columns(self):
        t = np.arange(5) * 0.1
        ds = Dataset(t=t, q=np.arange(5.0), tau=-np.arange(5.0), dq=np.ones(5))
        assert ds.q.shape == ds.tau.shape == ds.dq.shape == (5, 1)
        assert ds.names == ("q1",)
        np.testing.assert_array_equal(ds.tau[:, 0], -np.arange(5.0))

    def test_default_and_given_names(self):
        assert make(n_q=3).names == ("q1", "q2", "q3")
        assert make(n_q=2, names=["a", "b"]).names == ("a", "b")
        with pytest.raises(InputError, match="1 channel names for 2 position channels"):
            make(n_q=2, names=("a",))

    def test_time_must_be_1d(self):
        with pytest.raises(InputError, match=r"time must be 1-D \(n_samples\), got shape \(10, 1\)"):
            make(t=(np.arange(10) * 0.1)[:, None])

    def test_channels_must_be_at_most_2d(self):
        with pytest.raises(InputError, match=r"positions must be 2-D .* got shape \(10, 2, 1\)"):
            make(q=np.zeros((10, 2, 1)))

    def test_mismatched_lengths(self):
        with pytest.raises(InputError, match="mismatched lengths: time has 10 samples, efforts has 9"):
            make(tau=np.zeros((9, 2)))
        with pytest.raises(InputError, match="mismatched lengths: time has 10 samples, positions has 11"):
            make(q=np.zeros((11, 2)))
        with pytest.raises(InputError, match=r"mismatched shapes: velocities \(10, 1\) vs positions \(10, 2\)"):
            make(dq=np.zeros(10))

    def test_needs_two_samples(self):
        with pytest.raises(InputError, match="at least 2 samples, got 1"):
            Dataset(t=[0.0], q=[[1.0]], tau=[[1.0]])


class TestNonFinite:
    def test_nan_names_array_and_first_sample(self):
        q = make().q.copy()
        q[7, 1] = np.nan
        q[8, 0] = np.nan
        with pytest.raises(InputError, match=r"^positions contains NaN values \(2 entries, first at sample 7\)$"):
            make(q=q)

    def test_inf_in_efforts(self):
        tau = np.zeros((10, 2))
        tau[4, 0] = -np.inf
        with pytest.raises(InputError, match=r"^efforts contains inf values \(1 entries, first at sample 4\)$"):
            make(tau=tau)

    def test_kind_is_that_of_the_first_bad_sample(self):
        q = make().q.copy()
        q[3, 0] = np.inf
        q[5, 1] = np.nan
        with pytest.raises(InputError, match=r"positions contains inf values \(2 entries, first at sample 3\)"):
            make(q=q)

    @pytest.mark.parametrize("field, label", [("t", "time"), ("dq", "velocities"), ("ddq", "accelerations")])
    def test_every_array_is_checked(self, field, label):
        base = make()
        arr = (base.t if field == "t" else base.q).copy()
        arr[2] = np.nan
        with pytest.raises(InputError, match=f"^{label} contains NaN values"):
            make(**{field: arr})


class TestTime:
    @pytest.mark.parametrize(
        "t, message",
        [
            ([0.0, 0.25, 0.5, 0.5, 1.0], r"at sample 3 \(t=0.5 after t=0.5\)"),
            ([0.0, 0.25, 0.75, 0.5, 1.0], r"at sample 3 \(t=0.5 after t=0.75\)"),
        ],
        ids=["repeated", "backwards"],
    )
    def test_not_strictly_increasing(self, t, message):
        with pytest.raises(InputError, match="time is not strictly increasing " + message):
            Dataset(t=t, q=np.zeros(5), tau=np.zeros(5))

    def test_fs_and_duration(self):
        ds = make(n=11, dt=0.25)
        assert ds.fs == pytest.approx(4.0, rel=1e-12)
        assert ds.duration == pytest.approx(2.5, rel=1e-12)
        assert ds.n_samples == 11

    def test_fs_is_the_median_rate_despite_a_gap(self):
        t = np.r_[np.arange(50) * 0.01, 1.0 + np.arange(50) * 0.01]  # one 0.51 s dropout
        ds = Dataset(t=t, q=np.zeros(100), tau=np.zeros(100))
        assert ds.fs == pytest.approx(100.0, rel=1e-9)
        assert not ds.is_uniform()

    def test_is_uniform(self):
        rng = np.random.default_rng(4)
        n = 200
        assert make(n=n, dt=0.01).is_uniform()
        jittered = np.arange(n) * 0.01 + rng.uniform(-2e-6, 2e-6, n)  # |dt - 0.01| <= 4e-6 < 1e-3 * 0.01
        assert Dataset(t=jittered, q=np.zeros(n), tau=np.zeros(n)).is_uniform()
        rough = np.arange(n) * 0.01 + rng.uniform(-5e-4, 5e-4, n)
        ds = Dataset(t=rough, q=np.zeros(n), tau=np.zeros(n))
        assert not ds.is_uniform()
        assert ds.is_uniform(rtol=0.2)


class TestImmutability:
    def test_arrays_are_read_only(self):
        ds = make(dq=np.zeros((10, 2)))
        for arr in (ds.t, ds.q, ds.tau, ds.dq):
            with pytest.raises(ValueError, match="read-only"):
                arr[0] = 1.0

    def test_inputs_are_copied(self):
        q = np.zeros((10, 1))
        ds = make(q=q)
        q[0, 0] = 5.0
        assert ds.q[0, 0] == 0.0

    def test_fields_and_meta_are_frozen(self):
        ds = make(meta={"source": "x"})
        with pytest.raises(dataclasses.FrozenInstanceError):
            ds.q = np.zeros((10, 2))
        with pytest.raises(TypeError):
            ds.meta["source"] = "y"

    def test_replace_returns_a_new_value_and_merges_meta(self):
        ds = make(meta={"source": "a", "effort_kind": "torque"})
        new = ds.replace(tau=np.ones((10, 2)), meta={"effort_kind": "current"})
        assert dict(new.meta) == {"source": "a", "effort_kind": "current"}
        np.testing.assert_array_equal(new.tau, 1.0)
        assert ds.tau[0, 0] == 0.0 and ds.meta["effort_kind"] == "torque"


class TestWindows:
    def test_rows(self):
        ds = make(n=10, dq=np.arange(20.0).reshape(10, 2))
        w = ds.rows(2, 7)
        np.testing.assert_array_equal(w.t, np.arange(2, 7) * 0.25)
        np.testing.assert_array_equal(w.q, ds.q[2:7])
        np.testing.assert_array_equal(w.dq, ds.dq[2:7])
        assert w.ddq is None
        assert w.meta["history"] == ("rows[2:7]",)
        assert w.rows(1, 3).meta["history"] == ("rows[2:7]", "rows[1:3]")

    def test_rows_python_slice_semantics(self):
        ds = make(n=10)
        np.testing.assert_array_equal(ds.rows(-4, 10).t, ds.t[-4:])
        np.testing.assert_array_equal(ds.rows(7, 100).t, ds.t[7:])

    @pytest.mark.parametrize("start, stop, selected", [(3, 4, 1), (5, 5, 0), (8, 2, 0)])
    def test_rows_selecting_fewer_than_two(self, start, stop, selected):
        with pytest.raises(InputError, match=rf"row window \[{start}, {stop}\) selects {selected} of 10 samples"):
            make(n=10).rows(start, stop)

    def test_select_keeps_the_given_samples(self):
        ds = make(n=10, dq=np.arange(20.0).reshape(10, 2))
        w = ds.select(np.array([0, 3, 9]), "every third")
        np.testing.assert_array_equal(w.t, ds.t[[0, 3, 9]])
        np.testing.assert_array_equal(w.dq, ds.dq[[0, 3, 9]])
        assert w.meta["history"] == ("every third",)

    @pytest.mark.parametrize("idx", [[3], [4, 2], [0, 10], [-1, 3]])
    def test_select_refuses_bad_indices(self, idx):
        with pytest.raises(InputError, match="increasing sample indices within the 10 samples"):
            make(n=10).select(np.array(idx), "bad")

    def test_time_window_is_half_open(self):
        ds = make(n=10, dt=0.25)  # t = 0, 0.25, ..., 2.25
        w = ds.time_window(0.5, 1.5)
        np.testing.assert_array_equal(w.t, [0.5, 0.75, 1.0, 1.25])
        np.testing.assert_array_equal(w.tau, ds.tau[2:6])
        assert w.meta["history"] == ("time[0.5:1.5]",)

    def test_time_window_outside_the_data(self):
        with pytest.raises(InputError, match=r"selects 0 samples; data span \[0.0, 2.25\] s"):
            make(n=10, dt=0.25).time_window(5.0, 6.0)
