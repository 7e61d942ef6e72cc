"""The information a user passes, in the shapes metrology data come in: one σ per component
(``(k,)``) and per measure and component (``(M, k)``), as ODRPACK's ``weight_x``/``weight_y``
take them (runtime/inputs.py: ``information``), and ``--sigma NAME=SIGMA`` on the command
line (kanagen/cli.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import kanagen
from kanagen.cli import main

ROOT = Path(__file__).resolve().parents[1]


def run(*args):
    """``kanagen ARGS`` as a user types it: its exit code and output."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def _line_data(M=25, seed=4):
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 10, M)
    return np.c_[x + rng.normal(0, 0.05, M), 0.7 * x - 1 + rng.normal(0, 0.5, M)]


def test_per_component_and_per_measure_diagonals():
    fam = kanagen.load(ROOT / "examples" / "line.yaml")
    data = _line_data()
    w = np.array([1 / 0.05**2, 1 / 0.5**2])
    reference = kanagen.fit(fam, "line", data={"point": data}, info={"point": np.diag(w)})
    by_component = kanagen.fit(fam, "line", data={"point": data}, info={"point": w})
    assert by_component.success and reference.success
    np.testing.assert_array_equal(by_component.q, reference.q)
    np.testing.assert_array_equal(by_component.covariance, reference.covariance)
    scale = np.linspace(0.5, 2, len(data))  # per measure and component
    per = scale[:, None] * w
    full = kanagen.fit(fam, "line", data={"point": data},
                       info={"point": per[:, :, None] * np.eye(2)})
    diagonal = kanagen.fit(fam, "line", data={"point": data}, info={"point": per})
    np.testing.assert_array_equal(diagonal.q, full.q)
    assert diagonal.cost == full.cost
    # the σ's right: the reduced chi-square near 1 with the per-component information
    assert 0.4 < by_component.reduced_chi2 < 2.0
    assert kanagen.fit(fam, "line", data={"point": data}).reduced_chi2 < 0.5  # σ 1 each


def test_ambiguous_and_bad_information_is_refused_with_a_way_out():
    fam = kanagen.load(ROOT / "examples" / "line.yaml")
    two = _line_data(M=2)
    with pytest.raises(ValueError, match=r"np.diag\(v\) per component"):
        kanagen.fit(fam, "line", data={"point": two}, info={"point": [1.0, 2.0]})
    with pytest.raises(ValueError, match=">= 0"):
        kanagen.fit(fam, "line", data={"point": _line_data()}, info={"point": [1.0, -2.0]})
    with pytest.raises(ValueError, match=r"\(2,\) one per component"):
        kanagen.fit(fam, "line", data={"point": _line_data()}, info={"point": [1.0, 2.0, 3.0]})


def test_cli_sigma_per_component(tmp_path):
    data = _line_data()
    path = tmp_path / "line.csv"
    np.savetxt(path, data, delimiter=",", header="x,y", comments="", fmt="%.9f")
    spec = ROOT / "examples" / "line.yaml"
    out_json = tmp_path / "res.json"
    out = run("fit", spec, path, "--model", "line", "--local", "--sigma", "x=0.05,y=0.5",
              "--json", out_json)
    assert out.exit_code == 0, out.output
    fam = kanagen.load(spec)
    expected = kanagen.fit(fam, "line", data={"point": np.loadtxt(path, delimiter=",",
                                                                  skiprows=1)},
                           info={"point": [1 / 0.05**2, 1 / 0.5**2]})
    got = json.loads(out_json.read_text())
    np.testing.assert_allclose(list(got["params"].values()), expected.q, rtol=1e-12)
    assert got["sigma"] == {"x": 0.05, "y": 0.5}  # the record says what it assumed
    # a bare number is the components not named: the same fit
    out2 = tmp_path / "res2.json"
    assert run("fit", spec, path, "--model", "line", "--local", "--sigma", "0.5",
               "--sigma", "x=0.05", "--json", out2).exit_code == 0
    assert json.loads(out2.read_text())["params"] == got["params"]
    for bad, message in (("z=0.1", "not a component of channel 'point'"),
                         ("x=0", "sigma x must be positive"),
                         ("1,2", "one bare number at most")):
        out = run("fit", spec, path, "--model", "line", "--local", "--sigma", bad)
        assert out.exit_code == 2 and message in out.output, out.output
        assert "Traceback" not in out.output


def test_cli_sigma_from_the_data_columns(tmp_path):
    """``--sigma y=sd_y``: each measure's σ from a column of DATA (a CSV with sx, sy as
    metrology files carry them): the same fit as ``info`` of shape (M, k); ``kanagen batch``
    reads them per file."""
    data = _line_data()
    sd = np.c_[np.linspace(0.02, 0.08, len(data)), np.linspace(0.3, 0.9, len(data))]
    path = tmp_path / "line.csv"
    np.savetxt(path, np.c_[sd[:, 1], data, sd[:, 0]], delimiter=",", header="sy,x,y,sx",
               comments="", fmt="%.9f")
    spec = ROOT / "examples" / "line.yaml"
    out_json = tmp_path / "res.json"
    out = run("fit", spec, path, "--model", "line", "--local", "--sigma", "x=sx,y=sy",
              "--json", out_json)
    assert out.exit_code == 0, out.output
    read = np.loadtxt(path, delimiter=",", skiprows=1)
    expected = kanagen.fit(kanagen.load(spec), "line", data={"point": read[:, 1:3]},
                           info={"point": np.c_[read[:, 3], read[:, 0]] ** -2.0})
    got = json.loads(out_json.read_text())
    np.testing.assert_allclose(list(got["params"].values()), expected.q, rtol=1e-12)
    assert 0.4 < expected.reduced_chi2 < 2.5
    # the robust search and a batch, with the same columns
    assert run("fit", spec, path, "--sigma", "x=sx,y=sy").exit_code == 0
    summary = kanagen.batch(spec, [str(path)], db=tmp_path / "r.sqlite", workers=1,
                            sigma={"x": "sx", "y": "sy"}, model="line", local=True)
    assert summary.ok == 1, summary
    (row,) = kanagen.read_results(tmp_path / "r.sqlite")
    np.testing.assert_allclose(list(row["estimate"].values()), expected.q, rtol=1e-12)
    # a missing column, a sigma not positive, a file without named columns
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,sx,sy\n1,2,0.1,0.2\n2,3,0.1,0\n3,4,0.1,0.2\n")
    for data_file, sigma, message in (
            (path, "x=sdx", "lacks component(s) ['sdx'] (the sigma columns ['sdx'])"),
            (bad, "x=sx,y=sy", "column 'sy', measure 1: sigma 0.0 is not a positive number")):
        out = run("fit", spec, data_file, "--model", "line", "--local", "--sigma", sigma)
        assert out.exit_code == 2 and message in out.output, out.output
    npz = tmp_path / "line.npz"
    np.savez(npz, point=data)
    out = run("fit", spec, npz, "--model", "line", "--local", "--sigma", "y=sy")
    assert out.exit_code == 2 and "needs a file with named columns" in out.output
