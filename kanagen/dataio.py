"""Reading measures from files: CSV (header = component names), NPZ or JSON.

A data file may come from anyone: whatever is wrong with it — unreadable, corrupt, not the
format its name says, nested past reason, a field of megabytes, complex or boolean numbers —
becomes one :class:`DataError` naming the file (and the line where there is one), never a
traceback, and never the file's content.
"""

from __future__ import annotations

import csv
import json
import zipfile
from pathlib import Path

import numpy as np

#: A CSV field longer than this is refused (Python's csv module stops at 128 KiB anyway).
_FIELD_LIMIT = 1 << 17


class DataError(ValueError):
    """A data file that cannot be read as measures; the message names the file."""


def read_measures(path: str | Path, components: tuple[str, ...], channel: str) -> np.ndarray:
    """The (M, len(components)) array of ``channel`` from a data file.

    * CSV: a header row naming columns; the components are picked by name, in spec order
      (a UTF-8 byte-order mark is skipped; a column named twice is refused; names are
      case-sensitive). A file whose first line is numbers has no header: it is read as
      data when it has exactly the channel's columns, in spec order (as NPZ and JSON
      rows); otherwise an error says the header is missing.
    * NPZ: an array named after the channel (or the only array), columns in spec order.
    * JSON: ``{channel: [[...], ...]}`` or a list of rows, or a list of ``{component: value}``.

    Raises :class:`DataError` (a ``ValueError``) naming the file when it cannot be read.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            values = _from_npz(path, channel)
        elif suffix == ".json":
            values = _from_json(json.loads(path.read_text(encoding="utf-8")), components,
                                channel, path)
        else:
            values = _from_csv(path, components)
    except DataError:
        raise
    except OSError as exc:
        raise DataError(f"{path}: cannot read data: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}:{exc.lineno}: not JSON: {exc.msg}") from None
    except RecursionError:
        raise DataError(f"{path}: nested too deeply to be measures") from None
    except (ValueError, TypeError, KeyError, EOFError, zipfile.BadZipFile, csv.Error,
            MemoryError) as exc:
        raise DataError(f"{path}: cannot read data: {type(exc).__name__}") from None
    values = _numbers(values, path)
    if values.ndim == 2 and values.shape[1] == len(components) and \
            not np.all(np.isfinite(values)):
        i, k = (int(v) for v in np.argwhere(~np.isfinite(values))[0])
        raise DataError(f"{path}: measure {i} (from 0), {components[k]} is {values[i, k]}, "
                        "not a finite number (a measure must be)")
    return values


def _numbers(values, path: Path) -> np.ndarray:
    """Real numbers only: complex, boolean, object or text arrays are refused (a complex
    array would lose its imaginary part, booleans would pass for 0 and 1)."""
    array = np.asarray(values)
    if array.dtype.kind == "c":
        raise DataError(f"{path}: complex numbers are not measures")
    if array.dtype.kind == "b":
        raise DataError(f"{path}: booleans are not measures")
    if array.dtype.kind not in "iuf":
        raise DataError(f"{path}: measures must be numbers (found {array.dtype.name})")
    return array.astype(float)


def _from_npz(path: Path, channel: str) -> np.ndarray:
    loaded = np.load(path, allow_pickle=False)
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise DataError(f"{path}: not an .npz archive (an .npy file with that name?)")
    with loaded as npz:
        names = list(npz.files)
        key = channel if channel in names else (names[0] if len(names) == 1 else None)
        if key is None:
            raise DataError(f"{path}: no array named {channel!r} (found {names})")
        return npz[key]


def _from_csv(path: Path, components) -> np.ndarray:
    limit = csv.field_size_limit()
    try:
        csv.field_size_limit(_FIELD_LIMIT)
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = [(i, r) for i, r in enumerate(csv.reader(fh), start=1)
                    if r and not r[0].lstrip().startswith("#")]
    except csv.Error as exc:
        raise DataError(f"{path}: not CSV ({exc})") from None
    finally:
        csv.field_size_limit(limit)
    if not rows:
        raise DataError(f"{path}: empty data file")
    first = rows[0][1]
    if all(_is_number(f) and f.strip() not in components for f in first):  # no header
        width = len(first)
        if width != len(components):
            raise DataError(
                f"{path}:{rows[0][0]}: no header (the first line is numbers) and {width} "
                f"column(s), not the {len(components)} of the components "
                f"{list(components)}: add a header line naming the columns, e.g. "
                f"{','.join(components)}")
        return _csv_rows(path, rows, range(width), components)
    header = [h.strip() for h in rows[0][1]]
    twice = sorted({h for h in header if header.count(h) > 1})
    if twice:
        raise DataError(f"{path}:{rows[0][0]}: column(s) {twice} named twice in the header")
    missing = [c for c in components if c not in header]
    if missing:
        folded = {h.casefold(): h for h in header}
        cased = [f"{folded[c.casefold()]!r} for {c!r}" for c in missing
                 if c.casefold() in folded]
        hint = f" (names are case-sensitive: the header has {', '.join(cased)})" \
            if cased else ""
        raise DataError(f"{path}: header {header[:20]} lacks component(s) {missing}{hint}")
    return _csv_rows(path, rows[1:], [header.index(c) for c in components], components)


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _csv_rows(path: Path, rows, cols, components) -> np.ndarray:
    """The columns ``cols`` of ``rows`` (``(line, fields)``) as finite numbers (the
    ``components``, for messages)."""
    cols = list(cols)
    out = np.empty((len(rows), len(cols)))
    for at, (line, row) in enumerate(rows):
        try:
            out[at] = [float(row[j]) for j in cols]
        except (ValueError, IndexError):
            raise DataError(f"{path}:{line}: not a row of numbers ({len(row)} field(s))") \
                from None
        if not np.all(np.isfinite(out[at])):
            k = int(np.flatnonzero(~np.isfinite(out[at]))[0])
            raise DataError(f"{path}:{line}: {components[k]} is {row[cols[k]].strip()!r}, "
                            "not a finite number (a measure must be; drop the row or give "
                            "its value)")
    return out


def _from_json(obj, components, channel, path) -> np.ndarray:
    if isinstance(obj, dict):
        if channel not in obj:
            raise DataError(f"{path}: no key {channel!r}")
        obj = obj[channel]
    if isinstance(obj, list) and obj and isinstance(obj[0], dict):
        try:
            return np.array([[_number(r[c]) for c in components] for r in obj])
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{path}: bad record ({type(exc).__name__}: {exc})") from None
    if not isinstance(obj, list):
        raise DataError(f"{path}: measures must be a list of rows of numbers")
    try:
        return np.array([[_number(v) for v in row] for row in obj])
    except (TypeError, ValueError):
        raise DataError(f"{path}: measures must be a list of rows of numbers") from None


def _number(value) -> float:
    """A JSON number (booleans and strings are not)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{type(value).__name__} is not a number")
    return float(value)
