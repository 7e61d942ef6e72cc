"""The ``kanagen`` command line."""

from __future__ import annotations

import glob
import json
import sys
from pathlib import Path

import click
import numpy as np

from .modelspec import SpecError


def _fail(message: str, code: int = 2):
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="kanagen")
def main():
    """kanagen: declare a family of models in YAML, generate its estimation code, and find
    which model noisy measures with outliers support, with its estimate and uncertainty
    (robust multi-model estimation of INRIA report RR-4050).

    \b
    Typical use:
      kanagen show examples/conic.yaml          # what the spec declares
      kanagen build examples/conic.yaml -o generated
      kanagen fit examples/conic_lattice.yaml points.csv --scale 4   # robust, lattice
      kanagen fit examples/conic.yaml examples/data/ellipse_arc.csv --model conic --local
    """


@main.command()
@click.argument("specs", nargs=-1, type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out_dir", default="generated", show_default=True,
              type=click.Path(file_okay=False), help="Folder for the generated modules.")
@click.option("--backend", "backends", multiple=True, type=click.Choice(["numpy", "casadi"]),
              help="Module(s) to generate (repeatable): numpy (default), casadi (CasADi "
                   "Functions, written beside the NumPy module). With --check, default: "
                   "every backend whose file is in OUT.")
@click.option("--compile", "compile_", is_flag=True,
              help="Also compile the CasADi functions to C (CasADi's code generator and the "
                   "C compiler $CC or cc) into the cache that kanagen.load(..., "
                   "backend='compiled') uses. Without a compiler: a warning, not an error.")
@click.option("--check", is_flag=True,
              help="Regenerate in memory and fail with a diff if a file in OUT differs "
                   "(default SPECS: examples/*.yaml).")
def build(specs, out_dir, backends, compile_, check):
    """Generate the estimation module of each SPEC (YAML) into OUT."""
    from .codegen import build as build_spec
    from .codegen import check as check_specs

    if not specs:
        if not check:
            _fail("no spec given (kanagen build SPEC.yaml [-o DIR])")
        specs = sorted(glob.glob("examples/*.yaml"))
        if not specs:
            _fail("no spec given and no examples/*.yaml here")
    try:
        if check:
            diffs = check_specs(list(specs), out_dir, backends or None)
            for diff in diffs:
                click.echo(diff, nl=False)
            if diffs:
                _fail(f"{len(diffs)} generated file(s) in {out_dir} differ from their spec; "
                      f"run: kanagen build {' '.join(specs)} -o {out_dir}"
                      + "".join(f" --backend {b}" for b in backends), 1)
            click.echo(f"{len(specs)} spec(s): generated files in {out_dir} are up to date")
            return
        names = ("numpy", *(b for b in backends if b != "numpy"))
        for spec in specs:
            for path in build_spec(spec, out_dir, names):
                click.echo(f"{spec} -> {path}")
            if compile_:
                _compile(spec)
    except SpecError as exc:
        _fail(str(exc))


def _compile(spec: str) -> None:
    """Compile the CasADi functions of ``spec`` into the cache; a warning without compiler."""
    from .codegen.compile import CompileError, compile_family
    from .loader import _module_for
    from .modelspec import load_spec
    from .runtime.family import cache_dir

    family = load_spec(spec)
    try:
        library = compile_family(_module_for(family, "casadi"),
                                 _module_for(family, "numpy").FAMILY, cache_dir())
    except CompileError as exc:
        click.echo(f"warning: {spec}: not compiled: {exc}; kanagen.load(..., "
                   "backend='compiled') will use the uncompiled CasADi backend", err=True)
        return
    click.echo(f"{spec} -> {library} (compiled)")


@main.command()
@click.argument("spec", type=click.Path(exists=True, dir_okay=False))
def show(spec):
    """Print what SPEC declares: parameter, constants, channels, models and their lattice."""
    from .modelspec import load_spec

    try:
        fam = load_spec(spec)
    except SpecError as exc:
        _fail(str(exc))
    click.echo(f"family {fam.name!r} (sha256 {fam.sha256[:12]}...) from {spec}")
    click.echo("  parameter: " + ", ".join(f"{n}={v:g}" for n, v in fam.parameter))
    if fam.constants:
        click.echo("  constants: " + ", ".join(f"{n}={v:g}" for n, v in fam.constants))
    for ch in fam.channels:
        exact = f" (exact: {', '.join(ch.exact)})" if ch.exact else ""
        click.echo(f"  channel {ch.name}: [{', '.join(ch.components)}]{exact}")
        for eq in ch.equations:
            click.echo(f"    {eq} = 0")
    for m in fam.models:
        marker = " (null model)" if m.name == fam.null_model else ""
        click.echo(f"  model {m.name}{marker}: {len(m.constraints)} constraint(s)")
        for c in m.constraints:
            click.echo(f"    {c} = 0")
        for ch, eqs in m.equations:
            click.echo(f"    channel {ch} overridden: " + "; ".join(f"{e} = 0" for e in eqs))
        for alt in m.alternatives:
            click.echo(f"    -> {alt.model} (phi {alt.phi})")
    for d in fam.derived:
        click.echo(f"  derived {d.name}: shape {d.shape or 'scalar'}")


@main.command()
@click.argument("spec", type=click.Path(exists=True, dir_okay=False))
@click.argument("data", type=click.Path(exists=True, dir_okay=False))
@click.option("--channel", default=None,
              help="Channel of DATA (default: the only one of SPEC).")
@click.option("--scale", type=float, default=1.0, show_default=True, metavar="L*",
              help="L*, the order of magnitude of an inlier's error (report eq. 29). Errors "
                   "are squared distances in units of --sigma: an inlier's is about 1.")
@click.option("--scorer", type=click.Choice(["relevance", "ransac", "trimmed"]),
              default="relevance", show_default=True,
              help="Score of a sample's estimate over all the measures.")
@click.option("--phi", default=None, metavar="PHI",
              help="Cost factor of every edge of the lattice: a number, aic, ftest, ftest:P "
                   "or exp:K (default: each edge's factor from SPEC).")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of the random samples (same seed, same result).")
@click.option("--max-samples", type=click.IntRange(min=1), default=2000, show_default=True,
              help="Stop the search after this many random samples in all.")
@click.option("--model", default=None,
              help="Robust: search this model only, not the lattice. With --local: the model "
                   "to fit (default: the null model).")
@click.option("--local", is_flag=True,
              help="Fit one model (--model) to all the measures with the local estimator: no "
                   "random samples, no outlier rejection.")
@click.option("--sigma", type=float, default=None,
              help="Standard deviation of each measured component (info = 1/sigma²; "
                   "default 1).")
@click.option("--const", "consts", multiple=True, metavar="NAME=VALUE",
              help="Set a constant of SPEC (repeatable).")
@click.option("--max-iter", type=int, default=100, show_default=True,
              help="Iterations of the local estimator (--local only).")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None,
              help="Also write the result as JSON to this file; '-': to stdout, the text "
                   "going to stderr. Infinite or undefined numbers are null.")
@click.option("--backend", type=click.Choice(["numpy", "casadi", "compiled"]),
              default="numpy", show_default=True,
              help="What evaluates the equations; compiled: C through CasADi and the C "
                   "compiler, with the compiled estimator (same results, faster).")
def fit(spec, data, channel, scale, scorer, phi, seed, max_samples, model, local, sigma,
        consts, max_iter, json_out, backend):
    """Find the model of SPEC that the measures in DATA support, despite outliers.

    DATA is a CSV file whose header names the channel's components (in any order, other
    columns ignored), an NPZ file (an array named after the channel, or a single array) or a
    JSON file ({channel: rows}, a list of rows or a list of {component: value}). A measure's
    id is its row in DATA, from 0.

    By default, the robust lattice search of report §5: random minimal samples fit the null
    model, then each more general model from the measures its parent left out; each sample's
    estimate is scored against every measure at the scale L* (--scale), the best is refined
    on its inliers, and a general model replaces its parent only when its cost L~²/d beats
    the parent's by the factor Φ (--phi). A progress bar shows on a terminal. Printed: the
    lattice, one row per model estimated (the chosen one marked *), then the chosen model's
    estimate ± standard deviation (inf: unobservable) and its derived quantities.

    With --local, fit one model to all the measures with the local estimator of §2–3.

    Exit status: 0 when a model was found (--local: when the fit converged), 1 otherwise,
    2 on bad input.

    \b
    Examples:
      kanagen fit examples/conic_lattice.yaml arc.csv --scale 4 --json result.json
      kanagen fit examples/conic.yaml examples/data/ellipse_arc.csv --model conic --local
    """
    from . import load
    from .dataio import read_measures

    try:
        fam = load(spec, backend=backend)
        if channel is None:
            if len(fam.channels) != 1:
                _fail(f"--channel is required: {spec} has channels {list(fam.channels)}")
            channel = next(iter(fam.channels))
        components = fam.channel(channel).components
        X = read_measures(data, components, channel)
        if X.ndim != 2 or X.shape[0] == 0:
            _fail(f"{data}: no measures for channel {channel!r}")
        constants = _parse_constants(consts)
        if sigma is not None and not (sigma > 0 and np.isfinite(sigma)):
            _fail("--sigma must be a positive number")
        info = None if sigma is None else sigma**-2
        if model is not None:
            fam.model(model)
        if local:
            from . import fit as fit_model

            res = fit_model(fam, model, data={channel: X}, info={channel: info},
                            constants=constants, max_iter=max_iter)
        else:
            from . import Estimator

            phi = _parse_phi(phi)
            est = Estimator(fam, scale=scale, scorer=scorer, phi=phi, seed=seed,
                            channel=channel, constants=constants, model=model)
            est.add_measures(channel, X, info=info)
    except (SpecError, ValueError, OSError) as exc:
        _fail(str(exc))
    to_err = json_out == "-"  # stdout holds the JSON alone; the text goes to stderr
    if local:
        click.echo(res.summary(), err=to_err)
        _write_json(result_to_json(res), json_out)
        sys.exit(0 if res.success else 1)
    found = _report_robust(est, fam, channel, len(X), json_out, to_err, spec=spec, data=data,
                           scale=scale, scorer=scorer, phi=phi, seed=seed,
                           max_samples=max_samples)
    sys.exit(0 if found else 1)


def _parse_constants(items) -> dict[str, float]:
    constants = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            constants[name.strip()] = float(value)
        except ValueError:
            _fail(f"--const expects NAME=VALUE with a number, got {item!r}")
    return constants


def _parse_phi(text: str | None):
    """``--phi``: None (the spec's factors), a number, or a named factor, validated now (the
    estimator would only meet a bad one in the middle of the search)."""
    from .runtime.phi import phi as get_phi

    if text is None:
        return None
    try:
        choice = float(text)
    except ValueError:
        choice = text.strip()
    try:
        get_phi(choice)
    except ValueError as exc:
        _fail(f"--phi: {exc}")
    return choice


def _report_robust(est, fam, channel, measures, json_out, to_err, *, spec, data, scale,
                   scorer, phi, seed, max_samples) -> bool:
    """Run the search, print the lattice and the chosen model; True when a model was found."""
    interrupted = False
    try:
        samples = _search(est, max_samples)
    except KeyboardInterrupt:  # anytime: report the best model so far
        samples, interrupted = len(est.history), True
    best = est.best()
    found = best is not None and best.samples > 0 and bool(np.all(np.isfinite(best.q)))
    status = f"interrupted ({est.status})" if interrupted else est.status
    if not interrupted and samples >= max_samples and est.status != "done":
        status = f"stopped at --max-samples {max_samples} ({est.status})"
    chosen = best.model if found else None
    click.echo(f"family {fam.name!r}, channel {channel!r}: {measures} measures, L* = {scale:g}, "
               f"scorer {scorer}, {samples} sample(s): {status}", err=to_err)
    click.echo(_lattice_table(est.states(), chosen), err=to_err)
    if found:
        click.echo(_state_summary(best, measures), err=to_err)
    else:
        click.echo("no model found: no sample gave an estimate", err=to_err)
    report = estimator_to_json(est, chosen)
    report.update({"family": fam.name, "spec": str(spec), "data": str(data), "channel": channel,
                   "scale": scale, "scorer": scorer, "phi": phi, "seed": seed,
                   "max_samples": max_samples, "measures": measures, "total_samples": samples,
                   "status": est.status, "stop_reason": status})
    _write_json(report, json_out)
    return found


def _search(est, max_samples: int) -> int:
    """Step the estimator up to ``max_samples`` samples; a progress bar on a terminal."""
    samples = 0
    if not sys.stderr.isatty():
        while samples < max_samples and est.step():
            samples += 1
        return samples
    with click.progressbar(length=max_samples, label="sampling", file=sys.stderr,
                           item_show_func=lambda status: status) as bar:
        while samples < max_samples and est.step():
            samples += 1
            bar.update(1, est.status)
        bar.update(max_samples - samples, est.status)  # explored before the budget: full bar
    return samples


def _lattice_table(states, chosen: str | None) -> str:
    header = ("model", "parent", "d", "L~^2/d", "relevance", "inliers", "samples", "accepted")
    rows = [header]
    for s in states:
        rows.append((s.model, s.parent or "-", str(s.dof), f"{s.cost:.4g}",
                     f"{s.relevance:.4g}", str(len(s.inliers)), str(s.samples),
                     "yes" if s.accepted else "no"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    lines = []
    for k, row in enumerate(rows):
        mark = "*" if k and row[0] == chosen else " "
        lines.append((mark + " " + "  ".join(f"{c:<{w}}" for c, w in zip(row, widths,
                                                                          strict=True))).rstrip())
    return "\n".join(lines)


def _std(covariance) -> np.ndarray:
    """Standard deviations from a covariance: inf stays inf (unobservable)."""
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.clip(np.diag(np.asarray(covariance, dtype=float)), 0.0, None))


def _state_summary(best, measures: int) -> str:
    from .runtime.results import estimate_lines

    lines = [f"chosen model {best.model!r}: {len(best.inliers)} inlier(s), "
             f"{len(best.outliers)} outlier(s) of {measures} measures; L~^2/d = {best.cost:.6g}"
             f" (d = {best.dof}), relevance {best.relevance:.4g}, threshold "
             f"{best.threshold:.4g}, {best.samples} sample(s)"]
    if best.status not in ("estimated", "null"):
        lines.append(f"  refinement: {best.status}")
    lines += estimate_lines(best.params, best.slacks, _std(best.covariance), best.derived)
    return "\n".join(lines)


def _write_json(obj, json_out: str | None) -> None:
    if not json_out:
        return
    text = json.dumps(_finite(obj), indent=2, allow_nan=False)
    if json_out == "-":
        click.echo(text)
        return
    try:
        Path(json_out).write_text(text + "\n", encoding="utf-8")
    except OSError as exc:
        _fail(f"cannot write {json_out}: {exc.strerror or exc}")


def _finite(obj):
    """Plain JSON data: arrays as lists, inf and NaN as null."""
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def estimator_to_json(est, chosen: str | None) -> dict:
    """An Estimator's lattice and chosen model as plain JSON data (inf and NaN as null after
    :func:`_finite`)."""
    lattice = [{"model": s.model, "parent": s.parent, "dof": s.dof, "cost": s.cost,
                "relevance": s.relevance, "inliers": len(s.inliers), "outliers": len(s.outliers),
                "samples": s.samples, "accepted": s.accepted, "threshold": s.threshold,
                "status": s.status, "chosen": s.model == chosen}
               for s in est.states()]
    out = {"model": chosen, "lattice": lattice,
           "history": [[int(n), float(r)] for n, r in est.history]}
    best = est.best() if chosen is not None else None
    if best is None:
        return out
    std = _std(best.covariance)
    out.update({
        "params": dict(best.params),
        "std": dict(zip(best.params, std.tolist(), strict=False)),
        "slacks": dict(best.slacks),
        "components": [*best.params, *best.slacks],  # rows of covariance and info
        "covariance": np.asarray(best.covariance),
        "info": np.asarray(best.info),
        "cost": best.cost,
        "dof": best.dof,
        "relevance": best.relevance,
        "threshold": best.threshold,
        "samples": best.samples,
        "inliers": np.asarray(best.inliers, dtype=int),
        "outliers": np.asarray(best.outliers, dtype=int),
        "derived": {k: {"value": np.asarray(v.value), "std": np.asarray(v.std)}
                    for k, v in best.derived.items()},
        "model_status": best.status,
    })
    return out


def result_to_json(res) -> dict:
    """A FitResult as plain JSON data (inf and NaN as null after :func:`_finite`)."""
    def arr(a):
        return np.asarray(a).tolist()

    return {
        "model": res.model,
        "params": res.params,
        "std": dict(zip(res.params, arr(res.std), strict=False)),
        "slacks": res.slacks,
        "components": [*res.params, *res.slacks],  # rows of covariance and info
        "covariance": arr(res.covariance),
        "info": arr(res.info),
        "cost": res.cost,
        "dof": res.dof,
        "normalized_cost": res.normalized_cost,
        "residual": res.residual,
        "iterations": res.iterations,
        "success": res.success,
        "status": res.status,
        "message": res.message,
        "derived": {k: {"value": arr(v.value), "std": arr(v.std)}
                    for k, v in res.derived.items()},
        "measures": {k: arr(v) for k, v in res.measures.items()},
    }
