"""Closed-form initialisers: starting values for a model's minimal solves (report eq. 21).

The minimal solve of a sample starts from the parent model's estimate. For a model whose
solutions are far from it and several (a fundamental matrix from 7 matches has up to three;
a homography's pose two), a closed form on the sample gives better starts. A model names
its initializer in the spec (``initializer: two_view_fundamental``) — a key of
:data:`INITIALIZERS`, checked when the spec is read, never executable text — or the caller
passes ``initializers={model: name or callable}`` to :class:`~kanagen.Estimator` /
:func:`~kanagen.robust_fit` (``None`` switches one off).

An initializer is ``f(rows, constants) -> [ {parameter name: value}, ... ]``: ``rows`` are
the sample's measures of the sampled channel (data columns in the spec's order),
``constants`` the run-time constants by name. Each candidate (components it does not name
keep the parent's values) starts one minimal solve; every solution that passes is scored.
No candidate means that no parameter of the model passes through the sample (a seven-point
F whose focal lengths are imaginary): the sample is skipped. The final refinement on the
inliers also starts from the candidates and keeps the fit of least cost.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from . import geometry as g

Candidates = list[dict[str, float]]
InitializerFn = Callable[[np.ndarray, Mapping[str, float]], Candidates]

_TWO_VIEW_Q = ("f1", "f2", "qw", "qx", "qy", "qz", "tx", "ty", "tz", "wx", "wy", "wz")
_FOCAL_RANGE = (0.1, 10.0)  # focal lengths (× f0) read off F outside this range are noise


@dataclass(frozen=True)
class Initializer:
    """A registered closed form and what it needs of the family."""

    name: str
    fn: InitializerFn
    parameters: tuple[str, ...]
    constants: tuple[str, ...]
    width: int  # components of the sampled channel
    doc: str
    #: the candidates parameterise one estimate (the two decompositions of one homography
    #: give the same errors): a random sample scores only the first whose solve passes
    equivalent: bool = False

    def missing(self, parameter, constants, channels: Mapping[str, tuple[str, ...]]) -> str:
        """What the family lacks for this initializer ('' when nothing)."""
        lacks = [f"parameter {p!r}" for p in self.parameters if p not in parameter]
        lacks += [f"constant {c!r}" for c in self.constants if c not in constants]
        if not any(len(comps) == self.width for comps in channels.values()):
            lacks.append(f"a channel of {self.width} components")
        return ", ".join(lacks)


def _rays(X: np.ndarray, k: Mapping[str, float], f1: float = 1.0, f2: float = 1.0):
    """Pixel matches → rays (x, y, f) in the normalised coordinates of the family."""
    cx, cy, f0 = k["cx"], k["cy"], k["f0"]
    y1, y2 = np.empty((len(X), 3)), np.empty((len(X), 3))
    y1[:, 0], y1[:, 1], y1[:, 2] = (X[:, 0] - cx) / f0, (X[:, 1] - cy) / f0, f1
    y2[:, 0], y2[:, 1], y2[:, 2] = (X[:, 2] - cx) / f0, (X[:, 3] - cy) / f0, f2
    return y1, y2


def _pose_params(R: np.ndarray, t: np.ndarray) -> dict[str, float]:
    q = g.quaternion_from_rotation(R)
    return {"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3],
            "tx": t[0], "ty": t[1], "tz": t[2]}


def two_view_fundamental(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """``F`` by the seven-point (7 matches) or normalised eight-point algorithm (more), the
    focal lengths read off it (Bougnoux), then ``R, t`` from the essential matrix, chosen
    by cheirality. An ``F`` whose focal lengths are imaginary or out of range has no
    physical parameter through the sample: it gives no candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 7 or not np.all(np.isfinite(X)):
        return []
    x1, x2 = X[:, :2], X[:, 2:4]
    f0 = k["f0"]
    try:
        Fs = g.fundamental_7point(x1, x2) if len(X) == 7 else [g.fundamental_8point(x1, x2)]
        out = []
        for F in Fs:
            sq1, sq2 = g.focal_lengths(F, (k["cx"], k["cy"]), (k["cx"], k["cy"]))
            f1, f2 = np.sqrt(max(sq1, 0.0)) / f0, np.sqrt(max(sq2, 0.0)) / f0
            if not all(_FOCAL_RANGE[0] < f < _FOCAL_RANGE[1] for f in (f1, f2)):
                continue
            # F ∝ Tᵀ diag(1, 1, f2) E diag(1, 1, f1) T with T the pixel -> normalised map
            T = np.array([[1 / f0, 0, -k["cx"] / f0], [0, 1 / f0, -k["cy"] / f0], [0, 0, 1]])
            Tinv = np.linalg.inv(T)
            E = np.diag([1.0, 1.0, 1 / f2]) @ Tinv.T @ F @ Tinv @ np.diag([1.0, 1.0, 1 / f1])
            y1, y2 = _rays(X, k, f1, f2)
            R, t = g.best_pose(g.essential_poses(g.nearest_essential(E)), y1, y2)
            out.append({"f1": f1, "f2": f2, **_pose_params(R, t)})
        return out
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        return []


def two_view_homography(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """``H`` by the normalised DLT (4 matches or more), then ``(R, t, w)`` with
    ``H ∝ R + t wᵀ`` at the nominal focal length (the planar model's), in front of
    camera 1; each of the (two) decompositions is a candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 4 or not np.all(np.isfinite(X)):
        return []
    try:
        H = g.homography_dlt(X[:, :2], X[:, 2:4])
        f0 = k["f0"]
        T = np.array([[1 / f0, 0, -k["cx"] / f0], [0, 1 / f0, -k["cy"] / f0], [0, 0, 1]])
        Hn = T @ H @ np.linalg.inv(T)
        y1, y2 = _rays(X, k)
        return [{"f1": 1.0, "f2": 1.0, **_pose_params(R, t), "wx": w[0], "wy": w[1],
                 "wz": w[2]} for R, t, w in g.homography_poses(Hn, y1, y2)]
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        return []


INITIALIZERS: dict[str, Initializer] = {
    entry.name: entry for entry in (
        Initializer("two_view_fundamental", two_view_fundamental, _TWO_VIEW_Q,
                    ("cx", "cy", "f0"), 4, two_view_fundamental.__doc__.splitlines()[0]),
        Initializer("two_view_homography", two_view_homography, _TWO_VIEW_Q,
                    ("cx", "cy", "f0"), 4, two_view_homography.__doc__.splitlines()[0],
                    equivalent=True),
    )
}


def resolve(choice) -> InitializerFn | None:
    """A registry name, a callable or None → the initializer function (or None)."""
    if choice is None or callable(choice):
        return choice
    entry = INITIALIZERS.get(choice)
    if entry is None:
        raise ValueError(f"unknown initializer {choice!r} (known: "
                         f"{', '.join(sorted(INITIALIZERS))}, or a callable)")
    return entry.fn


def label_candidates(labels: Mapping[str, tuple[float, ...]]) -> InitializerFn:
    """The starts of a model with qualitative variables (``x in {a, b, ...}``): one per
    combination of labels. A local solver stays on the label it starts at, so every label
    is tried and the data choose (the best-scoring sample, the least-cost refinement)."""
    names = sorted(labels)
    combos = [dict(zip(names, values, strict=True))
              for values in itertools.product(*(labels[n] for n in names))]

    def candidates(rows, constants) -> Candidates:
        return [dict(c) for c in combos]

    return candidates


def model_initializers(fam, overrides: Mapping | None = None) -> dict[str, InitializerFn]:
    """Each model's initializer: the spec's choice, overridden by ``overrides``; a model
    with qualitative variables and no closed form starts on each of its labels. On the
    compiled backend a registered initializer named by the spec or an override runs as its
    compiled twin (:meth:`~kanagen.runtime.fastpath.FastPath.initializer`: the same
    candidates); a callable override runs as given."""
    out = {}
    overrides = dict(overrides or {})
    for name in overrides:
        fam.model(name)  # a clear error for an unknown model
    fast = getattr(fam, "fastpath", None)
    for name, info in fam.models.items():
        choice = overrides[name] if name in overrides else info.initializer
        fn = resolve(choice)
        if fast is not None and isinstance(choice, str):
            fn = fast.initializer(choice) or fn
        if isinstance(choice, str) and INITIALIZERS[choice].equivalent:
            fn.equivalent = True  # read by equivalent()
        if fn is None and info.labels and overrides.get(name, "") is not None:
            fn = label_candidates(info.labels)
        if fn is not None:
            out[name] = fn
    return out


def equivalent(fn: InitializerFn | None) -> bool:
    """Do the candidates of the initializer ``fn`` parameterise one estimate (a registered
    closed form flagged :attr:`Initializer.equivalent`)?"""
    return bool(getattr(fn, "equivalent", False))


def start_from(fam, candidate: Mapping[str, float], start: np.ndarray) -> np.ndarray | None:
    """``start`` with the candidate's named components replaced (None if one is unknown or
    not finite)."""
    q = np.array(start, dtype=float)
    for name, value in candidate.items():
        if name not in fam.parameter_names or not np.isfinite(value):
            return None
        q[fam.parameter_names.index(name)] = value
    return q
