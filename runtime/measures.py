"""The estimator's measures (report §5: a module fed at any time): per channel the rows in
the order they came — a stable integer id, the data row, its information and its exact
components — and, built from them, the validated channels and each model's problem (kept
until the measures or the constants change)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .family import ModelFamily
from .fit import make_problem
from .inputs import ChannelData, channel_data
from .projector import Problem


class MeasureStore:
    """Measures added and removed by id; the problems of the models built on them."""

    def __init__(self, fam: ModelFamily):
        self.fam = fam
        self._rows: dict[str, list] = {name: [] for name in fam.channels}  # (id, X, Q, exact)
        self._next_id = 0
        self.invalidate()

    def __len__(self) -> int:
        return sum(len(rows) for rows in self._rows.values())

    def add(self, channel: str, data, info=None, exact=None) -> tuple[np.ndarray, ChannelData]:
        """Validate and store measures of ``channel``: their new ids and the validated
        channel (:func:`~kanagen.runtime.inputs.channel_data`)."""
        given = None if exact is None else {channel: exact}
        ch = channel_data(self.fam, {channel: data}, {channel: info}, given)[0]
        Q = ch.Q if ch.Q.ndim == 3 else np.broadcast_to(ch.Q, (ch.size,) + ch.Q.shape)
        fixed = np.zeros(ch.X.shape, dtype=bool)
        if ch.fixed is not None:
            fixed[:, ch.index] = ch.fixed
        ids = np.arange(self._next_id, self._next_id + ch.size)
        self._next_id += ch.size
        self._rows[channel].extend(zip(ids.tolist(), ch.X, Q, fixed, strict=True))
        self.invalidate()
        return ids, ch

    def remove(self, gone: set[int]) -> None:
        """Forget the measures of the ids ``gone``."""
        for name in self._rows:
            self._rows[name] = [r for r in self._rows[name] if r[0] not in gone]
        self.invalidate()

    def invalidate(self) -> None:
        """The measures or the constants changed: the channels and problems are built anew."""
        self._channels: tuple | None = None
        self._problems: dict[str, Problem] = {}

    def channels(self) -> tuple[list[str], list[ChannelData], list[np.ndarray]]:
        """The channels that hold measures: their names, validated data and measure ids."""
        if self._channels is None:
            names = [n for n, rows in self._rows.items() if rows]
            chans, ids = [], []
            for name in names:
                rows = self._rows[name]
                X = np.array([r[1] for r in rows])
                Q = np.array([r[2] for r in rows])
                fixed = np.array([r[3] for r in rows])
                if np.all(Q == Q[0]):
                    Q = Q[0]  # one information for all: validated and factored once
                info = channel_data(self.fam, {name: X}, {name: Q},
                                    {name: fixed} if fixed.any() else None)[0]
                chans.append(info)
                ids.append(np.array([r[0] for r in rows], dtype=int))
            self._channels = (names, chans, ids)
        return self._channels

    def problem(self, model: str, q0: np.ndarray, Q0: np.ndarray,
                constants: Mapping) -> Problem:
        """The validated problem of ``model`` on the measures (one per model until the
        measures or the constants change; ``q0``, ``Q0`` validated already)."""
        problem = self._problems.get(model)
        if problem is None:
            problem = self._problems[model] = make_problem(
                self.fam, model, q0=q0, Q0=Q0, constants=constants,
                channels=tuple(self.channels()[1]), checked=True)
        return problem
