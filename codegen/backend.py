"""HOW to generate: a backend is a template folder, a printer and a list of templates.

The description of WHAT to generate (:class:`~kanagen.codegen.description.Description`) is the
same for every backend. A backend turns it into plain data for its templates (names, shapes
and code strings printed by its printer, which holds the backend's one SymPy lookup table)
and renders the templates listed in :attr:`Backend.templates`.

Recipe for a new backend (see also ``codegen/README.md``):

1. a printer in :mod:`kanagen.codegen.printer`: a :class:`~kanagen.codegen.printer.
   TablePrinter` subclass with ONE table from SymPy function classes to the target's
   functions, checked one-to-one, covering :data:`kanagen.modelspec.FUNCTIONS` and ``sign``;
2. a folder ``codegen/templates/<name>/`` with a module template and a ``util.jinja`` of
   macros (one macro per output kind);
3. a module ``codegen/<name>_backend.py`` defining ``BACKEND = Backend(name, folder,
   templates, context)`` where ``context(description)`` returns the plain data the
   templates see (print every expression there, never in the templates);
4. register it in :data:`kanagen.codegen.BACKENDS`; add a runtime adapter in
   :mod:`kanagen.runtime.backends` if its functions are not plain NumPy callables, and add
   its name to the differential test over the shipped specs (tests/test_backends.py).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import jinja2

from ..modelspec.ir import Family
from .description import Description, Function, describe
from .printer import TablePrinter
from .safe import comment_text


@dataclass(frozen=True)
class Backend:
    """A code generation target."""

    name: str
    folder: str  # template folder under codegen/templates
    templates: dict[str, str]  # template file -> generated file name ("{name}": family name)
    context: Callable[[Description], dict]  # description -> plain data for the templates

    def render(self, family: Family, source_name: str,
               description: Description | None = None) -> dict[str, str]:
        """Render ``family``; returns ``{file name: text}``. Deterministic for a given spec."""
        desc = description or describe(family, source_name)
        context = self.context(desc)
        env = environment(self.folder)
        return {target.format(name=family.name): tidy(env.get_template(t).render(**context))
                for t, target in self.templates.items()}


@cache
def environment(folder: str) -> jinja2.Environment:
    """The templates' environment; ``comment`` is the one filter text of a spec goes
    through inside comments and docstrings (:func:`~kanagen.codegen.safe.comment_text`)."""
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("kanagen.codegen", f"templates/{folder}"),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
    )
    env.filters["comment"] = comment_text
    return env


def tidy(text: str) -> str:
    """Strip trailing blanks and runs of more than two empty lines."""
    text = "\n".join(line.rstrip() for line in text.splitlines())
    return re.sub(r"\n{4,}", "\n\n\n", text).strip("\n") + "\n"


def printed(f: Function, printer_class: type[TablePrinter]):
    """``(temps, outputs)`` of ``f`` printed: ``[(name, code)]`` and, per output,
    ``[(index tuple, code)]``."""
    printer = printer_class(f.names())
    temps = [(t.name, printer.doprint(e)) for t, e in f.temps]
    outputs = [[(index, printer.doprint(e)) for index, e in o.entries] for o in f.outputs]
    return temps, outputs
