"""The projection of every measure (eq. 22) by one kernel per measure shape
(runtime/engine/measures.py: ``project_each``): the shipped shapes' kernels, their loops
unrolled, and the generic one for any other shape. Each measure is projected once, by its
own shape's kernel, whatever the order and the mix of its problem's channels, and to the
same numbers as in a problem of its channel alone."""

from __future__ import annotations

import numpy as np
import pytest

import kanagen
from kanagen.runtime import fit as fitting
from kanagen.runtime.engine import measures
from kanagen.runtime.engine.data import arrays

# two channels of the conics' shape (1 equation, 2 components), one of a scalar (1, 1) and
# one of three components (1, 3): two shipped shapes' kernel, two the generic one's
MIXED = """
name: mixed
parameter: {a: 1.0, s: 1.0}
channels:
  lvl:
    components: [h]
    equations: ["h - a"]
  pt:
    components: [x, y]
    equations: ["y - a*exp(-x**2/(2*s**2))"]
  tri:
    components: [u, w, z]
    equations: ["u*w - s*z"]
  pk:
    components: [x, y]
    equations: ["y - a*exp(-(x - 1)**2/(2*s**2))"]
models:
  m: {}
"""

Q = np.array([1.3, 0.7])


def _data(rng):
    return {"lvl": np.array([[1.1], [0.8]]),
            "pt": np.c_[rng.uniform(-2, 2, 5), rng.uniform(0, 1.2, 5)],
            "tri": rng.uniform(0.5, 2.0, (3, 3)),
            "pk": np.c_[rng.uniform(-1, 3, 4), rng.uniform(0, 1.2, 4)]}


def _project(fam, data, info, q, chosen=None):
    """``project_each`` on the problem of ``data``: ``(count, m̃, violations, ranks, A)``."""
    problem = fitting.make_problem(fam, "m", data, info, q, None, None)
    A = arrays(problem)
    c, C, D = measures.empty_evals(A, q.size)
    out = A.m.copy()
    viol, rank = np.zeros(A.chan.size), np.zeros(A.chan.size, dtype=np.int64)
    chosen = np.zeros(0, dtype=np.bool_) if chosen is None else chosen
    with np.errstate(all="ignore"):
        count = measures.project_each(A, q, out, measures.RESTORE_STEPS,
                                      measures.RESTORE_TOL, c, C, D, True, viol, rank,
                                      chosen, np.zeros(0, dtype=np.bool_))
    return int(count), out, viol, rank, A


@pytest.mark.parametrize("seed", range(3))
def test_each_measure_is_projected_once_as_in_its_channel_alone(seed):
    fam = kanagen.load_text(MIXED)
    rng = np.random.default_rng(seed)
    data = _data(rng)
    info = {"pt": np.diag(Q), "pk": 2.0, "tri": 0.5}
    q = np.array([1.0, 0.9])
    count, out, viol, rank, A = _project(fam, data, info, q)
    assert count == A.chan.size == 14
    assert np.all(rank == 1) and np.all(viol <= 1e-16)
    chosen = np.zeros(A.chan.size, dtype=np.bool_)
    chosen[[0, 3, 8, 13]] = True  # one measure of each channel
    assert _project(fam, data, info, q, chosen)[0] == 4
    # each channel alone: the same numbers, to the last bit
    for name in data:
        alone = {name: data[name]}
        _, out1, viol1, rank1, _ = _project(fam, alone, {k: v for k, v in info.items()
                                                         if k == name}, q)
        ch = list(data).index(name)
        rows = slice(int(A.start[ch]), int(A.start[ch] + A.size[ch]))
        d = int(A.Dn[ch])
        assert np.array_equal(out[rows, :d], out1[:, :d])
        assert np.array_equal(viol[rows], viol1) and np.array_equal(rank[rows], rank1)
