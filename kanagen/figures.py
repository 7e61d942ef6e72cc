"""The pictures of a result, drawn by matplotlib as SVG text to inline in a page.

Each function takes plain data (what a JSON record carries) and returns an ``<svg>``
element: the error histogram with its threshold (report Fig. 5), the best-relevance curve
(Fig. 9), the lattice of models (Fig. 13–14), the residuals, the measures of a planar
channel (with the fitted conic when the result has one), two-view matches drawn on their
images, and the measures coloured by structure (``kanagen structures``).
"""

from __future__ import annotations

import io
import re
from collections import defaultdict

import numpy as np

INLIER, OUTLIER = "#1f77b4", "#d62728"  # blue, red
CHOSEN = "#2ca02c"  # green
_SIZE = (7.0, 3.6)  # inches


def _svg(fig, name: str) -> str:
    """The figure as an ``<svg>`` element (no XML prolog, no metadata), deterministic, its
    ids and references to them prefixed with ``name``: the figures of one page never share
    an id."""
    import matplotlib

    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": "kanagen", "svg.fonttype": "path"}):
        fig.savefig(buf, format="svg", metadata={"Date": None}, bbox_inches="tight")
    text = buf.getvalue()
    text = re.sub(r"\s*<metadata>.*?</metadata>", "", text[text.index("<svg"):], flags=re.S)
    text = re.sub(r'\bid="([^"]+)"', rf'id="{name}-\1"', text)
    text = re.sub(r'href="#([^"]+)"', rf'href="#{name}-\1"', text)
    return re.sub(r"url\(#([^)]+)\)", rf"url(#{name}-\1)", text)


def _figure(size=_SIZE):
    from matplotlib.figure import Figure

    return Figure(figsize=size, layout="constrained")


def error_histogram(errors: np.ndarray, threshold: float | None, scale: float | None) -> str:
    """Histogram of the measures' errors (eq. 24) with the inlier/outlier threshold and
    ``L*`` (report Fig. 5), up to 6 thresholds (at most 20 L*, where the threshold search
    stops); the errors beyond are counted in the title."""
    e = np.asarray(errors, dtype=float)
    e = e[np.isfinite(e)]
    fig = _figure()
    ax = fig.subplots()
    marks = [v for v in (threshold, scale) if v is not None and np.isfinite(v)]
    top = float(e.max()) if e.size else 1.0
    if marks:
        top = min(top, 6.0 * max(marks))
    if scale:
        top = min(top, 20.0 * scale)
    top = max(top, 1.2 * max(marks, default=0.0), 1e-12)
    beyond = int(np.count_nonzero(e > top))
    ax.hist(e[e <= top], bins=80, range=(0.0, top), color=INLIER, alpha=0.8,
            label="measures")
    if threshold is not None and np.isfinite(threshold):
        ax.axvline(threshold, color=OUTLIER, lw=2, label=f"threshold {threshold:.3g}")
    if scale:
        ax.axvline(scale, color="0.3", lw=1, ls="--", label=f"L* = {scale:.3g}")
    ax.set_xlabel("error of a measure (eq. 24)")
    ax.set_ylabel("measures")
    title = f"{e.size} measures"
    if beyond:
        title += f"; {beyond} beyond {top:.3g}, not shown"
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=9)
    return _svg(fig, "histogram")


def relevance_curve(history) -> str:
    """The best relevance against the samples drawn (report Fig. 9)."""
    h = np.asarray(history, dtype=float).reshape(-1, 2)
    fig = _figure((7.0, 3.0))
    ax = fig.subplots()
    ax.step(h[:, 0], h[:, 1], where="post", color=INLIER, lw=1.5)
    ax.set_xlabel("samples drawn")
    ax.set_ylabel("best relevance")
    ax.set_xlim(left=0)
    ax.grid(alpha=0.3)
    return _svg(fig, "relevance")


def lattice_graph(edges, states: list[dict], chosen: str | None, null_model: str | None) -> str:
    """The lattice of models (report Fig. 13–14): a box per model with its d, cost L̃²/d,
    relevance and inliers; the chosen one highlighted, rejected ones hatched, models not
    estimated dashed; an arrow per edge, towards the more general model."""
    from matplotlib.patches import FancyArrowPatch

    by_name = {s["model"]: s for s in states}
    level = lattice_levels(edges, [s["model"] for s in states], null_model)
    rows = defaultdict(list)
    for n, lvl in level.items():
        rows[lvl].append(n)
    width = max((len(r) for r in rows.values()), default=1)
    fig = _figure((max(4.0, 2.6 * width), 1.1 * max(len(rows), 1) + 0.3))
    ax = fig.subplots()
    ax.set_axis_off()
    pos = {n: ((i + 0.5) / len(row) * width, -lvl) for lvl, row in rows.items()
           for i, n in enumerate(row)}
    for e in edges:
        if e[0] in pos and e[1] in pos:
            (x0, y0), (x1, y1) = pos[e[0]], pos[e[1]]
            ax.add_patch(FancyArrowPatch((x0, y0 - 0.28), (x1, y1 + 0.28),
                                         arrowstyle="-|>", mutation_scale=12, color="0.4"))
            if len(e) > 2 and e[2] is not None:
                ax.text((x0 + x1) / 2 + 0.05, (y0 + y1) / 2, f"Φ {e[2]}", fontsize=8,
                        color="0.35", va="center")
    for n, (x, y) in pos.items():
        s = by_name.get(n)
        style = {"boxstyle": "round,pad=0.4", "fc": "white", "ec": "0.5", "lw": 1}
        if s is None or not s.get("samples"):
            label, style["ls"] = f"{n}\nnot estimated", "--"
        else:
            label = (f"{n}\nd = {s['dof']}, L̃²/d = {_num(s['normalized_cost'])}\n"
                     f"relevance {_num(s['relevance'])}, {s['inliers']} inliers")
            if n == chosen:
                style.update(fc="#e5f5e0", ec=CHOSEN, lw=3)
                label = "★ " + label
            elif not s.get("accepted", True):
                style.update(fc="0.92", ec="0.6", hatch="///")
                label += "\nrejected"
        ax.text(x, y, label, ha="center", va="center", fontsize=9, bbox=style,
                fontweight="bold" if n == chosen else "normal")
    ax.set_xlim(0, width)
    ax.set_ylim(-max(level.values(), default=0) - 0.6, 0.6)
    return _svg(fig, "lattice")


def lattice_levels(edges, models=(), null_model: str | None = None) -> dict[str, int]:
    """The row of each model in the lattice drawing: the longest path to it from the null
    model (the lattice is a DAG: the spec refuses cycles); models out of its reach go below.

    Examples
    --------
    >>> lattice_levels([["none", "rotation"], ["rotation", "planar"], ["none", "planar"]])
    {'none': 0, 'rotation': 1, 'planar': 2}
    """
    names = list(dict.fromkeys([*([null_model] if null_model else []),
                                *(m for e in edges for m in e[:2]), *models]))
    level = dict.fromkeys(names[:1], 0)
    for _ in names:
        for e in edges:
            if e[0] in level and level.get(e[1], -1) < level[e[0]] + 1:
                level[e[1]] = level[e[0]] + 1
    bottom = max(level.values(), default=-1) + 1
    return {n: level.get(n, bottom) for n in names}


def _num(value) -> str:
    return "–" if value is None else f"{value:.4g}"


def residuals(errors: np.ndarray, inliers: np.ndarray, threshold: float | None) -> str:
    """Each measure's error against its id (log scale), inliers and outliers coloured, with
    the threshold."""
    e = np.asarray(errors, dtype=float)
    ids = np.arange(e.size)
    inside = np.zeros(e.size, bool)
    inside[np.asarray(inliers, dtype=int)] = True
    ok = np.isfinite(e)
    floor = max(np.min(e[ok & (e > 0)], initial=1.0) / 10, 1e-12)
    fig = _figure()
    ax = fig.subplots()
    for mask, colour, label in ((inside, INLIER, "inlier"), (~inside, OUTLIER, "outlier")):
        m = mask & ok
        ax.scatter(ids[m], np.maximum(e[m], floor), s=8, color=colour,
                   label=f"{label}s ({np.count_nonzero(m)})")
    if threshold is not None and np.isfinite(threshold):
        ax.axhline(threshold, color=OUTLIER, lw=1.5, ls="--", label="threshold")
    ax.set_yscale("log")
    ax.set_xlabel("measure (row of the data)")
    ax.set_ylabel("error (eq. 24)")
    ax.legend(fontsize=9, loc="best")
    ax.grid(alpha=0.3)
    return _svg(fig, "residuals")


def conic_curve(M: np.ndarray, xlim, ylim, n: int = 400) -> np.ndarray:
    """Points of the conic ``[x y 1] M [x y 1]ᵀ = 0`` (``M`` 3×3, pixels) inside the box
    ``xlim × ylim``: the zero contour of the implicit equation on an ``n × n`` grid, its
    pieces one after the other separated by a row of NaN; shape (k, 2), k = 0 when the conic
    does not cross the box (or M is not finite)."""
    import contourpy

    M = np.asarray(M, dtype=float)
    if M.shape != (3, 3) or not np.all(np.isfinite(M)) or not np.any(M):
        return np.empty((0, 2))
    M = (M + M.T) / (2.0 * np.max(np.abs(M)))
    x, y = np.linspace(*xlim, n), np.linspace(*ylim, n)
    gx, gy = np.meshgrid(x, y)
    p = np.stack([gx, gy, np.ones_like(gx)])
    z = np.einsum("i...,ij,j...->...", p, M, p)
    lines = contourpy.contour_generator(x, y, z, line_type="Separate").lines(0.0)
    pieces = [np.vstack([line, [np.nan, np.nan]]) for line in lines if len(line) > 1]
    return np.vstack(pieces)[:-1] if pieces else np.empty((0, 2))


def planar_measures(X: np.ndarray, inliers: np.ndarray, names=("x", "y"),
                    conic: np.ndarray | None = None) -> str:
    """The measures of a two-component channel, inliers and outliers coloured; with
    ``conic`` (a 3×3 matrix ``M``), the fitted curve ``[x y 1] M [x y 1]ᵀ = 0`` over them
    (an SVG group of id ``measures-fitted-curve``)."""
    X = np.asarray(X, dtype=float)
    inside = np.zeros(len(X), bool)
    inside[np.asarray(inliers, dtype=int)] = True
    fig = _figure((6.0, 4.5))
    ax = fig.subplots()
    if conic is not None and np.any(np.isfinite(X)):
        finite = X[np.all(np.isfinite(X), axis=1)]
        low, high = finite.min(axis=0), finite.max(axis=0)
        margin = 0.05 * np.maximum(high - low, 1.0)
        curve = conic_curve(conic, (low[0] - margin[0], high[0] + margin[0]),
                            (low[1] - margin[1], high[1] + margin[1]))
        if curve.size:
            ax.plot(*curve.T, color=CHOSEN, lw=1.5, label="fitted curve", gid="fitted-curve")
    ax.scatter(*X[~inside].T, s=10, color=OUTLIER, marker="x", label="outliers")
    ax.scatter(*X[inside].T, s=10, color=INLIER, label="inliers")
    ax.set_xlabel(names[0])
    ax.set_ylabel(names[1])
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=9)
    return _svg(fig, "measures")


def two_view_matches(X: np.ndarray, inliers: np.ndarray, first: np.ndarray,
                     second: np.ndarray, max_side: int = 1000) -> str:
    """Matches ``(x, y, x', y')`` (pixels) drawn on the two images side by side, a segment
    from each point to its match, inliers and outliers coloured."""
    X = np.asarray(X, dtype=float)
    inside = np.zeros(len(X), bool)
    inside[np.asarray(inliers, dtype=int)] = True
    images, steps = [], []
    for img in (first, second):
        img = np.asarray(img)
        step = max(1, int(np.ceil(max(img.shape[:2]) / max_side)))  # keep the page light
        images.append(img[::step, ::step])
        steps.append(step)
    (h1, w1), (h2, w2) = (im.shape[:2] for im in images)
    fig = _figure((10.0, 10.0 * max(h1, h2) / (w1 + w2) + 0.6))
    ax = fig.subplots()
    shift = w1 * steps[0]  # the second image starts here, in the first image's pixels
    for img, step, x0 in ((images[0], steps[0], 0), (images[1], steps[1], shift)):
        h, w = img.shape[:2]
        ax.imshow(img, extent=(x0 - 0.5, x0 + w * step - 0.5, h * step - 0.5, -0.5),
                  cmap="gray" if img.ndim == 2 else None, interpolation="nearest")
    for mask, colour, label in ((~inside, OUTLIER, "outliers"), (inside, INLIER, "inliers")):
        p, q = X[mask, :2], X[mask, 2:4] + [shift, 0]
        if p.size:
            ax.plot(np.c_[p[:, 0], q[:, 0]].T, np.c_[p[:, 1], q[:, 1]].T, color=colour,
                    lw=0.6, alpha=0.7)
            ax.scatter(np.r_[p[:, 0], q[:, 0]], np.r_[p[:, 1], q[:, 1]], s=6, color=colour,
                       label=f"{label} ({np.count_nonzero(mask)})")
    ax.set_xlim(-0.5, shift + w2 * steps[1] - 0.5)
    ax.set_ylim(max(h1 * steps[0], h2 * steps[1]) - 0.5, -0.5)
    ax.set_axis_off()
    ax.legend(fontsize=9, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncols=2)
    return _svg(fig, "matches")


def structure_measures(X: np.ndarray, labels: np.ndarray, names) -> str:
    """The measures coloured by their structure (``labels``: from 0; -1, outliers, grey
    crosses): the first two components, and for a channel of four (two views' matches
    ``x, y, x', y'``) the last two beside them — each point where its image has it."""
    import matplotlib

    X = np.asarray(X, dtype=float)
    labels = np.asarray(labels, dtype=int)
    views = [(0, 1)] + ([(2, 3)] if X.shape[1] == 4 else [])
    fig = _figure((6.0 * len(views), 4.5))
    colours = matplotlib.colormaps["tab10"]
    for ax, (i, j) in zip(np.atleast_1d(fig.subplots(1, len(views))), views, strict=True):
        out = labels < 0
        ax.scatter(X[out, i], X[out, j], s=10, color="#999999", marker="x",
                   label=f"outliers ({np.count_nonzero(out)})")
        for k in range(labels.max(initial=-1) + 1):
            mine = labels == k
            ax.scatter(X[mine, i], X[mine, j], s=10, color=colours(k % 10),
                       label=f"structure {k} ({np.count_nonzero(mine)})")
        ax.set_xlabel(names[i])
        ax.set_ylabel(names[j])
        ax.set_aspect("equal", adjustable="datalim")
        if len(views) == 2:
            ax.invert_yaxis()  # image rows down
    fig.axes[0].legend(fontsize=9)
    return _svg(fig, "structures")
