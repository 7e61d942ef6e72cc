"""The NumPy backend: renders a family description with jinja2 into one Python module.

Recipe for another backend: a template folder, a printer with one lookup table, and a render
function that takes the same plain-data description (see :func:`kanagen.codegen.describe`).
"""

from __future__ import annotations

import pprint
import re
from functools import cache

import jinja2

from ..modelspec.ir import Family
from .describe import describe

#: Which templates render to which file: one module per family.
TEMPLATES = {"module.py.jinja": "{name}.py"}


@cache
def environment() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.PackageLoader("kanagen.codegen", "templates"),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
    )


def render(family: Family, source_name: str) -> dict[str, str]:
    """Render ``family``; returns ``{file name: text}``. Deterministic for a given spec."""
    desc = describe(family, source_name)
    context = dict(desc, family_literal=pprint.pformat(desc["family"], width=96, sort_dicts=False))
    out = {}
    for template, target in TEMPLATES.items():
        text = environment().get_template(template).render(**context)
        out[target.format(name=family.name)] = _tidy(text)
    return out


def _tidy(text: str) -> str:
    """Strip trailing blanks and runs of more than two empty lines."""
    text = "\n".join(line.rstrip() for line in text.splitlines())
    return re.sub(r"\n{4,}", "\n\n\n", text).strip("\n") + "\n"
