"""Validation of the numbers a user passes in: data arrays, information matrices, q0, Q0.

Everything is checked before any work, with errors that say which channel, which measure and
what is wrong. The estimator itself then never raises on bad numerics.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .sqrt import closest_sqrt

if TYPE_CHECKING:  # annotations only: the family builds on this module's data types
    from .family import ModelFamily


@dataclass(frozen=True)
class ChannelData:
    """The measures of one channel, ready for the projector."""

    name: str
    X: np.ndarray  # (M, components) observed data, all columns
    index: np.ndarray  # columns of the corrected components
    m: np.ndarray  # (M, k) observed corrected components
    Q: np.ndarray  # information, (k, k) shared or (M, k, k)
    G: np.ndarray  # inverse of the closest square root of Q, same shape
    fixed: np.ndarray | None = None  # (M, k) exact corrected components (``exact=``), or None

    @property
    def size(self) -> int:
        return self.X.shape[0]

    def subset(self, rows: np.ndarray) -> ChannelData:
        """The same channel restricted to some measures (no validation again)."""
        per_measure = self.Q.ndim == 3
        return ChannelData(self.name, self.X[rows], self.index, self.m[rows],
                           self.Q[rows] if per_measure else self.Q,
                           self.G[rows] if per_measure else self.G,
                           None if self.fixed is None else self.fixed[rows])

    def with_corrected(self, mt: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """The data array (its rows ``rows``, default all) with the corrected columns
        replaced by ``mt``."""
        if self.index.size == self.X.shape[1]:
            return mt  # no exact component: the corrected measures are the whole data
        X = self.X.copy() if rows is None else self.X[rows]
        X[:, self.index] = mt
        return X


_FLOAT = np.dtype(float)


def real_array(value, what: str) -> np.ndarray:
    """``value`` as a float array: complex numbers (their imaginary part would be lost),
    booleans (they would pass for 0 and 1), text and objects (even "1") are refused, naming
    ``what``."""
    array = np.asarray(value)
    if type(array) is np.ndarray and array.dtype == _FLOAT:  # the common case: a copy
        return array.copy()
    if array.dtype.kind == "c":
        raise ValueError(f"{what} holds complex numbers; measures and information are real")
    if array.dtype.kind == "b":
        raise ValueError(f"{what} holds booleans, not numbers")
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{what} must be numbers, got {array.dtype.name} values")
    return np.array(array, dtype=float)


def _finite(a: np.ndarray, what: str) -> None:
    if math.isfinite(np.vdot(a, a)):  # a finite sum of squares: every entry finite
        return
    if np.isfinite(a).all():  # finite entries whose squares' sum overflows
        return
    where = np.argwhere(~np.isfinite(a))[0]
    raise ValueError(f"{what} contains NaN or infinite values (first at index "
                     f"{tuple(int(i) for i in where)})")


def _psd(Q: np.ndarray, what: str) -> None:
    if not np.allclose(Q, np.swapaxes(Q, -1, -2), rtol=1e-10, atol=1e-12 * np.abs(Q).max(
            initial=0.0)):
        raise ValueError(f"{what} must be symmetric")
    eig = np.linalg.eigvalsh(Q)
    scale = np.maximum(np.abs(eig).max(axis=-1, initial=0.0), np.finfo(float).tiny)
    worst = (eig.min(axis=-1) / scale) if eig.size else np.zeros(1)
    if np.any(worst < -1e-10):
        where = int(np.argmin(np.atleast_1d(worst)))
        raise ValueError(f"{what} must be positive semi-definite (an eigenvalue is negative"
                         + (f", measure {where})" if Q.ndim == 3 else ")"))


_EYES: dict = {}


def _eye(k: int) -> np.ndarray:
    """``np.eye(k)``, made once (read-only)."""
    eye = _EYES.get(k)
    if eye is None:
        eye = _EYES[k] = np.eye(k)
        eye.flags.writeable = False
    return eye


def information(value, k: int, M: int, what: str) -> np.ndarray:
    """Normalise an information specification to (k, k) or (M, k, k), validated: a number
    (``1/σ²`` of every component), one per component ``(k,)`` or per measure ``(M,)`` or
    both ``(M, k)`` (diagonal), a matrix ``(k, k)`` or one per measure ``(M, k, k)``."""
    if value is None:
        return np.eye(k)
    Q = real_array(value, what)
    _finite(Q, what)
    if Q.ndim == 0:
        if Q <= 0:
            raise ValueError(f"{what} must be positive, got {float(Q)}")
        return float(Q) * np.eye(k)
    if Q.shape == (M,) and not (M == k and k > 1):
        if np.any(Q <= 0):
            raise ValueError(f"{what}: per-measure scalars must be positive "
                             f"(measure {int(np.argmin(Q))} has {Q.min()})")
        return Q[:, None, None] * np.eye(k)
    if Q.shape == (k, k) or Q.shape == (M, k, k):
        _psd(Q, what)
        return Q
    if M != k and Q.shape in ((k,), (M, k)):  # per component (and measure): a diagonal
        if np.any(Q < 0):
            raise ValueError(f"{what}: a component's information must be >= 0, got "
                             f"{Q.min()}")
        return Q[..., None] * np.eye(k)
    ambiguous = (f" (with {M} measures of {k} components, ({k},) could be one per measure "
                 f"or one per component: pass np.diag(v) per component, or "
                 f"v[:, None, None] * np.eye({k}) per measure)") if M == k and Q.ndim == 1 \
        else ""
    raise ValueError(f"{what} has shape {Q.shape}; expected a scalar, ({k},) one per "
                     f"component, ({k}, {k}), ({M},) one per measure, ({M}, {k}) or "
                     f"({M}, {k}, {k}){ambiguous}")


_ROOTS: dict = {}  # inverse_root of a shared (k, k) information, by its bytes
_SCALARS: dict = {}  # (Q, G) of a number's information, by its value and size


def information_and_root(value, k: int, M: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`information` and its :func:`inverse_root`. A positive Python number (the
    common case: ``1/σ²``) gives ``value · I`` and its root made once per value and size
    (fit after fit with the same σ), as copies of the same numbers."""
    if not ((type(value) is float or type(value) is int) and 0 < value < math.inf):
        Q = information(value, k, M, what)  # anything else (bad numbers too) validated
        return Q, inverse_root(Q)
    key = (float(value), k)
    made = _SCALARS.get(key)
    if made is None:
        if len(_SCALARS) >= 256:
            _SCALARS.clear()
        Q = float(value) * _eye(k)
        made = _SCALARS[key] = (Q, inverse_root(Q))
    return made[0].copy(), made[1].copy()


def inverse_root(Q: np.ndarray) -> np.ndarray:
    """``G = L⁻¹`` for ``L`` the closest square root of ``Q`` (so ``Q⁺ = Gᵀ G``); a shared
    (k, k) information's once (a user's matrix is the same fit after fit)."""
    if Q.ndim != 2:
        return _inverse_root(Q)
    key = (Q.shape, Q.dtype.str, Q.tobytes())
    G = _ROOTS.get(key)
    if G is None:
        if len(_ROOTS) >= 256:
            _ROOTS.clear()
        G = _ROOTS[key] = _inverse_root(Q)
    return G.copy()


def _inverse_root(Q: np.ndarray) -> np.ndarray:
    L = closest_sqrt(Q)
    if Q.ndim == 2 and np.count_nonzero(L) == np.count_nonzero(np.diagonal(L)):  # diagonal:
        return np.diag(1.0 / np.diagonal(L))  # the solve's own divisions (the same numbers)
    eye = np.broadcast_to(np.eye(Q.shape[-1]), Q.shape)
    return np.linalg.solve(L, eye)


def data_hint(fam: ModelFamily) -> str:
    """How to pass measures to ``fam``: ``data={'point': array} (channels of family ...)``."""
    channels = "; ".join(f"{name!r} with columns {list(ch.components)}"
                         for name, ch in fam.channels.items())
    first = next(iter(fam.channels), "channel")
    return f"data={{{first!r}: array}} (channels of family {fam.name!r}: {channels})"


def describe(value) -> str:
    """``an array of shape (20, 2)``, ``a str``: what a user passed, for a message."""
    if isinstance(value, np.ndarray | list | tuple):
        return f"an array of shape {np.shape(value)}"
    return f"a {type(value).__name__}"


def check_data_mapping(fam: ModelFamily, data) -> None:
    """``data`` is a dict ``{channel: array}``; otherwise (a bare array, say) a ValueError
    that says how to pass it, naming the family's channels and their components."""
    if type(data) is not dict and not isinstance(data, Mapping):
        raise ValueError(f"data must be a dict {{channel name: array}}, got {describe(data)}: "
                         f"pass {data_hint(fam)}")


def channel_data(fam: ModelFamily, data: Mapping, info: Mapping | None,
                 exact: Mapping | None = None) -> list[ChannelData]:
    """Validate ``data``, ``info`` and ``exact`` (dicts keyed by channel name)."""
    check_data_mapping(fam, data)
    info = info or {}
    exact = exact or {}
    for what, value in (("info", info), ("exact", exact)):
        if type(value) is not dict and not isinstance(value, Mapping):
            raise ValueError(f"{what} must be a dict {{channel name: ...}}")
    for name in list(data) + list(info) + list(exact):
        fam.channel(name)
    out = []
    for name, value in data.items():
        ch = fam.channel(name)
        X = real_array(value, f"data for channel {name!r}")
        width = len(ch.components)
        if X.ndim == 1 and width == 1:
            X = X[:, None]
        if X.ndim != 2 or X.shape[1] != width:
            raise ValueError(f"data for channel {name!r} has shape {X.shape}; expected (M, "
                             f"{width}) with columns {list(ch.components)}")
        _finite(X, f"data for channel {name!r}")
        idx = ch.corrected_index
        Q, G = information_and_root(info.get(name), len(idx), X.shape[0],
                                    f"info for channel {name!r}")
        fixed = exact_mask(exact.get(name), ch, X.shape[0], f"exact for channel {name!r}")
        if fixed is not None:
            Q = np.broadcast_to(Q, (X.shape[0],) + Q.shape[-2:]).copy()
            G = exact_root(Q, fixed)
        m = X.copy() if ch.corrected == ch.components else X[:, idx]  # a copy either way
        out.append(ChannelData(name, X, idx, m, Q, G, fixed))
    return out


def exact_mask(value, channel, M: int, what: str) -> np.ndarray | None:
    """Which measured components are exact (ODRPACK's ``ifixx``), as (M, k) booleans over
    the channel's corrected components, or None when none is.

    ``value`` is ``{component: mask}`` (a mask being (M,) booleans or a list of measure
    indices) or (M, components) booleans over all the channel's components. A component the
    spec declares exact already stays exact; a measure may not have every component exact
    (its equation would then bind the parameter alone: write it as a constraint)."""
    if value is None:
        return None
    comps = list(channel.components)
    full = np.zeros((M, len(comps)), dtype=bool)
    if isinstance(value, Mapping):
        for comp, mask in value.items():
            if comp not in comps:
                raise ValueError(f"{what}: {comp!r} is not a component (the channel has "
                                 f"{comps})")
            full[:, comps.index(comp)] = _rows(mask, M, f"{what}[{comp!r}]")
    else:
        array = np.asarray(value)
        if array.dtype.kind != "b" or array.shape != (M, len(comps)):
            raise ValueError(f"{what} must be booleans of shape ({M}, {len(comps)}) or a "
                             f"dict {{component: mask}}, got {array.dtype.name} "
                             f"{array.shape}")
        full[:] = array
    fixed = full[:, channel.corrected_index]
    if not fixed.any():
        return None
    every = np.flatnonzero(fixed.all(axis=1))
    if every.size:
        raise ValueError(f"{what}: measure {int(every[0])} has every measured component "
                         "exact; its equation would bind the parameter alone (leave one "
                         "component free or write the relation as a constraint)")
    return fixed


def _rows(mask, M: int, what: str) -> np.ndarray:
    """(M,) booleans from booleans or measure indices."""
    array = np.asarray(mask)
    if array.dtype.kind == "b":
        if array.shape != (M,):
            raise ValueError(f"{what}: a boolean mask needs shape ({M},), got {array.shape}")
        return array
    if array.dtype.kind not in "iu" or array.ndim != 1:
        raise ValueError(f"{what} must be (M,) booleans or a list of measure indices")
    if array.size and (array.min() < -M or array.max() >= M):
        raise ValueError(f"{what}: measure index out of range for {M} measures")
    out = np.zeros(M, dtype=bool)
    out[array] = True
    return out


def exact_root(Q: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """``G`` (M, k, k) of :func:`inverse_root` when some components are exact: ``GᵀG`` is
    the inverse of the information of the free components (the exact ones' rows and columns
    removed), zero on the exact ones — their corrections stay zero."""
    G = np.zeros_like(Q)
    for pattern in np.unique(fixed, axis=0):
        rows = np.flatnonzero((fixed == pattern).all(axis=1))
        free = np.flatnonzero(~pattern)
        sub = inverse_root(Q[np.ix_(rows, free, free)])
        G[np.ix_(rows, free, free)] = sub
    return G


def check_search_options(*, scale, seed=0, samples_per_model=None, confidence=0.99,
                         inlier_ratio=0.5, min_samples=0, window=0.35,
                         max_samples=None) -> None:
    """The robust search's numeric options (:class:`~kanagen.Estimator`, ``robust_fit``,
    ``find_structures``), checked before any work: a bad value must not surface mid-run
    (``confidence=nan`` drew no sample and said "done")."""
    def number(value) -> bool:
        return not isinstance(value, bool) and isinstance(value, int | float | np.number)

    if scale is not None and not (number(scale) and 0 < scale < np.inf):
        raise ValueError(f"scale (L*) must be a positive finite number, got {scale!r}")
    if not (number(confidence) and 0 < confidence < 1):
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if not (number(inlier_ratio) and 0 < inlier_ratio <= 1):
        raise ValueError(f"inlier_ratio must be in (0, 1], got {inlier_ratio!r}")
    if not (number(window) and 0 < window < np.inf):
        raise ValueError(f"window must be a positive fraction of L*, got {window!r}")
    for name, value, least in (("min_samples", min_samples, 0),
                               ("samples_per_model", samples_per_model, 1),
                               ("max_samples", max_samples, 0)):
        if value is None and name != "min_samples":
            continue
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least:
            raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer)
                             or seed < 0):
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")


def parameter_vector(fam: ModelFamily, q, what: str = "q0") -> np.ndarray:
    """A parameter given as None (defaults), an array (n,) or a partial dict by name."""
    if q is None:
        return fam.q0
    if isinstance(q, Mapping):
        out = fam.q0
        for key, value in q.items():
            if key not in fam.parameter_names:
                raise ValueError(f"{what}: unknown parameter {key!r} (family has "
                                 f"{list(fam.parameter_names)})")
            out[fam.parameter_names.index(key)] = float(value)
    else:
        out = real_array(q, what)
        n_user = fam.n - len(fam.slack_names)
        if fam.slack_names and out.shape == (n_user,):
            out = fam.with_slacks(out)  # slack components follow from the parameter
        elif out.shape != (fam.n,):
            expected = f"({fam.n},)" + (f" or ({n_user},) without the slack components"
                                        if fam.slack_names else "")
            raise ValueError(f"{what} has shape {out.shape}; expected {expected}")
    _finite(out, what)
    return out


def prior_information(Q0, n: int) -> np.ndarray:
    """Q0 given as None (no prior), a scalar, a diagonal (n,) or a matrix (n, n)."""
    if Q0 is None:
        return np.zeros((n, n))
    Q = real_array(Q0, "Q0")
    _finite(Q, "Q0")
    if Q.ndim == 0:
        if Q < 0:
            raise ValueError(f"Q0 must be non-negative, got {float(Q)}")
        return float(Q) * np.eye(n)
    if Q.shape == (n,):
        if np.any(Q < 0):
            raise ValueError("Q0 diagonal must be non-negative")
        return np.diag(Q)
    if Q.shape != (n, n):
        raise ValueError(f"Q0 has shape {Q.shape}; expected a scalar, ({n},) or ({n}, {n})")
    _psd(Q, "Q0")
    return Q
