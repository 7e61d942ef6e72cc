"""The command line: what a user sees first."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

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


def test_fit_prints_the_estimate_and_writes_json(run, tmp_path):
    out_json = tmp_path / "res.json"
    out = run("fit", ROOT / "examples/conic.yaml", ROOT / "examples/data/ellipse_arc.csv",
              "--model", "conic", "--sigma", "1", "--json", out_json)
    assert out.exit_code == 0, out.output
    assert "converged" in out.output and "discriminant" in out.output
    res = json.loads(out_json.read_text())
    assert res["success"] and res["model"] == "conic"
    q = np.array(list(res["params"].values()))
    assert np.linalg.norm(q) == pytest.approx(1.0)
    assert res["derived"]["discriminant"]["value"] > 0  # an ellipse


def test_fit_reports_bad_data_without_traceback(run, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("x,z\n1,2\n")
    out = run("fit", ROOT / "examples/conic.yaml", bad, "--model", "conic")
    assert out.exit_code == 2
    assert "lacks component(s) ['y']" in out.output
    bad.write_text("x,y\n1,nan\n")
    out = run("fit", ROOT / "examples/conic.yaml", bad, "--model", "conic")
    assert out.exit_code == 2 and "NaN" in out.output
    out = run("fit", ROOT / "examples/conic.yaml", ROOT / "examples/data/ellipse_arc.csv",
              "--model", "parabola")
    assert out.exit_code == 2 and "unknown model 'parabola'" in out.output


def test_show_lists_the_lattice(run):
    out = run("show", ROOT / "examples/conic.yaml")
    assert out.exit_code == 0
    assert "model circle (null model)" in out.output and "-> conic (phi ftest)" in out.output
