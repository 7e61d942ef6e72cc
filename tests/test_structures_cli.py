"""`kanagen structures`: find_structures from the command line — the same structures as the
Python call with the same options, every measure's label, exit 1 when none is more than
chance, bad input exits 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_structures import crossing_lines

import kanagen
from kanagen.cli import main

ROOT = Path(__file__).resolve().parents[1]
LINE = ROOT / "examples" / "line.yaml"


def invoke(*args):
    return CliRunner().invoke(main, ["structures", *map(str, args)], catch_exceptions=False)


@pytest.fixture(scope="module")
def lines_csv(tmp_path_factory):
    xy, labels = crossing_lines(0)
    path = tmp_path_factory.mktemp("structures") / "lines.csv"
    sd = np.full(len(xy), 0.5)
    np.savetxt(path, np.c_[xy, sd], delimiter=",", header="x,y,sd", comments="")
    return path, xy, labels


def test_two_lines_as_the_python_call_finds_them(lines_csv):
    path, xy, labels = lines_csv
    out = invoke(LINE, path, "--sigma", "0.5", "--seed", 3, "--json", "-")
    assert out.exit_code == 0, out.output
    record = json.loads(out.stdout)
    assert "2 structure(s) more than chance" in out.stderr
    found = kanagen.find_structures(kanagen.load(LINE), data={"point": xy},
                                    info={"point": 4.0}, seed=3)
    assert len(record["structures"]) == len(found) == 2
    for entry, state in zip(record["structures"], found, strict=True):
        assert entry["model"] == state.model and entry["inliers"] == state.inliers.tolist()
        np.testing.assert_array_equal(list(entry["params"].values()),
                                      list(state.params.values()))
        assert entry["false_alarms"] == pytest.approx(state.false_alarms, rel=1e-12)
        assert entry["false_alarms"] < 1e-10
    got = np.array(record["labels"])
    for k, entry in enumerate(record["structures"]):
        assert np.all(got[entry["inliers"]] == k)
    assert np.count_nonzero(got == -1) == len(xy) - sum(len(e["inliers"])
                                                       for e in record["structures"])
    # each found structure is mostly one true line (labels 1 and 2; 0 = outliers)
    assert sorted(np.bincount(labels[got == k]).argmax() for k in range(2)) == [1, 2]


def test_sigma_from_a_column_is_the_same_as_the_number(lines_csv):
    path, _, _ = lines_csv
    by_number = json.loads(invoke(LINE, path, "--sigma", "0.5", "--json", "-").stdout)
    by_column = json.loads(invoke(LINE, path, "--sigma", "x=sd,y=sd", "--json", "-").stdout)
    assert [s["params"] for s in by_number["structures"]] == \
        [s["params"] for s in by_column["structures"]]


def test_no_structure_in_uniform_points_exits_1(tmp_path):
    path = tmp_path / "noise.csv"
    noise = np.random.default_rng(2).uniform([-50, -20], [50, 20], (100, 2))
    np.savetxt(path, noise, delimiter=",", header="x,y", comments="")
    out = invoke(LINE, path, "--json", tmp_path / "out.json")
    assert out.exit_code == 1
    assert "0 structure(s) more than chance (at most 5), 100 outlier(s)" in out.output
    record = json.loads((tmp_path / "out.json").read_text())
    assert record["structures"] == [] and set(record["labels"]) == {-1}


@pytest.mark.parametrize("args, message", [
    (("--max-structures", 0), "max-structures"),
    (("--model", "parabola"), "parabola"),
    (("--sigma", "-1"), "sigma"),
    (("--const", "nope=1"), "nope"),
])
def test_bad_input_exits_2(lines_csv, args, message):
    path, _, _ = lines_csv
    out = invoke(LINE, path, *args)
    assert out.exit_code == 2 and message in out.output


def test_report_of_structures_draws_them(lines_csv, tmp_path):
    """`kanagen report` of a structures record: each structure's section (model, inliers,
    NFA, estimate) and the measures coloured by structure; without the data, a note."""
    import re

    path, xy, _ = lines_csv
    result = tmp_path / "found.json"
    assert invoke(LINE, path, "--sigma", "0.5", "--json", result).exit_code == 0
    record = json.loads(result.read_text())
    page = tmp_path / "found.html"
    done = CliRunner().invoke(main, ["report", str(result), "-o", str(page)])
    assert done.exit_code == 0, done.output
    html = page.read_text()
    assert re.findall(r'data-figure="([a-z]+)"', html) == ["structures"]
    assert "2 structure(s) more than chance (at most 5)" in html
    outliers = len(xy) - sum(len(s["inliers"]) for s in record["structures"])
    assert f"; {outliers} outlier(s)." in html
    for k, s in enumerate(record["structures"]):
        assert f"Structure {k}: line" in html and f"{len(s['inliers'])} inliers" in html
        assert f"structure {k} ({len(s['inliers'])})" in html  # its legend in the figure
    assert "<h2>Estimate</h2>" not in html and "Chosen model" not in html
    record["data"], record["data_sha256"] = "elsewhere.csv", "0" * 64
    result.write_text(json.dumps(record))
    assert CliRunner().invoke(main, ["report", str(result), "-o", str(page)]).exit_code == 0
    assert "Measures not drawn" in page.read_text()


def test_structures_page_renders_in_headless_chromium(lines_csv, tmp_path):
    import os

    from test_report import CHROMIUM, rendered_figures

    if CHROMIUM is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing: .ci/run installs it (apt-get install chromium)")
        pytest.skip("chromium not installed (apt-get install chromium)")
    path, _, _ = lines_csv
    result, page = tmp_path / "found.json", tmp_path / "found.html"
    assert invoke(LINE, path, "--sigma", "0.5", "--json", result).exit_code == 0
    assert CliRunner().invoke(main, ["report", str(result), "-o", str(page)]).exit_code == 0
    (name, width, height, drawn), = rendered_figures(page, tmp_path)
    assert name == "structures" and width > 200 and height > 100 and drawn > 10


def test_constants_repeated_or_comma_separated():
    from kanagen.cli import _parse_constants

    assert _parse_constants(("cx=320,cy=240", "f0=640")) == {"cx": 320.0, "cy": 240.0,
                                                              "f0": 640.0}
