"""Log readers (CSV, TSV, NPZ, Parquet) and staged output folders, on real files in tmp_path."""

from __future__ import annotations

import hashlib
import importlib.util
import os
import stat

import numpy as np
import pytest

from dynid.errors import InputError, MissingExtraError
from dynid.io import TableReader, file_sha256, staged_output


def write_csv(path, header, rows, sep=","):
    path.write_text(sep.join(header) + "\n" + "".join(sep.join(str(v) for v in r) + "\n" for r in rows))
    return path


@pytest.fixture
def table():
    rng = np.random.default_rng(0)
    return rng.standard_normal((25, 4))


# ---------------------------------------------------------------------- CSV / TSV
class TestCsv:
    def test_columns_in_requested_order(self, tmp_path, table):
        path = tmp_path / "log.csv"
        np.savetxt(path, table, delimiter=",", header="t,a,b,c", comments="", fmt="%.17g")
        r = TableReader(path)
        assert r.kind == "csv"
        assert r.available == ["t", "a", "b", "c"]
        np.testing.assert_allclose(r.columns(["c", "t"]), table[:, [3, 0]], rtol=1e-15, atol=0)
        col = r.columns("b")
        assert col.shape == (25, 1)
        np.testing.assert_allclose(col[:, 0], table[:, 2], rtol=1e-15, atol=0)

    def test_tsv(self, tmp_path):
        path = write_csv(tmp_path / "log.tsv", ["t", "x"], [(0, 1.5), (0.1, -2.25)], sep="\t")
        np.testing.assert_array_equal(TableReader(path).columns(["x", "t"]), [[1.5, 0.0], [-2.25, 0.1]])

    def test_missing_columns_are_listed_with_what_the_file_has(self, tmp_path):
        path = write_csv(tmp_path / "log.csv", ["t", "q1", "q2"], [(0, 1, 2), (1, 3, 4)])
        with pytest.raises(InputError) as exc:
            TableReader(path).columns(["q1", "q3", "tau1"])
        # the path as given, the nearest names the file has (difflib), and everything it has
        assert str(exc.value) == (f"{path}: missing columns ['q3', 'tau1'] (nearest to 'q3': 'q2', 'q1'; no name like "
                                  "'tau1'); the file has ['t', 'q1', 'q2']")

    def test_non_numeric_cell(self, tmp_path):
        path = write_csv(tmp_path / "log.csv", ["t", "q1"], [(0, 1), (1, 2), (2, "abc"), (3, 4)])
        with pytest.raises(InputError, match=r"^log.csv: non-numeric value 'abc' in column 'q1' \(row 3\)$"):
            TableReader(path).columns(["t", "q1"])
        # the other column of that file is fine
        np.testing.assert_array_equal(TableReader(path).columns("t")[:, 0], [0, 1, 2, 3])

    def test_empty_cell_reads_as_nan_for_the_dataset_to_report(self, tmp_path):
        path = tmp_path / "log.csv"
        path.write_text("t,q1\n0,1\n1,\n2,3\n")
        x = TableReader(path).columns("q1")[:, 0]
        assert x[0] == 1.0 and np.isnan(x[1]) and x[2] == 3.0

    def test_header_only(self, tmp_path):
        path = write_csv(tmp_path / "log.csv", ["t", "q1"], [])
        with pytest.raises(InputError, match="log.csv: no data rows"):
            TableReader(path).columns("t")

    def test_binary_garbage(self, tmp_path):
        path = tmp_path / "log.csv"
        path.write_bytes(bytes(np.random.default_rng(1).integers(128, 256, 500, dtype=np.uint8)))
        with pytest.raises(InputError, match=r"log.csv is not UTF-8 text \(byte 0x[0-9a-f]{2} at offset 0 of the header\)"):
            TableReader(path).columns("t")

    def test_empty_column_list(self, tmp_path):
        path = write_csv(tmp_path / "log.csv", ["t"], [(0,), (1,)])
        with pytest.raises(InputError, match="empty column list"):
            TableReader(path).columns([])


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=f"^data file not found: {tmp_path / 'nope.csv'}$"):
        TableReader(tmp_path / "nope.csv")


def test_a_folder_is_not_a_file(tmp_path):
    (tmp_path / "dir.csv").mkdir()
    with pytest.raises(InputError, match="dir.csv is a folder, not a file"):
        TableReader(tmp_path / "dir.csv")


def test_unknown_suffix(tmp_path):
    path = tmp_path / "log.xlsx"
    path.write_text("t\n0\n")
    with pytest.raises(InputError, match=r"log.xlsx: unknown data file type '.xlsx' \(use .csv, .npz or .parquet\)"):
        TableReader(path)


def test_sha256(tmp_path):
    path = write_csv(tmp_path / "log.csv", ["t"], [(0,), (1,)])
    expected = hashlib.sha256(b"t\n0\n1\n").hexdigest()
    assert file_sha256(path) == expected == TableReader(path).sha256()


# ---------------------------------------------------------------------- NPZ
@pytest.fixture
def npz(tmp_path, table):
    path = tmp_path / "log.npz"
    np.savez(
        path,
        positions=table[:, :3],
        t=table[:, 0],
        a=table[:, 1],
        short=np.arange(5.0),
        names=np.array(["x", "y"]),
        cube=np.zeros((25, 2, 2)),
        **{"odd[1]": np.arange(25.0)},
    )
    return path


class TestNpz:
    def test_2d_key(self, npz, table):
        r = TableReader(npz)
        assert r.kind == "npz"
        np.testing.assert_array_equal(r.columns("positions"), table[:, :3])

    def test_list_of_1d_keys_stacks_columns(self, npz, table):
        np.testing.assert_array_equal(TableReader(npz).columns(["a", "t"]), table[:, [1, 0]])

    def test_indexed_column_of_a_2d_key(self, npz, table):
        r = TableReader(npz)
        np.testing.assert_array_equal(r.columns(["positions[2]", "positions[0]"]), table[:, [2, 0]])
        np.testing.assert_array_equal(r.columns(["t", "positions"]), np.column_stack([table[:, 0], table[:, :3]]))

    def test_a_key_that_looks_indexed_is_taken_literally_when_present(self, npz):
        np.testing.assert_array_equal(TableReader(npz).columns("odd[1]")[:, 0], np.arange(25.0))

    def test_missing_key_lists_keys(self, npz):
        with pytest.raises(InputError) as exc:
            TableReader(npz).columns(["t", "tau"])
        assert str(exc.value) == (f"{npz}: missing key 'tau' (nearest to 'tau': 't', 'a'); the file has ['a', 'cube', "
                                  "'names', 'odd[1]', 'positions', 'short', 't']")
        with pytest.raises(InputError, match="missing key 'tau\\[0\\]'"):
            TableReader(npz).columns("tau[0]")

    @pytest.mark.parametrize(
        "names, message",
        [
            ("positions[3]", r"'positions\[3\]' selects column 3 of an array of shape \(25, 3\)"),
            ("t[0]", r"'t\[0\]' selects column 0 of an array of shape \(25,\)"),
            (["t", "short"], r"mismatched lengths among \['t', 'short'\]: \[5, 25\]"),
            ("names", r"key 'names' is not numeric"),
            ("cube", r"key 'cube' has 3 dimensions; expected 1 or 2"),
        ],
    )
    def test_bad_selections(self, npz, names, message):
        with pytest.raises(InputError, match=message):
            TableReader(npz).columns(names)

    def test_not_a_zip_archive(self, tmp_path):
        path = tmp_path / "log.npz"
        with open(path, "wb") as fh:
            np.save(fh, np.arange(3.0))  # a .npy under an .npz name
        with pytest.raises(InputError, match="log.npz: not an NPZ file"):
            TableReader(path).columns("t")

    def test_object_arrays_are_refused_without_unpickling(self, tmp_path):
        path = tmp_path / "log.npz"
        np.savez(path, t=np.array([1.0, "a", None], dtype=object))
        with pytest.raises(InputError, match="log.npz: cannot read NPZ"):
            TableReader(path).columns("t")


# ---------------------------------------------------------------------- Parquet
def test_parquet(tmp_path, table):
    import pandas as pd

    path = tmp_path / "log.parquet"
    if importlib.util.find_spec("pyarrow") is None and importlib.util.find_spec("fastparquet") is None:
        path.write_bytes(b"PAR1 not really")
        with pytest.raises(MissingExtraError, match="reading Parquet needs pyarrow: pip install pyarrow"):
            TableReader(path).columns("t")
        return
    pd.DataFrame(table, columns=["t", "a", "b", "c"]).to_parquet(path)
    np.testing.assert_array_equal(TableReader(path).columns(["b", "t"]), table[:, [2, 0]])


def test_parquet_rows_from_the_middle(tmp_path):
    """RowStream of a Parquet file from a row inside a later row group (the groups before it skipped by
    their footer sizes: a chunk on a cluster worker, dynid.pipeline.cluster_qr): the same rows, in
    blocks of the asked size."""
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    from dynid.io.readers import RowStream

    x = np.random.default_rng(0).standard_normal((10_000, 3))
    path = tmp_path / "log.parquet"
    pq.write_table(pa.table({"a": x[:, 0], "b": x[:, 1], "c": x[:, 2]}), path, row_group_size=777)
    rs = RowStream(TableReader(path), ["c", "a"])
    for start, stop, block in [(0, None, 1000), (776, 777, 5), (777, 5000, 333), (5443, 10_000, 10_000), (9_999, None, 7),
                               (10_000, None, 3)]:
        got = list(rs.blocks(start, stop, block))
        np.testing.assert_array_equal(np.concatenate(got) if got else np.empty((0, 2)), x[start:stop][:, [2, 0]])
        assert all(g.shape[0] == block for g in got[:-1])


# ---------------------------------------------------------------------- staged output
def snapshot(folder):
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))}


class TestStagedOutput:
    def test_success_moves_all_files_into_a_new_folder(self, tmp_path):
        out = tmp_path / "a" / "b" / "out"
        with staged_output(out) as stage:
            assert stage.parent == out.parent and not out.exists()
            (stage / "x.txt").write_text("x")
            (stage / "sub").mkdir()
            (stage / "sub" / "y.txt").write_text("y")
            assert not out.exists()  # nothing visible until the body succeeded
        assert snapshot(out) == {"sub": None, "sub/y.txt": b"y", "x.txt": b"x"}
        assert os.listdir(out.parent) == ["out"]  # no staging folder left behind
        umask = os.umask(0)
        os.umask(umask)
        assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~umask  # like mkdir, not mkdtemp's 0700

    def test_failure_creates_nothing(self, tmp_path):
        out = tmp_path / "new" / "deeper" / "out"
        with pytest.raises(RuntimeError, match="boom"):
            with staged_output(out) as stage:
                (stage / "x.txt").write_text("half")
                raise RuntimeError("boom")
        assert os.listdir(tmp_path) == []  # neither out nor the parents made for it

    def test_failure_leaves_an_existing_folder_untouched(self, tmp_path):
        out = tmp_path / "out"
        out.mkdir()
        (out / "result.json").write_text("old")
        (out / "notes.txt").write_text("mine")
        before = snapshot(out)
        with pytest.raises(KeyboardInterrupt):
            with staged_output(out) as stage:
                (stage / "result.json").write_text("new")
                raise KeyboardInterrupt
        assert snapshot(out) == before
        assert os.listdir(tmp_path) == ["out"]

    def test_success_into_an_existing_folder_replaces_its_files_and_keeps_others(self, tmp_path):
        out = tmp_path / "out"
        (out / "data").mkdir(parents=True)
        (out / "result.json").write_text("old")
        (out / "notes.txt").write_text("mine")
        with staged_output(out) as stage:
            (stage / "result.json").write_text("new")
            (stage / "data").mkdir()
            (stage / "data" / "train.csv").write_text("t\n")
        assert snapshot(out) == {"data": None, "data/train.csv": b"t\n", "notes.txt": b"mine", "result.json": b"new"}
        assert os.listdir(tmp_path) == ["out"]

    def test_out_is_an_existing_file(self, tmp_path):
        out = tmp_path / "out"
        out.write_text("keep")
        with pytest.raises(InputError, match="exists and is not a folder"):
            with staged_output(out):
                pytest.fail("the body must not run")
        assert out.read_text() == "keep"
        assert os.listdir(tmp_path) == ["out"]

    def test_parent_is_a_file(self, tmp_path):
        (tmp_path / "f").write_text("keep")
        with pytest.raises(InputError, match="cannot create output folder"):
            with staged_output(tmp_path / "f" / "out"):
                pytest.fail("the body must not run")
        assert os.listdir(tmp_path) == ["f"]


# ---------------------------------------------------------------------- plain numeric CSV without pandas
def test_plain_numeric_csv_reads_what_pandas_reads_without_loading_it(tmp_path):
    """A CSV of numbers only is read by NumPy (pandas + pyarrow weigh ~77 MB, issue 20 item 10):
    the same doubles as pandas' reader for 17-significant-digit text (both round decimal text to the
    nearest double: round trip of repr exact), and files pandas reads by other rules (NA markers,
    quoted fields, unnamed columns) still go through pandas, with its results and messages."""
    import subprocess
    import sys

    rng = np.random.default_rng(4)
    values = rng.standard_normal((200, 3)) * 10.0 ** rng.integers(-8, 8, (200, 3))
    path = tmp_path / "log.csv"
    path.write_text("a,b,c\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in values))
    code = ("import sys; from dynid.io import TableReader; x = TableReader(sys.argv[1]).columns(['c', 'a']); "
            "import numpy as np; np.save(sys.argv[2], x); print('pandas' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path), str(tmp_path / "x.npy")], capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == "False"
    got = np.load(tmp_path / "x.npy")
    np.testing.assert_array_equal(got, values[:, [2, 0]])
    import pandas as pd
    np.testing.assert_array_equal(got, pd.read_csv(path)[["c", "a"]].to_numpy(dtype=float))
    # NA markers: pandas' rules (NaN), not a refusal
    na = write_csv(tmp_path / "na.csv", ["a", "b"], [[1.0, 2.0], ["NA", 3.0], [4.0, ""]])
    got = TableReader(na).columns(["a", "b"])
    assert np.isnan(got[1, 0]) and np.isnan(got[2, 1]) and got[0, 0] == 1.0 and got[1, 1] == 3.0
    # a word among the numbers: pandas' message, with its row and column
    bad = write_csv(tmp_path / "bad.csv", ["a", "b"], [[1.0, 2.0], [3.0, "x"]])
    with pytest.raises(InputError, match=r"non-numeric value 'x' in column 'b' \(row 2\)"):
        TableReader(bad).columns(["a", "b"])
    # header only: pandas' message
    empty = tmp_path / "empty.csv"
    empty.write_text("a,b\n")
    with pytest.raises(InputError, match="no data rows"):
        TableReader(empty).columns(["a"])
