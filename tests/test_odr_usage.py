"""Starts and exact measures as ODR users have them (issue 16): ``--start`` on the command
line, per-measure exactness (ODRPACK's ``ifixx``) in ``fit`` and ``Estimator``, and channels
that share component names."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import kanagen
from kanagen.cli import main

EXP = """name: exp_offset
parameter: {b0: 1.0, b1: 1.0, b2: 1.0}
channels:
  pt:
    components: [x, y]
    equations: ["y - (b0 + b1*exp(-b2*x))"]
models:
  m: {}
"""

# the same curve with the exact abscissas in a second channel sharing the component names
TWO = EXP.replace("name: exp_offset", "name: exp_two").replace("models:", """  fixed:
    components: [x, y]
    exact: [x]
    equations: ["y - (b0 + b1*exp(-b2*x))"]
models:""")


def _data(seed=3, M=25):
    rng = np.random.default_rng(seed)
    x = np.sort(rng.uniform(0, 5, M))
    y = 1.0 + 4.0 * np.exp(-0.8 * x)
    sx = 10 ** rng.uniform(-2.5, -1, M)
    sy = 10 ** rng.uniform(-2, -1, M)
    X = np.c_[x + sx * rng.standard_normal(M), y + sy * rng.standard_normal(M)]
    return X, sx, sy


def _info(sx, sy):
    return np.einsum("km,kl->mkl", np.vstack([sx**-2, sy**-2]), np.eye(2))


def test_exact_abscissas_match_odrpack_fix_x():
    odrpack = pytest.importorskip("odrpack")
    fam = kanagen.load_text(EXP, source="exp.yaml")
    X, sx, sy = _data()
    fixed = [0, 4, 9]
    res = kanagen.fit(fam, "m", data={"pt": X}, info={"pt": _info(sx, sy)},
                      exact={"pt": {"x": fixed}}, q0=[1.5, 3.0, 1.0])
    assert res.success, res.message
    assert np.array_equal(res.measures["pt"][fixed, 0], X[fixed, 0])  # not corrected
    assert not np.allclose(res.measures["pt"][:, 0], X[:, 0])  # the others are
    mask = np.zeros(len(X), dtype=bool)  # odrpack: True is fixed
    mask[fixed] = True
    ref = odrpack.odr_fit(lambda x, b: b[0] + b[1] * np.exp(-b[2] * x), X[:, 0], X[:, 1],
                          [1.5, 3.0, 1.0], weight_x=sx**-2, weight_y=sy**-2, fix_x=mask,
                          maxit=200, sstol=1e-14, partol=1e-14)
    assert np.allclose(res.q, ref.beta, rtol=1e-6, atol=1e-9)
    assert res.cost == pytest.approx(0.5 * ref.sum_square, rel=1e-6)


def test_exact_mask_equals_a_channel_with_exact_components():
    """The mask and a second channel declaring x exact (sharing the component names) give the
    same estimate — with a full (correlated) information the mask keeps the information of
    the free component, not the marginal of the covariance."""
    X, sx, sy = _data(seed=5)
    Q = _info(sx, sy)
    Q[:, 0, 1] = Q[:, 1, 0] = 0.6 * np.sqrt(Q[:, 0, 0] * Q[:, 1, 1])
    fixed = np.zeros(len(X), dtype=bool)
    fixed[[1, 2, 7, 20]] = True
    one = kanagen.load_text(EXP, source="exp.yaml")
    mask = kanagen.fit(one, "m", data={"pt": X}, info={"pt": Q},
                       exact={"pt": np.c_[fixed, np.zeros_like(fixed)]}, q0=[1, 4, 1])
    two = kanagen.load_text(TWO, source="two.yaml")
    split = kanagen.fit(two, "m", data={"pt": X[~fixed], "fixed": X[fixed]},
                        info={"pt": Q[~fixed], "fixed": Q[fixed, 1, 1]}, q0=[1, 4, 1])
    assert mask.success and split.success
    assert np.allclose(mask.q, split.q, rtol=1e-8)
    assert mask.cost == pytest.approx(split.cost, rel=1e-8)
    assert np.allclose(mask.covariance, split.covariance, rtol=1e-6)


def test_exact_mask_is_checked():
    fam = kanagen.load_text(EXP, source="exp.yaml")
    X, _, _ = _data()
    bad = [({"pt": {"z": [0]}}, "not a component"),
           ({"pt": {"x": [0], "y": [0]}}, "every measured component exact"),
           ({"pt": {"x": [99]}}, "out of range"),
           ({"pt": np.ones((3, 2), dtype=bool)}, "shape"),
           ({"pt": {"x": [0.5]}}, "indices"),
           ({"nope": {"x": [0]}}, "nope")]
    for exact, message in bad:
        with pytest.raises(ValueError, match=message):
            kanagen.fit(fam, "m", data={"pt": X}, exact=exact)


def test_estimator_takes_exact_measures():
    fam = kanagen.load_text(EXP, source="exp.yaml")
    X, sx, sy = _data(seed=8, M=40)
    X[30:, 1] += 3.0  # outliers
    est = kanagen.Estimator(fam, scale=4, seed=0)
    est.add_measures("pt", X, info=_info(sx, sy), exact={"x": [0, 1, 2]})
    est.run()
    best = est.best()
    assert set(best.outliers.tolist()) >= set(range(30, 40))
    fixed = np.arange(len(X)) < 3
    local = kanagen.fit(fam, "m", data={"pt": X[best.inliers]},
                        info={"pt": _info(sx, sy)[best.inliers]},
                        exact={"pt": {"x": fixed[best.inliers]}}, q0=best.q)
    assert np.allclose(best.q, local.q, rtol=1e-6)


def test_channels_share_component_names_but_not_other_names():
    two = kanagen.load_text(TWO, source="two.yaml")
    assert two.channel("pt").components == two.channel("fixed").components == ("x", "y")
    for text, message in [
        (TWO.replace("components: [x, y]\n    exact", "components: [x, x]\n    exact"),
         "already a component of this channel"),
        (TWO.replace("components: [x, y]\n    exact", "components: [b0, y]\n    exact"),
         "already a parameter")]:
        with pytest.raises(kanagen.SpecError, match=message):
            kanagen.load_text(text, source="bad.yaml")


def test_cli_start(tmp_path):
    spec = tmp_path / "exp.yaml"
    spec.write_text(EXP)
    X, _, _ = _data(seed=4)
    data = tmp_path / "pts.csv"
    np.savetxt(data, X, delimiter=",", header="x,y", comments="")
    runner = CliRunner()
    out = tmp_path / "r.json"
    # from the spec's start (b2 = 1) the fit converges; from b2=-5 far off too, via --start
    for args in (["--start", "b0=1.5,b1=3", "--start", "b2=0.5"], []):
        run = runner.invoke(main, ["fit", str(spec), str(data), "--local", *args,
                                   "--json", str(out)])
        assert run.exit_code == 0, run.output
        record = json.loads(out.read_text())
        assert record["success"] and record["params"]["b2"] == pytest.approx(0.8, rel=0.1)
    assert record["start"] == {}
    run = runner.invoke(main, ["fit", str(spec), str(data), "--local", "--start", "b0=1.5,b1=3",
                               "--start", "b2=0.5", "--json", str(out)])
    assert json.loads(out.read_text())["start"] == {"b0": 1.5, "b1": 3.0, "b2": 0.5}
    run = runner.invoke(main, ["fit", str(spec), str(data), "--start", "b2=0.5", "--scale", "4",
                               "--json", str(out)])
    assert run.exit_code == 0, run.output
    assert json.loads(out.read_text())["start"] == {"b2": 0.5}
    for bad, message in (("bx=1", "unknown parameter 'bx'"), ("b0", "NAME=VALUE"),
                         ("b0=nan", "finite")):
        run = runner.invoke(main, ["fit", str(spec), str(data), "--local", "--start", bad])
        assert run.exit_code == 2 and message in run.output, run.output
