"""Which Python functions the C kernels port (codegen/c/), and their fingerprints when the C
was last brought in line with them (a test-time check, nothing at run time).

tests/test_fastpath.py fails when one of :data:`PORTED` changes, naming it: port the change to
the C, run the differential tests (tests/test_fastpath.py, tests/test_fast_initializers.py),
then paste the output of ``python tests/port_fingerprints.py`` into :data:`FINGERPRINTS`.
The fingerprint is a hash of the syntax tree, docstrings and comments excluded.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
import inspect
import textwrap
from functools import cache
from types import ModuleType

#: Python functions (and module constants) that codegen/c/kanagen_fast.c ports, by module.
PORTED: dict[str, tuple[str, ...]] = {
    # kg_coherence: the measures projected onto their equations (eq. 22–24)
    "engine.measures": ("project_measure", "halving", "residual_into", "eval_measure", "quad",
                        "factor", "whiten_column", "correct", "worst_abs", "ROUNDING"),
    "sqrt": ("closest_sqrt", "reduced_sqrt", "reduced_solve", "triangular_solve",
             "equilibrium", "diagonal_max", "closest_root", "reduced_root", "solve_lower",
             "solve_kept", "EPS", "_TINY", "REDUNDANT"),
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
    'engine.measures.project_measure': 'e658f74f1618',
    'engine.measures.halving': 'bb062a68f777',
    'engine.measures.residual_into': '75842f52c352',
    'engine.measures.eval_measure': '5578fc3ad8ee',
    'engine.measures.quad': '105e5af99b00',
    'engine.measures.factor': '7f6c2a84e38c',
    'engine.measures.whiten_column': '4704fde1107d',
    'engine.measures.correct': '4ca345fe5051',
    'engine.measures.worst_abs': '1654b711f665',
    'engine.measures.ROUNDING': 'a6ed850332ba',
    'sqrt.closest_sqrt': 'b46be465048d',
    'sqrt.reduced_sqrt': 'f908fd4a9e93',
    'sqrt.reduced_solve': '7ef3dfa98e65',
    'sqrt.triangular_solve': '628602a3e7bb',
    'sqrt.equilibrium': 'b689e5d65daf',
    'sqrt.diagonal_max': 'f06bff609523',
    'sqrt.closest_root': '63796dd79116',
    'sqrt.reduced_root': '5ef7835b63c4',
    'sqrt.solve_lower': '48d384892f3b',
    'sqrt.solve_kept': 'e28eb93738b3',
    'sqrt.EPS': 'cf90b756d02d',
    'sqrt._TINY': '24623188d5ff',
    'sqrt.REDUNDANT': 'a11958cb4ea6',
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
    'geometry.best_pose': 'd36b79168e9c',
    'geometry.nearest_essential': '898b1d686f05',
    'geometry.homography_poses': 'e6c7f0b6a730',
    'geometry.rotation_from_pairs': 'd48c00712efd',
    'geometry.quaternion_from_rotation': '270f42cbd8ff',
}




def _node(module: ModuleType, name: str) -> ast.AST:
    """The syntax tree of a function, method, property or module constant, docstring out."""
    owner, _, attr = name.rpartition(".")
    if owner:
        cls = ast.parse(textwrap.dedent(inspect.getsource(getattr(module, owner))))
        body = cls.body[0].body
        node = next(n for n in body if getattr(n, "name", None) == attr)
    elif inspect.isfunction(getattr(module, name)) or \
            inspect.isfunction(getattr(getattr(module, name), "py_func", None)):  # a kernel
        function = getattr(module, name)
        function = getattr(function, "py_func", function)
        node = ast.parse(textwrap.dedent(inspect.getsource(function))).body[0]
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
    """The ported Python functions that differ from what the C port mirrors; without
    ``twins`` those of :data:`TWIN_MODULES` are not checked."""
    try:
        now = fingerprints(twins)
    except (OSError, TypeError, AttributeError, StopIteration):
        return ["<the runtime's source is not available>"]
    recorded = {k: v for k, v in FINGERPRINTS.items()
                if twins or k.partition(".")[0] not in TWIN_MODULES}
    return sorted(k for k in now.keys() | recorded.keys() if now.get(k) != recorded.get(k))


def main() -> None:
    """Print :data:`FINGERPRINTS` as they should read now (after porting a change)."""
    print("FINGERPRINTS: dict[str, str] = {")
    for name, value in fingerprints().items():
        print(f"    {name!r}: {value!r},")
    print("}")


if __name__ == "__main__":
    main()
