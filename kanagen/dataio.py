"""Reading measures from files: CSV (header = component names), NPZ or JSON."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np


def read_measures(path: str | Path, components: tuple[str, ...], channel: str) -> np.ndarray:
    """The (M, len(components)) array of ``channel`` from a data file.

    * CSV: a header row naming columns; the components are picked by name, in spec order.
    * NPZ: an array named after the channel (or the only array), columns in spec order.
    * JSON: ``{channel: [[...], ...]}`` or a list of rows, or a list of ``{component: value}``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as npz:
                names = list(npz.files)
                key = channel if channel in names else (names[0] if len(names) == 1 else None)
                if key is None:
                    raise ValueError(f"{path}: no array named {channel!r} (found {names})")
                return np.asarray(npz[key], dtype=float)
        if suffix == ".json":
            return _from_json(json.loads(path.read_text(encoding="utf-8")), components,
                              channel, path)
        return _from_csv(path, components)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read data: {exc.strerror}") from None


def _from_csv(path: Path, components) -> np.ndarray:
    with path.open(newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ValueError(f"{path}: empty data file")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in components if c not in header]
    if missing:
        raise ValueError(f"{path}: header {header} lacks component(s) {missing}")
    cols = [header.index(c) for c in components]
    out = np.empty((len(rows) - 1, len(cols)))
    for i, row in enumerate(rows[1:], start=2):
        try:
            out[i - 2] = [float(row[j]) for j in cols]
        except (ValueError, IndexError):
            raise ValueError(f"{path}:{i}: not a row of numbers: {row}") from None
    return out


def _from_json(obj, components, channel, path) -> np.ndarray:
    if isinstance(obj, dict):
        if channel not in obj:
            raise ValueError(f"{path}: no key {channel!r}")
        obj = obj[channel]
    if isinstance(obj, list) and obj and isinstance(obj[0], dict):
        try:
            return np.array([[float(r[c]) for c in components] for r in obj])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: bad record: {exc}") from None
    try:
        return np.asarray(obj, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: measures must be a list of rows of numbers") from None
