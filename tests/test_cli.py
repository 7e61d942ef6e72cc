"""The command line: what a user sees first."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import arc

from kanagen.cli import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def run():
    runner = CliRunner()

    def invoke(*args):
        return runner.invoke(main, [str(a) for a in args], catch_exceptions=False)

    return invoke


def test_help_explains_the_commands(run):
    out = run("--help")
    assert out.exit_code == 0
    for word in ("build", "fit", "show"):
        assert word in out.output
    assert "--check" in run("build", "--help").output


def test_build_writes_and_check_detects_drift(run, tmp_path):
    spec = tmp_path / "line.yaml"
    shutil.copy(ROOT / "examples" / "line.yaml", spec)
    out = run("build", spec, "-o", tmp_path / "gen")
    assert out.exit_code == 0 and (tmp_path / "gen" / "line.py").exists()
    assert run("build", "--check", spec, "-o", tmp_path / "gen").exit_code == 0
    generated = tmp_path / "gen" / "line.py"
    generated.write_text(generated.read_text().replace("do not edit", "edited"))
    out = run("build", "--check", spec, "-o", tmp_path / "gen")
    assert out.exit_code == 1
    assert "-" in out.output and "+" in out.output and "edited" in out.output


@pytest.fixture
def circle_csv(tmp_path):
    """Points of a circular arc with 30 % uniform outliers, as a CSV with a header."""
    xy, truth = arc("circle", 0)
    path = tmp_path / "arc.csv"
    np.savetxt(path, xy, delimiter=",", header="x,y", comments="", fmt="%.6f")
    return path, truth


LATTICE = ROOT / "examples/conic_lattice.yaml"


def test_fit_help_explains_the_robust_search(run):
    out = run("fit", "--help")
    assert out.exit_code == 0
    for word in ("--scale", "--scorer", "--phi", "--seed", "--max-samples", "--local",
                 "--json", "lattice", "Exit status"):
        assert word in out.output


def test_robust_fit_chooses_the_circle_and_writes_json(run, circle_csv, tmp_path):
    path, truth = circle_csv
    out_json = tmp_path / "res.json"
    out = run("fit", LATTICE, path, "--sigma", "1", "--scale", "4", "--json", out_json)
    assert out.exit_code == 0, out.output
    text = out.output
    assert "* circle" in text and "chosen model 'circle'" in text and "±" in text
    assert "matrix" in text  # the derived quantity
    res = json.loads(out_json.read_text())  # valid JSON: no Infinity / NaN
    assert res["model"] == "circle" and res["status"] == "done"
    assert res["channel"] == "point" and res["measures"] == len(truth)
    rows = {r["model"]: r for r in res["lattice"]}
    assert rows["circle"]["chosen"] and rows["circle"]["accepted"]
    assert rows["line"]["parent"] is None and rows["circle"]["parent"] == "line"
    for row in res["lattice"]:
        assert {"dof", "cost", "relevance", "inliers", "samples", "accepted"} <= set(row)
    # the lattice's most general model probed first: its samples in the total, said apart
    probe = res["probes"]["conic"]
    assert probe["samples"] > 0 and probe["inliers"] > 0
    assert f"conic probed first, from all measures: {probe['samples']} sample(s)" in text
    assert res["total_samples"] == probe["samples"] + sum(r["samples"] for r in res["lattice"])
    assert list(res["params"]) == ["A", "B", "C", "D", "E", "F"]
    assert set(res["std"]) == set(res["params"])
    assert set(res["slacks"]) == {"s_ellipse", "s_proper"}
    assert res["components"] == ["A", "B", "C", "D", "E", "F", "s_ellipse", "s_proper"]
    assert np.array(res["covariance"]).shape == (8, 8) == np.array(res["info"]).shape
    q = np.array(list(res["params"].values()))
    assert np.linalg.norm(q) == pytest.approx(1.0)
    assert res["params"]["A"] == pytest.approx(res["params"]["C"])  # a circle
    inliers, outliers = np.array(res["inliers"]), np.array(res["outliers"])
    assert len(inliers) + len(outliers) == len(truth)
    assert np.count_nonzero(truth[inliers]) >= 0.9 * np.count_nonzero(truth)
    assert res["relevance"] == rows["circle"]["relevance"] > 0
    assert res["samples"] == rows["circle"]["samples"] > 0
    assert np.array(res["derived"]["matrix"]["value"]).shape == (3, 3)
    assert np.array(res["derived"]["matrix"]["std"]).shape == (3, 3)
    history = np.array(res["history"])
    assert history.shape == (res["total_samples"], 2)
    assert np.all(np.diff(history[:, 0]) > 0) and np.all(np.diff(history[:, 1]) >= 0)


def test_robust_fit_options(run, circle_csv, tmp_path):
    path, _ = circle_csv
    out_json = tmp_path / "res.json"
    out = run("fit", LATTICE, path, "--scale", "4", "--scorer", "trimmed", "--phi", "aic",
              "--seed", "3", "--const", "f0=100", "--json", out_json)
    assert out.exit_code == 0, out.output
    res = json.loads(out_json.read_text())
    assert res["scale"] == 4.0 and res["scorer"] == "trimmed" and res["phi"] == "aic"
    assert res["seed"] == 3
    out = run("fit", LATTICE, path, "--phi", "0.5", "--model", "circle", "--json", out_json)
    assert out.exit_code == 0, out.output
    res = json.loads(out_json.read_text())
    assert res["phi"] == 0.5 and [r["model"] for r in res["lattice"]] == ["circle"]


@pytest.mark.skipif(tuple(map(int, version("click").split(".")[:2])) < (8, 2),
                    reason="CliRunner separates stdout from stderr from click 8.2")
def test_json_dash_keeps_stdout_pure_json(run, circle_csv):
    out = run("fit", LATTICE, circle_csv[0], "--json", "-")
    assert out.exit_code == 0, out.output
    assert json.loads(out.stdout)["model"] == "circle"
    assert "* circle" in out.stderr


def test_robust_fit_without_a_model_exits_1_with_null_for_inf(run, circle_csv, tmp_path):
    out_json = tmp_path / "res.json"
    out = run("fit", LATTICE, circle_csv[0], "--max-samples", "1", "--json", out_json)
    assert out.exit_code == 1
    assert "no model found" in out.output and "stopped at --max-samples 1" in out.output
    res = json.loads(out_json.read_text())
    assert res["model"] is None and res["lattice"][0]["cost"] is None  # inf -> null
    # kanagen fit runs Estimator.run (its budgets share --max-samples): its status says why
    # it paused
    assert res["total_samples"] == 1
    assert res["status"] == "paused (sample budget); searching line"
    assert res["scale"] == pytest.approx(10.8276, abs=1e-4) and not res["scale_given"]


def test_robust_fit_reports_bad_input_without_traceback(run, circle_csv, tmp_path):
    path, _ = circle_csv
    out = run("fit", LATTICE, path, "--channel", "pixel")
    assert out.exit_code == 2 and "error: unknown channel 'pixel'" in out.output
    bad = tmp_path / "bad.csv"
    bad.write_text("x,z\n1,2\n")
    out = run("fit", LATTICE, bad)
    assert out.exit_code == 2 and "error: " in out.output
    assert "lacks component(s) ['y']" in out.output
    bad.write_text("x,y\n1,oops\n")
    out = run("fit", LATTICE, bad)
    assert out.exit_code == 2 and "not a row of numbers" in out.output
    bad.write_text("x,y\n")
    out = run("fit", LATTICE, bad)
    assert out.exit_code == 2 and "no measures" in out.output
    for option, message in ((("--phi", "often"), "unknown cost factor"),
                            (("--scale", "0"), "must be positive"),
                            (("--const", "g=1"), "unknown constant 'g'"),
                            (("--model", "parabola"), "unknown model 'parabola'")):
        out = run("fit", LATTICE, path, *option)
        assert out.exit_code == 2 and message in out.output, out.output
    spec = tmp_path / "bad.yaml"
    spec.write_text("name: bad\nparameter: {A: 0}\n")
    out = run("fit", spec, path)
    assert out.exit_code == 2 and "error: " in out.output and "Traceback" not in out.output


def test_local_fit_prints_the_estimate_and_writes_json(run, tmp_path):
    out_json = tmp_path / "res.json"
    out = run("fit", ROOT / "examples/conic.yaml", ROOT / "examples/data/ellipse_arc.csv",
              "--model", "conic", "--local", "--sigma", "1", "--json", out_json)
    assert out.exit_code == 0, out.output
    assert "converged" in out.output and "discriminant" in out.output
    res = json.loads(out_json.read_text())
    assert res["success"] and res["model"] == "conic"
    q = np.array(list(res["params"].values()))
    assert np.linalg.norm(q) == pytest.approx(1.0)
    assert res["derived"]["discriminant"]["value"] > 0  # an ellipse


def test_fits_correct_their_bias_on_request(run, tmp_path):
    """--correct-bias: the local fit's hyperaccurate correction (runtime/hyper.py), said in
    its message; after a robust search, the chosen model refitted on its inliers less its
    bias (the record's estimate, with the bias removed; the lattice as found)."""
    args = ("fit", ROOT / "examples/conic.yaml", ROOT / "examples/data/ellipse_arc.csv",
            "--model", "conic", "--sigma", "1")
    out_json = tmp_path / "res.json"
    plain = tmp_path / "plain.json"
    out = run(*args, "--local", "--correct-bias", "--json", out_json)
    assert out.exit_code == 0, out.output
    assert "bias-corrected (hyperaccurate)" in out.output
    assert run(*args, "--local", "--json", plain).exit_code == 0
    a = np.array(list(json.loads(out_json.read_text())["params"].values()))
    b = np.array(list(json.loads(plain.read_text())["params"].values()))
    assert 0 < np.linalg.norm(a - b) < 1e-2 and np.linalg.norm(a) == pytest.approx(1.0)
    robust, robust_plain = tmp_path / "robust.json", tmp_path / "robust_plain.json"
    out = run(*args, "--correct-bias", "--json", robust)
    assert out.exit_code == 0, out.output
    assert "bias-corrected on its inliers (hyperaccurate)" in out.output
    assert run(*args, "--json", robust_plain).exit_code == 0
    hyper, ml = json.loads(robust.read_text()), json.loads(robust_plain.read_text())
    assert hyper["model"] == ml["model"] == "conic" and hyper["inliers"] == ml["inliers"]
    assert len(hyper["bias"]) == len(ml["params"]) and "bias" not in ml
    a, b = (np.array(list(r["params"].values())) for r in (hyper, ml))
    assert 0 < np.linalg.norm(a - b) < 1e-2 and np.linalg.norm(a) == pytest.approx(1.0)


def test_local_fit_reports_bad_data_without_traceback(run, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("x,z\n1,2\n")
    out = run("fit", ROOT / "examples/conic.yaml", bad, "--model", "conic", "--local")
    assert out.exit_code == 2
    assert "lacks component(s) ['y']" in out.output
    bad.write_text("x,y\n1,nan\n")
    out = run("fit", ROOT / "examples/conic.yaml", bad, "--model", "conic", "--local")
    assert out.exit_code == 2 and "bad.csv:2: y is 'nan', not a finite number" in out.output
    for name, write in (("bad.npz", lambda p: np.savez(p, point=[[1.0, 2.0], [3.0, np.inf]])),
                        ("bad.json", lambda p: p.write_text('{"point": [[1, 2], [3, NaN]]}'))):
        write(tmp_path / name)  # no lines: the measure and its component
        out = run("fit", ROOT / "examples/conic.yaml", tmp_path / name)
        assert out.exit_code == 2 and f"{name}: measure 1 (from 0), y is " in out.output
    out = run("fit", ROOT / "examples/conic.yaml", ROOT / "examples/data/ellipse_arc.csv",
              "--model", "parabola", "--local")
    assert out.exit_code == 2 and "unknown model 'parabola'" in out.output


def test_show_lists_the_lattice(run):
    out = run("show", ROOT / "examples/conic.yaml")
    assert out.exit_code == 0
    assert "model circle (null model)" in out.output and "-> conic (phi ftest)" in out.output


@pytest.mark.parametrize("spec", ["two_view", "hysteresis"])
def test_show_wraps_long_expressions(run, spec):
    """Issue 20: the expanded equations of two_view are ~1,000 characters; show folds them
    (and the parameter list) at about 100 columns."""
    out = run("show", ROOT / "examples" / f"{spec}.yaml")
    assert out.exit_code == 0
    lines = out.output.splitlines()
    assert max(map(len, lines)) <= 120, max(lines, key=len)
    if spec == "two_view":
        assert any(line.startswith("        ") for line in lines)  # a continuation
        assert "channel match overridden:" in out.output


def test_build_casadi_backend_and_check(run, tmp_path):
    spec = tmp_path / "line.yaml"
    shutil.copy(ROOT / "examples" / "line.yaml", spec)
    out = run("build", spec, "-o", tmp_path / "gen", "--backend", "casadi")
    assert out.exit_code == 0
    assert {p.name for p in (tmp_path / "gen").iterdir()} == {"line.py", "line_casadi.py"}
    assert run("build", "--check", spec, "-o", tmp_path / "gen").exit_code == 0
    casadi_file = tmp_path / "gen" / "line_casadi.py"
    casadi_file.write_text(casadi_file.read_text().replace("ca.SX.sym", "ca.MX.sym", 1))
    out = run("build", "--check", spec, "-o", tmp_path / "gen")
    assert out.exit_code == 1 and "line_casadi.py" in out.output


def test_build_compile_without_compiler_warns(run, tmp_path, monkeypatch):
    monkeypatch.setenv("KANAGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(tmp_path / "missing-cc"))
    out = run("build", ROOT / "examples" / "line.yaml", "-o", tmp_path / "gen", "--compile")
    assert out.exit_code == 0
    assert "not compiled: no C compiler" in out.output
    assert "uncompiled CasADi backend" in out.output


@pytest.mark.skipif(tuple(map(int, version("click").split(".")[:2])) < (8, 2),
                    reason="CliRunner separates stdout from stderr from click 8.2")
def test_fit_on_the_compiled_backend_gives_the_same_answer(run, circle_csv):
    path, _ = circle_csv
    args = ("fit", LATTICE, path, "--scale", 4, "--max-samples", 200, "--json", "-")
    outs = [json.loads(run(*args, "--backend", b).stdout) for b in ("numpy", "compiled")]
    assert outs[0]["model"] == outs[1]["model"] and outs[0]["inliers"] == outs[1]["inliers"]
    np.testing.assert_allclose(list(outs[1]["params"].values()),
                               list(outs[0]["params"].values()), rtol=1e-8, atol=1e-12)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child needs POSIX")
def test_ctrl_c_during_fit_reports_the_best_so_far_and_exits_130(tmp_path):
    """Issue 20: Ctrl-C during a long `kanagen fit` prints what it has and exits 130, like
    `kanagen batch` (it used to exit 0)."""
    xy = np.random.default_rng(0).uniform(-10, 10, (5000, 2))  # noise: a long search
    path = tmp_path / "noise.csv"
    np.savetxt(path, xy, delimiter=",", header="x,y", comments="", fmt="%.6f")
    json_out = tmp_path / "result.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "kanagen", "fit", str(LATTICE), str(path), "--scale", "4",
         "--max-samples", "10000000", "--json", str(json_out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        # Ctrl-C's default handling, even when the tests run as a background job (which
        # starts with SIGINT ignored, and its children inherit that)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.default_int_handler))
    try:
        time.sleep(3)  # well into the search (or still loading: 130 all the same)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, out + err
    assert "interrupted" in out + err
    if json_out.exists():  # interrupted in the search: the best model so far is written
        assert json.loads(json_out.read_text())["stop_reason"].startswith("interrupted")
