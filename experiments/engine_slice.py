"""Issue 17: the two engine routes measured on one slice, the measure projection.

The slice is ``runtime/projector.py: project_measures`` (report eq. 22 with eq. 18's halving
per measure), the hottest function of a fit. It runs on the same inputs, in one process, as

* **NumPy**: ``project_measures`` on a problem of ``kanagen.load(name)`` (the generated NumPy
  functions and kernels), under ``np.errstate(all="ignore")`` as ``coherence_errors`` calls it;
* **numba**, one source (experiments/_engine_slice_kernels.py) that runs as plain Python
  (``NUMBA_DISABLE_JIT=1``) and under ``@njit(cache=True, error_model="numpy")``, in two forms:

  - *vectorised*: ``project_channel``, all the measures per step as the NumPy version,
    calling the family's generated measure function, ``whiten_<p>_<k>`` and
    ``correct_<p>_<k>`` njit-compiled as emitted, except for what numba refuses, which
    :class:`_NumbaCompatible` (an AST transform) rewrites the way the code generator would
    have to;
  - *rows*: ``project_rows``, one measure at a time to its end as the C port runs it, calling
    the measure function's *row form* (``_RowForm``: the generated function with its
    ``[:, ...]`` dropped, writing one measure's ``c, C, D`` into given arrays) and the
    runtime's generic per-measure whiten/correct;

  both *specialised* per (model, channel): their syntax trees copied into the family's
  njit-able module with the generated functions bound by name (``_Specialise``), which is
  what makes numba's cache work (``--alternatives`` times passing them as arguments);
* **C**: ``kanagen.load(name, backend="compiled")``, then the problem's
  ``FastPath.coherence(model, problem, q, iterations, tol)`` (``kg_coherence`` of
  codegen/c/kanagen_fast.c: the same projection, returning ``‖m̃ − m‖²_Q + violation`` and
  the ranks).

Cases: (i) ``conic``, 30 points on the upper half of benchmarks/conic_odr.py's ellipse, noise
σ = 1, ``q`` the true conic moved by 1e-4 (relative) and normalised; (ii) ``two_view`` model
``general``, ``two_view_scene("general", n=200, outliers=0.3, sigma=0.5, seed=1)`` (286
matches) at its true parameter. ``iterations=50, tol=1e-10`` (``coherence_errors``'s
geometric error).

Printed: the agreement of numba with NumPy (projected measures, violations, ranks), also with
numba off, and of C with NumPy (totals, ranks); per-call times (each version timed in
batches of ~30 ms, interleaved, 7 rounds, the fastest batch mean kept) and their ratios;
compile costs, each in a fresh subprocess: numba cold with its cache off, cold filling an
empty cache, warm from that cache; C cold (``kanagen.load(name, backend="compiled")`` into an
empty ``$KANAGEN_CACHE``, a temporary folder, never the user's cache) and warm.

Everything is written under a temporary folder (the transformed modules, numba's cache,
the C library), removed at the end. Run ``python experiments/engine_slice.py`` (about two
minutes; ``--alternatives`` also times the unspecialised projector; ``--survey`` compiles
every function of the two generated modules and prints what numba refuses, a few minutes
more; ``--keep`` keeps the temporary folder). Needs numba (``pip install numba``).
"""

from __future__ import annotations

import os
import sys
import tempfile

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
#: Everything this script writes: transformed modules, numba's cache, the C library cache.
_CREATED = "ENGINE_SLICE_DIR" not in os.environ
WORK = os.environ.get("ENGINE_SLICE_DIR") or tempfile.mkdtemp(prefix="engine_slice_")
os.environ["ENGINE_SLICE_DIR"] = WORK
os.environ["NUMBA_CACHE_DIR"] = os.path.join(WORK, "numba")
os.environ["KANAGEN_CACHE"] = os.path.join(WORK, "kanagen")  # not the user's cache
#: numba's cache on (default) or off ("0": the cold compile without writing a cache)
CACHE = os.environ.get("ENGINE_SLICE_CACHE", "1") != "0"

import argparse  # noqa: E402
import ast  # noqa: E402
import importlib  # noqa: E402
import importlib.util  # noqa: E402
import inspect  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

_T0 = time.perf_counter()
import numba  # noqa: E402
from numba import types as nbtypes  # noqa: E402

_T_NUMBA = time.perf_counter() - _T0

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _engine_slice_kernels as kernels  # noqa: E402

import kanagen  # noqa: E402
from kanagen.runtime.fit import make_problem  # noqa: E402
from kanagen.runtime.inputs import parameter_vector  # noqa: E402
from kanagen.runtime.projector import project_measures, quadratic  # noqa: E402

JIT = not numba.config.DISABLE_JIT
ITERATIONS, TOL = 50, 1e-10


# -- the generated module, made njit-able ------------------------------------------------------

class _NumbaCompatible(ast.NodeTransformer):
    """The generator's constructs numba refuses on the slice, rewritten minimally (what the
    code generator would emit instead): ``np.stack([a, b], axis=1)`` in ``whiten_<p>_<k>``
    (the kept-equation mask; codegen/templates/numpy/util.jinja) — numba's ``np.stack`` takes
    a tuple of arrays, not a list: ``np.stack((a, b), axis=1)``. (Off the slice, ``derived``
    returns a dict of tuples keyed by name, which numba types but cannot hand back to Python:
    a tuple in the order of ``FAMILY["derived"]`` would do; ``--survey``.)"""

    def __init__(self):
        self.changes: list[str] = []
        self._function = "<module>"

    def visit_FunctionDef(self, node):
        outer, self._function = self._function, node.name
        self.generic_visit(node)
        self._function = outer
        return node

    def visit_Call(self, node):
        self.generic_visit(node)
        fn = node.func
        if isinstance(fn, ast.Attribute) and fn.attr == "stack" and \
                isinstance(fn.value, ast.Name) and fn.value.id == "np" and node.args and \
                isinstance(node.args[0], ast.List):
            node.args[0] = ast.Tuple(elts=node.args[0].elts, ctx=ast.Load())
            self.changes.append(f"{self._function}: np.stack([...]) -> np.stack((...,))")
        return node


class _Specialise(ast.NodeTransformer):
    """:func:`~_engine_slice_kernels.project_channel` and its ``halving`` for one measure
    function: the arguments ``measure``, ``whiten``, ``correct`` dropped, their calls made to
    the generated functions' global names, the two functions renamed."""

    def __init__(self, bound: dict[str, str], names: dict[str, str]):
        self.bound, self.names = bound, names

    def visit_FunctionDef(self, node):
        self.generic_visit(node)
        node.name = self.names[node.name]
        node.args.args = [a for a in node.args.args if a.arg not in self.bound]
        node.decorator_list = []
        return node

    def visit_Call(self, node):
        self.generic_visit(node)
        if isinstance(node.func, ast.Name):
            if node.func.id in self.bound:
                node.func = ast.Name(id=self.bound[node.func.id], ctx=ast.Load())
            elif node.func.id in self.names:
                node.func = ast.Name(id=self.names[node.func.id], ctx=ast.Load())
                node.args = [a for a in node.args
                             if not (isinstance(a, ast.Name) and a.id in self.bound)]
        return node


class _RowForm(ast.NodeTransformer):
    """A generated measure function ``measure_<...>(q, m, k) -> (c, C, D)`` (vectorised over
    the rows of m) as ``measure_<...>_row(q, m, k, c, C, D)`` for one measure: ``m`` one row,
    the outputs written into the given (p,), (p, n), (p, k) arrays. Mechanical: ``[:, ...]``
    dropped from the subscripts of m and of the outputs, ``M`` and the allocations
    (``np.zeros``) replaced by ``fill(0.0)``, nothing returned."""

    def __init__(self, outputs: list[str]):
        self.arrays = {"m", *outputs}
        self.outputs = outputs

    def visit_Subscript(self, node):
        self.generic_visit(node)
        sl = node.slice
        if isinstance(node.value, ast.Name) and node.value.id in self.arrays and \
                isinstance(sl, ast.Tuple) and isinstance(sl.elts[0], ast.Slice) and \
                sl.elts[0].lower is None and sl.elts[0].upper is None:
            rest = sl.elts[1:]
            node.slice = rest[0] if len(rest) == 1 else ast.Tuple(elts=rest, ctx=ast.Load())
        return node


def row_form(fn) -> str:
    """The source of :class:`_RowForm`'s version of the generated measure function ``fn``."""
    tree = ast.parse(inspect.getsource(fn)).body[0]
    outputs = [e.id for e in tree.body[-1].value.elts]
    body = []
    for stmt in tree.body[1:]:  # the docstring out
        if isinstance(stmt, ast.Assign) and isinstance(stmt.targets[0], ast.Name):
            name = stmt.targets[0].id
            if name == "M":
                continue
            if name in outputs:
                body.append(ast.parse(f"{name}.fill(0.0)").body[0])
                continue
        if isinstance(stmt, ast.Return):
            body.append(ast.Return(value=None))
            continue
        body.append(_RowForm(outputs).visit(stmt))
    tree.body = body
    tree.name = f"{fn.__name__}_row"
    tree.args.args += [ast.arg(arg=o) for o in outputs]
    return ast.unparse(ast.fix_missing_locations(tree))


def specialised_projectors(module) -> list[str]:
    """``project_<channel>[__<model>]`` (and its halving) per measure function of the
    family's models, bound to the measure function and the kernels of its sizes."""
    meta, out, done = module.FAMILY, [], set()
    source = [ast.parse(inspect.getsource(f)).body[0]
              for f in (kernels.halving, kernels.project_channel)]
    rows = [ast.parse(inspect.getsource(f)).body[0]
            for f in (kernels.halving_row, kernels.project_rows)]
    for entry in module.MODELS.values():
        for channel, fn in entry["channels"].items():
            if fn.__name__ in done:
                continue
            done.add(fn.__name__)
            ch = meta["channels"][channel]
            with np.errstate(all="ignore"):
                p = fn(np.zeros(len(meta["parameter"])), np.zeros((0, len(ch["components"]))),
                       np.ones(len(meta["constants"])))[0].shape[1]
            suffix = fn.__name__.removeprefix("measure_")
            bound = {"measure": fn.__name__, "whiten": f"whiten_{p}_{len(ch['corrected'])}",
                     "correct": f"correct_{p}_{len(ch['corrected'])}"}
            names = {"halving": f"_halving_{suffix}", "project_channel": f"project_{suffix}"}
            for tree in source:
                tree = _Specialise(bound, names).visit(ast.parse(ast.unparse(tree)))
                out.append(ast.unparse(ast.fix_missing_locations(tree)))
            # per measure: the measure function's row form and the projector of the C port
            out.append(row_form(fn))
            bound = {"measure_row": f"{fn.__name__}_row"}
            names = {"halving_row": f"_halving_rows_{suffix}",
                     "project_rows": f"project_rows_{suffix}"}
            for tree in rows:
                tree = _Specialise(bound, names).visit(ast.parse(ast.unparse(tree)))
                out.append(ast.unparse(ast.fix_missing_locations(tree)))
    return out


def njit_source(module) -> tuple[str, list[str]]:
    """The source of a generated NumPy module with :class:`_NumbaCompatible`'s rewrites and
    the specialised projectors appended (what the generator would emit), and the list of
    rewrites."""
    tree = ast.parse(inspect.getsource(module))
    fix = _NumbaCompatible()
    tree = ast.fix_missing_locations(fix.visit(tree))
    tail = ["# The measure projection (experiments/_engine_slice_kernels.py), specialised",
            "from _engine_slice_kernels import _ROUNDING, _nanmax_abs, correct_row, "
            "whiten_row, with_corrected"]
    return "\n\n\n".join([ast.unparse(tree), "\n".join(tail),
                           *specialised_projectors(module)]) + "\n", fix.changes


def numba_module(name: str):
    """The transformed generated module of family ``name``, written under WORK (only when
    its text changed: numba's cache is keyed by the file's time stamp) and imported."""
    generated = importlib.import_module(f"kanagen.generated.{name}")
    text, changes = njit_source(generated)
    folder = Path(WORK) / "src"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"kanagen_nb_{name}.py"
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")
    modname = f"kanagen_nb_{name}"
    if modname in sys.modules:
        return sys.modules[modname], changes
    spec = importlib.util.spec_from_file_location(modname, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.modules[modname] = module
    return module, changes


def _jitted(module, name: str):
    """The module's function ``name`` njit-compiled (lazily), rebound in the module so that
    the functions calling it by its global name call the compiled one."""
    fn = getattr(module, name)
    if not isinstance(fn, numba.core.registry.CPUDispatcher):
        fn = numba.njit(cache=CACHE, error_model="numpy")(fn)
        setattr(module, name, fn)
    return fn


# -- the cases ---------------------------------------------------------------------------------

def conic_case():
    """30 points on half an ellipse (benchmarks/conic_odr.py's scene), σ = 1."""
    cx, cy, a, b, angle = 330.0, 250.0, 220.0, 130.0, np.deg2rad(25.0)
    t = np.linspace(0.0, np.pi, 30)
    c, s = np.cos(angle), np.sin(angle)
    u, v = a * np.cos(t), b * np.sin(t)
    clean = np.column_stack([cx + c * u - s * v, cy + s * u + c * v])
    rng = np.random.default_rng(4050)
    xy = clean + rng.normal(0.0, 1.0, clean.shape)
    R = np.array([[c, -s], [s, c]])
    Qe = R @ np.diag([1 / a**2, 1 / b**2]) @ R.T
    z = np.array([cx, cy])
    f0 = 100.0
    theta = np.array([Qe[0, 0], Qe[0, 1], Qe[1, 1], -(Qe @ z)[0] / f0, -(Qe @ z)[1] / f0,
                      (z @ Qe @ z - 1.0) / f0**2])
    theta /= np.linalg.norm(theta)
    q = theta + 1e-4 * rng.normal(size=6) * np.abs(theta).max()
    q /= np.linalg.norm(q)
    return {"family": "conic", "model": "conic", "channel": "point",
            "data": {"point": xy}, "info": {"point": 1.0}, "constants": None, "q": q,
            "label": "conic, 30 points, σ=1"}


def two_view_case():
    """``two_view_scene("general", n=200, outliers=0.3, sigma=0.5, seed=1)``, true q."""
    from kanagen.scenes import two_view_scene

    scene = two_view_scene("general", n=200, outliers=0.3, sigma=0.5, seed=1)
    return {"family": "two_view", "model": "general", "channel": "match",
            "data": {"match": scene.data}, "info": {"match": 1.0 / scene.sigma**2},
            "constants": scene.constants, "q": scene.params(),
            "label": f"two_view general, {len(scene.data)} matches (30 % outliers)"}


CASES = {"conic": conic_case, "two_view": two_view_case}


def problem_for(case, backend="numpy"):
    fam = kanagen.load(case["family"], backend=backend)
    problem = make_problem(fam, case["model"], case["data"], case["info"],
                           constants=case["constants"])
    return fam, problem, parameter_vector(fam, case["q"], "q")


# -- the numba slice ---------------------------------------------------------------------------

class NumbaSlice:
    """The projector of one (family, model, channel) under numba (or plain Python).

    ``form="vectorised"``: the generated measure function and kernels as emitted (njit-
    compiled lazily, on the problem's own types) and the specialised projector
    ``project_<channel>[__<model>]`` calling them, all measures at once per step (the NumPy
    version's order of work). ``form="rows"``: the measure function's row form and
    ``project_rows_<channel>[__<model>]``, one measure at a time to its end (the C port's
    order of work)."""

    def __init__(self, fam, problem, model: str, form: str = "vectorised"):
        ch = problem.channels[0]
        self.module, self.changes = numba_module(fam.module.FAMILY["name"])
        measure = fam.measurement_function(model, ch.name)
        whiten, correct = problem.kernels[0]
        suffix = measure.__name__.removeprefix("measure_")
        self.form = form
        if form == "rows":
            self.names = [f"{measure.__name__}_row"]
            self.name = f"project_rows_{suffix}"
            halving = f"_halving_rows_{suffix}"
        else:
            self.names = [f.__name__ for f in (measure, whiten, correct)]
            self.name = f"project_{suffix}"
            halving = f"_halving_{suffix}"
        self.args = (np.ascontiguousarray(ch.X), np.ascontiguousarray(ch.index, np.int64),
                     np.ascontiguousarray(ch.Q), np.ascontiguousarray(ch.G),
                     np.ascontiguousarray(problem.k))
        self.eps = float(problem.eps)
        X, index, Q, G, k = self.args
        q = np.ascontiguousarray(problem.q0, dtype=float)
        with np.errstate(all="ignore"):
            self.p = measure(q, X[:1], k)[0].shape[1]
        self.seconds = {"generated": 0.0, "projector": 0.0}
        if not JIT:
            self.project = getattr(self.module, self.name)
            return
        t0 = time.perf_counter()
        fns = [_jitted(self.module, n) for n in self.names]
        # one call each on the problem's own types: compiles (or loads) the generated code
        if form == "rows":
            n = q.size
            fns[0](q, X[0].copy(), k, np.empty(self.p), np.empty((self.p, n)),
                   np.empty((self.p, index.size)))
        else:
            c, C, D = fns[0](q, X, k)
            _, _, state = fns[1](D, G, np.zeros((X.shape[0], c.shape[1], 2)), self.eps)
            fns[2](state, G, np.zeros((X.shape[0], c.shape[1])))
        t1 = time.perf_counter()
        _jitted(self.module, halving)
        self.project = _jitted(self.module, self.name)
        self(q, 2)
        self.fns = fns
        self.seconds = {"generated": t1 - t0, "projector": time.perf_counter() - t1}

    def __call__(self, q, iterations=ITERATIONS, tol=TOL):
        X, index, Q, G, k = self.args
        if self.form == "rows":
            return self.project(self.p, q, X, index, Q, G, k, iterations, tol, self.eps)
        return self.project(q, X, index, Q, G, k, iterations, tol, self.eps)


def alternatives(case) -> dict:
    """The unspecialised projector under numba, the compiled functions as arguments: as
    first-class function values (explicit signatures; cacheable) and as dispatchers (lazy;
    numba's cache never hits them in a new process). Per-call seconds, and the same results."""
    fam, problem, q = problem_for(case)
    sl = NumbaSlice(fam, problem, case["model"])
    X, index, Q, G, k = sl.args
    plain = kernels.halving
    kernels.halving = numba.njit(error_model="numpy")(plain)  # the generic one, compiled
    try:
        ftypes = [nbtypes.FunctionType(f.nopython_signatures[0]) for f in sl.fns]
        sig = (*ftypes, nbtypes.float64[::1], *[numba.typeof(a) for a in sl.args[:4]],
               nbtypes.float64[::1], nbtypes.int64, nbtypes.float64, nbtypes.float64)
        first_class = numba.njit(sig)(kernels.project_channel)
        by_dispatcher = numba.njit(kernels.project_channel)
        by_dispatcher(*sl.fns, q, X, index, Q, G, k, ITERATIONS, TOL, sl.eps)
    finally:
        kernels.halving = plain
    ref = sl(q)
    calls = {"specialised": lambda: sl(q),
             "function values": lambda: first_class(*sl.fns, q, X, index, Q, G, k,
                                                    ITERATIONS, TOL, sl.eps),
             "dispatchers": lambda: by_dispatcher(*sl.fns, q, X, index, Q, G, k, ITERATIONS,
                                                  TOL, sl.eps)}
    for name, fn in calls.items():
        if not all(np.array_equal(a, b) for a, b in zip(fn(), ref, strict=True)):
            raise AssertionError(f"{name}: results differ from the specialised projector")
    return _best_of(calls)


# -- agreement ---------------------------------------------------------------------------------

FORMS = ("vectorised", "rows")


def compare(case) -> dict:
    """Per numba form: against NumPy (projected measures, violations, ranks, totals), and
    C against NumPy (totals ``‖m̃ − m‖²_Q + violation``, ranks)."""
    fam, problem, q = problem_for(case)
    ch = problem.channels[0]
    with np.errstate(all="ignore"):
        mt, viol, rank, _ = project_measures(problem, q, (ch.m,), ITERATIONS, TOL)
    total_np = quadratic(mt[0] - ch.m, ch.Q) + viol[0]
    out = {"M": ch.size, "moved": float(np.max(np.abs(mt[0] - ch.m))),
           "vmax": float(np.max(viol[0]))}
    for form in FORMS:
        sl = NumbaSlice(fam, problem, case["model"], form)
        with np.errstate(all="ignore"):
            m_nb, v_nb, r_nb, steps = sl(q)
        total_nb = quadratic(m_nb - ch.m, ch.Q) + v_nb
        res = {"steps": int(steps),
               "dm": float(np.max(np.abs(m_nb - mt[0]))),
               "dm_rel": float(np.max(np.abs(m_nb - mt[0])) / np.max(np.abs(mt[0]))),
               "dv": float(np.max(np.abs(v_nb - viol[0]))),
               "dv_rel": float(np.max(np.abs(v_nb - viol[0])) / max(np.max(viol[0]), 1e-300)),
               "rank_mismatch": int(np.sum(r_nb != rank[0])),
               "total_rel": float(np.max(np.abs(total_nb - total_np)) / np.max(total_np))}
        if not JIT and form == "vectorised":  # the unspecialised source, plain functions
            plain = [getattr(sl.module, n) for n in sl.names]
            with np.errstate(all="ignore"):
                generic = kernels.project_channel(*plain, q, *sl.args, ITERATIONS, TOL,
                                                  sl.eps)
            res["generic_same"] = all(np.array_equal(a, b) for a, b in
                                      zip(generic, (m_nb, v_nb, r_nb, steps), strict=True))
        out[form] = res
    if JIT:
        famc, problem_c, _ = problem_for(case, "compiled")
        if problem_c.compiled is not None:
            fp, model = problem_c.compiled
            totals, kept = fp.coherence(model, problem_c, q, ITERATIONS, TOL)
            out["C"] = {"total_rel": float(np.max(np.abs(totals[0] - total_np))
                                           / np.max(total_np)),
                        "rank_mismatch": int(np.sum(kept[0] != rank[0]))}
    return out


# -- timing ------------------------------------------------------------------------------------

def timings(case, rounds: int = 7, batch: float = 0.03) -> dict:
    """Per-call seconds of the three versions, interleaved batches, fastest batch mean."""
    fam, problem, q = problem_for(case)
    ch = problem.channels[0]
    vec = NumbaSlice(fam, problem, case["model"], "vectorised")
    rows = NumbaSlice(fam, problem, case["model"], "rows")
    famc, problem_c, _ = problem_for(case, "compiled")
    if problem_c.compiled is None:
        raise SystemExit("the compiled fast path is off: no C route")
    fp, model = problem_c.compiled

    def numpy_call():
        with np.errstate(all="ignore"):
            project_measures(problem, q, (ch.m,), ITERATIONS, TOL)

    calls = {"numpy": numpy_call, "vectorised": lambda: vec(q), "rows": lambda: rows(q),
             "C": lambda: fp.coherence(model, problem_c, q, ITERATIONS, TOL)}
    return _best_of(calls, rounds, batch)


def _best_of(calls: dict, rounds: int = 7, batch: float = 0.03) -> dict:
    """Per-call seconds of each call: batches of ~``batch`` seconds, interleaved, the
    fastest batch mean of ``rounds``."""
    counts = {}
    for name, fn in calls.items():
        fn()
        t0 = time.perf_counter()
        fn()
        counts[name] = max(1, int(batch / max(time.perf_counter() - t0, 1e-7)))
    best = dict.fromkeys(calls, np.inf)
    for _ in range(rounds):
        for name, fn in calls.items():
            n = counts[name]
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            best[name] = min(best[name], (time.perf_counter() - t0) / n)
    return best


# -- compile costs (each in a fresh subprocess) ------------------------------------------------

def _warm_up(a):
    return np.zeros(3) + a.sum()


def compile_numba(family: str) -> dict:
    """(In a subprocess.) Compile (or load from the cache) what the slice needs, per form."""
    t0 = time.perf_counter()
    case = CASES[family]()
    fam, problem, q = problem_for(case)
    out = {"import_numba": _T_NUMBA, "setup": time.perf_counter() - t0}
    t1 = time.perf_counter()  # numba's first compile in a process sets itself up: apart
    numba.njit(_warm_up)(np.ones(3))
    out["warm_up"] = time.perf_counter() - t1
    for form in FORMS:
        t1 = time.perf_counter()
        sl = NumbaSlice(fam, problem, case["model"], form)
        out[form] = {"slice": time.perf_counter() - t1, **sl.seconds, "functions": sl.names}
    return out


def compile_c(family: str) -> dict:
    """(In a subprocess.) ``kanagen.load(family, backend="compiled")`` into $KANAGEN_CACHE."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a CompileWarning must show
        t0 = time.perf_counter()
        kanagen.load(family, backend="compiled")
    return {"load": time.perf_counter() - t0}


def subprocess_json(args: list[str], env: dict) -> dict:
    done = subprocess.run([sys.executable, __file__, *args], env={**os.environ, **env},
                          capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def compile_costs(family: str) -> dict:
    """numba: cold with its cache off, cold into an empty cache, warm; C: cold, warm."""
    off = os.path.join(WORK, "cold_off")
    out = {
        "numba_off": subprocess_json(["--compile-numba", family], {
            "ENGINE_SLICE_DIR": off, "ENGINE_SLICE_CACHE": "0"}),
        "numba_cold": subprocess_json(["--compile-numba", family], {}),
        "numba_warm": subprocess_json(["--compile-numba", family], {}),
        "c_cold": subprocess_json(["--compile-c", family], {}),
        "c_warm": subprocess_json(["--compile-c", family], {}),
    }
    return out


# -- what numba refuses in the generated modules -----------------------------------------------

def _sample_args(module, fn_name: str, rng):
    """Arguments of the right shapes for a generated function (for the survey)."""
    meta = module.FAMILY
    n, k = len(meta["parameter"]), np.array([v for _, v in meta["constants"]], dtype=float)
    q = np.array([v for _, v in meta["parameter"]], dtype=float) + 0.1
    if fn_name.endswith("__reduced"):
        model = fn_name.removesuffix("__reduced").split("__")[-1].removeprefix("c0_")
        q = q[meta["reductions"][model]["free"]]
    if fn_name.startswith("measure_"):
        channel = next(c for c in meta["channels"] if fn_name.startswith(f"measure_{c}"))
        width = len(meta["channels"][channel]["components"])
        return (q, rng.normal(size=(5, width)), k)
    if fn_name.startswith(("whiten_", "correct_")):
        p, kk = (int(x) for x in fn_name.split("_")[1:])
        D, G = rng.normal(size=(5, p, kk)), np.eye(kk)
        if fn_name.startswith("whiten_"):
            return (D, G, rng.normal(size=(5, p, 2)), 1e-15)
        state = getattr(module, f"whiten_{p}_{kk}")(D, G, rng.normal(size=(5, p, 2)), 1e-15)[2]
        return (state, G, rng.normal(size=(5, p)))
    del n
    return (q, k)


def survey(family: str) -> list[tuple[str, str, str]]:
    """Every function of the generated module, njit-compiled (and called once) as emitted
    and, where the transform changed it, transformed: ``(function, as emitted,
    transformed)`` with "ok" or the first line of numba's error."""
    rng = np.random.default_rng(0)
    emitted = importlib.import_module(f"kanagen.generated.{family}")
    fixed, changes = numba_module(family)
    changed = {c.split(":")[0] for c in changes}
    rows = []
    for name, fn in inspect.getmembers(emitted, inspect.isfunction):
        if fn.__module__ != emitted.__name__ or fn.__name__ != name:  # DERIVED: an alias
            continue
        verdicts = []
        for module in (emitted, fixed) if name in changed else (emitted,):
            try:
                with np.errstate(all="ignore"):
                    fn = getattr(module, name)
                    numba.njit(getattr(fn, "py_func", fn))(*_sample_args(emitted, name, rng))
                verdicts.append("ok")
            except Exception as exc:  # numba's TypingError and friends
                lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
                key = next((ln for ln in lines if ln.startswith(("No implementation",
                                                                 "Cannot", "Invalid",
                                                                 "Unknown", "Use of"))),
                           lines[1] if len(lines) > 1 else lines[0])
                verdicts.append(f"{type(exc).__name__}: {key[:110]}")
        rows.append((name, verdicts[0], verdicts[1] if len(verdicts) > 1 else "(unchanged)"))
    return rows


def emitted_kernel_error(family: str, p: int, k: int) -> str:
    """numba's verdict on ``whiten_<p>_<k>`` as emitted (what the transform fixes)."""
    module = importlib.import_module(f"kanagen.generated.{family}")
    rng = np.random.default_rng(0)
    try:
        numba.njit(getattr(module, f"whiten_{p}_{k}"))(*_sample_args(module, f"whiten_{p}_{k}",
                                                                      rng))
        return "ok"
    except Exception as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        sig = next((ln for ln in lines if "found for signature" in ln), lines[0])
        at = next((ln for ln in lines if "np.stack" in ln), "")
        return f"{type(exc).__name__}: {sig} ... {at}"


# -- main --------------------------------------------------------------------------------------

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compile-numba", metavar="FAMILY", help=argparse.SUPPRESS)
    parser.add_argument("--compile-c", metavar="FAMILY", help=argparse.SUPPRESS)
    parser.add_argument("--check", action="store_true",
                        help="agreement only (run it with NUMBA_DISABLE_JIT=1: plain Python)")
    parser.add_argument("--survey", action="store_true",
                        help="also njit every function of the generated modules")
    parser.add_argument("--alternatives", action="store_true",
                        help="also time the unspecialised projector with the compiled "
                        "functions as arguments")
    parser.add_argument("--keep", action="store_true", help=f"keep {WORK}")
    args = parser.parse_args()
    if args.compile_numba:
        print(json.dumps(compile_numba(args.compile_numba)))
        return
    if args.compile_c:
        print(json.dumps(compile_c(args.compile_c)))
        return
    if args.check:
        print(json.dumps({name: compare(make()) for name, make in CASES.items()}))
        return
    try:
        run(args)
    finally:
        if _CREATED and not args.keep:
            shutil.rmtree(WORK, ignore_errors=True)


def _agreement(label: str, res: dict) -> list[str]:
    lines = []
    for form in FORMS:
        r = res[form]
        line = (f"  {label} [{form}]: {r['steps']} steps, max|Δm̃| {r['dm']:.1e} px "
                f"({r['dm_rel']:.1e} rel.), max|Δviolation| {r['dv']:.1e} "
                f"({r['dv_rel']:.1e} rel.), ranks differing {r['rank_mismatch']}, "
                f"totals {r['total_rel']:.1e} rel.")
        if "generic_same" in r:
            line += ("; the unspecialised source, plain functions as arguments: "
                     + ("the same" if r["generic_same"] else "DIFFERENT"))
        lines.append(line)
    if "C" in res:
        lines.append(f"  C (kg_coherence): totals {res['C']['total_rel']:.1e} rel., ranks "
                     f"differing {res['C']['rank_mismatch']}")
    return lines


def run(args) -> None:
    print(f"numba {numba.__version__}, numpy {np.__version__}, python "
          f"{sys.version.split()[0]}; work folder {WORK}")
    print("Compile costs first, a fresh subprocess each ...", flush=True)
    costs = {name: compile_costs(name) for name in CASES}
    cases = {name: make() for name, make in CASES.items()}

    print("\nAgreement with NumPy's project_measures (iterations=50, tol=1e-10): the numba "
          "forms' projected measures, violations, ranks and totals ‖m̃ − m‖²_Q + violation; "
          "C's totals and ranks")
    plain = subprocess_json(["--check"], {"NUMBA_DISABLE_JIT": "1"})
    for name, case in cases.items():
        res = compare(case)
        print(f" {case['label']}: M={res['M']}, measures moved up to {res['moved']:.3g} px,"
              f" largest violation left {res['vmax']:.2g}")
        print("\n".join(_agreement("numba", res)))
        print("\n".join(_agreement("plain Python (NUMBA_DISABLE_JIT=1)", plain[name])))

    print("\nWhat numba refuses in the generated modules as emitted (the transform fixes it):")
    for name, p, k in (("conic", 1, 2), ("two_view", 1, 4), ("two_view", 3, 4)):
        print(f"  {name}.whiten_{p}_{k}: {emitted_kernel_error(name, p, k)}")
    for name in CASES:
        ch = numba_module(name)[1]
        print(f"  transform of generated/{name}.py: {len(ch)} rewrites ({'; '.join(ch)})")

    print("\nPer call, µs (fastest of 7 interleaved ~30 ms batches; numba 'vectorised': the "
          "generated functions as emitted, all measures per step; 'rows': one measure at a "
          "time, the measure function's row form)")
    print("| case | NumPy | numba vectorised | numba rows | C | vectorised / C | rows / C | "
          "NumPy / rows |")
    print("|---|---|---|---|---|---|---|---|")
    for case in cases.values():
        t = timings(case)
        print(f"| {case['label']} | {t['numpy'] * 1e6:.0f} | {t['vectorised'] * 1e6:.1f} | "
              f"{t['rows'] * 1e6:.1f} | {t['C'] * 1e6:.1f} | {t['vectorised'] / t['C']:.1f} |"
              f" {t['rows'] / t['C']:.1f} | {t['numpy'] / t['rows']:.0f} |", flush=True)

    print("\nCompile costs, s, a fresh subprocess each (numba: what the slice needs, per "
          "form — the generated functions it calls, then the projector with its helpers; "
          "C: kanagen.load(name, backend=\"compiled\") into an empty $KANAGEN_CACHE, the "
          "whole family's library)")
    print("| family | form | numba cold, cache off | numba cold, filling the cache | "
          "numba warm, from the cache | C cold | C warm |")
    print("|---|---|---|---|---|---|---|")
    for name, c in costs.items():
        for form in FORMS:
            off = c["numba_off"][form]
            print(f"| {name} | {form} ({', '.join(off['functions'])}) | {off['slice']:.2f} "
                  f"({off['generated']:.2f} + {off['projector']:.2f}) | "
                  f"{c['numba_cold'][form]['slice']:.2f} | "
                  f"{c['numba_warm'][form]['slice']:.3f} | {c['c_cold']['load']:.2f} | "
                  f"{c['c_warm']['load']:.3f} |")
    print("(paid once per process besides: import numba "
          f"{costs['conic']['numba_warm']['import_numba']:.2f} s; numba setting itself up at "
          "its first compile in a process, timed on a 2-line function before the slice, "
          "cold | warm process: "
          + ", ".join(f"{name} {c['numba_off']['warm_up']:.2f} | "
                      f"{c['numba_warm']['warm_up']:.2f} s" for name, c in costs.items())
          + "; C's warm load includes importing CasADi)")

    if args.alternatives:
        print("\nThe unspecialised projector, the compiled functions as arguments, µs per call"
              " (vectorised form)")
        print("| case | specialised (emitted per model and channel) | first-class function "
              "values (cacheable) | dispatchers (never cached) |")
        print("|---|---|---|---|")
        for case in cases.values():
            t = alternatives(case)
            print(f"| {case['label']} | {t['specialised'] * 1e6:.1f} | "
                  f"{t['function values'] * 1e6:.1f} | {t['dispatchers'] * 1e6:.1f} |")

    if args.survey:
        print("\nSurvey: every generated function njit-compiled (as emitted | transformed)")
        for name in CASES:
            for fn, emitted, fixed in survey(name):
                if emitted != "ok" or fixed not in ("ok", "(unchanged)"):
                    print(f"  {name}.{fn}: {emitted} | {fixed}")
            print(f"  {name}: every other function compiles and runs as emitted")


if __name__ == "__main__":
    main()
