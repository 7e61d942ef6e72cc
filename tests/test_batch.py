"""Batch runs: every dataset once in SQLite, resume, errors recorded, SIGKILL-safe."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from killrun import kill_halfway
from scenes import arc

import kanagen
from kanagen.cli import main

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]
LATTICE = str(ROOT / "examples" / "conic_lattice.yaml")
FAST = {"scale": 4.0, "max_samples": 20}  # tiny runs: the engine is under test, not the search


@pytest.fixture(scope="module")
def scheduler():
    """One worker process behind a dask.distributed scheduler, shared by the tests."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster:
        yield cluster.scheduler_address


def write_scenes(folder: Path, count: int, n: int = 15) -> list[str]:
    """``count`` arcs (lines and circles, 30 % outliers) as CSV files; their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(count):
        xy, _ = arc(("line", "circle")[k % 2], 100 + k, n=n)
        path = folder / f"scene{k:03d}.csv"
        np.savetxt(path, xy, delimiter=",", header="x,y", comments="", fmt="%.6f")
        paths.append(str(path))
    return paths


def rows(db) -> list[dict]:
    return kanagen.read_results(db, with_record=True)


def test_batch_takes_the_options_of_fit():
    def names(command):
        return {p.name for p in main.commands[command].params}

    assert names("fit") - {"spec", "data", "json_out"} == \
        names("batch") - {"spec", "data_glob", "db", "workers", "scheduler", "retry_errors"}
    out = CliRunner().invoke(main, ["batch", "--help"])
    for word in ("--scale", "--max-samples", "--workers", "--scheduler", "--db", "resume",
                 "Exit status"):
        assert word in out.output


def test_batch_records_every_dataset_with_its_error_and_resumes(tmp_path, scheduler):
    paths = write_scenes(tmp_path / "data", 4)
    bad = tmp_path / "data" / "scene900.csv"  # read by the parent: fails before any worker
    bad.write_text("x,z\n1,2\n")
    nan = tmp_path / "data" / "scene901.csv"  # read fine, refused by the estimator on a worker
    nan.write_text("x,y\n1,2\n3,nan\n5,6\n")
    db = tmp_path / "out" / "results.sqlite"
    seen = []
    summary = kanagen.batch(LATTICE, str(tmp_path / "data" / "*.csv"), db=db, workers=2,
                            progress=seen.append, **FAST)
    assert (summary.datasets, summary.skipped, summary.errors) == (6, 0, 2)
    assert summary.ok + summary.no_model == 4
    assert sorted(o.dataset for o in seen) == sorted([*paths, str(bad), str(nan)])
    table = {r["dataset"]: r for r in rows(db)}
    assert set(table) == {*paths, str(bad), str(nan)}
    assert "lacks component(s) ['y']" in table[str(bad)]["message"]
    assert table[str(nan)]["message"].endswith(
        ".csv:3: y is 'nan', not a finite number (a measure must be; drop the row or give "
        "its value)")
    for name in (str(bad), str(nan)):
        assert table[name]["status"] == "error" and table[name]["record"] is None
    for path in paths:
        row = table[path]
        rec = row["record"]
        assert row["status"] == "ok" and row["model"] == rec["model"] in ("line", "circle")
        assert row["spec_sha256"] == kanagen.load(LATTICE).sha256
        assert json.loads(row["options"])["max_samples"] == 20
        assert list(row["estimate"]) == ["A", "B", "C", "D", "E", "F", "s_ellipse", "s_proper"]
        assert np.array(row["info"]).shape == (8, 8)
        assert row["inliers"] == rec["inliers"] and row["n_inliers"] == len(rec["inliers"])
        assert row["measures"] == len(rec["errors"]) == 21  # 15 points and 6 outliers
        assert row["cost"] == rec["normalized_cost"] > 0 and row["dof"] == rec["dof"]
        assert row["seconds"] > 0 and row["finished"]
    # resume: nothing is estimated again, nothing duplicated, nothing changed
    again = kanagen.batch(LATTICE, str(tmp_path / "data" / "*.csv"), db=db, **FAST)
    assert (again.skipped, again.estimated, again.workers) == (6, 0, 0)
    assert rows(db) == list(table.values())
    # the failed datasets are retried on request, the others are not
    bad.write_text(Path(paths[0]).read_text())
    retried = kanagen.batch(LATTICE, str(tmp_path / "data" / "*.csv"), db=db,
                            scheduler=scheduler, retry_errors=True, **FAST)
    assert (retried.skipped, retried.ok, retried.errors) == (4, 1, 1)
    after = {r["dataset"]: r for r in rows(db)}
    assert len(after) == 6 and after[str(bad)]["status"] == "ok"
    assert all(after[p] == table[p] for p in paths)
    assert retried.workers == 1  # the scheduler's
    # other options are another run: new rows beside the old ones
    kanagen.batch(LATTICE, paths[:1], db=db, scheduler=scheduler, scale=4.0, max_samples=20,
                  seed=1)
    assert len(rows(db)) == 7 and len(kanagen.read_results(db, paths[0])) == 2


def test_a_batch_record_is_what_fit_json_writes(tmp_path, scheduler):
    path = write_scenes(tmp_path, 1)[0]
    db = tmp_path / "r.sqlite"
    kanagen.batch(LATTICE, [path], db=db, scheduler=scheduler, **FAST)
    out = tmp_path / "fit.json"
    run = CliRunner().invoke(main, ["fit", LATTICE, path, "--scale", "4", "--max-samples",
                                    "20", "--json", str(out)], catch_exceptions=False)
    assert run.exit_code == 0, run.output
    fitted = json.loads(out.read_text())
    assert rows(db)[0]["record"] == fitted
    assert fitted["errors"][fitted["inliers"][0]] < fitted["threshold"]
    assert fitted["edges"] == [["line", "circle", "ftest"], ["circle", "ellipse", "ftest"],
                               ["ellipse", "conic", "ftest"]]


def test_batch_refuses_bad_input_clearly(tmp_path):
    paths = write_scenes(tmp_path, 1)
    db = tmp_path / "r.sqlite"
    for kwargs, message in (({"scale": 0}, "must be positive"),
                            ({"phi": "often"}, "unknown cost factor"),
                            ({"model": "parabola"}, "unknown model 'parabola'"),
                            ({"channel": "pixel"}, "unknown channel 'pixel'"),
                            ({"constants": {"g": 1.0}}, "unknown constant 'g'")):
        with pytest.raises(ValueError, match=message):
            kanagen.batch(LATTICE, paths, db=db, **kwargs)
    with pytest.raises(ValueError, match="no data file matches"):
        kanagen.batch(LATTICE, str(tmp_path / "*.npz"), db=db)
    assert not db.exists() or kanagen.read_results(db) == []
    not_db = tmp_path / "not.sqlite"
    not_db.write_text("hello " * 1000)
    with pytest.raises(ValueError, match="not a kanagen results database"):
        kanagen.batch(LATTICE, paths, db=not_db, **FAST)
    with pytest.raises(ValueError, match="no such results database"):
        kanagen.read_results(tmp_path / "missing.sqlite")


def test_read_results_as_a_dataframe(tmp_path, scheduler):
    pd = pytest.importorskip("pandas")
    paths = write_scenes(tmp_path, 2)
    db = tmp_path / "r.sqlite"
    kanagen.batch(LATTICE, paths, db=db, scheduler=scheduler, **FAST)
    frame = kanagen.read_results(db, as_frame=True)
    assert isinstance(frame, pd.DataFrame) and len(frame) == 2
    assert {"dataset", "model", "estimate", "inliers", "cost", "status", "seconds"} \
        <= set(frame.columns)
    assert "record" not in frame.columns


def test_sigkill_halfway_then_resume_does_every_dataset_once(tmp_path):
    """A batch killed with SIGKILL halfway and started again ends with every dataset done
    once: none lost, none duplicated, the database intact."""
    count = 16
    paths = write_scenes(tmp_path / "data", count)
    db = tmp_path / "r.sqlite"
    command = [sys.executable, "-m", "kanagen", "batch", LATTICE,
               str(tmp_path / "data" / "*.csv"), "--db", str(db), "--workers", "2",
               "--scale", "4", "--max-samples", "20"]
    killed_at = kill_halfway(command, db, count)
    before = {r["dataset"]: r for r in rows(db)}
    assert count // 2 <= len(before) == killed_at < count, "the kill did not land halfway"
    with sqlite3.connect(db) as con:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    again = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stdout + again.stderr
    assert f"{len(before)} already in" in again.stdout
    after = rows(db)
    assert sorted(r["dataset"] for r in after) == paths  # each exactly once
    assert all(r["status"] != "error" for r in after)
    by_name = {r["dataset"]: r for r in after}
    assert all(by_name[name] == row for name, row in before.items())  # none lost or redone


def test_fit_options_are_validated_and_keyed_canonically():
    import doctest

    import kanagen.fitjob as fitjob

    assert doctest.testmod(fitjob).failed == 0
    a = kanagen.FitOptions(scale=4, phi="0.5", constants={"f0": 100, "a": 1})
    b = kanagen.FitOptions(scale=4.0, phi=0.5, constants=[("a", 1.0), ("f0", 100.0)])
    assert a == b and a.key("point") == b.key("point") != a.key("line")
    assert a.key("point") != kanagen.FitOptions(scale=4, phi=0.5, seed=1).key("point")
    for bad, message in (({"scorer": "best"}, "unknown scorer"),
                         ({"max_samples": 0}, "max_samples must be an integer >= 1"),
                         ({"seed": 1.5}, "seed must be an integer"),
                         ({"sigma": float("inf")}, "sigma must be positive"),
                         ({"phi": "exp:x"}, "phi: "),
                         ({"constants": {"f0": "wide"}}, "constants must map names")):
        with pytest.raises(ValueError, match=message):
            kanagen.FitOptions(**bad)


def test_batch_on_the_compiled_backend_records_the_same_estimates(tmp_path, scheduler):
    """The workers load the family on the backend asked for; the estimates are the
    NumPy runtime's (to 1e-10), so the backend is not part of what a re-run resumes on."""
    from kanagen.codegen.compile import CompileError, compiler

    try:
        compiler()
    except CompileError:
        pytest.skip("no C compiler")
    paths = write_scenes(tmp_path / "data", 2)
    out = {}
    for backend in ("numpy", "compiled"):
        db = tmp_path / f"{backend}.sqlite"
        kanagen.batch(LATTICE, paths, db=db, scheduler=scheduler, backend=backend, **FAST)
        out[backend] = {r["dataset"]: r for r in rows(db)}
    assert out["numpy"].keys() == out["compiled"].keys() == set(paths)
    for path in paths:
        a, b = out["numpy"][path], out["compiled"][path]
        assert (a["status"], a["model"], a["inliers"]) == (b["status"], b["model"], b["inliers"])
        assert a["options"] == b["options"]
        assert b["estimate"].keys() == a["estimate"].keys()
        for name, value in a["estimate"].items():
            assert b["estimate"][name] == pytest.approx(value, rel=1e-10, abs=1e-10)
        assert b["cost"] == pytest.approx(a["cost"], rel=1e-10)
