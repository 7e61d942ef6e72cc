"""Spec parsing: the whitelist, errors naming file and line, hostile input, the SymPy route."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
import sympy as sp

import kanagen
from kanagen.modelspec import SpecError, family_from_data, parse_expression, parse_spec

X, Y = sp.Symbol("x", real=True), sp.Symbol("y", real=True)

GOOD = """\
name: demo
constants: {f0: 2.0}
parameter: {a: 1.0, b: 0.0}
channels:
  pt:
    components: [x, y]
    equations:
      - y - a*x - b*f0
models:
  flat:
    constraints: [a]
    alternatives: {line: ftest}
  line:
    constraints: []
"""


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("2*x**2 - sqrt(x)", 2 * X**2 - sp.sqrt(X)),
        ("-x + +y", -X + Y),
        ("atan2(y, x) + abs(x)", sp.atan2(Y, X) + sp.Abs(X)),
        ("exp(-x/2) * cos(pi*y)", sp.exp(-X / 2) * sp.cos(sp.pi * Y)),
        ("1.5e-3 * x", sp.Float(1.5e-3) * X),
    ],
)
def test_expression_whitelist_accepts(text, expected):
    assert sp.simplify(parse_expression(text, {"x": X, "y": Y}) - expected) == 0


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("__import__('os').system('true')", "not allowed"),
        ("x.__class__", "Attribute not allowed"),
        ("eval('1')", "not allowed"),
        ("lambda: 1", "Lambda not allowed"),
        ("[x for x in y]", "not allowed"),
        ("x if y else 1", "IfExp not allowed"),
        ("x == y", "Compare not allowed"),
        ("x % 2", "Mod not allowed"),
        ("'text'", "not a number"),
        ("z + 1", "unknown symbol 'z'"),
        ("sqrt", "without a call"),
        ("sqrt(x, y)", "takes 1 argument"),
        ("sqrt(x=1)", "keyword"),
        ("x ** 1000", "exponent"),
        ("x +", "cannot parse"),
        ("x[0]", "Subscript not allowed"),
    ],
)
def test_expression_whitelist_rejects(text, fragment):
    with pytest.raises(SpecError, match=fragment):
        parse_expression(text, {"x": X, "y": Y}, "f.yaml", 3)


def test_good_spec_parses():
    fam = parse_spec(GOOD, "demo.yaml")
    assert fam.parameter_names == ("a", "b")
    assert fam.null_model == "flat"
    assert fam.model("flat").alternatives[0].model == "line"
    assert fam.channel("pt").corrected == ("x", "y")


def _error(text: str) -> SpecError:
    with pytest.raises(SpecError) as info:
        parse_spec(textwrap.dedent(text), "bad.yaml")
    return info.value


@pytest.mark.parametrize(
    ("old", "new", "line", "fragment"),
    [
        ("y - a*x - b*f0", "y - a*x - G", 8, "unknown symbol 'G'"),
        ("constraints: [a]", "constraints: [a + q]", 11, "unknown symbol 'q'"),
        ("{line: ftest}", "{curve: ftest}", 12, "unknown alternative 'curve'"),
        ("{line: ftest}", "{line: sometimes}", 12, "cost factor"),
        ("{line: ftest}", "{line: -1}", 12, "must be positive"),
        ("parameter: {a: 1.0, b: 0.0}", "parameter: {a: 1.0, x: 0.0}", 6, "duplicate name 'x'"),
        ("parameter: {a: 1.0, b: 0.0}", "parameter: {a: 1.0, b: yes}", 3, "real number"),
        ("parameter: {a: 1.0, b: 0.0}", "parameter: {a: 1.0, lambda: 0.0}", 3, "reserved"),
        ("parameter: {a: 1.0, b: 0.0}", "parameter: {a: 1.0, sqrt: 0.0}", 3, "reserved"),
        ("parameter: {a: 1.0, b: 0.0}", "parameter: {a: 1.0, b: 0.0, 'c d': 1}", 3,
         "not an identifier"),
        ("components: [x, y]", "components: x", 6, "must be a list"),
        ("    equations:\n", "    exact: [x, y]\n    equations:\n", 7, "no component to correct"),
        ("    equations:\n", "    exact: [z]\n    equations:\n", 7, "exact component 'z'"),
        ("name: demo", "name: demo\nextra: 1", 2, "unknown key 'extra'"),
        ("y - a*x - b*f0", "y - a*x/0", 8, "not finite"),
        ("name: demo", "name: demo\nunits: {a: px, zz: m}", 2, "'zz' is not a parameter"),
        ("name: demo", "name: demo\nunits: {a: '<b>px</b>'}", 2, "must be short text"),
        ("name: demo", "name: demo\nunits: {a: 3}", 2, "must be short text"),
        ("name: demo", "name: demo\nunits: [px]", 2, "units must be a mapping"),
        ("constants: {f0: 2.0}", "constants: {f0: {value: 2.0, assume: 'it is <b>'}}", 2,
         "assume must be short text"),
        ("constants: {f0: 2.0}", "constants: {f0: {assume: scale}}", 2, "missing its value"),
        ("constants: {f0: 2.0}", "constants: {f0: {value: 2.0, guess: x}}", 2,
         "unknown key 'guess'"),
    ],
)
def test_spec_errors_name_file_and_line(old, new, line, fragment):
    assert old in GOOD
    err = _error(GOOD.replace(old, new))
    assert fragment in err.message
    assert err.source == "bad.yaml"
    assert err.line == line, str(err)
    assert str(err).startswith(f"bad.yaml:{line}: ")


def test_a_constant_may_say_what_its_default_stands_for():
    fam = parse_spec(GOOD.replace("constants: {f0: 2.0}",
                                  "constants: {f0: {value: 2.0, assume: 'image width, px'}}"),
                     "assume.yaml")
    assert fam.constants == (("f0", 2.0),) and dict(fam.assumed) == {"f0": "image width, px"}


def test_units_are_text_beside_values():
    fam = parse_spec(GOOD.replace("name: demo", "name: demo\nunits: {a: 'm/s^2', x: µm, "
                                  "f0: '°C'}"), "units.yaml")
    assert dict(fam.units) == {"a": "m/s^2", "x": "µm", "f0": "°C"}
    assert parse_spec(GOOD, "plain.yaml").units == ()
    # a dimensionless component: an empty unit, or none given (``a:`` alone)
    for text in ("units: {a: '', x: px}", "units: {a: , x: px}"):
        fam = parse_spec(GOOD.replace("name: demo", "name: demo\n" + text), "units.yaml")
        assert dict(fam.units) == {"a": "", "x": "px"}


def test_duplicate_key_and_cycle():
    err = _error(GOOD.replace("  line:\n    constraints: []",
                              "  line:\n    constraints: []\n  line:\n    constraints: []"))
    assert "duplicate name 'line'" in err.message and err.line == 15
    err = _error(GOOD.replace("    constraints: []", "    constraints: []\n"
                              "    alternatives: [flat]"))
    assert "cycle in the model lattice" in err.message


@pytest.mark.parametrize(
    ("extra", "model", "fragment"),
    [
        ("  orphan:\n    constraints: [b]\n", "orphan", "no model names it"),
        ("  child:\n    constraints: []\n  orphan:\n    constraints: [b]\n"
         "    alternatives: [child]\n", "child", "parent(s) 'orphan' are not reached"),
    ],
    ids=["no edge", "edge from an unreached model"],
)
def test_a_model_no_edge_reaches_is_an_error(extra, model, fragment):
    """Issue 20: a model the lattice search never reaches from the null model is a spec
    error naming the model, file and line, not a model silently never tried."""
    err = _error(GOOD + extra)
    assert f"model {model!r} is never tried" in err.message and fragment in err.message
    assert "null model 'flat'" in err.message
    assert str(err).startswith("bad.yaml:15: ")
    # reached through an alternative: fine
    parse_spec(GOOD.replace("{line: ftest}", "{line: ftest, orphan: ftest}") + extra)
    # the search starts at the declared null model: from 'line', 'flat' is never tried
    err = _error(GOOD + "null_model: line\n")
    assert "model 'flat' is never tried" in err.message and err.line == 10


def test_yaml_tags_and_bad_yaml_rejected():
    assert "tag" in _error("name: !!python/object/apply:os.system ['true']\n").message
    assert "invalid YAML" in _error("name: [unclosed\n").message
    assert "empty spec" in _error("").message
    assert "missing required key 'models'" in _error(GOOD.split("models:")[0]).message


def test_hostile_spec_executes_nothing(tmp_path):
    marker = tmp_path / "pwned"
    hostile = GOOD.replace("y - a*x - b*f0", f"__import__('os').system('touch {marker}')")
    with pytest.raises(SpecError, match="not allowed"):
        parse_spec(hostile, "hostile.yaml")
    spec = tmp_path / "hostile.yaml"
    spec.write_text(hostile)
    out = subprocess.run([sys.executable, "-m", "kanagen", "build", str(spec), "-o",
                          str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert f"{spec}:8:" in out.stderr
    assert not marker.exists()
    assert not (tmp_path / "demo.py").exists()


def test_cli_reports_spec_error_without_traceback(tmp_path):
    spec = tmp_path / "bad.yaml"
    spec.write_text(GOOD.replace("b*f0", "G"))
    out = subprocess.run([sys.executable, "-m", "kanagen", "show", str(spec)],
                         capture_output=True, text=True)
    assert out.returncode == 2
    assert out.stderr.strip() == f"error: {spec}:8: unknown symbol 'G' in expression " \
                                 "'y - a*x - G'"


def test_family_from_sympy_matches_yaml():
    a, b, f0 = sp.symbols("a b f0")
    x, y = sp.symbols("x y")
    fam = family_from_data({
        "name": "demo",
        "constants": {f0: 2.0},
        "parameter": {a: 1.0, b: 0.0},
        "channels": {"pt": {"components": [x, y], "equations": [y - a * x - b * f0]}},
        "models": {"flat": {"constraints": [a], "alternatives": {"line": "ftest"}},
                   "line": {"constraints": []}},
    })
    ref = parse_spec(GOOD, "demo.yaml")
    assert fam.parameter == ref.parameter and fam.constants == ref.constants
    assert fam.channels == ref.channels
    assert [m.constraints for m in fam.models] == [m.constraints for m in ref.models]
    with pytest.raises(SpecError, match="not allowed"):
        family_from_data({"name": "f", "parameter": {a: 1.0}, "models": {"m": {}},
                          "channels": {"pt": {"components": [x],
                                              "equations": [sp.Heaviside(x) - a]}}})
    loaded = kanagen.load(fam)
    c, C, D = loaded.measurement("line", "pt", [2.0, 1.0], [[1.0, 5.0]])
    assert c[0, 0] == pytest.approx(5.0 - 2.0 - 2.0)
    assert C[0, 0].tolist() == [-1.0, -2.0] and D[0, 0].tolist() == [-2.0, 1.0]
