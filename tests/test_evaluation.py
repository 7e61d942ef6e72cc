"""The misclassification metric (best matching) and the two-view geometric errors, against
independent references: brute force over every matching, and closed forms."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kanagen.evaluation import (
    labels_from_structures,
    misclassification,
    sampson_errors,
    transfer_errors,
)


def brute_force(labels, assigned) -> float:
    """Every one-to-one map of found structures to labelled ones (or to nothing); outliers
    stay outliers; the least error wins."""
    labels, assigned = np.asarray(labels), np.asarray(assigned)
    true = sorted(set(labels[labels > 0].tolist()))
    found = sorted(set(assigned[assigned > 0].tolist()))
    slots = true + [None] * len(found)  # None: the found structure has no partner
    best = 1.0
    for image in itertools.permutations(slots, len(found)):
        mapping = {0: 0, **{f: (t if t is not None else -1)
                            for f, t in zip(found, image, strict=True)}}
        mapped = np.array([mapping[a] for a in assigned.tolist()])
        best = min(best, float(np.mean(mapped != labels)))
    return best


classes = st.lists(st.integers(0, 3), min_size=1, max_size=14)


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_misclassification_is_the_best_matching(data):
    labels = data.draw(classes)
    assigned = data.draw(st.lists(st.integers(0, 4), min_size=len(labels),
                                  max_size=len(labels)))
    assert misclassification(labels, assigned) == pytest.approx(brute_force(labels, assigned))


@settings(max_examples=60, deadline=None)
@given(classes, st.permutations([1, 2, 3]))
def test_misclassification_ignores_the_numbering(labels, perm):
    labels = np.array(labels)
    renumbered = np.array([0, *perm])[labels]
    assert misclassification(labels, renumbered) == 0.0
    assert misclassification(labels, labels) == 0.0


def test_misclassification_counts_outliers_as_a_class():
    labels = [0, 0, 1, 1, 2, 2]
    assert misclassification(labels, [1, 1, 1, 1, 2, 2]) == pytest.approx(2 / 6)
    assert misclassification(labels, [0, 0, 0, 0, 0, 0]) == pytest.approx(4 / 6)
    # two labelled structures merged into one found structure: one of them is wrong
    assert misclassification(labels, [0, 0, 1, 1, 1, 1]) == pytest.approx(2 / 6)
    # a found structure with no partner is wrong throughout
    assert misclassification([1, 1, 1, 1], [1, 1, 2, 2]) == pytest.approx(0.5)


@pytest.mark.parametrize("labels, assigned", [([0, 1], [0]), ([[0, 1]], [[0, 1]]),
                                              ([0, -1], [0, 1]), ([0.5, 1], [0, 1]),
                                              ([], [])])
def test_misclassification_refuses_bad_input(labels, assigned):
    with pytest.raises(ValueError):
        misclassification(np.array(labels), np.array(assigned))


def test_labels_from_structures():
    out = labels_from_structures(6, [np.array([0, 1, 2]), np.array([2, 3]), np.array([])])
    assert out.tolist() == [1, 1, 1, 2, 0, 0]
    with pytest.raises(ValueError):
        labels_from_structures(3, [np.array([3])])


def test_transfer_error_closed_form():
    H = np.array([[2.0, 0.0, 1.0], [0.0, 2.0, -1.0], [0.0, 0.0, 1.0]])  # p2 = 2 p1 + (1, -1)
    m = np.array([[1.0, 1.0, 3.0, 1.0], [0.0, 0.0, 4.0, 3.0]])
    assert transfer_errors(H, m) == pytest.approx([0.0, 5.0])


def test_sampson_error_is_the_distance_to_the_line_of_a_rectified_pair():
    """F of a rectified pair (v2 = v): the Sampson error of a match is |v2 − v|/√2, the
    distance of (v, v2) to the line v = v2 (exact here, the constraint being linear)."""
    F = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    m = np.array([[10.0, 5.0, 3.0, 5.0], [7.0, 2.0, 100.0, 6.0]])
    assert sampson_errors(F, m) == pytest.approx([0.0, 4.0 / np.sqrt(2)])
    assert sampson_errors(-3.0 * F, m) == pytest.approx(sampson_errors(F, m))


def test_errors_refuse_bad_shapes():
    with pytest.raises(ValueError):
        transfer_errors(np.eye(3), np.zeros((3, 3)))
    with pytest.raises(ValueError):
        sampson_errors(np.eye(3), np.zeros(4))
