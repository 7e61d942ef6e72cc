"""kanagen report: one self-contained HTML page, checked in headless Chromium."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scenes import arc

from kanagen.cli import main
from kanagen.figures import CHOSEN, INLIER, OUTLIER
from kanagen.fitjob import FitOptions
from kanagen.resultsdb import ResultsDB, Row, encode

pytest.importorskip("matplotlib")

ROOT = Path(__file__).resolve().parents[1]
LATTICE = ROOT / "examples" / "conic_lattice.yaml"
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium"
                                        if Path("/usr/bin/chromium").exists() else None)

# A two-view family small enough for a test: matches (x, y) -> (x', y') of a rectified pair
# (one equation per match: the epipolar line y' = (1 + s) y + t), the null model "shift"
# (s = 0) under the general "scaled".
TWO_VIEW = """
name: rectified_views
parameter: {s: 0.0, t: 0.0}
channels:
  match:
    components: [x, y, xp, yp]
    equations: [yp - (1 + s)*y - t]
models:
  shift:
    constraints: [s]
    alternatives: {scaled: ftest}
  scaled:
    constraints: []
"""


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture
def conic_result(tmp_path):
    """A robust fit of a circular arc with outliers, as kanagen fit --json writes it."""
    xy, _ = arc("circle", 3, n=40)
    data = tmp_path / "arc.csv"
    np.savetxt(data, xy, delimiter=",", header="x,y", comments="", fmt="%.6f")
    out = tmp_path / "result.json"
    done = run("fit", LATTICE, data, "--scale", "4", "--max-samples", "60", "--json", out)
    assert done.exit_code == 0, done.output
    return out, data


@pytest.fixture
def two_view_result(tmp_path):
    """Matches between two textured images shifted by (12, -5) px, a quarter of them wrong;
    the images as PNG files."""
    import matplotlib.image

    rng = np.random.default_rng(7)
    texture = rng.uniform(0, 1, (140, 200))
    first, second = texture[10:130, 20:190], texture[15:135, 8:178]  # second = first moved
    for name, img in (("first.png", first), ("second.png", second)):
        matplotlib.image.imsave(tmp_path / name, img, cmap="gray")
    p = rng.uniform([0, 0], [170, 120], (60, 2))
    q = p + [12.0, -5.0] + rng.normal(0, 0.3, p.shape)
    q[:15] = rng.uniform([0, 0], [170, 120], (15, 2))
    data = tmp_path / "matches.csv"
    np.savetxt(data, np.c_[p, q], delimiter=",", header="x,y,xp,yp", comments="", fmt="%.4f")
    spec = tmp_path / "rectified_views.yaml"
    spec.write_text(TWO_VIEW)
    out = tmp_path / "matches.json"
    done = run("fit", spec, data, "--sigma", "0.3", "--scale", "4", "--max-samples", "60",
               "--json", out)
    assert done.exit_code == 0, done.output
    assert json.loads(out.read_text())["model"] == "shift"  # y' = y - 5
    return out, data, (tmp_path / "first.png", tmp_path / "second.png")


def figures_of(html: str) -> list[str]:
    return re.findall(r'data-figure="([a-z]+)"', html)


def test_report_of_a_robust_fit_has_every_figure(conic_result, tmp_path):
    result, data = conic_result
    page = tmp_path / "report.html"
    done = run("report", result, "-o", page)
    assert done.exit_code == 0, done.output
    html = page.read_text()
    assert figures_of(html) == ["histogram", "relevance", "lattice", "residuals", "measures"]
    assert html.count("<svg") == 5 and "<?xml" not in html
    # self-contained: no external resource of any kind
    assert not re.search(r'(src|href)="(?!#|data:)', html)
    assert not re.search(r'(?<!xmlns=")(?<!xmlns:xlink=")https?://', html)
    rec = json.loads(result.read_text())
    assert f"Chosen model: <span class=\"chosen\">{rec['model']}</span>" in html
    assert "threshold" in html and "Φ" in html
    assert rec["false_alarms"] < 1 and "More than chance: " in html  # its NFA, said
    rec["false_alarms"] = 12.0  # a record whose model chance explains: a warning
    result.write_text(json.dumps(rec))
    assert run("report", result, "-o", page).exit_code == 0
    assert '<p class="warn">NOT more than chance: 12 false alarms' in page.read_text()
    # an arc of a circle: B and the other models' slacks (appendix F) are pinned, no estimates
    assert rec["model"] == "circle"
    assert rec["pinned"] == {"B": 0.0, "s_ellipse": 1.0, "s_proper": 1.0}
    assert "Pinned by the model circle (not estimated): B = 0." in html
    assert "<td>s_ellipse</td>" not in html and "<td>B</td>" not in html
    # the ids of the figures never collide
    ids = re.findall(r' id="([^"]+)"', html)
    assert len(ids) == len(set(ids))


def test_report_of_a_batch_dataset_and_bad_requests(conic_result, tmp_path):
    result, data = conic_result
    rec = json.loads(result.read_text())
    db = tmp_path / "r.sqlite"
    with ResultsDB(db) as store:
        key = FitOptions(scale=4, max_samples=60).key("point")
        store.write(Row(str(data), rec["spec_sha256"], key, rec["family"], "point", "ok",
                        encode(rec), rec["stop_reason"], 0.5))
        store.write(Row("broken.csv", rec["spec_sha256"], key, rec["family"], "point", "error",
                        encode(None), "broken.csv: not a row of numbers"))
    page = tmp_path / "from_db.html"
    done = run("report", "--db", db, "--dataset", data, "-o", page)
    assert done.exit_code == 0, done.output
    html = page.read_text()
    assert "batch status <b>ok</b>" in html and len(figures_of(html)) == 5
    for args, message in (
            (("--db", db, "--dataset", "nowhere.csv"), "no dataset 'nowhere.csv'; it has"),
            (("--db", db, "--dataset", "broken.csv"), "failed: broken.csv: not a row"),
            (("--db", db), "--db needs --dataset"),
            ((result, "--db", db, "--dataset", data), "not both"),
            ((result, "--images", data, data), "images need two-view matches"),
            ((data,), "not JSON")):
        done = run("report", *args, "-o", tmp_path / "x.html")
        assert done.exit_code == 2 and message in done.output, done.output
        assert "Traceback" not in done.output


def test_report_of_a_local_fit(tmp_path):
    out = tmp_path / "local.json"
    done = run("fit", ROOT / "examples/conic.yaml", ROOT / "examples/data/ellipse_arc.csv",
               "--model", "conic", "--local", "--json", out)
    assert done.exit_code == 0, done.output
    rec = json.loads(out.read_text())
    assert rec["local"] and len(rec["errors"]) == len(rec["measures"]["point"])
    page = tmp_path / "local.html"
    assert run("report", out, "-o", page).exit_code == 0
    assert figures_of(page.read_text()) == ["histogram", "residuals", "measures"]


def test_two_view_report_draws_the_matches(two_view_result, tmp_path):
    result, data, images = two_view_result
    page = tmp_path / "views.html"
    done = run("report", result, "--images", *images, "-o", page)
    assert done.exit_code == 0, done.output
    html = page.read_text()
    assert figures_of(html) == ["histogram", "relevance", "lattice", "residuals", "matches"]
    assert "data:image/png;base64," in html  # the images inside the page
    assert run("report", result, "-o", page).exit_code == 0
    # without images: a neutral hint, nothing styled as an error
    assert '<p class="hint">Two-view matches: give the two images (--images' in \
        page.read_text()
    assert 'class="warn"' not in page.read_text()
    # without the data file: said on the page, no traceback
    moved = data.rename(tmp_path / "elsewhere.csv")
    done = run("report", result, "--images", *images, "-o", page)
    assert done.exit_code == 0 and "Matches not drawn" in page.read_text()
    done = run("report", result, "--images", *images, "--data", moved, "-o", page)
    assert "matches" in figures_of(page.read_text())


def chromium(*args: str, profile: Path) -> subprocess.CompletedProcess:
    command = [CHROMIUM, "--headless", "--disable-gpu", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", "--no-first-run",
               "--disable-extensions", f"--user-data-dir={profile}", *args]
    if os.geteuid() == 0:
        command.insert(2, "--no-sandbox")  # Chromium refuses root with its sandbox
    return subprocess.run(command, capture_output=True, text=True, timeout=180)


# Appended to a copy of the page: lay out each figure and write its size and drawn elements
# into the DOM, which --dump-dom then shows.
PROBE = """<script>
document.body.dataset.rendered = JSON.stringify(
  [...document.querySelectorAll("figure.kanagen-figure")].map(f => {
    const svg = f.querySelector("svg"), box = svg.getBoundingClientRect();
    return [f.dataset.figure, Math.round(box.width), Math.round(box.height),
            svg.querySelectorAll("path, use, image").length];
  }));
</script>"""


def rendered_figures(page: Path, tmp_path: Path) -> list:
    """``[figure, width, height, elements drawn]`` of each figure of ``page`` as headless
    Chromium lays it out (:data:`PROBE`)."""
    probe = tmp_path / "probe.html"
    probe.write_text(page.read_text().replace("</body>", PROBE + "</body>"))
    dom = chromium("--virtual-time-budget=2000", "--dump-dom", probe.as_uri(),
                   profile=tmp_path / "profile1")
    assert dom.returncode == 0, dom.stderr[-2000:]
    found = re.search(r'data-rendered="([^"]*)"', dom.stdout)
    assert found, dom.stdout[:2000]
    return json.loads(found.group(1).replace("&quot;", '"'))


@pytest.mark.parametrize("kind", ["conic", "two_view"])
def test_report_renders_in_headless_chromium(kind, request, tmp_path):
    if CHROMIUM is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing: .ci/run installs it (apt-get install chromium)")
        pytest.skip("chromium not installed (apt-get install chromium)")
    import matplotlib.image

    if kind == "conic":
        result, _ = request.getfixturevalue("conic_result")
        extra, expected = [], "measures"
    else:
        result, _, images = request.getfixturevalue("two_view_result")
        extra, expected = ["--images", *images], "matches"
    page = tmp_path / "page.html"
    assert run("report", result, *extra, "-o", page).exit_code == 0
    probe = tmp_path / "probe.html"
    rendered = rendered_figures(page, tmp_path)
    assert [r[0] for r in rendered] == ["histogram", "relevance", "lattice", "residuals",
                                        expected]
    for name, width, height, drawn in rendered:
        assert width > 200 and height > 100 and drawn > 10, (name, width, height, drawn)
    shot = tmp_path / "page.png"
    done = chromium("--window-size=1200,6000", "--hide-scrollbars", f"--screenshot={shot}",
                    page.as_uri(), profile=tmp_path / "profile2")
    assert done.returncode == 0 and shot.exists(), done.stderr[-2000:]
    pixels = matplotlib.image.imread(shot)[..., :3]

    def count(colour: str) -> int:
        rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255
        return int(np.count_nonzero(np.abs(pixels - rgb).max(axis=-1) < 10 / 255))

    # the figures are drawn: inliers, outliers and the threshold, the chosen model's box
    assert count(INLIER) > 500 and count(OUTLIER) > 200 and count(CHOSEN) > 100
    if kind == "two_view":  # without the images: no text styled as an error on the page
        assert run("report", result, "-o", page).exit_code == 0
        probe.write_text(page.read_text().replace("</body>", RED_TEXT + "</body>"))
        dom = chromium("--virtual-time-budget=2000", "--dump-dom", probe.as_uri(),
                       profile=tmp_path / "profile3")
        found = re.search(r'data-red-text="([^"]*)"', dom.stdout)
        assert found and found.group(1) == "0", (found and found.group(1), dom.stderr[-500:])


# Counts the page's text paragraphs and spans drawn in red (an error's style).
RED_TEXT = """<script>
document.body.dataset.redText = [...document.querySelectorAll("p, span, li, td")].filter(
  e => e.textContent.trim() && getComputedStyle(e).color === "rgb(214, 39, 40)").length;
</script>"""


def test_lattice_rows_are_longest_paths_from_the_null_model():
    import doctest

    import kanagen.figures as figures

    assert doctest.testmod(figures).failed == 0
    edges = [["none", m] for m in ("zoom", "rotation", "translation")] + \
        [["zoom", "planar"], ["rotation", "planar"], ["translation", "general"],
         ["planar", "general"]]
    assert figures.lattice_levels(edges, ["none", "zoom"], "none") == {
        "none": 0, "zoom": 1, "rotation": 1, "translation": 1, "planar": 2, "general": 3}
    assert figures.lattice_levels([], ["circle"], "line") == {"line": 0, "circle": 1}


def _curve_of(html: str) -> str:
    """The SVG group of the fitted curve in the measures figure ('' if none)."""
    match = re.search(r'<g id="measures-fitted-curve">(.*?)</g>', html, flags=re.S)
    return match.group(1) if match else ""


def test_measures_of_a_conic_fit_show_the_fitted_curve(conic_result, tmp_path):
    """A conic result's measures figure draws its zero set ``[x y 1] M [x y 1]ᵀ = 0`` (the
    derived ``matrix``); a record without a conic matrix draws the measures alone."""
    from kanagen.report import render_report

    result, data = conic_result
    page = tmp_path / "report.html"
    assert run("report", result, "-o", page).exit_code == 0
    curve = _curve_of(page.read_text())
    assert "<path" in curve and CHOSEN in curve and len(curve) > 2000  # a curve, not a dot
    assert "the fitted curve in green" in page.read_text()

    rec = json.loads(result.read_text())
    xy = np.loadtxt(data, delimiter=",", skiprows=1)
    assert _curve_of(render_report(rec, measures=xy))
    derived = {k: v for k, v in rec["derived"].items() if k != "matrix"}
    for broken in ({}, {"matrix": {"value": [[1.0, 2.0], [3.0, 4.0]], "std": np.eye(2)}},
                   {"matrix": {"value": np.eye(3, k=1), "std": np.eye(3)}},
                   {"matrix": {"value": [[None] * 3] * 3, "std": np.eye(3)}}):
        html = render_report({**rec, "derived": {**derived, **broken}}, measures=xy)
        assert "measures" in figures_of(html) and not _curve_of(html)


def test_conic_curve_lies_on_the_conic():
    from kanagen.figures import conic_curve

    # the ellipse of benchmarks/conic_odr.py: centre (330, 250), semi-axes 220/130, 25°
    c, s = np.cos(np.radians(25.0)), np.sin(np.radians(25.0))
    R = np.array([[c, -s], [s, c]])
    Q = R @ np.diag([220.0**-2, 130.0**-2]) @ R.T
    z = np.array([330.0, 250.0])
    M = np.block([[Q, -(Q @ z)[:, None]], [-(Q @ z)[None, :], np.array([[z @ Q @ z - 1.0]])]])
    pts = conic_curve(-3.0 * M, (0.0, 640.0), (0.0, 480.0))  # scale and sign do not matter
    assert np.count_nonzero(np.isnan(pts[:, 0])) == 0  # one closed piece
    d = pts - z
    assert np.allclose(np.einsum("ki,ij,kj->k", d, Q, d), 1.0, atol=1e-3)
    angles = np.arctan2(*(d @ R)[:, ::-1].T)
    assert np.ptp(angles) > 6.0  # all the way round
    # the part of it inside a smaller box: pieces separated by NaN rows
    pts = conic_curve(M, (200.0, 400.0), (0.0, 480.0))
    assert np.count_nonzero(np.isnan(pts[:, 0])) == 1
    ok = pts[np.isfinite(pts[:, 0])]
    assert ok[:, 0].min() >= 200.0 and ok[:, 0].max() <= 400.0
    # a line (A = B = C = 0): y = 100; a conic away from the box: nothing
    line = conic_curve([[0, 0, 0], [0, 0, 0.5], [0, 0.5, -100]], (0.0, 50.0), (0.0, 200.0))
    assert np.allclose(line[:, 1], 100.0) and np.ptp(line[:, 0]) > 49.0
    assert conic_curve(M, (2000.0, 3000.0), (0.0, 480.0)).shape == (0, 2)


def test_report_shows_units_and_not_the_pinned_components(tmp_path):
    """Units beside the values; what the model pins (a circle's B = 0, the other models'
    slacks) is said once, not listed as an estimate (issue 20)."""
    xy, _ = arc("circle", 2, n=50, outliers=0.0)
    data = tmp_path / "circle.csv"
    np.savetxt(data, xy, delimiter=",", header="x,y", comments="", fmt="%.6f")
    out = tmp_path / "circle.json"
    done = run("fit", LATTICE, data, "--model", "circle", "--local", "--json", out)
    assert done.exit_code == 0, done.output
    rec = json.loads(out.read_text())
    assert rec["pinned"] == {"B": 0.0, "s_ellipse": 1.0, "s_proper": 1.0}
    assert rec["units"]["radius"] == "px" and rec["units"]["angle"] == "deg"
    page = tmp_path / "circle.html"
    assert run("report", out, "-o", page).exit_code == 0
    html = page.read_text()
    table = html[html.index("<h2>Estimate</h2>"):]
    table = table[:table.index("</table>")]
    rows = re.findall(r"<tr><td>([^<]+)</td><td class=\"num\">[^<]*</td>"
                      r"<td class=\"num\">[^<]*</td><td>([^<]*)</td></tr>", table)
    names = [name for name, _ in rows]
    assert names[:5] == ["A", "C", "D", "E", "F"]
    assert "B" not in names and "s_ellipse" not in names and "s_proper" not in names
    assert dict(rows)["radius"] == "px" and dict(rows)["centre[0]"] == "px"
    assert "Pinned by the model circle (not estimated): B = 0." in html
