"""Messages people read (issue 20 item 4): each mistake is named with what to write instead."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import kanagen
from kanagen.dataio import DataError, read_measures
from kanagen.modelspec import SpecError, parse_expression, parse_spec

ROOT = Path(__file__).resolve().parents[1]
LINE = ROOT / "examples" / "line.yaml"
SYMBOLS = {"x": sp.Symbol("x"), "y": sp.Symbol("y")}

SPEC = """\
name: demo
parameter: {a: 1.0, b: 0.0}
channels:
  pt:
    components: [x, y]
    equations:
      - y - a*x - b
models:
  flat:
    constraints: [a]
    alternatives: {line: ftest}
  line:
    constraints: []
derived:
  slope: a
  angle: atan(slope)
"""


@pytest.fixture(scope="module")
def fam():
    return kanagen.load(str(LINE))


def test_a_bare_array_as_data_names_the_channels(fam):
    channel, ch = next(iter(fam.channels.items()))
    X = np.zeros((5, len(ch.components)))
    with pytest.raises(ValueError) as err:
        kanagen.fit(fam, data=X)
    message = str(err.value)
    assert "truth value" not in message
    assert f"data={{{channel!r}: array}}" in message and str(list(ch.components)) in message
    assert "shape (5, 2)" in message


def test_measures_passed_as_the_model_say_where_they_go(fam):
    channel, ch = next(iter(fam.channels.items()))
    with pytest.raises(ValueError) as err:
        kanagen.fit(fam, np.zeros((5, len(ch.components))))
    message = str(err.value)
    assert "truth value" not in message and "model must be a model name" in message
    assert f"data={{{channel!r}: array}}" in message


def test_caret_suggests_double_star():
    with pytest.raises(SpecError, match=r"'\^' is not allowed.*write '\*\*'"):
        parse_expression("x^2 + y", SYMBOLS)
    err = _spec_error(SPEC.replace("[a]", "[a^2]"))
    assert "'**'" in err.message and err.line == 10


@pytest.mark.parametrize(("text", "name"), [("np.hypot(x, y)", "np.hypot"),
                                            ("math.sqrt(x)", "math.sqrt"),
                                            ("f(x)(y)", "f(x)")])
def test_a_disallowed_call_names_the_function(text, name):
    with pytest.raises(SpecError) as err:
        parse_expression(text, SYMBOLS)
    assert f"call to {name!r} not allowed" in err.value.message
    assert "Attribute(" not in err.value.message and "Name(" not in err.value.message
    if name == "math.sqrt":
        assert "write sqrt(...)" in err.value.message


def test_a_derived_quantity_using_another_points_to_define():
    err = _spec_error(SPEC)
    assert "derived quantity 'angle' uses the derived quantity 'slope'" in err.message
    assert "define:" in err.message and err.line == 16
    fixed = SPEC.replace("derived:", "define:\n  tilt: a\nderived:").replace(
        "slope: a", "slope: tilt").replace("atan(slope)", "atan(tilt)")
    assert [d.name for d in parse_spec(fixed).derived] == ["slope", "angle"]
    # an unknown name that is no derived quantity keeps its plain message
    assert "unknown symbol 'nope'" in _spec_error(SPEC.replace("atan(slope)", "nope")).message


def test_a_csv_header_differing_in_case_says_so(tmp_path):
    path = tmp_path / "upper.csv"
    path.write_text("X,y\n1,2\n3,4\n")
    with pytest.raises(DataError, match=r"lacks component\(s\) \['x'\].*case-sensitive.*'X' "
                                        r"for 'x'"):
        read_measures(path, ("x", "y"), "point")
    path.write_text("a,b\n1,2\n")
    with pytest.raises(DataError) as err:
        read_measures(path, ("x", "y"), "point")
    assert "case" not in str(err.value)


def test_a_csv_without_header_is_data_when_its_columns_match(tmp_path):
    path = tmp_path / "bare.csv"
    path.write_text("1,2\n3,4\n5.5,-6e1\n")
    np.testing.assert_array_equal(read_measures(path, ("x", "y"), "point"),
                                  [[1, 2], [3, 4], [5.5, -60]])
    path.write_text("1,2,3\n4,5,6\n")
    with pytest.raises(DataError, match=r"bare.csv:1: no header .* 3 column\(s\), not the 2 "
                                        r".*add a header line .*x,y"):
        read_measures(path, ("x", "y"), "point")
    path.write_text("1,2\n3,x\n")
    with pytest.raises(DataError, match=r"bare.csv:2: not a row of numbers"):
        read_measures(path, ("x", "y"), "point")


def _spec_error(text: str) -> SpecError:
    with pytest.raises(SpecError) as info:
        parse_spec(text, "bad.yaml")
    return info.value
