"""The compiled fast path of the robust search: ctypes glue to ``kg_coherence``,
``kg_minimal`` and the sampling calls (docs/fastpath.md).

``codegen/c/kanagen_fast.c`` is a mechanical port of the NumPy runtime's measure projection
(eq. 22–24), square roots and minimal solve (eq. 21), compiled with a family's CasADi C into
the library of ``kanagen.load(..., backend="compiled")``. :class:`FastPath` packs a problem
into flat arrays and calls them. (The local fit runs the NumPy iteration: its verified
trust region has no port.)

The port mirrors the Python functions listed in :data:`PORTED`; their syntax trees
(docstrings and comments excluded) are fingerprinted in :data:`FINGERPRINTS`. When one of
them changes, the fast path switches itself off (the NumPy path runs: right results, only
slower) and tests/test_fastpath.py fails, naming the functions to port again. After porting
and testing, print the new fingerprints with ``python -m kanagen.runtime.fastpath``.
"""

from __future__ import annotations

import ast
import ctypes
import hashlib
import importlib
import inspect
import textwrap
import threading
import warnings
from functools import cache
from pathlib import Path
from types import ModuleType

import numpy as np

#: Python functions (and module constants) that codegen/c/kanagen_fast.c ports, by module.
PORTED: dict[str, tuple[str, ...]] = {
    # kg_coherence: the measures projected onto their equations (eq. 22–24)
    "projector": ("project_measures", "_halving", "quadratic", "_ROUNDING"),
    "sqrt": ("closest_sqrt", "reduced_sqrt", "reduced_solve", "triangular_solve",
             "_equilibrium", "_closest_single", "_reduced_single", "_scale", "EPS", "_TINY",
             "REDUNDANT"),
    "kernels": ("whiten", "correct"),
    # kg_minimal: eq. 21
    "minimal": ("coherence_errors", "minimal_solve_problem", "_solved", "_FREE_STEPS",
                "_WATCHDOG", "_SLOW"),
    "inputs": ("inverse_root", "ChannelData.with_corrected"),
    # codegen/c/kanagen_geometry.c: the closed-form initialisers (FastPath.initializer),
    # in the library of a family that names one of them only (TWIN_MODULES)
    "two_view_starts": ("two_view_fundamental", "two_view_homography", "_rays",
                        "_pose_params", "_FOCAL_RANGE", "_TWO_VIEW_Q", "two_view_rotation",
                        "two_view_translation", "_kabsch",
                        "_in_focal_range", "_rotation_candidate", "_DEGENERATE"),
    "geometry": ("homogeneous", "cross", "normalising_transform", "_unit", "_normalised",
                 "_epipolar_rows", "fundamental_8point", "fundamental_7point", "_ALPHAS",
                 "_CUBIC_FROM_VALUES", "homography_dlt", "epipoles", "focal_lengths",
                 "essential_poses", "depths", "best_pose", "nearest_essential",
                 "homography_poses", "rotation_from_pairs", "quaternion_from_rotation"),
}

#: The modules of :data:`PORTED` that only codegen/c/kanagen_geometry.c ports: a library
#: without the twins (its family names no two-view initializer) neither checks nor imports
#: them (:func:`changed`).
TWIN_MODULES = frozenset({"two_view_starts", "geometry"})

#: Fingerprints of :data:`PORTED` when the C port was last brought in line with them.
FINGERPRINTS: dict[str, str] = {
    'projector.project_measures': 'c3d1d84ea5b4',
    'projector._halving': '788448d7ecbd',
    'projector.quadratic': 'ad2172806540',
    'projector._ROUNDING': 'b19a1c4efef9',
    'sqrt.closest_sqrt': 'b4340982303f',
    'sqrt.reduced_sqrt': '81d2a95ecf3e',
    'sqrt.reduced_solve': 'caecf64cc8c0',
    'sqrt.triangular_solve': '01c0fd119e19',
    'sqrt._equilibrium': 'dd8612e57ac3',
    'sqrt._closest_single': '12aebbdf103d',
    'sqrt._reduced_single': 'd5c2329a2e14',
    'sqrt._scale': 'bdb7682c62c0',
    'sqrt.EPS': 'cf90b756d02d',
    'sqrt._TINY': '24623188d5ff',
    'sqrt.REDUNDANT': 'a11958cb4ea6',
    'kernels.whiten': 'ffc3e108b3d4',
    'kernels.correct': '0e183f7e3c8f',
    'minimal.coherence_errors': 'b6d9e82e820b',
    'minimal.minimal_solve_problem': '4b123dbff38e',
    'minimal._solved': 'ac88707f4a75',
    'minimal._FREE_STEPS': '3e5ab2fb8dd8',
    'minimal._WATCHDOG': '533d3f19a9e0',
    'minimal._SLOW': '148df96ae1c0',
    'inputs.inverse_root': '051a001e58d2',
    'inputs.ChannelData.with_corrected': 'cc3fdd26454a',
    'two_view_starts.two_view_fundamental': '27e179692ec5',
    'two_view_starts.two_view_homography': '8d4b488b7110',
    'two_view_starts._rays': '415fcf057322',
    'two_view_starts._pose_params': 'b4aae0a3cb9e',
    'two_view_starts._FOCAL_RANGE': 'f87b8f36bcc4',
    'two_view_starts._TWO_VIEW_Q': '6a4d9d3c3a06',
    'two_view_starts.two_view_rotation': 'e16ecad83d03',
    'two_view_starts.two_view_translation': '2226bf4bcbf0',
    'two_view_starts._kabsch': 'bdab072395a2',
    'two_view_starts._in_focal_range': 'ad3b05c687d5',
    'two_view_starts._rotation_candidate': '0929c0d2b305',
    'two_view_starts._DEGENERATE': '2f88dcb41fb8',
    'geometry.homogeneous': 'e78e47b5ab90',
    'geometry.cross': 'b585c32c4b02',
    'geometry.normalising_transform': '85230fff495e',
    'geometry._unit': '2e0b093c84a9',
    'geometry._normalised': 'afdd541189c5',
    'geometry._epipolar_rows': '9ae49e54014e',
    'geometry.fundamental_8point': '94fd8ba26c68',
    'geometry.fundamental_7point': '97eb416ca91d',
    'geometry._ALPHAS': '024e7accb4a5',
    'geometry._CUBIC_FROM_VALUES': 'c95f60d17ee2',
    'geometry.homography_dlt': '4892afa7dfd3',
    'geometry.epipoles': 'e77cc33dbce4',
    'geometry.focal_lengths': '39c84f8e93d6',
    'geometry.essential_poses': 'b863be224cb9',
    'geometry.depths': 'd929c1fd98c6',
    'geometry.best_pose': '7dbb992250cc',
    'geometry.nearest_essential': '898b1d686f05',
    'geometry.homography_poses': 'e6c7f0b6a730',
    'geometry.rotation_from_pairs': 'd48c00712efd',
    'geometry.quaternion_from_rotation': '270f42cbd8ff',
}


#: The initialisers with a compiled twin (codegen/c/kanagen_geometry.c: ``kg_<name>``), and
#: which of the values it writes (in the order of ``_TWO_VIEW_Q``) their candidates name.
TWINS: dict[str, tuple[tuple[int, str], ...]] = {
    "two_view_fundamental": tuple(enumerate(
        ("f1", "f2", "qw", "qx", "qy", "qz", "tx", "ty", "tz"))),
    "two_view_homography": tuple(enumerate(
        ("f1", "f2", "qw", "qx", "qy", "qz", "tx", "ty", "tz", "wx", "wy", "wz"))),
    "two_view_rotation": tuple(enumerate(("f1", "f2", "qw", "qx", "qy", "qz"))),
    "two_view_translation": ((6, "tx"), (7, "ty"), (8, "tz")),
}
#: The values a twin writes per candidate: ``len(two_view_starts._TWO_VIEW_Q)``,
#: ``KG_TWIN_WIDTH`` of codegen/c/kanagen_sample.c (a constant here: the sampler of a family
#: without twins imports no two-view code).
TWIN_WIDTH = 12


class FastPathWarning(UserWarning):
    """The compiled fast path is off: the Python it ports has changed since."""


def _node(module: ModuleType, name: str) -> ast.AST:
    """The syntax tree of a function, method, property or module constant, docstring out."""
    owner, _, attr = name.rpartition(".")
    if owner:
        cls = ast.parse(textwrap.dedent(inspect.getsource(getattr(module, owner))))
        body = cls.body[0].body
        node = next(n for n in body if getattr(n, "name", None) == attr)
    elif inspect.isfunction(getattr(module, name)):
        node = ast.parse(textwrap.dedent(inspect.getsource(getattr(module, name)))).body[0]
    else:
        tree = ast.parse(inspect.getsource(module))
        node = next(n for n in tree.body if isinstance(n, ast.Assign | ast.AnnAssign)
                    and name in {getattr(t, "id", None) for t in
                                 (n.targets if isinstance(n, ast.Assign) else [n.target])}
                    or isinstance(n, ast.Assign) and any(
                        isinstance(t, ast.Tuple) and name in {e.id for e in t.elts}
                        for t in n.targets))
    if isinstance(node, ast.FunctionDef) and node.body and isinstance(node.body[0], ast.Expr) \
            and isinstance(getattr(node.body[0], "value", None), ast.Constant):
        node.body = node.body[1:]
    return node


@cache
def _module_fingerprints(short: str) -> dict[str, str]:
    """The current fingerprints of the names of :data:`PORTED` in module ``short``."""
    out = {}
    module = importlib.import_module(f"kanagen.runtime.{short}")
    for name in PORTED[short]:
        dump = ast.dump(_node(module, name), include_attributes=False)
        out[f"{short}.{name}"] = hashlib.sha256(dump.encode()).hexdigest()[:12]
    return out


def fingerprints(twins: bool = True) -> dict[str, str]:
    """The current fingerprints of :data:`PORTED`: ``{"module.name": hash}`` (without
    ``twins``: not those of :data:`TWIN_MODULES`, which are then not imported)."""
    out = {}
    for short in PORTED:
        if twins or short not in TWIN_MODULES:
            out.update(_module_fingerprints(short))
    return out


def changed(twins: bool = True) -> list[str]:
    """The ported Python functions that differ from what the C port mirrors (all of them
    when their source cannot be read, e.g. an installation without .py files); without
    ``twins`` (a library without kanagen_geometry.c) those of :data:`TWIN_MODULES` are not
    checked."""
    try:
        now = fingerprints(twins)
    except (OSError, TypeError, AttributeError, StopIteration):
        return ["<the runtime's source is not available>"]
    recorded = {k: v for k, v in FINGERPRINTS.items()
                if twins or k.partition(".")[0] not in TWIN_MODULES}
    return sorted(k for k in now.keys() | recorded.keys() if now.get(k) != recorded.get(k))


class FastPath:
    """The robust search's compiled calls of a family library: ``kg_coherence``
    (:meth:`coherence`, for ``coherence_errors``), ``kg_minimal`` (:meth:`minimal`, for
    ``minimal_solve_problem``), the closed-form initialisers ``kg_two_view_*``
    (:meth:`initializer`; only in the library of a family one of whose models names one:
    :attr:`has_twins`),
    ``kg_closest_root`` (:meth:`closest_sqrt`, for the tests) and the sampling calls
    ``kg_sample``, ``kg_search`` and ``kg_choice_draw`` that runtime/fastsample.py drives.
    (The compiled local fit, ``kg_fit``, was removed on 2026-11-25, issue 17: the local fit
    runs runtime/iterate.py on every backend.)

    Parameters
    ----------
    library : path
        The shared library built by :func:`kanagen.codegen.compile.compile_family`.
    module : module
        The family's generated NumPy module (its ``FAMILY`` metadata).
    """

    def __init__(self, library: Path, module: ModuleType):
        self.library = Path(library)
        lib = ctypes.CDLL(str(library))
        self._root = lib.kg_closest_root
        self._root.argtypes = [ctypes.c_long, ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p]
        self._root.restype = ctypes.c_int
        self._coherence = lib.kg_coherence
        self._coherence.argtypes = [ctypes.c_void_p] * 2
        self._coherence.restype = ctypes.c_int
        self._minimal = lib.kg_minimal
        self._minimal.argtypes = [ctypes.c_void_p] * 2
        self._minimal.restype = ctypes.c_int
        self.sample = lib.kg_sample  # one sample of a robust search (fastsample.py)
        self.sample.argtypes = [ctypes.c_void_p] * 3
        self.sample.restype = ctypes.c_int
        self.search = lib.kg_search  # samples of a robust search until a better one
        self.search.argtypes = [ctypes.c_void_p] * 8
        self.search.restype = ctypes.c_int
        self.choice = lib.kg_choice_draw  # one draw of kg_search's (fastsample.py)
        self.choice.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_long, ctypes.c_void_p]
        self.choice.restype = None
        # kg_sample calls the twins by number: all of TWINS, or none (KG_TWINS 0: the family
        # names no two-view initializer, kanagen_geometry.c is not compiled in)
        count = lib.kg_sample_twins()
        if count not in (0, len(TWINS)):
            raise RuntimeError(f"compiled library {library} has {count} closed forms in "
                               f"kg_sample, TWINS names {len(TWINS)}")
        self._twins = {}  # the compiled initialisers by name (initializer)
        for name in TWINS if count else ():
            fn = getattr(lib, f"kg_{name}")
            fn.argtypes = [ctypes.c_long] + [ctypes.c_void_p] * 3
            fn.restype = ctypes.c_int
            self._twins[name] = fn
        meta = module.FAMILY
        self.n = len(meta["parameter"])
        self.names = tuple(n for n, _ in meta["parameter"])
        self.slack = frozenset(meta.get("slack", ()))
        #: per channel: id, number of components, corrected ones and their columns
        self.channels = {
            name: (i, len(ch["components"]), len(ch["corrected"]),
                   [ch["components"].index(c) for c in ch["corrected"]])
            for i, (name, ch) in enumerate(meta["channels"].items())}
        self.model_ids = {name: i for i, name in enumerate(meta["models"])}
        self._local = threading.local()  # per thread: reused argument buffers
        sizes = (ctypes.c_longlong * 6)()
        lib.kg_sizes(sizes)
        expected = [self.n, len(meta["constants"]), len(meta["channels"]), len(meta["models"]),
                    len(meta["derived"]), len(meta.get("slack", ()))]
        if list(sizes) != expected:
            raise RuntimeError(f"compiled library {library} does not match family "
                               f"{meta['name']!r}: sizes {list(sizes)} vs {expected}")

    @property
    def has_twins(self) -> bool:
        """Does the library hold the compiled closed forms (``kg_two_view_*``)?"""
        return bool(self._twins)

    @classmethod
    def load(cls, library: Path, module: ModuleType) -> FastPath | None:
        """The fast path of ``library``, or None (with a warning) when the Python it ports
        has changed since the port (see :data:`FINGERPRINTS`; the two-view closed forms
        only when the library holds their twins)."""
        stale = changed(twins=ctypes.CDLL(str(library)).kg_sample_twins() > 0)
        if stale:
            warnings.warn("the compiled fast path of the estimator is off: the Python it "
                          f"ports has changed ({', '.join(stale)}); fits run the NumPy "
                          "iteration (see docs/fastpath.md)", FastPathWarning, stacklevel=3)
            return None
        return cls(library, module)

    def coherence(self, model: str, problem, q: np.ndarray, iterations: int, tol: float):
        """``kg_coherence``: per channel of the validated ``problem``, the measures projected
        onto their equations at ``q`` (:func:`~kanagen.runtime.projector.project_measures`
        with ``iterations`` and ``tol``): ``(‖m̃ − m‖²_Q + violation, equations kept)``, as
        two tuples of (M,) arrays; None when kg_coherence refuses the input (not finite)."""
        sizes = [ch.X.shape[0] for ch in problem.channels]
        ws, where = self.coherence_input(model, problem, iterations, tol)
        ws[0][where[0]:where[0] + self.n] = q
        ws[0][where[1]:where[1] + self.n] = q
        if self._coherence(ws[2], ws[3]) != 0:
            return None
        out = ws[1]
        totals, kept, at = [], [], 0
        for M in sizes:
            totals.append(out[at:at + M].copy())
            kept.append(out[at + M:at + 2 * M].astype(np.int64))
            at += 2 * M
        return tuple(totals), tuple(kept)

    def coherence_input(self, model: str, problem, iterations: int, tol: float):
        """kg_coherence's input for the validated ``problem`` (its start and prior slots
        holding q0) and where its inputs are (:meth:`_layout`): packed once per problem
        and thread, since a search scores every sample on the same problem."""
        packed = getattr(self._local, "coherence", None)
        if packed is None or packed[0] is not problem or packed[1] != (model, iterations, tol):
            size = 2 * sum(ch.X.shape[0] for ch in problem.channels)
            ws, where = self._packed_at(model, problem, problem.q0, problem.eps, iterations,
                                        tol, size, own=True)
            packed = self._local.coherence = (problem, (model, iterations, tol), ws, where)
        return packed[2], packed[3]

    def _packed_at(self, model: str, problem, q: np.ndarray, eps: float, iterations: int,
                   tol: float, size_out: int, own: bool = False) -> tuple[list, list]:
        """The thread's buffers (``own``: new ones) with the input of kg_coherence /
        kg_minimal packed: the validated ``problem``'s measures, start and prior both ``q``;
        and where each input went (:meth:`_layout`)."""
        channels = [(ch.name, ch.X, ch.Q, ch.G) for ch in problem.channels]
        q = np.asarray(q, dtype=float)
        size_in, head, where = self._layout(model, channels, problem.k, eps, iterations, tol)
        if own:
            inp, out = np.empty(size_in), np.empty(size_out)
            ws = [inp, out, ctypes.c_void_p(inp.ctypes.data),
                  ctypes.c_void_p(out.ctypes.data)]
        else:
            ws = self._buffers(size_in, size_out)
        inp = ws[0]
        self._pack(inp, head, where, channels, problem.k)
        n = self.n
        inp[where[0]:where[0] + n] = q
        inp[where[1]:where[1] + n] = q
        for (_, X, _, _), (x_at, _, _) in zip(channels, where[4:], strict=True):
            inp[x_at:x_at + X.size] = X.ravel()
        return ws, where

    def minimal(self, model: str, problem, target: np.ndarray, max_iter: int, xtol: float,
                eps: float):
        """``kg_minimal``: :func:`~kanagen.runtime.minimal.minimal_solve_problem` of the validated
        ``problem`` (its measures the sample) from ``target``: ``(q, success, rank,
        iterations, violation)``, or None when kg_minimal refuses the input."""
        ws = self._packed_at(model, problem, target, eps, max_iter, xtol, self.n + 4)[0]
        if self._minimal(ws[2], ws[3]) != 0:
            return None
        n, out = self.n, ws[1]
        success, rank, iterations, violation = out[n:n + 4].tolist()
        return out[:n].copy(), bool(success), int(rank), int(iterations), violation

    def initializer(self, name: str):
        """The compiled twin of the registered initializer ``name``
        (:data:`~kanagen.runtime.initializers.INITIALIZERS`): the same function of
        ``(rows, constants)``, the same candidates to rounding level (codegen/c/
        kanagen_geometry.c), or None when it has none or the library lacks it (a family
        that names no two-view initializer). Where the C code does not cover a sample (a
        degenerate one, whose outcome in the Python follows LAPACK's arbitrary basis) the
        twin runs the Python."""
        fn = self._twins.get(name)
        if fn is None:
            return None
        from .initializers import INITIALIZERS

        python = INITIALIZERS[name].fn
        names = TWINS[name]
        width = TWIN_WIDTH
        local = self._local

        def twin(rows, constants):
            ws = getattr(local, "init", None)
            if ws is None:
                k, out = np.empty(3), np.empty(4 * width)
                ws = local.init = (k, out, ctypes.c_void_p(k.ctypes.data),
                                   ctypes.c_void_p(out.ctypes.data))
            X = rows
            if type(X) is not np.ndarray or X.dtype.char != "d" or X.ndim != 2 \
                    or X.shape[1] != 4 or not X.flags.c_contiguous:
                return python(rows, constants)
            k, out = ws[0], ws[1]
            k[0], k[1], k[2] = constants["cx"], constants["cy"], constants["f0"]
            count = fn(X.shape[0], X.ctypes.data, ws[2], ws[3])
            if count < 0:
                return python(rows, constants)
            values = out[:count * width].tolist()
            return [{n: values[c * width + i] for i, n in names}
                    for c in range(count)]

        twin.twin = name  # kg_sample calls the C itself (fastsample.py)
        return twin

    def closest_sqrt(self, S: np.ndarray, eps: float) -> np.ndarray:
        """The compiled :func:`~kanagen.runtime.sqrt.closest_sqrt` of one matrix (what the
        estimator factors; for the differential tests of the port)."""
        S = np.ascontiguousarray(S, dtype=float)
        if S.ndim != 2 or S.shape[0] != S.shape[1] or S.shape[0] > self.n:
            raise ValueError(f"a square matrix of size at most {self.n} is needed, got "
                             f"shape {S.shape}")
        L = np.empty_like(S)
        self._root(S.shape[0], S.ctypes.data, eps, L.ctypes.data)
        return L

    # -- packing --------------------------------------------------------------------------
    def _buffers(self, size_in: int, size_out: int):
        """This thread's argument buffers (grown when too small) and their addresses."""
        ws = getattr(self._local, "ws", None)
        if ws is None or ws[0].size < size_in or ws[1].size < size_out:
            inp = np.empty(max(size_in, 2 * (ws[0].size if ws else 0), 256))
            out = np.empty(max(size_out, 2 * (ws[1].size if ws else 0), 512))
            ws = self._local.ws = [inp, out, ctypes.c_void_p(inp.ctypes.data),
                                   ctypes.c_void_p(out.ctypes.data)]
        return ws

    def _layout(self, model, channels, k, eps, max_iter, xtol):
        """Where each input goes in the C's input array: (size_in, head, the offsets of
        start, q0, Q0, k, and per channel of X, Q, G)."""
        n = self.n
        head = [self.model_ids[model], len(channels), max_iter, 1 if self.slack else 0, eps,
                xtol, 0, 0]  # no strict slacks, no prior: kg_read's layout
        for name, X, Q, _ in channels:
            head += (self.channels[name][0], X.shape[0], Q.ndim == 3)
        at = len(head)
        where = [at, at + n, at + 2 * n]  # start, q0, (Q0: none)
        at += 2 * n
        where.append(at)  # k
        at += k.size
        for _, X, Q, G in channels:
            where.append((at, at + X.size, at + X.size + Q.size))
            at += X.size + Q.size + G.size
        return at, np.array(head, dtype=float), where

    @staticmethod
    def _pack(inp, head, where, channels, k):
        """Write the header, constants and per channel Q and G at their places."""
        inp[:head.size] = head
        inp[where[3]:where[3] + k.size] = k
        for (_, _, Q, G), (_, q_at, g_at) in zip(channels, where[4:], strict=True):
            inp[q_at:q_at + Q.size] = Q.ravel()
            inp[g_at:g_at + G.size] = G.ravel()

def main() -> None:
    """Print :data:`FINGERPRINTS` as they should read now (after porting a change)."""
    print("FINGERPRINTS: dict[str, str] = {")
    for name, value in fingerprints().items():
        print(f"    {name!r}: {value!r},")
    print("}")


if __name__ == "__main__":
    main()

