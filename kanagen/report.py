"""``kanagen report``: one self-contained HTML page of a result, with its pictures.

The page is rendered by jinja2 from a JSON record (``kanagen fit --json``, the record a
batch run stored for a dataset, or ``kanagen structures --json``); the figures are
matplotlib SVG inlined in it (:mod:`kanagen.figures`), so the page needs nothing but
itself.
"""

from __future__ import annotations

import math
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from .dataio import read_measures
from .fitjob import measures_sha256


def load_record(result: str | Path | None = None, *, db: str | Path | None = None,
                dataset: str | None = None) -> tuple[dict, dict | None]:
    """The JSON record of a result file, or of a dataset in a results database, with the
    database row (status, time; None for a file)."""
    import json

    from .resultsdb import read_record

    if (result is None) == (db is None):
        raise ValueError("give a RESULT.json or --db with --dataset, not both")
    if result is not None:
        try:
            record = json.loads(Path(result).read_text(encoding="utf-8"))
        except OSError as exc:
            raise ValueError(f"{result}: cannot read: {exc.strerror}") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"{result}: not JSON: {exc}") from None
        if not isinstance(record, dict) or ("model" not in record and
                                            "structures" not in record):
            raise ValueError(f"{result}: not a kanagen result (kanagen fit or structures "
                             "--json)")
        return record, None
    if dataset is None:
        raise ValueError("--db needs --dataset NAME")
    return read_record(db, dataset)


def read_data(record: dict, data: str | Path | None = None,
              base: str | Path | None = None) -> np.ndarray | None:
    """The measures of a record: from ``data`` if given; else from the file it names (as
    is, or relative to ``base``) when that file holds the very measures the record was
    estimated from (their hash, ``data_sha256``) — a result file may come from anyone, and
    must not make a report read and draw another file. None otherwise."""
    components = record.get("channel_components")
    if not components:
        return None
    if data is not None:
        return read_measures(data, tuple(components), record["channel"])
    named, digest = record.get("data"), record.get("data_sha256")
    if not (isinstance(named, str) and named and isinstance(digest, str)):
        return None
    for path in [Path(named)] + ([Path(base) / named] if base is not None else []):
        try:
            if not path.is_file():
                continue
            measures = read_measures(path, tuple(components), record["channel"])
        except (OSError, ValueError):
            continue
        if measures_sha256(measures) == digest:
            return measures
    return None


def render_report(record: dict, *, measures: np.ndarray | None = None,
                  images: tuple | None = None, title: str | None = None,
                  row: dict | None = None) -> str:
    """The HTML page of a record.

    Parameters
    ----------
    record : dict
        A JSON record (``kanagen fit --json``; a batch run stores the same).
    measures : (M, k) array, optional
        The dataset's measures: a planar channel (2 components) is drawn, inliers coloured.
    images : (first, second) image arrays, optional
        For two-view data (4 components ``x, y, x', y'``, in pixels): the matches drawn on
        both images.
    title : str, optional
        Page title (default: the dataset).
    row : dict, optional
        The database row of a batch result (status, time).
    """
    from . import figures

    count = _count(record)
    if "structures" in record:
        return _render(record, row, count, *_structure_figures(record, measures), title)
    inliers = np.asarray(record.get("inliers") or [], dtype=int)
    errors = record.get("errors")
    e = None if errors is None else np.array([np.nan if v is None else v for v in errors],
                                             dtype=float)
    figs, notes = [], []  # notes: ("warn" — something missing — or "hint", text)

    def add(fid, fig_title, svg, caption):
        figs.append({"id": fid, "title": fig_title, "svg": svg, "caption": caption})

    if e is not None and e.size:
        add("histogram", "Error histogram", figures.error_histogram(
            e, record.get("threshold"), record.get("scale")),
            "Errors of the measures under the chosen model (eq. 24), in units of their "
            "information; the threshold between inliers and outliers is the first minimum or "
            "saddle of the smoothed histogram (report §4, Fig. 5).")
    if record.get("history"):
        add("relevance", "Best relevance against samples", figures.relevance_curve(
            record["history"]),
            "The best relevance (eq. 29) found after each random sample, over the whole "
            "lattice search (report Fig. 9): steep while good samples are found, flat after.")
    if record.get("lattice"):
        add("lattice", "Lattice of models", figures.lattice_graph(
            record.get("edges") or [], record["lattice"], record.get("model"),
            record.get("null_model")),
            "Models from the most constrained (top) to the most general; each box gives d, "
            "the cost L̃²/d, the relevance and the inliers; the chosen model is starred and "
            "green, rejected ones hatched (report §5, Fig. 13–14).")
    if e is not None and e.size and record.get("model"):
        add("residuals", "Residuals", figures.residuals(e, inliers, record.get("threshold")),
            "Each measure's error under the chosen model, by row of the data.")
    components = record.get("channel_components") or []
    if measures is not None and len(components) == 2 and record.get("model"):
        conic = _conic_matrix(record)
        add("measures", "Measures", figures.planar_measures(measures, inliers, components,
                                                            conic),
            "The measures, inliers of the chosen model in blue, outliers in red"
            + ("; the fitted curve in green." if conic is not None else "."))
    if images is not None:
        _check_two_view(record)
        if measures is None:
            notes.append(("warn", "Matches not drawn: the data file was not found (give it "
                                  "with --data)."))
        else:
            add("matches", "Matches", figures.two_view_matches(measures, inliers, *images),
                f"Matches from the first image ({components[0]}, {components[1]}) to the "
                f"second ({components[2]}, {components[3]}); inliers in blue, outliers red.")
    elif len(components) == 4 and record.get("model"):
        notes.append(("hint", "Two-view matches: give the two images (--images FIRST SECOND) "
                              "to see them drawn, inliers and outliers coloured."))
    elif measures is None and len(components) == 2 and record.get("model"):
        notes.append(("warn", "Measures not drawn: the data file was not found (give it with "
                              "--data)."))
    return _render(record, row, count, figs, notes, title)


def _render(record: dict, row, count, figs: list, notes: list, title) -> str:
    """The page of ``record`` with its figures and notes (the template's one call)."""
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("kanagen", "templates"),
                             autoescape=True, undefined=jinja2.ChainableUndefined,
                             trim_blocks=True, lstrip_blocks=True)
    page = env.get_template("report.html.jinja")
    structures = [{**entry, "estimate": _estimate(entry), "pinned_text": _pinned(entry)}
                  for entry in record.get("structures") or []]
    return page.render(rec=record, row=row, count=count, figures=figs, notes=notes,
                       title=title or record.get("data") or "result", num=_num,
                       options=_options(record), estimate=_estimate(record),
                       pinned=_pinned(record), version=_version(),
                       structures=structures if "structures" in record else None)


def _structure_figures(record: dict, measures: np.ndarray | None) -> tuple[list, list]:
    """The figure of a ``kanagen structures`` record: its measures coloured by structure
    (when the data were found), or a note saying they were not."""
    from . import figures

    labels = record.get("labels")
    components = record.get("channel_components") or []
    if measures is None or labels is None or len(labels) != len(measures) or \
            len(components) < 2:
        return [], [("warn", "Measures not drawn: the data file was not found (give it "
                             "with --data).")]
    svg = figures.structure_measures(measures, np.asarray(labels, dtype=int), components)
    return [{"id": "structures", "title": "Structures", "svg": svg,
             "caption": "The measures coloured by the structure they belong to (outliers "
                        "of every structure grey)" + ("; the first image's points left, "
                                                     "the second's right." if
                                                     len(components) == 4 else ".")}], []


def write_report(out: str | Path, result: str | Path | None = None, *,
                 db: str | Path | None = None, dataset: str | None = None,
                 data: str | Path | None = None, images=None) -> Path:
    """Write the page of a result file or of a dataset of a results database to ``out``.

    ``images``: two image files (PNG, JPEG) for two-view data. Returns the path written.
    """
    record, row = load_record(result, db=db, dataset=dataset)
    pictures = None
    if images is not None:
        _check_two_view(record)
        if len(images) != 2:
            raise ValueError("images: give the first and the second image")
        pictures = tuple(_image(p) for p in images)
    measures = read_data(record, data, Path(result if result is not None else db).parent)
    html = render_report(record, measures=measures, images=pictures, row=row,
                         title=dataset or record.get("data"))
    out = Path(out)
    try:
        out.write_text(html, encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot write {out}: {exc.strerror}") from None
    return out


def _check_two_view(record: dict) -> None:
    components = record.get("channel_components") or []
    if len(components) != 4:
        raise ValueError(f"images need two-view matches (a channel of 4 components x, y, "
                         f"x', y'); channel {record.get('channel')!r} has {components}")


def _image(path) -> np.ndarray:
    import matplotlib.image

    try:
        return matplotlib.image.imread(path)
    except (OSError, ValueError, SyntaxError) as exc:
        raise ValueError(f"{path}: cannot read the image: {exc}") from None


def _conic_matrix(record: dict) -> np.ndarray | None:
    """The fitted conic of a planar result: its derived ``matrix`` when that is a finite
    symmetric 3×3 ``M`` of ``[x y 1] M [x y 1]ᵀ = 0`` (the conic specs'), else None."""
    d = (record.get("derived") or {}).get("matrix")
    if not isinstance(d, dict):
        return None
    try:
        M = np.asarray(d.get("value"), dtype=float)
    except (TypeError, ValueError):
        return None
    if M.shape != (3, 3) or not np.all(np.isfinite(M)) or not np.allclose(M, M.T):
        return None
    return M


def _count(record: dict) -> int | None:
    measures = record.get("measures")
    if isinstance(measures, dict):  # a local fit's corrected measures
        return sum(len(v) for v in measures.values())
    return measures


def _num(value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def _options(record: dict) -> list[tuple[str, str]]:
    names = ("scale", "scorer", "phi", "seed", "max_samples", "max_iter", "local",
             "max_structures")
    labels = {"scale": "L* (scale)", "phi": "Φ", "max_samples": "max samples",
              "max_iter": "max iterations", "max_structures": "max structures"}
    return [(labels.get(n, n), _num(record[n]) if n != "phi" or record[n] is not None
             else "the spec's, per edge")
            for n in names if n in record]


def _estimate(record: dict) -> list[tuple[str, str, str, str]]:
    """(name, value, std, unit) of each estimated component and derived quantity; the
    components the model pins are no estimates (:func:`_pinned`)."""
    params = {**(record.get("params") or {}), **(record.get("slacks") or {})}
    std, pinned = record.get("std") or {}, record.get("pinned") or {}
    units = record.get("units") or {}
    rows = [(n, _num(v), _num(std.get(n)) if n in std else "", units.get(n, ""))
            for n, v in params.items() if n not in pinned]
    for name, d in (record.get("derived") or {}).items():
        value, sd = np.asarray(d["value"], dtype=object), np.asarray(d["std"], dtype=object)
        unit = units.get(name, "")
        if value.ndim == 0:
            rows.append((name, _num(value.item()), _num(sd.item()), unit))
            continue
        for index in np.ndindex(value.shape):
            rows.append((f"{name}{list(index)}", _num(value[index]), _num(sd[index]), unit))
    return rows


def _pinned(record: dict) -> str:
    """``B = 0, ...``: what the chosen model fixes."""
    pinned, slacks = record.get("pinned") or {}, record.get("slacks") or {}
    return ", ".join(f"{name} = {_num(value)}" for name, value in pinned.items()
                     if name not in slacks)


def _version() -> str:
    try:
        return version("kanagen")
    except PackageNotFoundError:
        return "(source)"
