"""When every start of the plan fails, the descent is made once more under Marquardt's
scaling (runtime/engine/iterate.py: ``marquardt_scale``; runtime/iterate.py, "Starts").

The trust region's norm is ODRPACK's scaling, the start's magnitudes. Along a curved valley
whose parameters change by orders of magnitude on the way (Meyer's function, NIST's MGH10:
``y = b1 exp(b2 / (x + b3))``, ``b1`` from 0.02 to 0.0056 while ``b2`` goes from 4,000 to
6,181), that norm holds the steps to a fixed fraction of the start and the iteration crawls:
from NIST's second start every descent of the plan stopped at its cap of 100 iterations,
where scipy's ``least_squares`` (trf or MINPACK's lm) converges in 130 evaluations. The
information's own diagonal, ``sqrt(H_aa)`` kept at its largest (MINPACK's ``diag``), follows
the valley: the same start converges. A fit that converges under the start's scaling is
unchanged (the fallback comes last). NIST's data are read from ``../shared/data`` (or
``$KANAGEN_DATA``); without them that test is skipped.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

import kanagen
from benchmarks.nist_strd import SOLVED_DIGITS, data_available, data_dir, load_problem, run_kanagen

needs_data = pytest.mark.skipif(not data_available(),
                                reason=f"NIST StRD files not found in {data_dir()}")

#: Meyer's function with NIST's second start for MGH10; its data made here.
MEYER = """
name: meyer
parameter: {b1: 0.02, b2: 4000.0, b3: 250.0}
channels:
  obs:
    components: [x, y]
    exact: [x]
    equations:
      - y - b1*exp(b2/(x + b3))
models:
  meyer:
    constraints: []
"""

CERTIFIED = np.array([5.6096364710e-03, 6.1813463463e+03, 3.4522363462e+02])


@pytest.fixture(scope="module")
def meyer(tmp_path_factory):
    """The family and its data: NIST's abscissae, the certified curve, noise of σ 2 (NIST's
    residuals are ~2.3)."""
    path = tmp_path_factory.mktemp("meyer") / "meyer.yaml"
    path.write_text(MEYER)
    x = 50.0 + 5.0 * np.arange(16)
    y = CERTIFIED[0] * np.exp(CERTIFIED[1] / (x + CERTIFIED[2]))
    return kanagen.load(path), np.c_[x, y + 2.0 * np.random.default_rng(3).standard_normal(16)]


def _least_squares(data: np.ndarray) -> np.ndarray:
    """The same least-squares problem solved by scipy's MINPACK (an independent reference),
    from the certified values."""
    x, y = data.T

    def residual(b):
        return y - b[0] * np.exp(b[1] / (x + b[2]))

    return least_squares(residual, CERTIFIED, method="lm", xtol=1e-15, ftol=1e-15,
                         gtol=1e-15).x


@pytest.mark.parametrize("scale", [1e-8, 1.0, 1e8])
def test_meyer_from_nists_second_start_at_the_default_budget(meyer, scale):
    """Before: the cap (status 1) at every information scale; now the minimum MINPACK
    finds, at each scale (Marquardt's scaling does not depend on it)."""
    fam, data = meyer
    res = kanagen.fit(fam, "meyer", data={"obs": data}, info={"obs": scale})
    assert res.success, res.message
    assert np.allclose(res.q, _least_squares(data), rtol=1e-7)
    assert res.iterations > 100  # reached by the fallback, after the plan's descents capped


def test_a_fit_that_converges_under_the_start_scaling_is_unchanged(meyer):
    """The fallback is the plan's last descent: from the certified values (one iteration
    from the minimum) it is never made."""
    fam, data = meyer
    res = kanagen.fit(fam, "meyer", data={"obs": data}, info={"obs": 1.0}, q0=CERTIFIED)
    assert res.success and res.iterations < 10


@needs_data
@pytest.mark.parametrize("start", [0, 1], ids=["start1", "start2"])
def test_nist_mgh10_at_the_benchmarks_budget(start):
    """``python benchmarks/nist_strd.py`` (500 iterations a descent): MGH10 from its first
    start was the one case scipy's trf solved and kanagen did not (every descent of the plan
    at its cap); now both starts reach the certified values."""
    run = run_kanagen(load_problem("MGH10"), start, max_iter=500)
    assert run.success and run.lre_min >= SOLVED_DIGITS, run.message
