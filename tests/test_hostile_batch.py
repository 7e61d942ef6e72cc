"""Hostile data files and databases (issue 15 items 3, 8, 10): a dataset that cannot be read
is recorded as failed and the run goes on; two batches on one database estimate each dataset
once; a foreign SQLite file, a read-only folder and a result naming any path are refused."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import arc

import kanagen
from benchmarks.hostile import bad_data_files
from kanagen.cli import main
from kanagen.dataio import DataError, read_measures

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]
LATTICE = str(ROOT / "examples" / "conic_lattice.yaml")
FAST = {"scale": 4.0, "max_samples": 20}


def _good(folder: Path, count: int) -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(count):
        xy, _ = arc(("line", "circle")[k % 2], 300 + k, n=15)
        path = folder / f"good{k:02d}.csv"
        np.savetxt(path, xy, delimiter=",", header="x,y", comments="", fmt="%.6f")
        paths.append(str(path))
    return paths


def test_unreadable_files_are_one_clear_error(tmp_path):
    for name, reason in bad_data_files(tmp_path).items():
        with pytest.raises(DataError, match=reason) as err:
            read_measures(tmp_path / name, ("x", "y"), "point")
        assert str(err.value).startswith(str(tmp_path / name)), name
        assert "99999" not in str(err.value)  # never the file's content


def test_a_bom_and_a_header_in_any_column_order_read(tmp_path):
    path = tmp_path / "bom.csv"
    path.write_bytes("\ufeffy,x\n2,1\n4,3\n".encode())
    np.testing.assert_array_equal(read_measures(path, ("x", "y"), "point"), [[1, 2], [3, 4]])


def test_a_batch_records_each_unreadable_file_and_estimates_the_others(tmp_path):
    good = _good(tmp_path / "data", 3)
    reasons = bad_data_files(tmp_path / "data")
    db = tmp_path / "r.sqlite"
    summary = kanagen.batch(LATTICE, str(tmp_path / "data" / "*"), db=db, workers=1, **FAST)
    table = {Path(r["dataset"]).name: r for r in kanagen.read_results(db)}
    assert summary.datasets == len(good) + len(reasons)
    assert summary.errors == len(reasons) and summary.ok + summary.no_model == len(good)
    for name, reason in reasons.items():
        assert table[name]["status"] == "error" and reason in table[name]["message"], name
    for path in good:
        assert table[Path(path).name]["status"] == "ok"
    # a rerun does not stop at the same file: everything is recorded
    again = kanagen.batch(LATTICE, str(tmp_path / "data" / "*"), db=db, workers=1, **FAST)
    assert again.estimated == 0 and again.skipped == summary.datasets


def _run_batch(folder: Path, db: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "kanagen", "batch", LATTICE, str(folder / "*.csv"), "--db",
         str(db), "--workers", "1", "--scale", "4", "--max-samples", "20"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.parametrize("existing", [False, True], ids=["new db", "existing db"])
def test_two_concurrent_batches_estimate_each_dataset_once(tmp_path, existing):
    """Two batch processes started together on one database: no "database is locked", and
    every dataset estimated once in all (each claims a dataset before estimating it)."""
    paths = _good(tmp_path / "data", 8)
    db = tmp_path / "r.sqlite"
    if existing:
        kanagen.batch(LATTICE, paths[:1], db=db, workers=1, **FAST)
    runs = [_run_batch(tmp_path / "data", db) for _ in range(2)]
    outputs = [run.communicate(timeout=600) for run in runs]
    for run, (_, err) in zip(runs, outputs, strict=True):
        assert run.returncode == 0, err
    estimated = 0
    for out, _ in outputs:
        line = out.strip().splitlines()[-1]
        estimated += int(line.split(": ")[1].split(" estimated")[0])
    assert estimated == len(paths) - existing
    rows = kanagen.read_results(db)
    assert sorted(r["dataset"] for r in rows) == sorted(paths)
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT COUNT(*) FROM claims").fetchone()[0] == 0


def test_a_claim_of_a_dead_run_is_taken_over(tmp_path):
    from kanagen.resultsdb import ResultsDB, claim_owner

    paths = _good(tmp_path / "data", 2)
    db = tmp_path / "r.sqlite"
    options = kanagen.fitjob.FitOptions(**FAST).key("point")
    sha = kanagen.load(LATTICE).sha256
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    with ResultsDB(db) as store:
        host = claim_owner().split(":")[0]
        assert store.claim(paths[0], sha, options, f"{host}:{dead}:gone")
        mine = claim_owner()
        assert store.claim(paths[0], sha, options, mine)  # its process is gone
        assert not store.claim(paths[0], sha, options, f"{host}:{os.getpid()}:other")
        store.release(mine)
    summary = kanagen.batch(LATTICE, paths, db=db, workers=1, **FAST)
    assert summary.estimated == 2


def test_a_foreign_sqlite_file_is_refused_unchanged(tmp_path):
    db = tmp_path / "mine.sqlite"
    with sqlite3.connect(db) as con:
        con.execute("CREATE TABLE accounts (name TEXT)")
        con.execute("INSERT INTO accounts VALUES ('me')")
    before = db.read_bytes()
    paths = _good(tmp_path / "data", 1)
    with pytest.raises(ValueError, match="not a kanagen results database"):
        kanagen.batch(LATTICE, paths, db=db, workers=1, **FAST)
    assert db.read_bytes() == before
    with sqlite3.connect(db) as con:
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
        assert {r[0] for r in con.execute("SELECT name FROM sqlite_master")} == {"accounts"}


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root writes into read-only folders")
def test_a_new_db_in_a_read_only_folder_is_a_clear_error(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    paths = _good(tmp_path / "data", 1)
    out = CliRunner().invoke(main, ["batch", LATTICE, paths[0], "--db",
                                    str(folder / "r.sqlite"), "--scale", "4"])
    assert out.exit_code == 2 and "cannot open the results database" in out.output
    assert "Traceback" not in out.output


def test_a_db_path_that_cannot_be_opened_is_a_clear_error(tmp_path):
    """(As root the read-only folder above is writable: a path under a file stands for it.)"""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    paths = _good(tmp_path / "data", 1)
    out = CliRunner().invoke(main, ["batch", LATTICE, paths[0], "--db",
                                    str(blocker / "r.sqlite"), "--scale", "4"])
    assert out.exit_code == 2 and "cannot open the results database" in out.output
    assert "Traceback" not in out.output


def test_a_report_reads_only_the_file_holding_the_result_s_measures(tmp_path):
    """A result JSON is data from anyone: the file it names is read only when it holds the
    very measures the result was estimated from (their sha256 in the record) — never
    /etc/passwd, never another CSV — and an error never echoes a file's content."""
    from kanagen.fitjob import measures_sha256
    from kanagen.report import read_data

    mine = tmp_path / "mine.csv"
    mine.write_text("x,y\n1,2\n3,4\n")
    secret = tmp_path / "secret.csv"
    secret.write_text("x,y\n5,6\n")
    base = {"channel": "point", "channel_components": ["x", "y"], "model": "line",
            "data_sha256": measures_sha256(np.array([[1.0, 2.0], [3.0, 4.0]]))}
    assert read_data({**base, "data": str(mine)}).shape == (2, 2)
    for named in (str(secret), "/etc/passwd", "../secret.csv", str(tmp_path)):
        assert read_data({**base, "data": named}, base=tmp_path) is None
    assert read_data({k: v for k, v in base.items() if k != "data_sha256"} |
                     {"data": str(mine)}) is None  # no hash: not read
    (tmp_path / "leak.csv").write_text("x,y\nTOPSECRET:x:0:0,KEY\n")
    with pytest.raises(DataError) as err:
        read_data(base, data=tmp_path / "leak.csv")
    assert "TOPSECRET" not in str(err.value) and "KEY" not in str(err.value)
