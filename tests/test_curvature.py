"""The profile's exact Hessian (runtime/engine/curvature.py) against central differences of
its exact gradient (each side a restoration of the measures), at the fitted point of every
shipped family's scenarios and of a two-channel spec with an exact component; and the end's
check that uses it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scenarios import OFF_CONSTRAINTS, SCENARIOS, TWOCHAN, twochan_data

import kanagen
from kanagen.common.link import link
from kanagen.runtime.engine import curvature, points, verify
from kanagen.runtime.engine.data import arrays, pack_measures
from kanagen.runtime.fit import fit_problem, make_problem
from kanagen.runtime.linalg import null_space, solve_small, sym_eigh

#: Every scenario fit that ends at a minimum: not those that cannot reach their constraints
#: (test_an_end_off_its_constraints_is_no_success).
CASES = [(spec, k) for spec, make in SCENARIOS.items() for k in range(len(make()))
         if (spec, k) not in OFF_CONSTRAINTS]


def _at_fit(fam, model, data, info, start, constants, exact=None):
    """The engine's restored point at the fit's estimate and its linearisation."""
    problem = make_problem(fam, model, data, info, start, constants=constants, exact=exact)
    res = fit_problem(fam, model, problem)
    assert res.status == 0, res.message
    link()
    A = arrays(problem)
    mt = pack_measures(A, tuple(res.measures[ch.name][:, ch.index]
                                for ch in problem.channels))
    x, _ = points.restore(A, res.q, mt, 30)
    ok, lin, _ = points.project_point(A, x, 0.0, np.zeros(0))
    assert ok
    return A, x, lin


def _differences(A, x, step=1e-4):
    """``∇²F`` by central differences of the profile's exact gradient, Richardson-extrapolated
    (steps ``h`` and ``h/2``: an error of order ``h⁴``, the profile being strongly curved
    where a measure may move along one component only)."""
    n = x.q.size
    top = np.abs(x.q).max()

    def central(j, h):
        up, down = x.q.copy(), x.q.copy()
        up[j] += h
        down[j] -= h
        ok_up, g_up = verify.profile_gradient(A, x, up)
        ok_down, g_down = verify.profile_gradient(A, x, down)
        assert ok_up and ok_down
        return (g_up - g_down) / (2 * h)

    H = np.zeros((n, n))
    for j in range(n):
        h = step * max(abs(x.q[j]), 1e-3 * top, 1e-8)
        H[:, j] = (4 * central(j, h / 2) - central(j, h)) / 3
    return 0.5 * (H + H.T)


def _check(A, x, lin, rtol=1e-5):
    ok, H = curvature.profile_hessian(A, x, lin, np.eye(x.q.size))
    assert ok
    np.testing.assert_array_equal(H, H.T)
    reference = _differences(A, x)
    scale = np.abs(reference).max()
    assert np.abs(H - reference).max() <= rtol * scale, (H, reference)
    return H


@pytest.mark.parametrize("spec,k", CASES)
def test_exact_hessian_matches_differences(spec, k):
    fam = kanagen.load(spec.removesuffix(".yaml"))
    model, data, info, start, constants = SCENARIOS[spec]()[k]
    _check(*_at_fit(fam, model, data, info, start, constants))


def test_exact_hessian_two_channels_exact_component(tmp_path):
    """Two channels of different widths, one with a component known exactly (its G row is
    zero: no correction, no sensitivity) and a non-polynomial equation."""
    path = tmp_path / "twochan.yaml"
    path.write_text(TWOCHAN)
    fam = kanagen.load(str(path))
    data = twochan_data(0, 25, 20)
    for model in ("free", "sphere"):
        _check(*_at_fit(fam, model, data, {"pts": 400.0, "obs": 400.0}, None, None))


def test_exact_hessian_measures_known_exactly():
    """Measures with a component fixed by ``exact=``: the sensitivity stays in the free
    component."""
    fam = kanagen.load("conic")
    model, data, info, start, _ = SCENARIOS["conic.yaml"]()[1]
    xy = data["point"]
    mask = np.zeros(len(xy), dtype=bool)
    mask[::3] = True
    _check(*_at_fit(fam, model, data, info, start, None, {"point": {"x": mask}}))


def test_prior_information_adds_to_the_hessian():
    """``Q0`` enters ``F`` as ½‖q − q0‖²_Q0: its Hessian adds to the measures'."""
    fam = kanagen.load("line")
    model, data, info, start, constants = SCENARIOS["line.yaml"]()[1]
    A, x, lin = _at_fit(fam, model, data, info, start, constants)
    eye = np.eye(x.q.size)
    ok, H = curvature.profile_hessian(A, x, lin, eye)
    Q0 = np.diag([3.0, 5.0])
    problem = make_problem(fam, model, data, info, start, Q0=Q0)
    A0 = arrays(problem)
    ok0, H0 = curvature.profile_hessian(A0, x, lin, eye)
    assert ok and ok0
    np.testing.assert_allclose(H0 - H, Q0, rtol=1e-12, atol=1e-12 * np.abs(H).max())


def test_singular_system_reports_failure():
    """A measure whose KKT system is singular (all its whitened Jacobian zero) gives
    ``ok`` False, not a Hessian."""
    K = np.zeros((3, 3))
    R = np.ones((3, 2))
    assert not solve_small(K, R, 3, 2)
    K = np.array([[2.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 0.0]])
    X = np.arange(6.0).reshape(3, 2)
    R = K @ X
    assert solve_small(K.copy(), R, 3, 2)
    np.testing.assert_allclose(R, X, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("spec,k", [("conic.yaml", 1), ("two_view.yaml", 2),
                                     ("two_view_calibrated.yaml", 3)])
def test_tangent_directions_give_the_projected_hessian(spec, k):
    """Along the tangent basis ``W`` of the end's check: ``Wᵀ ∇²F W``, the same as the
    full Hessian projected."""
    fam = kanagen.load(spec.removesuffix(".yaml"))
    model, data, info, start, constants = SCENARIOS[spec]()[k]
    A, x, lin = _at_fit(fam, model, data, info, start, constants)
    W = verify.tangent_basis(x, lin.info)
    assert 0 < W.shape[1] < x.q.size
    ok, H = curvature.profile_hessian(A, x, lin, np.eye(x.q.size))
    ok_w, K = curvature.profile_hessian(A, x, lin, W)
    assert ok and ok_w and K.shape == (W.shape[1],) * 2
    reference = W.T @ H @ W
    assert np.abs(K - reference).max() <= 1e-7 * np.abs(reference).max()


def test_verified_fit_reports_the_exact_curvature():
    """A verified conic fit's curvature is the least eigenvalue of the exact Hessian of the
    Lagrangian on the tangent space, in units of the information (a minimum: positive)."""
    fam = kanagen.load("conic")
    model, data, info, start, constants = SCENARIOS["conic.yaml"]()[1]
    A, x, lin = _at_fit(fam, model, data, info, start, constants)
    H = _check(A, x, lin)
    lam0 = points.multipliers(x, lin.gradient)
    W = verify.tangent_basis(x, lin.info)
    K = W.T @ (H + points.constraint_curvature(A, x.q, lam0)) @ W
    ok, least, direction, basis = verify.exact_curvature(A, x, lin, W, lam0)
    assert ok
    assert least == pytest.approx(np.linalg.eigvalsh(0.5 * (K + K.T))[0], rel=1e-7)
    assert least > 0
    assert basis is W  # no direction left out: the constraint is regular
    problem = make_problem(fam, model, data, info, start, constants=constants)
    res = fit_problem(fam, model, problem)
    assert res.success and "no negative curvature" in res.message


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.integers(0, 5), st.integers(0, 2**32 - 1), st.booleans())
def test_multipliers_are_the_least_squares_solution(r, extra, seed, dependent):
    """``λ0`` minimises ``‖C0ᵀ λ0 + ∇F‖`` as NumPy's ``lstsq`` does (its minimum-norm
    solution where constraints are dependent), from the constraints' SVD by rotations
    when they are independent."""
    link()
    rng = np.random.default_rng(seed)
    n = r + extra
    C0 = rng.standard_normal((r, n)) * 10.0 ** rng.uniform(-3, 3, (r, 1))
    if dependent and r > 1:
        C0[-1] = C0[0] * 2.0
    g = rng.standard_normal(n)
    x = points.Pt(np.zeros(n), np.zeros((0, 1)), np.zeros(r), C0, np.zeros((0, 1)),
                  np.zeros((0, 1, n)), np.zeros((0, 1, 1)), 0.0, 0.0)
    lam = points.multipliers(x, g)
    reference = np.linalg.lstsq(C0.T, -g, rcond=np.finfo(float).eps * n)[0]
    scale = np.abs(reference).max() + 1e-300
    assert np.abs(lam - reference).max() <= 1e-9 * scale


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 12), st.integers(0, 2**32 - 1), st.integers(0, 3))
def test_symmetric_eigen_as_lapack(n, seed, kind):
    """``sym_eigh`` (Jacobi rotations) gives NumPy's ``eigh``'s eigenvalues, ascending, from
    the lower triangle, and orthonormal eigenvectors: definite, indefinite, singular and
    badly scaled matrices."""
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((n, n))
    if kind == 0:
        K = B @ B.T
    elif kind == 1:
        K = B + B.T
    elif kind == 2:  # singular: rank n - 1 (or 0)
        B[:, -1] = 0.0
        K = B @ B.T
    else:  # scales over ten orders of magnitude
        D = np.diag(10.0 ** rng.uniform(-5, 5, n))
        K = D @ (B @ B.T) @ D
    upper_garbage = K + np.triu(rng.standard_normal((n, n)), 1)
    w, V = sym_eigh(upper_garbage)
    reference = np.linalg.eigvalsh(K)
    scale = np.abs(K).max()
    assert np.all(np.diff(w) >= 0)
    assert np.abs(w - reference).max() <= 1e-12 * scale
    np.testing.assert_allclose(V.T @ V, np.eye(n), atol=1e-12)
    assert np.abs(K @ V - V * w).max() <= 1e-12 * scale


def test_symmetric_eigen_refuses_non_finite():
    K = np.eye(3)
    K[2, 1] = np.nan
    with pytest.raises(np.linalg.LinAlgError):
        sym_eigh(K)


@settings(max_examples=120, deadline=None)
@given(st.integers(0, 5), st.integers(1, 10), st.integers(0, 2**32 - 1), st.integers(0, 3))
def test_null_space_as_lapack(r, s, seed, kind):
    """``null_space`` (Jacobi rotations, completed by Householder reflections) spans the
    space LAPACK's SVD gives — the same rank cut, the same projector — with orthonormal
    columns: independent, dependent, more rows than columns, tiny and zero rows."""
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((r, s))
    if kind == 1 and r >= 2:
        B[-1] = 2.0 * B[0]  # a dependent row
    elif kind == 2:
        B *= 1e-9
    elif kind == 3 and r:
        B[0] = 0.0
    Z = null_space(B, 1e-10)
    if r and np.abs(B).max() > 0:
        _, S, Vt = np.linalg.svd(B)
        reference = Vt[int((S > 1e-10 * S[0]).sum()):].T
    else:
        reference = np.eye(s)
    assert Z.shape == reference.shape
    np.testing.assert_allclose(Z.T @ Z, np.eye(Z.shape[1]), atol=1e-13)
    np.testing.assert_allclose(Z @ Z.T, reference @ reference.T, atol=1e-12)
    if r:
        assert np.abs(B @ Z).max(initial=0.0) <= 1e-12 * max(np.abs(B).max(), 1e-300)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 9), st.integers(0, 2**32 - 1))
def test_lost_direction_measure_without_constraints(n, seed):
    """The end's lost-direction measure (``verify.weakest``) with no constraint: the least
    eigenvalue of the information scaled to a unit diagonal over the largest, as NumPy's
    ``eigh`` gives it, and its direction in the parameter's components."""
    from kanagen.runtime.engine.points import Pt

    rng = np.random.default_rng(seed)
    J = rng.standard_normal((n + 2, n)) * 10.0 ** rng.uniform(-3, 3, n)
    info = J.T @ J
    x = Pt(np.ones(n), np.zeros((0, 1)), np.zeros(0), np.zeros((0, n)), np.zeros((0, 1)),
           np.zeros((0, 1, n)), np.zeros((0, 1, 1)), 0.0, 0.0)
    ok, least, u = verify.weakest(info, x, 0.0)
    d = np.sqrt(np.diag(info))
    w, V = np.linalg.eigh(info / np.outer(d, d))
    assert ok
    assert least == pytest.approx(w[0] / w[-1], rel=1e-7, abs=1e-13)
    if w.size == 1 or w[1] - w[0] > 1e-6 * w[-1]:  # a direction well defined: separated
        ref = V[:, 0] / d
        assert min(np.abs(u - ref).max(), np.abs(u + ref).max()) <= 1e-6 * np.abs(ref).max()


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 9), st.integers(0, 2**32 - 1), st.floats(-16, 0))
def test_certainly_above_never_certifies_a_smaller_ratio(k, seed, log_ratio):
    """``verify.certainly_above`` (which spares the lost-direction check its eigenproblem)
    says True only when the least eigenvalue of the unit-diagonal matrix really is above
    ``ratio`` times its largest — the eigenproblem would have said the same — and says it
    for a well-conditioned matrix."""
    rng = np.random.default_rng(seed)
    U, _ = np.linalg.qr(rng.standard_normal((k, k)))
    w = 10.0 ** rng.uniform(-16, 0, k)
    w[rng.integers(k)] = 1.0
    M = (U * w) @ U.T
    d = np.sqrt(np.diag(M))
    S = M / np.outer(d, d)
    S = 0.5 * (S + S.T)
    ratio = 10.0 ** log_ratio
    eig = np.linalg.eigvalsh(S)
    if verify.certainly_above(S, ratio):
        assert eig[0] > ratio * eig[-1]
    assert verify.certainly_above(np.eye(k), 1e-3)
    # the bound loses a factor k² at worst (λmax ≥ 1 on a unit diagonal); rounding aside
    if ratio >= 1e-10 and eig[0] / eig[-1] > k * k * ratio * 1.1:
        assert verify.certainly_above(S, ratio)


PINNED = """name: pinned
parameter: {x: 0.0, z: 0.0}
channels:
  point:
    components: [u, v]
    equations: [u - x, v - z]
models:
  pinned:
    constraints: [x + z**2, x]
"""


def _pinned():
    """``x + z² = 0`` and ``x = 0`` pin ``z = 0``; their gradients there do not see ``z``.
    The data pull ``x`` to −5 and leave ``z`` at 0 exactly (the ``v`` in opposite pairs)."""
    fam = kanagen.load_text(PINNED, "pinned.yaml")
    rng = np.random.default_rng(1)
    u = -5.0 + 0.1 * rng.standard_normal(20)
    h = 0.1 * rng.standard_normal(10)
    return fam, {"point": np.column_stack([u, np.column_stack([h, -h]).ravel()])}


def test_a_tangent_the_constraints_allow_to_first_order_only_is_no_saddle():
    """At ``z = 0`` the direction of ``z`` is tangent to the constraints to first order, and
    with the minimum-norm multipliers (the rows of ``C0`` dependent there) the Lagrangian's
    curvature along it is −4 in units of the information; but no curve on the constraints
    goes along it (``z² = −x = 0``): the fit's end is a minimum — before, a saddle (status
    5) that no step could leave."""
    fam, data = _pinned()
    res = kanagen.fit(fam, data=data, q0=np.zeros(2))
    assert res.success and res.status == 0, res.message
    np.testing.assert_array_equal(res.q, [0.0, 0.0])
    link()
    A = arrays(make_problem(fam, "pinned", data, None, np.zeros(2)))
    x, _ = points.restore(A, np.zeros(2), A.m, 30)
    ok, lin, _ = points.project_point(A, x, 0.0, np.zeros(0))
    W = verify.tangent_basis(x, lin.info)
    lam0 = points.multipliers(x, lin.gradient)
    assert ok and W.shape[1] == 1 and abs(W[1, 0]) > 0  # z's direction: tangent
    ok, K = curvature.profile_hessian(A, x, lin, W)  # F_zz = 20 (20 measures): 1 along W
    K = K + W.T @ points.constraint_curvature(A, x.q, lam0) @ W  # + 2 λ0[0] z•²
    expected = 1.0 + 2.0 * lam0[0] * W[1, 0] ** 2  # λ0[0] = Σ(u − x) / 2 ≈ −50: ≈ −4
    assert ok and K[0, 0] == pytest.approx(expected, rel=1e-9) and expected < -3.9
    assert not verify.second_order_tangent(A, x, W[:, 0])  # ... the constraints forbid
    ok, least, direction, basis = verify.exact_curvature(A, x, lin, W, lam0)
    assert ok and least == 0.0 and basis.shape == (2, 0)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_every_tangent_of_independent_constraints_is_one_to_second_order(seed):
    """Where the rows of ``C0`` are independent (the conic's unit norm and its circle's two
    more), every direction tangent to them to first order is one to second order."""
    rng = np.random.default_rng(seed)
    fam = kanagen.load("conic")
    for k in (0, 1):
        model, data, info, start, constants = SCENARIOS["conic.yaml"]()[k]
        A, x, lin = _at_fit(fam, model, data, info, start, constants)
        T = null_space(x.C0, 1e-10)
        d = T @ rng.standard_normal(T.shape[1])
        assert verify.second_order_tangent(A, x, d)


@pytest.mark.parametrize("case", [1, 2])
def test_an_end_off_its_constraints_is_no_success(case):
    """The hysteresis scenario's second and third fits (t = ±2.5 from the other state: the
    switch forces the state over, the readings are the old state's) cannot reach their
    constraints. The third reaches a point where the whitened violation of its constraints
    is nothing (their rows there are dependent, the violated ones' pivots dropped) but
    ``c0`` is −2: the end requires the constraints themselves within rounding, as the steps
    do. The second runs a slack of a branch it is not on off to −1.4e27: the rounding of
    ``c0`` taken from ``max|q|`` was 1.9e41, and ``c0`` = 1 on rows without that slack
    passed; each row's rounding now comes from the components it involves. Both were a
    success (status 0) before; now the cap, and its message says the point is off."""
    fam = kanagen.load("hysteresis")
    model, data, info, start, constants = SCENARIOS["hysteresis.yaml"]()[case]
    res = kanagen.fit(fam, model, data=data, info=info, q0=start, constants=constants)
    assert not res.success and res.status != 0, res.message
    assert res.constraint_violation >= 1.0
    assert "off its equations or constraints" in res.message, res.message


def test_the_rounding_of_a_constraint_is_its_own():
    """``c0_at_rounding`` takes each row's rounding from the components its gradient sees:
    a huge component another row alone involves does not hide a violated row; a row that
    involves it is allowed its rounding."""
    q = np.array([1.0, 1e27])
    C0 = np.array([[1.0, 0.0], [0.0, 2e27]])
    assert not points.c0_at_rounding(q, np.array([1e-6, 0.0]), C0)
    assert points.c0_at_rounding(q, np.array([1e-13, 1e40]), C0)
    assert not points.c0_at_rounding(q, np.array([1e-13, 1e42]), C0)
    assert not points.c0_at_rounding(q, np.array([np.nan, 0.0]), C0)
    assert points.c0_at_rounding(q, np.zeros(0), np.zeros((0, 2)))


def test_a_fit_that_ends_off_its_constraints_says_how_far():
    """The hysteresis at t = 0 from the state 1: its answer y = −1 sits at the corner of the
    saturation, where two factors of a product row vanish together (docs/engine.md: no KKT
    point there). From a start around it the iteration ends at y ≈ −1.005 with ``c0`` at
    1e-3 — no success, and its message gives the violation it ended with."""
    fam = kanagen.load("hysteresis")
    constants = {"t": 0.0, "s_prev": 1.0}
    rng = np.random.default_rng(3)
    y0, s0 = -1.0 + rng.normal(0.0, 0.1), 1.0 + rng.normal(0.0, 0.1)
    start = fam.with_slacks(np.array([y0, s0]), fam.constant_vector(constants), "hysteresis")
    res = kanagen.fit(fam, "hysteresis", data={"reading": np.array([[-0.99], [-1.02]])},
                      q0=start, constants=constants)
    assert not res.success and res.status in (1, 7), res.message
    assert res.constraint_violation > 1e-6
    assert f"(constraint_violation {res.constraint_violation:.3g})" in res.message
