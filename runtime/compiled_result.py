"""The :class:`FitResult` of the compiled estimator, unpacked from its flat output on demand.

``kg_fit`` (docs/fastpath.md) writes every output of a fit into one array: the scalars,
``q``, the information and covariance, each derived quantity's value, Jacobian and
covariance, and per channel the corrected measures and ranks. Turning all of it into
dictionaries of arrays and :class:`DerivedValue` objects costs a third of a conic fit, and
most callers read a few fields (``q``, ``success``, ``cost``). :class:`CompiledFitResult`
is a :class:`FitResult` whose scalar fields and ``q`` are set at once and whose other
fields are made from the output array the first time they are read (then kept): the same
values as an eagerly built result, to the bit.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np

from .iterate import FAILED, MESSAGES
from .results import DerivedValue, FitResult

#: Leading scalars of kg_fit's output: cost, δ, E², start violation, status, iterations,
#: rank0, success, dof, outputs valid.
SCALARS = 10


class CompiledFitResult(FitResult):
    """A :class:`FitResult` over the output array of the compiled estimator.

    Made by :meth:`unpack`; behaves as the frozen dataclass it extends (fields, ``std``,
    ``summary``, ``dataclasses.replace``), its array and dictionary fields built on first
    access.
    """

    @classmethod
    def unpack(cls, fastpath, model: str, channels, out: np.ndarray) -> CompiledFitResult:
        """The result of ``kg_fit`` for ``model`` on ``channels`` (name, X, Q, G), from
        ``out`` (owned by the result)."""
        cost, delta, residual, _, status, iterations, _, success, dof, _ = \
            out[:SCALARS].tolist()
        status, iterations = int(status), int(iterations)
        message = MESSAGES[status]
        if status == FAILED:
            message += " at the starting point" if iterations == 0 else " in the projector"
        result = object.__new__(cls)  # the frozen dataclass's fields, without its __init__
        result.__dict__.update(
            model=model, q=out[SCALARS:SCALARS + fastpath.n], cost=cost, dof=int(dof),
            residual=residual, constraint_violation=delta, iterations=iterations,
            success=bool(success), status=status, message=message,
            _source=(fastpath, channels, out))
        return result

    def __getattr__(self, name: str) -> Any:
        # only called for what is not in the instance yet: the fields made on demand
        make = _FIELDS.get(name)
        source = self.__dict__.get("_source")
        if make is None or source is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        value = make(self, *source)
        self.__dict__[name] = value
        return value

    def __reduce__(self):
        # pickled and copied as the plain FitResult it stands for (the library handle in
        # its source does not pickle)
        return _plain, ({f.name: getattr(self, f.name) for f in fields(FitResult)},)


def _plain(values: dict) -> FitResult:
    return FitResult(**values)


def _params(res, fastpath, channels, out):
    slack = fastpath.slack
    return {k: v for k, v in zip(fastpath.names, res.q.tolist(), strict=True)
            if k not in slack}


def _slacks(res, fastpath, channels, out):
    slack = fastpath.slack
    return {k: v for k, v in zip(fastpath.names, res.q.tolist(), strict=True) if k in slack}


def _info(res, fastpath, channels, out):
    n = fastpath.n
    return out[SCALARS + n:SCALARS + n + n * n].reshape(n, n)


def _covariance(res, fastpath, channels, out):
    n = fastpath.n
    return out[SCALARS + n + n * n:SCALARS + n + 2 * n * n].reshape(n, n)


def _derived(res, fastpath, channels, out):
    return {name: DerivedValue(out[v].reshape(vs), out[c].reshape(cs), out[j].reshape(js))
            for name, v, vs, c, cs, j, js in fastpath.reports[res.model]}


def _channels(res, fastpath, channels, out):
    """Corrected measures (all columns) and ranks per channel: both fields at once."""
    at = SCALARS + fastpath.n + 2 * fastpath.n * fastpath.n + fastpath.derived_size
    measures, ranks = {}, {}
    for name, X, _, _ in channels:
        _, width, k, index = fastpath.channels[name]
        M = X.shape[0]
        mt = out[at:at + M * k].reshape(M, k)
        if k == width:
            measures[name] = mt
        else:
            full = X.copy()
            full[:, index] = mt
            measures[name] = full
        ranks[name] = out[at + M * k:at + M * k + M].astype(np.int64)
        at += M * k + M
    res.__dict__["ranks"] = ranks
    return measures


def _ranks(res, fastpath, channels, out):
    res.__dict__["measures"] = _channels(res, fastpath, channels, out)
    return res.__dict__["ranks"]


_FIELDS = {"params": _params, "slacks": _slacks, "info": _info, "covariance": _covariance,
           "derived": _derived, "measures": _channels, "ranks": _ranks}
