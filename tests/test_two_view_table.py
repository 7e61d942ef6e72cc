"""experiments/two_view_table.py: a Fig. 16 row from matches."""

from __future__ import annotations

import numpy as np

from experiments import two_view_table
from kanagen.scenes import two_view_scene


def test_a_row_from_matches():
    s = two_view_scene("zoom", n=60, outliers=0.2, sigma=0.5, seed=3)
    row = two_view_table.table_row(s.data, s.constants, sigma=0.5)
    assert row["model"] == "zoom" and row["inliers"] >= 57 and row["matches"] == len(s.data)
    # a least-squares residual of the image points near the noise level; the general model
    # on the same inliers can only lower it
    assert 0.25 < row["residual"] < 0.6
    assert row["residual_general"] <= row["residual"] * (1 + 1e-6)
    assert abs(row["derived"]["zoom_factor"] - s.K2[0, 0] / s.K1[0, 0]) < 0.01
    text = two_view_table.format_table([("zoom", row)])
    assert text.splitlines()[1].split()[:2] == ["zoom", "zoom"]
    assert len(two_view_table.REPORT_FIG16) == 6 and np.isclose(
        two_view_table.REPORT_FIG16[0][2], 0.056)
