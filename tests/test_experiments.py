"""The report's appendix-B Φ table and κ fit, and its §4 Stewart simulation (``experiments/``)."""

from __future__ import annotations

import functools
import math
import re

import numpy as np
import pytest

from experiments import phi_table, stewart


def test_phi_table_matches_report_p05():
    """Every printed entry is ours to 0.01; the report truncates to two decimals."""
    ours = phi_table.table(0.5)
    assert [len(row) for row in ours] == [len(row) for row in phi_table.REPORT_TABLE_P05]
    for row, rep in zip(ours, phi_table.REPORT_TABLE_P05, strict=True):
        for v, r in zip(row, rep, strict=True):
            assert abs(v - r) < 0.01
    assert phi_table.truncation_mismatches() == []
    # the first entries, where truncation and rounding agree
    assert ours[0][:3] == pytest.approx([0.25, 0.14, 0.09], abs=0.005)
    assert ours[1][0] == pytest.approx(0.38, abs=0.005)


def test_phi_table_layout():
    """Row d holds d' = d+1..8; Φ(d, 2d) = 1/4 at P = 0.5 (the F(d, d) median is 1)."""
    rows = phi_table.table(0.9)
    assert [len(r) for r in rows] == list(range(7, 0, -1))
    assert all(0.0 < v < 1.0 for r in rows for v in r)
    half = phi_table.table(0.5)
    for d in range(1, 5):
        assert half[d - 1][d - 1] == pytest.approx(0.25, abs=1e-9)
    text = phi_table.format_table(half)
    assert text.splitlines()[1].split()[1:4] == ["0.250", "0.143", "0.091"]


def test_p2k_index_set():
    pairs = phi_table.p2k_pairs()
    assert len(pairs) == 24 and pairs[0] == (1, 2) and pairs[-1] == (8, 11)
    assert phi_table.P2K_DIVISOR == 16


@functools.cache
def _fits() -> dict[float, dict[str, float]]:
    return {p: phi_table.fit_kappa(p) for p in (0.5, 0.9)}


def test_kappa_fits_finite_and_minimal():
    for p, fit in _fits().items():
        lo, hi = phi_table.KAPPA_BOUNDS
        assert math.isfinite(fit["kappa"]) and lo <= fit["kappa"] <= hi
        assert fit["error"] == pytest.approx(math.sqrt(fit["sum_of_squares"]) / 16)
        for dk in (-0.05, 0.05):
            k = min(max(fit["kappa"] + dk, lo), hi)
            assert phi_table.sum_of_squares(k, p) >= fit["sum_of_squares"] - 1e-12
    # Φ falls as P rises, so the fitted κ rises with P
    assert _fits()[0.9]["kappa"] > _fits()[0.5]["kappa"]


def test_kappa_printed(capsys):
    assert phi_table.main() == 0
    out = capsys.readouterr().out
    for p, fit in _fits().items():
        line = re.search(rf"^\s*{p:.1f}\s+(\S+)\s+(\S+)\s+\S+\s+(\S+)", out, re.M)
        assert line is not None, f"no κ line for P = {p}"
        assert float(line.group(1)) == pytest.approx(fit["kappa"], abs=1e-3)
        assert float(line.group(2)) == phi_table.REPORT_KAPPA[p]
        assert float(line.group(3)) == pytest.approx(fit["error"], abs=1e-5)


@functools.cache
def _stewart() -> tuple[dict[str, float], ...]:
    return tuple(stewart.simulate())


def test_stewart_table_shape():
    rows = _stewart()
    assert len(rows) == len(stewart.SETTINGS) == 10
    assert sum(r["bimodal"] for r in rows) == 6
    for r in rows:
        for name in stewart.SCORER_NAMES:
            assert np.isfinite(r[f"bias_{name}"]) and np.isfinite(r[f"mae_{name}"])
            assert abs(r[f"bias_{name}"]) <= r[f"mae_{name}"] + 1e-12
            assert r[f"report_{name}"] in stewart.REPORT_BIAS[name]
    # with the second population 2σ away and holding 40 % of the inliers, every scorer drifts
    # towards it (the report: "all bias are positive")
    assert all(rows[-1][f"bias_{name}"] > 0.5 for name in stewart.SCORER_NAMES)


def test_stewart_relevance_not_worse_than_ransac():
    rows = _stewart()
    r = stewart.mean_abs_bias(rows, "relevance", bimodal_only=True)
    a = stewart.mean_abs_bias(rows, "ransac", bimodal_only=True)
    assert r <= a, f"relevance mean |bias| {r:.3f} > ransac-like {a:.3f} on bimodal settings"


def test_stewart_deterministic_per_setting():
    """A row depends on the seed and its setting only, not on the others run with it."""
    one = stewart.simulate(settings=stewart.SETTINGS[-1:], reps=5, n=200)
    both = stewart.simulate(settings=stewart.SETTINGS[-2:], reps=5, n=200)
    assert one[0] == both[1]


def test_perf_map_names_the_kernels_a_run_used(tmp_path):
    """``experiments/perf_map.py`` runs a script and leaves ``perf``'s map of numba's
    compiled kernels: the engine's functions, at distinct addresses, with their sizes."""
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "fit.py"
    script.write_text(
        "import numpy as np, kanagen\n"
        "t = np.linspace(0.0, 6.0, 30)\n"
        "xy = np.c_[3 * np.cos(t), 2 * np.sin(t)]\n"
        "print(kanagen.fit(kanagen.load('conic'), 'conic', data={'point': xy}).success)\n")
    tool = Path(__file__).resolve().parents[1] / "experiments" / "perf_map.py"
    run = subprocess.run([sys.executable, str(tool), str(script)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "True"
    found = re.search(r"perf map: (\S+) \((\d+) functions\)", run.stderr)
    assert found and int(found.group(2)) > 10
    path = Path(found.group(1))
    try:
        rows = [line.split(" ", 2) for line in path.read_text().splitlines()]
    finally:
        path.unlink()
    addresses = [int(a, 16) for a, _, _ in rows]
    assert addresses == sorted(set(addresses))
    assert all(int(size, 16) > 0 for _, size, _ in rows)
    assert any("kanagen" in name and "run_flat" in name for *_, name in rows)


def test_two_view_parts_times_the_fits_by_role_and_the_samples_by_size():
    """``experiments/two_view_parts.py`` on one scene: the fits the refinement asked for,
    by role (LO-RANSAC's refinement among them), and the samples of the search."""
    from experiments import two_view_parts

    total, fits, bursts = two_view_parts.measure(1)
    assert total > 0.0
    assert "refined" in fits and all(calls > 0 and seconds > 0.0
                                     for calls, seconds, _ in fits.values())
    assert bursts and all(samples >= none for samples, none, _ in bursts.values())
    text = two_view_parts.report(1, total, fits, bursts)
    assert "refined" in text and "samples (n, k)" in text and "% of the search" in text
