"""The engine's view of a problem: flat arrays the compiled kernels read.

Every channel's measures are stacked into one set of per-measure arrays, padded to the
widest channel: measure ``i`` belongs to channel ``chan[i]``, which gives its equation
count ``P``, its corrected components ``Dn`` (their columns ``col`` in the data row ``X``),
its data width ``W`` and the address of its row kernel (:mod:`.rows`). The information
``Q`` and its inverse root ``G`` are per measure.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass, field

import numpy as np

from kanagen.common.borrow import alive, borrow
from kanagen.common.jit import NUMBA, jit
from kanagen.common.link import KINDS, kind, layout, link

from .rows import compiled_row

#: The fields and their kinds (kanagen.common.link: ``f`` float, ``i`` integer, ``f2`` a
#: C-ordered float matrix ...): :func:`arrays` makes each field of its kind.
_SCHEMA = (
    ("q0", "f1"), ("Q0", "f2"), ("k", "f1"), ("eps", "f"),  # prior, constants, pivot floor
    ("c0_addr", "i"), ("r", "i"),  # the parameter constraints' kernel and their number
    # per measure: channel, data row, observed values, metric and its inverse root
    ("chan", "i1"), ("X", "f2"), ("m", "f2"), ("Q", "f3"), ("G", "f3"),
    # per channel: corrected columns, equations, corrected count, data width, row kernel and
    # its values form (c and D only), equations linear in the parameter (1: C free of it)
    ("col", "i2"), ("P", "i1"), ("Dn", "i1"), ("W", "i1"), ("meas_addr", "i1"),
    ("vals_addr", "i1"), ("linear", "i1"),
    ("scale", "f1"), ("size", "i1"), ("start", "i1"),
    # inequality relations (appendix F), strict relations' slacks (component, power)
    ("slack_addr", "i"), ("kinds", "i1"), ("clauses", "b2"), ("T", "f2"), ("t", "f1"),
    ("strict_idx", "i1"), ("strict_pow", "i1"),
)
_FIELDS = [name for name, _ in _SCHEMA]
#: The engine's package: its kernels' linked callees are linked before the arrays are made.
_ENGINE = __name__.rpartition(".")[0]
_INDEX = {name: at for at, name in enumerate(_FIELDS)}
#: Per field: its dtype (a NumPy scalar type, and as a dtype: comparing an array's dtype to
#: a scalar type costs a microsecond) and rank (0: a number).
_LAYOUT = tuple((dtype, np.dtype(dtype), rank) for dtype, rank in
                (layout(kind) for _, kind in _SCHEMA))


def _of_kind(value, dtype, described, rank: int):
    """``value`` as its field's kind: a number, or a C-ordered array of its dtype
    (``described``) and rank."""
    if rank == 0:
        return dtype(value).item()
    if type(value) is np.ndarray and value.dtype is described and value.ndim == rank and \
            value.flags.c_contiguous:
        return value
    out = np.ascontiguousarray(value, dtype=dtype)
    if out.ndim != rank:
        raise ValueError(f"engine arrays: a field of rank {rank} has shape {out.shape}")
    return out


if NUMBA is not None and not jit.disabled:
    from numba.core import types
    from numba.experimental import structref

    @structref.register
    class ArraysType(types.StructRef):
        def preprocess_fields(self, fields):
            return tuple((name, types.unliteral(typ)) for name, typ in fields)

    class _Proxy(structref.StructRefProxy):
        """The arrays of one problem for the kernels, passed by reference (a numba
        structure); the Python side reads the same arrays as its attributes (each field
        put there when made, :func:`Arrays`; else from its record)."""

        def __new__(cls, *values):
            # numba's own constructor is a closure compiled in every process (half a second
            # of a process's first fit); this one is a kernel, cached like the others
            return _construct(*values)

        def __getattr__(self, name):
            try:
                return self.__dict__["_record"][_INDEX[name]]
            except KeyError:
                raise AttributeError(name) from None

    structref.define_proxy(_Proxy, ArraysType, _FIELDS)

    @jit
    def _construct(*values):
        """A new record of :data:`_SCHEMA`'s fields ``values`` (numba's constructor of
        :class:`_Proxy`)."""
        return _Proxy(*values)
    kind("A", lambda: ArraysType([(name, KINDS[k]()) for name, k in _SCHEMA]))

    def Arrays(*values):  # noqa: N802 - the record's constructor
        """The arrays of one problem (one model, its measures, its prior) for the kernels:
        ``values`` in :data:`_SCHEMA`'s order, each of its field's kind (:func:`_of_kind`)."""
        proxy = _Proxy(*values)
        proxy.__dict__.update(zip(_FIELDS, values, strict=True))  # plain attributes for Python
        proxy.__dict__["_record"] = values
        return proxy
else:  # interpreted: a plain record
    Arrays = namedtuple("Arrays", _FIELDS)


def _row_address(module, function, arity: int, table: str = "ROWS") -> int:
    """The compiled row form of ``function`` (or its values form: ``table="VALUES"``)."""
    rows = getattr(module, table, None)
    name = getattr(function, "__name__", None)
    if rows is None or name not in rows:
        raise ValueError(f"the generated module of family {module.FAMILY['name']!r} has no "
                         f"row form of {name!r} (generated by an older kanagen: rebuild it)")
    return compiled_row(rows[name], arity)


@dataclass(frozen=True)
class RowKernels:
    """A model's compiled row kernels (in ``r`` for a reduced model, ``q = T r + t``): the
    part of :class:`Arrays` that does not depend on the measures."""

    c0: int
    r: int
    #: channel name -> (address, its values form's, equations per measure, linear in q: 0/1)
    measures: dict
    slack: int
    kinds: np.ndarray
    clauses: np.ndarray
    T: np.ndarray
    t: np.ndarray


def row_kernels(fam, model: str, reduced=None) -> RowKernels:
    """The row kernels of ``model`` (its reduced form with ``reduced``, a
    :class:`~kanagen.runtime.family.Reduction`)."""
    module = fam.module
    entry = module.MODELS[model]
    table = entry["reduced"] if reduced is not None else entry
    n = fam.n if reduced is None else len(np.atleast_1d(reduced.free))
    k = fam.constant_vector(None)
    linear = getattr(module, "LINEAR", ())  # none in a module of an older kanagen
    with np.errstate(all="ignore"):
        r = int(np.asarray(table["c0"](np.zeros(n), k)[0]).size)
        measures = {}
        for name, function in table["channels"].items():
            width = len(fam.channel(name).components)
            p = function(np.zeros(n), np.zeros((0, width)), k)[0].shape[1]
            measures[name] = (_row_address(module, function, 4),
                              _row_address(module, function, 4, "VALUES"), int(p),
                              int(getattr(function, "__name__", None) in linear))
    slack, kinds, clauses = 0, np.zeros(0, dtype=np.int64), np.zeros((0, 0), np.bool_)
    own = module.FAMILY.get("slack_clauses", {}).get(model) or []
    if own and getattr(module, "SLACK_MEASURES", None) is not None:
        kinds = np.array([(">=", ">", "!=").index(kind)
                          for kind in module.FAMILY["slack_kinds"]], dtype=np.int64)
        clauses = np.zeros((len(own), kinds.size), dtype=np.bool_)
        for a, clause in enumerate(own):
            clauses[a, list(clause)] = True
        slack = compiled_row(module.ROWS["slack_measures"], 3)
    T = np.eye(fam.n) if reduced is None else np.asarray(reduced.T, dtype=float)
    t = np.zeros(fam.n) if reduced is None else np.asarray(reduced.t, dtype=float)
    return RowKernels(_row_address(module, table["c0"], 3), r, measures, slack, kinds,
                      clauses, np.ascontiguousarray(T), np.ascontiguousarray(t))


def model_rows(fam, model: str, reduced=None) -> RowKernels:
    """:func:`row_kernels`, made once per family, model and form."""
    cache = fam.__dict__.setdefault("_row_kernels", {})
    key = (model, reduced is not None)
    if key not in cache:
        cache[key] = row_kernels(fam, model, reduced)
    return cache[key]


def arrays(problem) -> Arrays:
    """The kernels' arrays of ``problem`` (its :class:`RowKernels` in ``problem.rows``),
    made once per problem object — for a subset of a problem whose arrays are made
    (``Problem.subset``), gathered from them (:func:`_gathered`)."""
    cached = problem.__dict__.get("_arrays")
    if cached is not None:
        return cached
    parent = problem.__dict__.pop("_subset_of", None)  # not kept once used
    if parent is not None:
        out = _subset(*parent)
        object.__setattr__(problem, "_arrays", out)
        return out
    rows: RowKernels = problem.rows
    channels = problem.channels
    shape = _shape(rows, channels, problem.strict_slacks)
    sizes = [ch.X.shape[0] for ch in channels]
    M, nch, wmax, dmax = sum(sizes), len(channels), shape.wmax, shape.dmax
    if nch == 1:  # one channel: its arrays as they are
        ch = channels[0]
        X, m = _of_kind(ch.X, *_F2), _of_kind(ch.m, *_F2)
        Q, G = _per_measure(ch.Q, M), _per_measure(ch.G, M)
        chan, size, start = shape.single(M)
    else:
        X, m = np.zeros((M, wmax)), np.zeros((M, dmax))
        Q, G = np.zeros((M, dmax, dmax)), np.zeros((M, dmax, dmax))
        start = np.zeros(nch, dtype=np.int64)
        at = 0
        for j, ch in enumerate(channels):
            size, w, d = sizes[j], ch.X.shape[1], ch.index.size
            start[j] = at
            X[at:at + size, :w] = ch.X
            m[at:at + size, :d] = ch.m
            Q[at:at + size, :d, :d] = ch.Q
            G[at:at + size, :d, :d] = ch.G
            at += size
        chan = np.repeat(np.arange(nch, dtype=np.int64), sizes)
        size = np.array(sizes, dtype=np.int64)
    scale = channel_scales(m, Q, start, size, shape.Dn)
    out = Arrays(
        _of_kind(problem.q0, *_LAYOUT[_INDEX["q0"]]),
        _of_kind(problem.Q0, *_LAYOUT[_INDEX["Q0"]]),
        _of_kind(problem.k, *_LAYOUT[_INDEX["k"]]), float(problem.eps),
        int(rows.c0), int(rows.r), chan, X, m, Q, G,
        shape.col, shape.P, shape.Dn, shape.W, shape.addr, shape.values, shape.linear, scale,
        size, start,
        int(rows.slack), rows.kinds, rows.clauses, rows.T, rows.t,
        shape.strict_idx, shape.strict_pow,
    )  # the fields made here of their kinds (RowKernels' and _Shape's too: made so)
    link(_ENGINE)
    object.__setattr__(problem, "_arrays", out)
    return out


_F2 = _LAYOUT[_INDEX["X"]]


def _per_measure(Q: np.ndarray, M: int) -> np.ndarray:
    """A channel's information (or its root) per measure: ``(M, d, d)``, C-ordered."""
    if Q.ndim == 3:
        return _of_kind(Q, *_LAYOUT[_INDEX["Q"]])
    out = np.empty((M,) + Q.shape)
    out[...] = Q
    return out


@dataclass(frozen=True)
class _Shape:
    """The fields of :class:`Arrays` fixed by a model's channels' layout (names, data
    widths, corrected columns) and its strict slacks: made once per layout (:func:`_shape`),
    shared by its problems (the kernels only read them)."""

    wmax: int
    dmax: int
    col: np.ndarray
    P: np.ndarray
    Dn: np.ndarray
    W: np.ndarray
    addr: np.ndarray
    values: np.ndarray
    linear: np.ndarray
    strict_idx: np.ndarray
    strict_pow: np.ndarray
    singles: dict = field(default_factory=dict, compare=False)  # single's, by size

    def single(self, M: int) -> tuple:
        """A one-channel problem's ``chan, size, start`` for ``M`` measures: made once per
        size and shared (the kernels and the Python only read them)."""
        out = self.singles.get(M)
        if out is None:
            if len(self.singles) >= 64:
                self.singles.clear()
            out = self.singles[M] = (np.zeros(M, dtype=np.int64),
                                     np.array([M], dtype=np.int64), np.zeros(1, dtype=np.int64))
        return out


def _shape(rows: RowKernels, channels, strict) -> _Shape:
    """:class:`_Shape` of a problem, cached on its :class:`RowKernels` (once per family,
    model and form) by its channels' layout."""
    key = (tuple((ch.name, ch.X.shape[1], ch.index.tobytes()) for ch in channels), strict)
    cache = rows.__dict__.setdefault("_shapes", {})
    out = cache.get(key)
    if out is None:
        if len(cache) >= 64:
            cache.clear()
        nch = len(channels)
        widths = [ch.X.shape[1] for ch in channels]
        dims = [ch.index.size for ch in channels]
        dmax = max(dims, default=1)
        col = np.full((nch, dmax), -1, dtype=np.int64)
        P, addr = np.zeros(nch, dtype=np.int64), np.zeros(nch, dtype=np.int64)
        values, linear = np.zeros(nch, dtype=np.int64), np.zeros(nch, dtype=np.int64)
        for j, ch in enumerate(channels):
            col[j, :dims[j]] = ch.index
            addr[j], values[j], P[j], linear[j] = rows.measures[ch.name]
        out = cache[key] = _Shape(
            max(widths, default=1), dmax, col, P, np.array(dims, dtype=np.int64),
            np.array(widths, dtype=np.int64), addr, values, linear,
            np.array([i for i, _ in strict], dtype=np.int64),
            np.array([p for _, p in strict], dtype=np.int64))
    return out


#: The fields :func:`_gathered` makes anew for a subset (the rest are the parent's).
_GATHERED = ("chan", "X", "m", "Q", "G", "size", "start", "scale")


@jit
def _gathered(A, rows, counts):
    """The per-measure arrays of ``A``'s measures ``rows`` (each channel's indices among
    its measures, ``counts[j]`` of channel ``j``, channel after channel; negative ones from
    its end), each channel's size and start among them and its scale
    (:func:`channel_scales`), in :data:`_GATHERED`'s order."""
    M, nch = rows.size, A.P.size
    chan = np.empty(M, dtype=np.int64)
    X, m = np.zeros((M, A.X.shape[1])), np.zeros((M, A.m.shape[1]))
    Q, G = np.zeros((M,) + A.Q.shape[1:]), np.zeros((M,) + A.G.shape[1:])
    start = np.zeros(nch, dtype=np.int64)
    # the loop's arrays borrowed (kanagen.common.borrow): no reference counts per row
    X0, m0, Q0, G0, at0, size0, Dn = borrow((A.X, A.m, A.Q, A.G, A.start, A.size, A.Dn))
    bX, bm, bQ, bG = borrow((X, m, Q, G))
    s = 0
    for ch in range(nch):
        start[ch] = s
        for _ in range(counts[ch]):
            r = rows[s]
            i = at0[ch] + (r + size0[ch] if r < 0 else r)
            chan[s] = ch
            for j in range(X0.shape[1]):
                bX[s, j] = X0[i, j]
            for u in range(m0.shape[1]):
                bm[s, u] = m0[i, u]
                for v in range(m0.shape[1]):
                    bQ[s, u, v] = Q0[i, u, v]
                    bG[s, u, v] = G0[i, u, v]
            s += 1
    alive((X, m, Q, G))
    return chan, X, m, Q, G, counts.copy(), start, channel_scales(m, Q, start, counts, Dn)


@jit
def channel_scales(m, Q, start, size, Dn):
    """Per channel, the magnitude of its measures in their information metric (the
    rounding floors of the cost and of the measures' moves): the largest corrected value
    times the root of the largest information on the diagonal, 0 for no measure. ``m``,
    ``Q``: the per-measure arrays (channel ``j``'s ``size[j]`` rows from ``start[j]``, its
    first ``Dn[j]`` components)."""
    scale = np.zeros(size.size)
    for ch in range(size.size):
        top_m, top_q = 0.0, 0.0
        for i in range(start[ch], start[ch] + size[ch]):
            for u in range(Dn[ch]):
                top_m = max(top_m, abs(m[i, u]))
                top_q = max(top_q, abs(Q[i, u, u]))
        scale[ch] = top_m * np.sqrt(top_q) if size[ch] else 0.0
    return scale


def _subset(A: Arrays, rows: tuple) -> Arrays:
    """The arrays of the problem on the measures ``rows`` (per channel) of the problem
    whose arrays are ``A``: the same as :func:`arrays` would make, gathered in one kernel
    call."""
    picked = [np.flatnonzero(r) if (r := np.asarray(part)).dtype == np.bool_ else r
              for part in rows]
    counts = np.array([r.size for r in picked], dtype=np.int64)
    flat = (picked[0] if len(picked) == 1 else np.concatenate(picked) if picked else
            np.zeros(0)).astype(np.int64)
    values = list(A.__dict__["_record"] if hasattr(A, "__dict__") else A)  # interpreted: a tuple
    for name, value in zip(_GATHERED, _gathered(A, flat, counts), strict=True):
        values[_INDEX[name]] = value
    return Arrays(*values)  # the parent's fields and the kernel's: of their kinds


def pack_measures(A: Arrays, mt) -> np.ndarray:
    """Per-channel corrected measures stacked into the padded per-measure layout."""
    if len(mt) == 1 and mt[0].shape[1] == A.m.shape[1]:
        return np.ascontiguousarray(mt[0], dtype=float)
    out = np.zeros(A.m.shape)
    for j, part in enumerate(mt):
        out[A.start[j]:A.start[j] + A.size[j], :part.shape[1]] = part
    return out


def unpack_measures(A: Arrays, padded: np.ndarray) -> tuple:
    """The padded per-measure layout cut back into per-channel arrays."""
    if A.size.size == 1 and padded.shape[1] == A.Dn[0]:  # one channel, no padding
        return (padded,)
    return tuple(padded[A.start[j]:A.start[j] + A.size[j], :A.Dn[j]]
                 for j in range(A.size.size))


def per_channel(A: Arrays, values: np.ndarray) -> tuple:
    """A per-measure vector cut into per-channel vectors."""
    if A.size.size == 1:
        return (values,)
    return tuple(values[A.start[j]:A.start[j] + A.size[j]] for j in range(A.size.size))


def pack_evals(A: Arrays, evals, n: int):
    """Per-channel equations ``(c, C, D)`` stacked into the padded layout."""
    if len(evals) == 1:
        c, C, D = evals[0]
        if c.shape[1] == max(1, A.P[0]) and D.shape[2] == A.m.shape[1]:
            return (np.ascontiguousarray(c, dtype=float), np.ascontiguousarray(C, dtype=float),
                    np.ascontiguousarray(D, dtype=float))
    M, pmax, dmax = A.chan.size, max(1, int(A.P.max(initial=1))), A.m.shape[1]
    c, C, D = np.zeros((M, pmax)), np.zeros((M, pmax, n)), np.zeros((M, pmax, dmax))
    for j, (cj, Cj, Dj) in enumerate(evals):
        rows = slice(A.start[j], A.start[j] + A.size[j])
        c[rows, :cj.shape[1]] = cj
        C[rows, :Cj.shape[1]] = Cj
        D[rows, :Dj.shape[1], :Dj.shape[2]] = Dj
    return c, C, D


def unpack_evals(A: Arrays, c, C, D) -> tuple:
    """The padded equations cut back into per-channel ``(c, C, D)``."""
    if A.size.size == 1 and c.shape[1] == A.P[0] and D.shape[2] == A.Dn[0]:  # no padding
        return ((c, C, D),)
    out = []
    for j in range(A.size.size):
        rows = slice(A.start[j], A.start[j] + A.size[j])
        p, d = A.P[j], A.Dn[j]
        out.append((c[rows, :p], C[rows, :p], D[rows, :p, :d]))
    return tuple(out)
