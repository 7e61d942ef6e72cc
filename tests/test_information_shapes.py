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
    runner = CliRunner()

    def run(*args):
        return runner.invoke(main, [str(a) for a in args], catch_exceptions=False)

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
