"""The ``kanagen`` command line."""

from __future__ import annotations

import glob
import json
import sys
from pathlib import Path

import click

from .modelspec import SpecError


def _fail(message: str, code: int = 2):
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def limit_options(command):
    """``--trusted`` and ``--limit NAME=VALUE``: what reading a spec may cost (the bounds of
    :class:`kanagen.modelspec.Limits`, documented in the README)."""
    command = click.option(
        "--limit", "limit", multiple=True, metavar="NAME=VALUE",
        help="Raise one bound on what reading SPEC may cost (repeatable), e.g. "
             "max_nodes=1000000; see the README's limits.")(command)
    return click.option(
        "--trusted", is_flag=True,
        help="Lift every bound on what reading SPEC may cost (a spec you wrote).")(command)


def _limits(trusted: bool, limit: tuple[str, ...]):
    from .modelspec import Limits

    try:
        return (Limits.trusted() if trusted else Limits()).with_options(limit)
    except ValueError as exc:
        _fail(str(exc))


def _initializers():
    """The runtime's initialiser registry: the names a spec's models may give, and what
    each needs (handed to the spec reader as data)."""
    from .runtime.initializers import INITIALIZERS

    return INITIALIZERS


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
      kanagen fit examples/conic_lattice.yaml points.csv             # robust, lattice
      kanagen fit examples/conic.yaml examples/data/ellipse_arc.csv --model conic --local
      kanagen batch examples/conic_lattice.yaml 'scenes/*.csv' --db results.sqlite
      kanagen structures examples/line.yaml drawing.csv   # several lines in one file
      kanagen report result.json -o report.html       # a page with the pictures
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
@limit_options
def build(specs, out_dir, backends, compile_, check, trusted, limit):
    """Generate the estimation module of each SPEC (YAML) into OUT."""
    from .codegen import build as build_spec
    from .codegen import check as check_specs

    limits = _limits(trusted, limit)
    if not specs:
        if not check:
            _fail("no spec given (kanagen build SPEC.yaml [-o DIR])")
        specs = sorted(glob.glob("examples/*.yaml"))
        if not specs:
            _fail("no spec given and no examples/*.yaml here")
    try:
        if check:
            diffs = check_specs(list(specs), out_dir, backends or None, _initializers())
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
            for path in build_spec(spec, out_dir, names, limits, _initializers()):
                click.echo(f"{spec} -> {path}")
            if compile_:
                _compile(spec, limits)
    except SpecError as exc:
        _fail(str(exc))


def _compile(spec: str, limits) -> None:
    """Compile the CasADi functions of ``spec`` into the cache; a warning without compiler."""
    from .codegen.compile import CompileError, compile_family
    from .loader import _module_for
    from .modelspec import load_spec
    from .runtime.family import cache_dir

    family = load_spec(spec, limits, _initializers())
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
@limit_options
def show(spec, trusted, limit):
    """Print what SPEC declares: parameter, constants, channels, models and their lattice."""
    from .modelspec import load_spec

    try:
        fam = load_spec(spec, _limits(trusted, limit), _initializers())
    except SpecError as exc:
        _fail(str(exc))
    click.echo(f"family {fam.name!r} (sha256 {fam.sha256[:12]}...) from {spec}")
    click.echo(_wrap_expr("parameter: " + ", ".join(f"{n}={v:g}" for n, v in fam.parameter),
                          "  "))
    if fam.constants:
        click.echo(_wrap_expr("constants: " + ", ".join(f"{n}={v:g}" for n, v in fam.constants),
                              "  "))
    for ch in fam.channels:
        exact = f" (exact: {', '.join(ch.exact)})" if ch.exact else ""
        click.echo(f"  channel {ch.name}: [{', '.join(ch.components)}]{exact}")
        for eq in ch.equations:
            click.echo(_wrap_expr(f"{eq} = 0", "    "))
    for m in fam.models:
        marker = " (null model)" if m.name == fam.null_model else ""
        click.echo(f"  model {m.name}{marker}: {len(m.constraints)} constraint(s)")
        for c in m.constraints:
            click.echo(_wrap_expr(f"{c} = 0", "    "))
        for ch, eqs in m.equations:
            text = "; ".join(f"{e} = 0" for e in eqs)
            click.echo(_wrap_expr(f"channel {ch} overridden: {text}", "    "))
        for alt in m.alternatives:
            click.echo(f"    -> {alt.model} (phi {alt.phi})")
    for d in fam.derived:
        click.echo(f"  derived {d.name}: shape {d.shape or 'scalar'}")


SHOW_WIDTH = 100


def _wrap_expr(text: str, indent: str, width: int = SHOW_WIDTH) -> str:
    """``text`` indented, folded at the spaces around its operators (`` + ``, `` - ``,
    ``; ``, ``, ``) into lines of about ``width`` columns, the continuations indented four more.
    A run without spaces longer than the line (a long product) is not cut."""
    import textwrap

    return "\n".join(textwrap.wrap(text, width, initial_indent=indent,
                                    subsequent_indent=indent + "    ",
                                    break_long_words=False, break_on_hyphens=False))


#: --sigma and --const of `kanagen fit`, `batch` and `structures`
sigma_option = click.option(
    "--sigma", "sigmas", multiple=True, metavar="SIGMA|NAME=SIGMA,...",
    help="Standard deviation of each measured component (info = 1/sigma²; default 1): one "
         "number for all, or per component by name, a number or a column of DATA holding one "
         "per measure, e.g. --sigma dose=0.02,response=sd_response (repeatable; a bare "
         "number: the components not named).")
const_option = click.option(
    "--const", "consts", multiple=True, metavar="NAME=VALUE,...",
    help="Set constants of SPEC, e.g. --const cx=320,cy=240 (repeatable).")
#: --json of `kanagen fit` and `structures`
json_option = click.option(
    "--json", "json_out", type=click.Path(dir_okay=False), default=None,
    help="Also write the result as JSON to this file; '-': to stdout, the text going to "
         "stderr. Infinite or undefined numbers are null.")


def fit_options(command):
    """The estimation options of ``kanagen fit``, shared with ``kanagen batch`` (defined once,
    turned into a :class:`~kanagen.fitjob.FitOptions` by :func:`_fit_options`)."""
    options = [
        click.option("--channel", default=None,
                     help="Channel of DATA (default: the only one of SPEC)."),
        click.option("--scale", type=float, default=None, metavar="L*",
                     help="L*, the order of magnitude of an inlier's error (report eq. 29). "
                          "Errors are squared distances in units of --sigma per equation: an "
                          "inlier's is about 1. Default: each model's chi-square quantile "
                          "chi2_p(0.999)/p of its p equations per measure (10.83 for one, 6.91 "
                          "for two), right when --sigma is the noise."),
        click.option("--scorer", type=click.Choice(["relevance", "ransac", "trimmed"]),
                     default="relevance", show_default=True,
                     help="Score of a sample's estimate over all the measures."),
        click.option("--phi", default=None, metavar="PHI",
                     help="Cost factor of every edge of the lattice: a number, aic, ftest, "
                          "ftest:P or exp:K (default: each edge's factor from SPEC)."),
        click.option("--seed", type=int, default=0, show_default=True,
                     help="Seed of the random samples (same seed, same result)."),
        click.option("--max-samples", type=click.IntRange(min=1), default=2000,
                     show_default=True,
                     help="Stop the search after this many random samples in all."),
        click.option("--fixed-budget", is_flag=True,
                     help="Draw for each model the samples of eq. 25 at an assumed half of "
                          "inliers (default: as many as the inlier ratio of its best estimate "
                          "so far asks, within --max-samples)."),
        click.option("--model", default=None,
                     help="Robust: search this model only, not the lattice. With --local: the "
                          "model to fit (default: the null model)."),
        click.option("--local", is_flag=True,
                     help="Fit one model (--model) to all the measures with the local "
                          "estimator: no random samples, no outlier rejection."),
        sigma_option,
        const_option,
        click.option("--max-iter", type=int, default=100, show_default=True,
                     help="Iterations of the local estimator (--local only)."),
        click.option("--correct-bias", is_flag=True,
                     help="Remove the second-order bias of the estimate (Kanatani's "
                          "hyperaccurate correction): of the local fit, or of the chosen "
                          "model refitted on its inliers."),
        click.option("--start", "starts", multiple=True, metavar="NAME=VALUE,...",
                     help="Starting values of parameters, e.g. --start b0=1,b1=2 (repeatable; "
                          "the others keep SPEC's). With --local, where the iteration starts; "
                          "otherwise the null model's estimate before any sample."),
    ]
    for option in reversed(options):
        command = option(command)
    return command


backend_option = click.option(
    "--backend", type=click.Choice(["compiled", "numpy", "casadi"]), default=None,
    help="What evaluates the equations (the same results): compiled (the default, or "
         "$KANAGEN_BACKEND): C through CasADi and the C compiler, compiled once per spec and "
         "cached, the NumPy backend with a warning where no C compiler works; numpy: the "
         "generated NumPy module, no compiler needed.")


def _fit_options(scale, scorer, phi, seed, max_samples, fixed_budget, model, local, sigmas,
                 consts, max_iter, starts, correct_bias=False):
    """The validated FitOptions of :func:`fit_options`' values; bad input exits 2."""
    from .fitjob import FitOptions

    try:
        return FitOptions(scale=scale, scorer=scorer, phi=phi, seed=seed,
                          max_samples=max_samples, model=model, local=local,
                          sigma=_parse_sigmas(sigmas),
                          constants=_parse_constants(consts), max_iter=max_iter,
                          start=_parse_pairs(",".join(starts).split(","), "--start"),
                          adaptive=not fixed_budget, correct_bias=correct_bias)
    except ValueError as exc:
        _fail(str(exc))


@main.command()
@click.argument("spec", type=click.Path(exists=True, dir_okay=False))
@click.argument("data", type=click.Path(exists=True, dir_okay=False))
@fit_options
@json_option
@backend_option
@limit_options
def fit(spec, data, channel, json_out, backend, trusted, limit, **options):
    """Find the model of SPEC that the measures in DATA support, despite outliers.

    DATA is a CSV file whose header names the channel's components (in any order, other
    columns ignored, names case-sensitive; a file without a header is read when it has
    exactly the components' columns, in spec order), an NPZ file (an array named after the
    channel, or a single array) or a JSON file ({channel: rows}, a list of rows or a list of
    {component: value}). A measure's id is its row in DATA, from 0.

    By default, the robust lattice search of report §5: random minimal samples fit the null
    model, then each more general model from the measures its parent left out; each sample's
    estimate is scored against every measure at the scale L* (--scale), the best is refined
    on its inliers, and a general model replaces its parent only when its cost L~²/d beats
    the parent's by the factor Φ (--phi). A progress bar shows on a terminal. Printed: the
    lattice, one row per model estimated (the chosen one marked *), then the chosen model's
    estimate ± standard deviation (inf: unobservable) and its derived quantities. The JSON
    also carries what `kanagen report` draws: every measure's error, the threshold, the
    best-relevance curve and the lattice.

    With --local, fit one model to all the measures with the local estimator of §2–3.

    Ctrl-C stops the search: the best model so far is printed (and written to --json) as
    usual, with stop reason "interrupted", and the exit status is 130, as for `kanagen batch`.

    The chosen model's number of false alarms (NFA, printed and in the JSON) says whether
    its inliers are more than chance: at most 1, measures uniform in their box would rarely
    give as many; above 1, they would (no structure shown: exit status 1).

    Exit status: 0 when a model was found that is more than chance (--local: when the fit
    converged), 1 otherwise, 2 on bad input, 130 when interrupted (Ctrl-C).

    \b
    Examples:
      kanagen fit examples/conic_lattice.yaml arc.csv --json result.json
      kanagen fit examples/conic.yaml examples/data/ellipse_arc.csv --model conic --local
    """
    opts = _fit_options(**options)
    try:
        _fit(spec, data, channel, json_out, backend, trusted, limit, opts)
    except KeyboardInterrupt:  # before or after the search: nothing to report
        _fail("interrupted", 130)


def _dataset(spec, data, channel, backend, trusted, limit, opts):
    """SPEC loaded and DATA's measures of its channel, checked (``kanagen fit`` and
    ``structures``): ``(fam, channel, X, sigmas)``, ``sigmas`` the per-measure σ columns
    ``opts`` names (or None). Bad input raises or exits 2."""
    from . import load
    from .dataio import read_measures
    from .fitjob import read_sigmas, resolve_channel

    fam = load(spec, backend=backend, limits=_limits(trusted, limit))
    channel = resolve_channel(fam, channel)
    opts.check(fam)
    X = read_measures(data, fam.channel(channel).components, channel)
    if X.ndim != 2 or X.shape[0] == 0:
        _fail(f"{data}: no measures for channel {channel!r}")
    return fam, channel, X, read_sigmas(data, opts, channel)


def _fit(spec, data, channel, json_out, backend, trusted, limit, opts):
    """The body of ``kanagen fit``; exits with its status."""
    from .fitjob import local_record, make_estimator

    try:
        fam, channel, X, sigmas = _dataset(spec, data, channel, backend, trusted, limit, opts)
        if opts.local:
            res, record = local_record(fam, X, channel, opts, spec=spec, data=data,
                                       sigmas=sigmas)
        else:
            est = make_estimator(fam, X, channel, opts, sigmas)
    except (SpecError, ValueError, OSError) as exc:
        _fail(str(exc))
    to_err = json_out == "-"  # stdout holds the JSON alone; the text goes to stderr
    if opts.local:
        click.echo(res.summary(), err=to_err)
        _write_json(record, json_out)
        sys.exit(0 if res.success else 1)
    found, interrupted = _report_robust(est, fam, channel, X, json_out, to_err, opts,
                                        spec=spec, data=data, sigmas=sigmas)
    meaningful = found and not est.best().false_alarms > 1
    sys.exit(130 if interrupted else 0 if meaningful else 1)


@main.command()
@click.argument("spec", type=click.Path(exists=True, dir_okay=False))
@click.argument("data", type=click.Path(exists=True, dir_okay=False))
@click.option("--channel", default=None, help="Channel of DATA (default: the only one of SPEC).")
@click.option("--model", default=None,
              help="The model of every structure (default: the lattice search picks one "
                   "for each).")
@click.option("--max-structures", type=click.IntRange(min=1), default=5, show_default=True,
              help="Structures at most (a cap: the search stops at the first that chance "
                   "explains).")
@click.option("--scale", type=float, default=None, metavar="L*",
              help="L* (default: each model's chi2_p(0.999)/p, as for `kanagen fit`).")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of the random samples (same seed, same result).")
@click.option("--max-samples", type=click.IntRange(min=1), default=2000, show_default=True,
              help="Random samples of each search at most.")
@sigma_option
@const_option
@json_option
@backend_option
@limit_options
def structures(spec, data, channel, model, max_structures, scale, seed, max_samples, sigmas,
               consts, json_out, backend, trusted, limit):
    """Find the several structures of SPEC's models in DATA (clustered data, report §4):
    lines in a drawing, planes or rigid motions in the matches of two views.

    One structure is found by the robust search, its inliers are taken out, and the search
    goes on among the rest while what it finds is more than chance: its number of false
    alarms (NFA: the chance that measures uniform in their box give as many inliers, times
    the hypotheses a search may try) at most 1. Then each measure goes to the structure
    that explains it best and each structure is refitted on its own. DATA is read as by
    `kanagen fit`. Printed: each structure's model, inliers, NFA and estimate ± standard
    deviation; the JSON also has every measure's structure (labels: -1 for an outlier).

    Exit status: 0 when a structure was found, 1 when none is more than chance, 2 on bad
    input, 130 when interrupted (Ctrl-C).

    \b
    Examples:
      kanagen structures examples/line.yaml drawing.csv --sigma 0.5 --json found.json
      kanagen structures examples/two_view.yaml matches.csv --model planar \\
          --const cx=320,cy=240,f0=640
    """
    from .fitjob import FitOptions
    from .structjob import structures_record, structures_summary

    try:
        opts = FitOptions(scale=scale, seed=seed, max_samples=max_samples, model=model,
                          sigma=_parse_sigmas(sigmas), constants=_parse_constants(consts))
        fam, channel, X, sigmas = _dataset(spec, data, channel, backend, trusted, limit, opts)
        found, record = structures_record(fam, X, channel, opts, max_structures, spec=spec,
                                          data=data, sigmas=sigmas)
    except (SpecError, ValueError, OSError) as exc:
        _fail(str(exc))
    except KeyboardInterrupt:
        _fail("interrupted", 130)
    to_err = json_out == "-"
    click.echo(f"family {fam.name!r}, channel {channel!r}: {len(X)} measures", err=to_err)
    click.echo(structures_summary(found, len(X), max_structures), err=to_err)
    _write_json(record, json_out)
    sys.exit(0 if found else 1)


@main.command()
@click.argument("spec", type=click.Path(exists=True, dir_okay=False))
@click.argument("data_glob", metavar="'DATA_GLOB'")
@fit_options
@click.option("--db", required=True, type=click.Path(dir_okay=False),
              help="SQLite file of the results (created when missing; a re-run resumes).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local worker processes (default: the CPUs available).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="A dask.distributed scheduler (tcp://host:8786): run on its workers "
                   "instead of local ones.")
@click.option("--retry-errors", is_flag=True,
              help="Estimate again the datasets whose earlier run failed.")
@backend_option
@limit_options
def batch(spec, data_glob, channel, db, workers, scheduler, retry_errors, backend, trusted, limit,
          **options):
    """Estimate every dataset matching DATA_GLOB with SPEC and the same options, in parallel.

    One estimation per data file (formats as for `kanagen fit`; quote the glob, ** matches
    folders recursively) on Dask workers: local processes by default, or the workers of a
    dask.distributed scheduler (--scheduler; they need kanagen, not the files: the measures
    travel with each task). Each dataset's outcome is written to the SQLite database --db as
    it finishes, in its own transaction: the dataset, the spec's hash, the options, the
    chosen model, its estimate, Q~, inliers, cost L~²/d, status and time, and the full JSON
    record of `kanagen fit --json` (what `kanagen report --db` draws).

    Re-running the same command skips what is done; a dataset that fails is recorded with
    its error and the run goes on; a run killed at any moment keeps every finished result.
    A progress bar over datasets shows on a terminal.

    Exit status: 0 when no dataset failed, 1 otherwise, 2 on bad input.

    \b
    Examples:
      kanagen batch examples/conic_lattice.yaml 'scenes/*.csv' --db results.sqlite
      kanagen batch spec.yaml 'pairs/**/*.npz' --channel match --db r.sqlite --workers 8
      kanagen batch spec.yaml 'pairs/*.csv' --db r.sqlite --scheduler tcp://10.0.0.1:8786
    """
    from .batching import batch as run_batch

    opts = _fit_options(**options)
    bar = None

    def start(todo, skipped):
        nonlocal bar
        if skipped:
            click.echo(f"{skipped} dataset(s) already in {db}: skipped", err=True)
        if todo and sys.stderr.isatty():
            bar = click.progressbar(length=todo, label="datasets", file=sys.stderr,
                                    item_show_func=lambda o: o and f"{o.dataset}: {o.status}")
            bar.__enter__()

    def step(outcome):
        if bar is not None:
            bar.update(1, outcome)
        if outcome.status == "error":
            where = "" if outcome.message.startswith(outcome.dataset) else f"{outcome.dataset}: "
            click.echo(f"{chr(10) if bar else ''}error: {where}{outcome.message}", err=True)

    try:
        summary = run_batch(spec, data_glob, db=db, channel=channel, workers=workers,
                            scheduler=scheduler, retry_errors=retry_errors, progress=step,
                            on_start=start, options=opts, backend=backend,
                            limits=_limits(trusted, limit))
    except (SpecError, ValueError, OSError, ImportError) as exc:
        _fail(str(exc))
    except KeyboardInterrupt:
        _fail(f"interrupted: the finished datasets are in {db}; the same command resumes", 130)
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    click.echo(str(summary))
    sys.exit(1 if summary.errors else 0)


@main.command()
@click.argument("result", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--db", type=click.Path(exists=True, dir_okay=False), default=None,
              help="A results database of kanagen batch (with --dataset).")
@click.option("--dataset", default=None, help="The dataset of --db to report.")
@click.option("-o", "--out", required=True, type=click.Path(dir_okay=False),
              help="The HTML file to write.")
@click.option("--data", type=click.Path(exists=True, dir_okay=False), default=None,
              help="The dataset's measures (default: the file the result names, if there).")
@click.option("--images", nargs=2, type=click.Path(exists=True, dir_okay=False),
              default=None, metavar="FIRST SECOND",
              help="Two-view data: the two images, to draw the matches on.")
def report(result, db, dataset, out, data, images):
    """Write one self-contained HTML page of a result, with its pictures.

    RESULT is the JSON of `kanagen fit --json` (or of `kanagen structures --json`: each
    structure's estimate, and the measures coloured by structure); or give --db and
    --dataset for a dataset of a batch run. The page shows the chosen model and its
    estimate, the error histogram with the inlier threshold (report Fig. 5), the best
    relevance against samples (Fig. 9), the lattice of models with d and cost, the chosen
    one highlighted (Fig. 13–14), the residuals, the measures of a planar channel, and for
    two-view data (x, y, x', y') with --images the matches on both images, inliers and
    outliers coloured. Figures are SVG drawn by matplotlib, inlined: the page needs no other
    file.

    \b
    Examples:
      kanagen fit examples/conic_lattice.yaml examples/data/ellipse_outliers.csv \\
          --json result.json && kanagen report result.json -o report.html
      kanagen report --db results.sqlite --dataset scenes/s001.csv -o s001.html
    """
    from .report import write_report

    try:
        path = write_report(out, result, db=db, dataset=dataset, data=data, images=images)
    except ImportError as exc:
        _fail(f"kanagen report needs matplotlib ({exc}): pip install 'kanagen[report]'")
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    click.echo(f"wrote {path}")


def _parse_constants(items) -> dict[str, float]:
    """``--const`` values: ``NAME=VALUE`` pairs, repeated or comma-separated (as --start)."""
    return _parse_pairs([p for item in items for p in item.split(",") if p.strip()],
                        "--const")


def _parse_sigmas(items) -> float | dict[str, float | str] | None:
    """``--sigma`` values: one number (all the components), or ``NAME=SIGMA`` pairs, SIGMA
    a number or a column of DATA (a bare number among them: ``"*"``, the components not
    named); bad input exits 2 (FitOptions checks the numbers)."""
    parts = [p.strip() for item in items for p in item.split(",") if p.strip()]
    bare = [p for p in parts if "=" not in p]
    if len(bare) > 1:
        _fail(f"--sigma: one bare number at most (the components not named), got {bare}")
    try:
        default = float(bare[0]) if bare else None
    except ValueError:
        _fail(f"--sigma expects a number or NAME=SIGMA, got {bare[0]!r}")
    named = {}
    for part in parts:
        name, sep, value = part.partition("=")
        if sep:
            if not name.strip() or not value.strip():
                _fail(f"--sigma expects NAME=SIGMA (a number or a column), got {part!r}")
            named[name.strip()] = value.strip()
    if not named:
        return default
    return named if default is None else {**named, "*": default}


def _parse_pairs(items, option: str) -> dict[str, float]:
    """``NAME=VALUE`` items (empty ones skipped) as a mapping; bad input exits 2."""
    out = {}
    for item in items:
        if not item.strip():
            continue
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            number = float(value)
        except ValueError:
            _fail(f"{option} expects NAME=VALUE with a number, got {item!r}")
        out[name.strip()] = number  # finite: checked by FitOptions
    return out


def _report_robust(est, fam, channel, X, json_out, to_err, opts, *, spec,
                   data, sigmas=None) -> tuple[bool, bool]:
    """Run the search, print the lattice and the chosen model; (a model was found, the
    search was interrupted by Ctrl-C)."""
    from .fitjob import corrected_choice, robust_record

    interrupted = False
    try:
        samples = _search(est, opts.max_samples)
    except KeyboardInterrupt:  # anytime: report the best model so far
        samples, interrupted = len(est.history), True
    corrected = corrected_choice(est, fam, opts, channel, X, sigmas) \
        if opts.correct_bias else None
    record = robust_record(est, fam, opts, channel=channel, X=X, samples=samples, spec=spec,
                           data=data, interrupted=interrupted, corrected=corrected)
    measures = len(X)
    click.echo(f"family {fam.name!r}, channel {channel!r}: {measures} measures, "
               f"L* = {_scale_text(record, opts)}, scorer {opts.scorer}, {samples} sample(s): "
               f"{record['stop_reason']}", err=to_err)
    click.echo(_lattice_table(est.states(), record["model"]), err=to_err)
    for model, probe in est.probes.items():
        click.echo(f"  ({model} probed first, from all measures: {probe['samples']} "
                   f"sample(s), {probe['inliers']} inlier(s))", err=to_err)
    if record["found"]:
        click.echo(_state_summary(est.best(), measures), err=to_err)
        if corrected is not None:
            click.echo(_corrected_summary(corrected), err=to_err)
    else:
        click.echo("no model found: no sample gave an estimate", err=to_err)
    _write_json(record, json_out)
    return record["found"], interrupted


def _scale_text(record: dict, opts) -> str:
    """L* as the summary says it: the one given, or the chosen model's default."""
    if opts.scale is not None:
        return f"{opts.scale:g}"
    if record.get("scale") is None:
        return "default (chi2_p(0.999)/p)"
    return f"{record['scale']:.3g} (default, chi2_p(0.999)/p)"


def planned_total(est, max_samples: int, drawn: int) -> int:
    """The length of the progress bar: what the search plans in all now
    (:attr:`~kanagen.Estimator.planned`, counted from this run's first sample), within
    ``max_samples``, and never below what is drawn."""
    return max(min(est.planned - (est.samples - drawn), max_samples), drawn, 1)


def _search(est, max_samples: int) -> int:
    """Step the estimator up to ``max_samples`` samples; a progress bar on a terminal, whose
    length is the samples the search plans (it moves as the budgets adapt)."""
    from .fitjob import search

    if not sys.stderr.isatty():
        return search(est, max_samples)
    with click.progressbar(length=planned_total(est, max_samples, 0), label="sampling",
                           file=sys.stderr, item_show_func=lambda status: status) as bar:
        def on_sample(e):
            drawn = bar.pos + 1
            bar.length = planned_total(e, max_samples, drawn)
            bar.update(1, e.status)

        samples = search(est, max_samples, on_sample)
        bar.length = max(samples, 1)  # done (or stopped): the bar is full
        bar.update(0, est.status)
    return samples


def _lattice_table(states, chosen: str | None) -> str:
    header = ("model", "parent", "d", "L~^2/d", "relevance", "inliers", "samples", "accepted")
    rows = [header]
    for s in states:
        rows.append((s.model, s.parent or "-", str(s.dof), f"{s.normalized_cost:.4g}",
                     f"{s.relevance:.4g}", str(len(s.inliers)), str(s.samples),
                     "yes" if s.accepted else "no"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    lines = []
    for k, row in enumerate(rows):
        mark = "*" if k and row[0] == chosen else " "
        lines.append((mark + " " + "  ".join(f"{c:<{w}}" for c, w in zip(row, widths,
                                                                          strict=True))).rstrip())
    return "\n".join(lines)


def _state_summary(best, measures: int) -> str:
    from .runtime.results import estimate_lines

    lines = [f"chosen model {best.model!r}: {len(best.inliers)} inlier(s), "
             f"{len(best.outliers)} outlier(s) of {measures} measures; "
             f"L~^2/d = {best.normalized_cost:.6g}"
             f" (d = {best.dof}), relevance {best.relevance:.4g}, threshold "
             f"{best.threshold:.4g}, {best.samples} sample(s)" + best._chance_line()]
    if best.status not in ("estimated", "null"):
        lines.append(f"  refinement: {best.status}")
    lines += estimate_lines(best.params, best.slacks, best.std, best.derived,
                            best.units, best.pinned)
    return "\n".join(lines)


def _corrected_summary(res) -> str:
    """The chosen model refitted on its inliers less its bias (--correct-bias)."""
    from .runtime.results import estimate_lines

    lines = [f"bias-corrected on its inliers (hyperaccurate): {res.message}"]
    lines += estimate_lines(res.params, res.slacks, res.std, res.derived, res.units,
                            res.pinned)
    return "\n".join(lines)


def _write_json(obj, json_out: str | None) -> None:
    if not json_out:
        return
    from .fitjob import finite

    text = json.dumps(finite(obj), indent=2, allow_nan=False)
    if json_out == "-":
        click.echo(text)
        return
    try:
        Path(json_out).write_text(text + "\n", encoding="utf-8")
    except OSError as exc:
        _fail(f"cannot write {json_out}: {exc.strerror or exc}")
