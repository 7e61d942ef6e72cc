"""Matrices in the spec language: define:, vector equations, per-model derived and
initializer, the ess cost factor — and the errors they can raise, with file and line."""

from __future__ import annotations

import re

import numpy as np
import pytest
import sympy as sp

import kanagen
from kanagen.modelspec import SpecError, parse_expression, parse_spec
from kanagen.runtime.initializers import INITIALIZERS

X, Y, Z = (sp.Symbol(n, real=True) for n in "xyz")
NAMES = {"x": X, "y": Y, "z": Z}


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[x, y, z]", sp.Matrix([X, Y, Z])),
        ("[[x, 0], [0, y]] @ [1, 2]", sp.Matrix([X, 2 * Y])),
        ("transpose([x, y])", sp.Matrix([[X, Y]])),
        ("cross([1, 0, 0], [x, y, z])", sp.Matrix([0, -Z, Y])),
        ("skew([x, y, z]) @ [1, 2, 3]", sp.Matrix([X, Y, Z]).cross(sp.Matrix([1, 2, 3]))),
        ("dot([x, y], [y, x])", 2 * X * Y),
        ("det([[x, y], [z, 1]])", X - Y * Z),
        ("trace(diag(x, y, 2))", X + Y + 2),
        ("[[x, y], [z, 1]][1, 0] + [x, y, z][2]", 2 * Z),
        ("2 * [x, y] / 4 - [x, 0]", sp.Matrix([-X / 2, Y / 2])),
    ],
)
def test_matrix_expressions(text, expected):
    value = parse_expression(text, NAMES)
    if isinstance(expected, sp.MatrixBase):
        assert value.shape == expected.shape
        assert sp.simplify(sp.Matrix(value) - expected) == sp.zeros(*expected.shape)
    else:
        assert sp.simplify(value - expected) == 0


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("[x, y] * [x, y]", "write '@'"),
        ("[x, y] @ [x, y]", "'@' of a 2×1 matrix and a 2×1 matrix"),
        ("[x, y] + [x, y, z]", "cannot add"),
        ("x + [x]", "cannot add a scalar"),
        ("sqrt([x, y])", "sqrt needs a scalar"),
        ("x / [x]", "division by a 1×1 matrix"),
        ("[x] ** 2", "'**' of a matrix"),
        ("cross([x, y], [x, y])", "cross of a 2×1 matrix"),
        ("det([x, y])", "det of a 2×1 matrix"),
        ("dot(x, y)", "needs a matrix or vector"),
        ("[[x, y], [z]]", "unequal length"),
        ("[]", "empty list"),
        ("[x, y][2]", "out of range"),
        ("[x, y][y]", "integer literals"),
        ("diag()", "at least one"),
        ("skew", "without a call"),
        ("x[0]", "Subscript not allowed"),
    ],
)
def test_matrix_expression_errors(text, fragment):
    with pytest.raises(SpecError, match=re.escape(fragment)) as info:
        parse_expression(text, NAMES, "m.yaml", 7)
    assert info.value.line == 7


SPEC = """\
name: mat
constants: {k: 2.0}
parameter: {a: 1.0, b: 0.0, c: 0.0}
define:
  n: [a, b, c]
  p: [x, y, k]
  M: "[[a, 0, 0], [0, a, 0], [0, 0, 1]]"
  r: sqrt(dot(n, n))
channels:
  pt:
    components: [x, y]
    equations:
      - dot(n, p)
models:
  unit:
    constraints: [r**2 - 1, c]
    derived: [normal]
    alternatives: {free: ftest}
  free:
    constraints:
      - dot(n, n) - 1
    equations:
      pt:
        - cross(M @ p, n)[2]
derived:
  normal: n / r
  scaled: M @ n
"""


def test_definitions_are_substituted():
    fam = parse_spec(SPEC, "mat.yaml")
    a, b, c, x, y, k = (sp.Symbol(s, real=True) for s in "abcxyk")
    assert sp.expand(fam.channel("pt").equations[0] - (a * x + b * y + c * k)) == 0
    assert fam.model("unit").constraints[0] == a**2 + b**2 + c**2 - 1
    assert fam.model("unit").derived == ("normal",)
    assert fam.model("free").derived is None
    assert {d.name: d.shape for d in fam.derived} == {"normal": (3,), "scaled": (3,)}
    assert fam.model("unit").alternatives[0].phi == "ftest"


def test_per_model_derived_reaches_the_results():
    fam = kanagen.load(parse_spec(SPEC, "mat.yaml"))
    xy = np.array([[1.0, 0.0], [2.0, 0.1], [3.0, -0.1], [4.0, 0.05]])
    unit = kanagen.fit(fam, "unit", data={"pt": xy}, q0=[0.0, 1.0, 0.0])
    free = kanagen.fit(fam, "free", data={"pt": xy}, q0=unit.q)
    assert set(unit.derived) == {"normal"} and set(free.derived) == {"normal", "scaled"}
    np.testing.assert_allclose(unit.derived["normal"].value,
                               unit.q / np.linalg.norm(unit.q), atol=1e-12)


def _error(old: str, new: str) -> SpecError:
    assert old in SPEC
    with pytest.raises(SpecError) as info:
        parse_spec(SPEC.replace(old, new), "bad.yaml", initializers=INITIALIZERS)
    return info.value


@pytest.mark.parametrize(
    ("old", "new", "fragment"),
    [
        ("    constraints: [r**2 - 1, c]", "    constraints: [n @ transpose(p)]",
         "symbol 'x' (through a definition) is not available here"),
        ("  normal: n / r", "  normal: p", "not available here"),
        ("  r: sqrt(dot(n, n))", "  r: sqrt(n)", "sqrt needs a scalar"),
        ("  r: sqrt(dot(n, n))", "  r: sqrt(dot(n, q))", "unknown symbol 'q'"),
        ("  r: sqrt(dot(n, n))", "  n: a", "duplicate name 'n'"),
        ("    derived: [normal]", "    derived: [normale]", "unknown derived quantity"),
        ("    derived: [normal]", "    initializer: nope", "unknown initializer 'nope'"),
        ("    derived: [normal]", "    initializer: two_view_homography",
         "needs parameter 'f1'"),
        ("    derived: [normal]", "    initializer: two_view_rotation", "needs parameter 'f1'"),
        ("    derived: [normal]", "    initializer: two_view_translation",
         "needs parameter 'f1'"),
        ("parameter: {a: 1.0,", "parameter: {a: '[1.0]',", "expected a scalar"),
        ("{free: ftest}", "{free: 'ftest:'}", "cost factor"),
        ("{free: ftest}", "{free: 'ftest:2'}", "in (0, 1)"),
    ],
)
def test_matrix_spec_errors_name_file_and_line(old, new, fragment):
    err = _error(old, new)
    line = SPEC.splitlines().index(next(x for x in SPEC.splitlines() if old in x)) + 1
    assert fragment in err.message and err.line == line, str(err)


def test_initializer_names_are_data_handed_to_the_reader():
    """modelspec imports nothing of the runtime: the registry reaches the reader as data
    (kanagen.load and the command line hand it over); without it the names are unchecked
    there, and kanagen.load refuses an unknown one of a family built elsewhere."""
    import kanagen

    text = SPEC.replace("    derived: [normal]", "    initializer: nope")
    fam = parse_spec(text, "bad.yaml")  # no registry: not checked here
    with pytest.raises(SpecError, match="unknown initializer 'nope'"):
        kanagen.load(fam)
    with pytest.raises(SpecError, match="bad.yaml:.*unknown initializer 'nope'"):
        kanagen.load_text(text, "bad.yaml")
    fake = {"nope": type("Needs", (), {"missing": lambda self, **kw: "a miracle"})()}
    with pytest.raises(SpecError, match="'nope' needs a miracle"):
        parse_spec(text, "bad.yaml", initializers=fake)


def test_vector_equations_expand_to_their_entries():
    text = SPEC.replace("      - dot(n, p)", "      - cross(n, p)")
    fam = parse_spec(text, "mat.yaml")
    assert len(fam.channel("pt").equations) == 3
