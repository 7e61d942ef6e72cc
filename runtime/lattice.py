"""The lattice of models (report §5): its structure, and the decisions between models.

Pure functions the estimator's walk and scheduler call on its model states
(:class:`~kanagen.runtime.walk.LatticeWalk`, :class:`~kanagen.runtime.schedule.Scheduler`):
which models come before which (:func:`reachable`, :func:`lattice_parents`,
:func:`anchor`), how many of a child's degrees of freedom its parent's inliers fix
(:func:`fixed_by`), whether a general model replaces a specific one (:func:`beats`) and
which of several accepted models is the best (:func:`select`). The cost test of eq. 36 is
:func:`general_wins`, on two fits the estimator makes on the measures both models take as
inliers (its ``replaces(specific, general)``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .family import ModelFamily
    from .results import FitResult, ModelState

MORE_SUPPORT = 1.2  # a general model wins outright when it explains this much more
SUPPORT = 0.95  # ... and must keep this fraction of its parent's relevance
RELEVANT = 0.1  # a parent explaining fewer measures than this fraction is no base
HOPELESS = 0.5  # a child whose best sample reaches less than this share of what replacing
#                its parent needs is refined briefly (Scheduler._hopeless)
RANK_SAMPLE = 60  # corrected inliers of a parent used to count what they fix of a child
RANK_TOL = 1e-6  # relative singular value below which a direction is not fixed
SAME_FIT = 1e-6  # relative cost difference below which two fits are the same fit

Shape = Mapping[str, tuple[int, int]]  # model -> (equations per measure, free dof)
Replaces = Callable[["ModelState", "ModelState"], bool]


def reachable(fam: ModelFamily, root: str) -> set[str]:
    """The models the lattice reaches from ``root`` through the alternatives."""
    seen, todo = {root}, [root]
    while todo:
        for alt, _ in fam.model(todo.pop()).alternatives:
            if alt not in seen:
                seen.add(alt)
                todo.append(alt)
    return seen


def tops(fam: ModelFamily, root: str) -> list[str]:
    """The most general models the lattice reaches from ``root`` (no alternatives of their
    own), in the family's order; none when the lattice is the root alone."""
    models = reachable(fam, root)
    if len(models) < 2:
        return []
    return [m for m in fam.models if m in models and not fam.model(m).alternatives]


def lattice_parents(fam: ModelFamily, model: str, among: set[str]) -> list[str]:
    """The models of ``among`` that name ``model`` as an alternative."""
    return [m for m in fam.models if m in among
            and any(alt == model for alt, _ in fam.model(m).alternatives)]


def anchor(states: Mapping[str, ModelState], skipped: Mapping[str, str | None],
           model: str | None) -> str | None:
    """The model itself if accepted, else the nearest accepted model it was compared with:
    a rejected model does not hide a more general one (a hyperbola is neither a circle nor
    an ellipse, but it is a conic). ``skipped`` maps a model never estimated to its parent."""
    seen = set()
    while model is not None and model not in seen:
        seen.add(model)
        state = states.get(model)
        if state is not None and state.accepted:
            return model
        model = state.parent if state is not None else skipped.get(model)
    return None


def rank(rows: np.ndarray) -> int | None:
    """Rank of a matrix of equations' gradients, each row scaled to unit norm (None when not
    finite)."""
    norms = np.linalg.norm(rows, axis=1)
    rows = rows[norms > 0] / norms[norms > 0, None]
    if not np.all(np.isfinite(rows)):
        return None
    sv = np.linalg.svd(rows, compute_uv=False)
    return int(np.count_nonzero(sv > RANK_TOL * sv[0])) if sv.size else 0


def fixed_by(fam: ModelFamily, parent: ModelState, free_parent: int, model: str,
             channel: str, corrected: np.ndarray | None, constants,
             across: bool = False) -> int:
    """How many of ``model``'s free degrees of freedom the parent's inliers fix: the rank of
    ``model``'s equations at the parent's estimate over its inliers corrected onto the
    parent (report §5's singular configurations: matches on a plane fix 5 of a fundamental
    matrix's 7, not the 8 of their homography, so the general model needs 2 matches off the
    plane, not 1), and at most the parent's own (``free_parent``) — unless the edge goes
    ``across`` a change of equations per measure. There the parent's inliers are a singular
    configuration of the child whatever the parent's freedom: matches of no motion (the
    parent fixes nothing of its own) fix 4 of a fundamental matrix's 7, and its samples need
    only the 3 others off them. Along an edge of the same equations, a parent close to the
    child's structure holds its inliers only loosely: the cap keeps the samples the report's
    additional measures."""
    if corrected is None or not len(corrected):
        return free_parent
    with np.errstate(all="ignore"):
        _, C, _ = fam.measurement(model, channel, parent.q, corrected[:RANK_SAMPLE], constants)
        C0 = fam.c0(model, parent.q, constants)[1]
    both, alone = rank(np.r_[C0, C.reshape(-1, fam.n)]), rank(C0)
    if both is None or alone is None:
        return free_parent
    fixed = max(both - alone, 0)
    return fixed if across else min(free_parent, fixed)


def ranks_differ(shape: Shape, a: ModelState, b: ModelState) -> bool:
    return a.model in shape and b.model in shape and shape[a.model][0] != shape[b.model][0]


def explains_more(general: ModelState, specific: ModelState) -> bool:
    """The more general of two models with different numbers of equations per measure wins
    only by explaining clearly more measures (a fifth more inliers). Its errors do not
    compare with the other's (``χ²₁`` against ``χ²₂/2``), and the other's inliers are a
    singular configuration for it (no motion, or a plane, for a fundamental matrix: report
    §5), where its fit is degenerate and its cost low for free — a cost test on common
    inliers would be no test."""
    return general.inliers.size >= MORE_SUPPORT * specific.inliers.size


def beats(parent: ModelState, state: ModelState, shape: Shape, replaces: Replaces) -> bool:
    """Does the general model replace its parent? (report eq. 36, made comparable)

    A general model that explains clearly more measures (relevance up by a fifth) wins
    outright; one that explains fewer loses (a general model fitted to a few measures has a
    small cost for free). Otherwise ``replaces`` decides on the measures both take as
    inliers. Between models with different numbers of equations per measure:
    :func:`explains_more`.
    """
    if ranks_differ(shape, parent, state):
        return explains_more(state, parent)
    if state.relevance >= MORE_SUPPORT * parent.relevance:
        return True
    if state.relevance < SUPPORT * parent.relevance:
        return False
    return replaces(parent, state)


def support_needed(parent: ModelState, across: bool, measures: int) -> float:
    """The fewest inliers a child of ``parent`` explains when it replaces it (:func:`beats`):
    across a change of equations per measure a fifth more than its parent
    (:func:`explains_more`); else it keeps :data:`SUPPORT` of its parent's relevance, and
    each inlier adds at most ``1 / measures`` to a relevance (eq. 29, or the share of
    inliers of the ransac-like score)."""
    if across:
        return MORE_SUPPORT * parent.inliers.size
    return SUPPORT * parent.relevance * measures


def hopeless(parent: ModelState, relevance: float, inliers: int, across: bool) -> bool:
    """Is a general model whose best random sample has this ``relevance`` and these
    ``inliers`` far (:data:`HOPELESS`) from what :func:`beats` asks to replace ``parent``?
    Across a change of equations per measure: a fifth more inliers; else at least
    :data:`SUPPORT` of the parent's relevance. Its final refinement then takes a few
    iterations: a refinement that doubles the support of the best sample, which its local
    optimisation has refined already, is not what refinement does — and a model that does
    not fit the data converges slowly, often not in ``max_iter`` iterations."""
    if across:
        return inliers < HOPELESS * MORE_SUPPORT * parent.inliers.size
    return relevance < HOPELESS * SUPPORT * parent.relevance


def select(states: list[ModelState], shape: Shape, replaces: Replaces) -> ModelState:
    """The best of several accepted models: those not clearly out-supported (a fifth more
    inliers), then from the most specific (most equations per measure, fewest free degrees
    of freedom) a more general one replaces it only if it passes the test of :func:`beats`
    without its shortcuts — the report's "most specific model of optimal cost"."""
    if len(states) == 1:
        return states[0]
    top = max(s.inliers.size for s in states)
    cands = [s for s in states if s.inliers.size * MORE_SUPPORT >= top] or list(states)
    cands.sort(key=lambda s: (-shape.get(s.model, (1, 0))[0], shape.get(s.model, (1, 0))[1],
                              s.normalized_cost))
    current = cands[0]
    for other in cands[1:]:
        if not (current.samples and other.samples):
            continue
        if explains_more(other, current) if ranks_differ(shape, current, other) \
                else replaces(current, other):
            current = other
    return current


def general_wins(specific: FitResult, general: FitResult, phi) -> bool:
    """``L̃'²/d' < Φ(d, d') L̃²/d`` (eq. 36) for two fits on the same measures, strictly
    beyond rounding: on common measures ``d' − d`` counts only the extra freedom, as the
    F-test of appendix B presumes, and a model that only drops an inequality (ellipse →
    conic, same ``d``) reaches the very same fit when the inequality is not active."""
    if not (np.isfinite(specific.normalized_cost) and np.isfinite(general.normalized_cost)):
        return False
    factor = phi(specific.dof, general.dof)
    return bool(general.normalized_cost < factor * specific.normalized_cost * (1 - SAME_FIT))
