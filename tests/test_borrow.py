"""Arrays borrowed for the engine's innermost loops (kanagen.common.borrow), and what the
iteration reports at its returned point (kanagen.runtime.engine.iterate.projected_at): the
same as the projector's there, to the last bit."""

from __future__ import annotations

import numpy as np
import pytest
from scenarios import TWOCHAN, close, twochan_data

import kanagen
from kanagen.common.borrow import alive, borrow
from kanagen.common.jit import NUMBA, jit
from kanagen.runtime.fit import fit_problem, make_problem
from kanagen.runtime.iterate import CONVERGED, iterate
from kanagen.runtime.projector import evaluate, project
from kanagen.runtime.results import constrained_covariance


@jit
def _rows_doubled(a):
    """Every row of a borrowed copy of ``a`` doubled in place, through views."""
    out = a.copy()
    view = borrow(out)
    for i in range(view.shape[0]):
        row = view[i]
        for j in range(row.size):
            row[j] *= 2.0
    alive(out)
    return out


@jit
def _kept_alive(n):
    """A local owner borrowed, then arrays of its size made and dropped in the loop: were the
    owner released at its last use (no :func:`alive`), they would take its memory and the
    borrowed view would read theirs (checked: without ``alive`` this returns 1.0)."""
    owner = np.zeros(n)
    view = borrow(owner)
    for i in range(n):
        other = np.full(n, -1.0)
        view[i] = i + 1.0 + other[0] + 1.0
    total = 0.0
    for i in range(n):
        total += view[i]
    alive(owner)
    return total


@jit
def _same_memory(a):
    b = borrow(a)
    c, d = borrow((a, a[1:]))  # a tuple: each array borrowed
    return b.ctypes.data == a.ctypes.data and b.shape == a.shape and \
        b.strides == a.strides and c.ctypes.data == a.ctypes.data and \
        d.ctypes.data == a[1:].ctypes.data and d.shape == a[1:].shape


def test_a_borrowed_array_is_its_owner_without_a_reference():
    a = np.arange(12.0).reshape(4, 3)
    assert _same_memory(a)
    np.testing.assert_array_equal(_rows_doubled(a), 2.0 * a)
    np.testing.assert_array_equal(a, np.arange(12.0).reshape(4, 3))  # the input untouched


def test_alive_keeps_a_borrowed_arrays_owner():
    assert _kept_alive(64) == 64 * 65 / 2


@pytest.mark.skipif(NUMBA is not None and not jit.disabled, reason="interpreted only")
def test_interpreted_borrow_is_the_array():
    a = np.ones(3)
    assert borrow(a) is a and alive((a,)) is None


def _problems():
    twochan = kanagen.load_text(TWOCHAN, "twochan.yaml")
    data = twochan_data(4, 25, 12)
    out = [(twochan, model, make_problem(twochan, model, data, {"pts": 4.0, "obs": 2.0},
                                         np.array([0.7, 0.5, 0.8])))
           for model in ("free", "sphere")]
    conic = kanagen.load("conic")
    angle = np.linspace(0.2, 3.0, 30)
    xy = np.c_[300 + 200 * np.cos(angle), 250 + 120 * np.sin(angle)]
    xy += np.random.default_rng(5).normal(0, 1.0, xy.shape)
    out.append((conic, "conic", make_problem(conic, "conic", {"point": xy}, {"point": 1.0})))
    return out


@pytest.mark.parametrize("case", range(3))
def test_a_fit_reports_the_projector_at_its_point(case):
    """The information, ranks, constraints kept and residual a fit reports come from the
    kernel that ran the iteration; the projector called at the returned point gives the
    same, bit for bit, and so the same covariance."""
    fam, model, problem = _problems()[case]
    out = iterate(problem, problem.q0, report=True)
    assert out.status == CONVERGED
    lin, proj = project(problem, out.point)
    got = out.projected
    np.testing.assert_array_equal(got.info, lin.info)
    np.testing.assert_array_equal(got.C0, proj.C0)
    assert (got.rank0, got.residual) == (proj.rank0, proj.residual)
    for mine, theirs in zip(got.ranks, lin.ranks, strict=True):
        np.testing.assert_array_equal(mine, theirs)
    res = fit_problem(fam, model, problem)
    np.testing.assert_array_equal(res.info, lin.info)
    np.testing.assert_array_equal(res.covariance, constrained_covariance(lin.info, proj.C0))
    assert iterate(problem, problem.q0).projected is None  # not asked for


@pytest.mark.parametrize("case", range(3))
def test_the_outcome_makes_its_point_when_read(case):
    """An outcome holds its returned point's q, m̃, cost and violation; the whole point,
    cut from the kernel's layout when first read, has the same numbers and the equations
    the NumPy path's evaluation at (q, m̃) gives — bit for bit for rational equations (the
    conic's); to rounding for twochan's ``exp(-b t)``, whose NumPy (SIMD code on AVX-512
    processors) and C library versions may differ by an ulp —; the verdict is the checks'
    (a minimum)."""
    fam, model, problem = _problems()[case]
    out = iterate(problem, problem.q0, report=True)
    x = out.point
    assert out.point is x  # made once
    np.testing.assert_array_equal(out.q, x.q)
    for mine, theirs in zip(out.mt, x.mt, strict=True):
        np.testing.assert_array_equal(mine, theirs)
    assert (out.cost, out.delta) == (x.cost, x.delta)
    y = evaluate(problem, x.q, x.mt)
    np.testing.assert_array_equal(x.c0, y.c0)
    np.testing.assert_array_equal(x.C0, y.C0)
    for mine, theirs in zip(x.evals, y.evals, strict=True):
        for a, b in zip(mine, theirs, strict=True):
            if fam.name == "conic":
                np.testing.assert_array_equal(a, b)
            else:
                close(a, b, rtol=1e-14)
    # the NumPy path sums the cost in its own order: to rounding
    assert x.delta == (y.delta if fam.name == "conic" else pytest.approx(y.delta, abs=1e-12))
    assert x.cost == pytest.approx(y.cost, rel=1e-13)
    assert out.verdict is out.verdict and out.verdict.minimum


@pytest.mark.parametrize("case", range(3))
@pytest.mark.parametrize(("verify", "max_iter"), [(False, 100), (True, 1), (True, 0)])
def test_every_end_reports_the_projector_at_its_point(case, verify, max_iter):
    """Whichever end made it — an unverified stop, the cap's check, no iteration at all —
    the report at the returned point is the projector's there, bit for bit (the iteration's
    own linearisation when it made one at that point, else made for the report)."""
    fam, model, problem = _problems()[case]
    out = iterate(problem, problem.q0, max_iter=max_iter, verify=verify, report=True)
    lin, proj = project(problem, out.point)
    got = out.projected
    assert got is not None
    np.testing.assert_array_equal(got.info, lin.info)
    np.testing.assert_array_equal(got.C0, proj.C0)
    assert (got.rank0, got.residual) == (proj.rank0, proj.residual)
    for mine, theirs in zip(got.ranks, lin.ranks, strict=True):
        np.testing.assert_array_equal(mine, theirs)
