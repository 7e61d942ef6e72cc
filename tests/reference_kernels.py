"""Per-measure algebra of the projector, generic over sizes (report appendix A, Fig. 17).

For each measure, with ``Q_i⁺ = Gᵀ G`` (``G = L_Q⁻¹``, ``L_Q`` the closest square root of
``Q_i``): ``E = D Gᵀ``, ``S = E Eᵀ = D Q⁺ Dᵀ``, ``L`` its reduced square root. ``whiten``
applies ``L⁻¹`` to any stacked right-hand sides; ``correct`` returns ``Gᵀ Eᵀ L⁻ᵀ z``, the
measure correction ``Q⁺ Dᵀ S⁻ (r − C q)`` given the whitened ``z = r̄ − C̄ q``.

The engine's per-measure algebra (runtime/engine/measures.py: ``factor``, ``whiten_column``,
``correct``) is tested against this NumPy version, vectorised over the measures
(tests/test_codegen.py).
"""

from __future__ import annotations

import numpy as np

from kanagen.runtime.sqrt import reduced_solve, reduced_sqrt


def whiten(D: np.ndarray, G: np.ndarray, B: np.ndarray, eps: float):
    """Return ``(L⁻¹ B, kept, state)`` for D (M, p, k), G (k, k) or (M, k, k), B (M, p, t)."""
    E = D @ np.swapaxes(G, -1, -2)
    S = E @ np.swapaxes(E, -1, -2)
    L, kept = reduced_sqrt(S, eps)
    return reduced_solve(L, kept, B), kept, (E, L, kept)


def correct(state, G: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Measure corrections (M, k) from whitened residuals ``z`` (M, p)."""
    E, L, kept = state
    y = reduced_solve(L, kept, z, transpose=True)
    t = np.einsum("mpj,mp->mj", E, y)
    return np.einsum("...jl,...j->...l", G, t) if G.ndim == 3 else t @ G
