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
    """kanagen: declare a family of models in YAML, generate its estimation code, and fit it
    to noisy measures with the projector of INRIA report RR-4050.

    \b
    Typical use:
      kanagen show examples/conic.yaml          # what the spec declares
      kanagen build examples/conic.yaml -o generated
      kanagen fit examples/conic.yaml examples/data/ellipse_arc.csv --model conic
    """


@main.command()
@click.argument("specs", nargs=-1, type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out_dir", default="generated", show_default=True,
              type=click.Path(file_okay=False), help="Folder for the generated modules.")
@click.option("--check", is_flag=True,
              help="Regenerate in memory and fail with a diff if a file in OUT differs "
                   "(default SPECS: examples/*.yaml).")
def build(specs, out_dir, check):
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
            diffs = check_specs(list(specs), out_dir)
            for diff in diffs:
                click.echo(diff, nl=False)
            if diffs:
                _fail(f"{len(diffs)} generated file(s) in {out_dir} differ from their spec; "
                      f"run: kanagen build {' '.join(specs)} -o {out_dir}", 1)
            click.echo(f"{len(specs)} spec(s): generated files in {out_dir} are up to date")
            return
        for spec in specs:
            for path in build_spec(spec, out_dir):
                click.echo(f"{spec} -> {path}")
    except SpecError as exc:
        _fail(str(exc))


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
@click.option("--model", default=None, help="Model to fit (default: the null model).")
@click.option("--channel", default=None, help="Channel of DATA (default: the only one).")
@click.option("--sigma", type=float, default=None,
              help="Standard deviation of each corrected component (info = 1/sigma²).")
@click.option("--const", "consts", multiple=True, metavar="NAME=VALUE",
              help="Set a constant (repeatable).")
@click.option("--max-iter", type=int, default=100, show_default=True)
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None,
              help="Write the result as JSON to this file ('-' for stdout).")
def fit(spec, data, model, channel, sigma, consts, max_iter, json_out):
    """Fit MODEL of SPEC to the measures in DATA (CSV with a header naming the components,
    NPZ or JSON) with the local estimator, and print the estimate with its uncertainty."""
    from . import fit as fit_model
    from . import load
    from .dataio import read_measures

    try:
        fam = load(spec)
        if channel is None:
            if len(fam.channels) != 1:
                _fail(f"--channel is required: {spec} has channels {list(fam.channels)}")
            channel = next(iter(fam.channels))
        info = fam.channel(channel)
        X = read_measures(data, info.components, channel)
        constants = {}
        for item in consts:
            name, sep, value = item.partition("=")
            if not sep:
                _fail(f"--const expects NAME=VALUE, got {item!r}")
            constants[name] = float(value)
        if sigma is not None and not sigma > 0:
            _fail("--sigma must be positive")
        res = fit_model(fam, model, data={channel: X},
                        info={channel: None if sigma is None else sigma**-2},
                        constants=constants, max_iter=max_iter)
    except SpecError as exc:
        _fail(str(exc))
    except ValueError as exc:
        _fail(str(exc))
    click.echo(res.summary())
    if json_out:
        text = json.dumps(result_to_json(res), indent=2)
        if json_out == "-":
            click.echo(text)
        else:
            Path(json_out).write_text(text + "\n", encoding="utf-8")
    sys.exit(0 if res.success else 1)


def result_to_json(res) -> dict:
    """A FitResult as plain JSON data."""
    def arr(a):
        return np.asarray(a).tolist()

    return {
        "model": res.model,
        "params": res.params,
        "std": dict(zip(res.params, arr(res.std), strict=True)),
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
