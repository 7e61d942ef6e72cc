"""``kanagen structures``: the several structures of one dataset
(:func:`kanagen.find_structures`) as a JSON record and a printed summary."""

from __future__ import annotations

import numpy as np

from .evaluation import labels_from_structures
from .fitjob import FitOptions, channel_info, estimate_json, record_header
from .runtime.family import ModelFamily
from .runtime.results import ModelState, estimate_lines
from .runtime.structures import find_structures


def structures_record(fam: ModelFamily, X: np.ndarray, channel: str, opts: FitOptions,
                      max_structures: int, *, spec: str, data: str,
                      sigmas: np.ndarray | None = None) -> tuple[list[ModelState], dict]:
    """The structures of the measures ``X`` of ``channel`` (at most ``max_structures``, each
    more than chance) and their record: the header of ``kanagen fit``'s, each structure's
    estimate (:func:`~kanagen.fitjob.estimate_json`) with its inliers (rows of DATA), the
    threshold they pass and its number of false alarms, and ``labels``: each measure's
    structure (from 0; -1: an outlier of every one)."""
    info = channel_info(opts, fam, channel, sigmas)
    found = find_structures(fam, data={channel: X},
                            info=None if info is None else {channel: info},
                            max_structures=max_structures, model=opts.model,
                            max_samples=opts.max_samples, seed=opts.seed, scale=opts.scale,
                            scorer=opts.scorer, phi=opts.phi, q0=opts.q0(),
                            constants=dict(opts.constants))
    labels = labels_from_structures(len(X), [s.inliers for s in found]) - 1  # -1: outlier
    record = {**record_header(fam, channel, spec, data, X), "max_structures": max_structures,
              "seed": opts.seed, "scale": opts.scale, "sigma": opts.plain_sigma(),
              "constants": dict(opts.constants), "measures": len(X),
              "structures": [{"model": s.model, **estimate_json(s),
                              "inliers": np.asarray(s.inliers, dtype=int),
                              "threshold": s.threshold, "relevance": s.relevance,
                              "false_alarms": s.false_alarms, "status": s.status}
                             for s in found],
              "labels": labels}
    return found, record


def structures_summary(found: list[ModelState], measures: int, max_structures: int) -> str:
    """What ``kanagen structures`` prints: the count, then each structure's estimate."""
    outliers = measures - sum(len(s.inliers) for s in found)
    lines = [f"{len(found)} structure(s) more than chance (at most {max_structures}), "
             f"{outliers} outlier(s) of {measures} measures"]
    for k, s in enumerate(found):
        lines.append(f"structure {k}: model {s.model!r}, {len(s.inliers)} inlier(s), "
                     f"threshold {s.threshold:.4g}, {s.false_alarms:.3g} false alarm(s) "
                     f"(NFA), L~^2/d = {s.normalized_cost:.6g} (d = {s.dof})"
                     + ("" if s.success else f"; refinement: {s.status}"))
        lines += estimate_lines(s.params, s.slacks, s.std, s.derived, s.units, s.pinned)
    return "\n".join(lines)
