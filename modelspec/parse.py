"""Turn YAML text or plain Python data (with SymPy expressions) into a validated :class:`Family`.

Validation happens here, before any code is generated: names, types, the symbols each
expression may use, the models' alternatives and the acyclicity of the model lattice.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import sympy as sp

from .constructs import compile_formula, is_formula, parse_formula, slack_start
from .digest import sha256_text
from .errors import SpecError
from .expressions import (
    CONSTANTS,
    FUNCTIONS,
    Matrix,
    check_identifier,
    parse_expression,
    shape_text,
)
from .guards import tree_size
from .ir import Alternative, Channel, Derived, Family, Model, symbol
from .limits import DEFAULT, Limits
from .yamlsrc import Located, read_yaml

_TOP_KEYS = ("name", "description", "constants", "parameter", "define", "channels", "models",
             "derived", "null_model", "units")
#: a unit as people write it: "px", "deg", "m/s^2", "µm", "1/K", "N·m", "%"
_UNIT = re.compile(r"[A-Za-z0-9µΩ°%²³·/^*(). -]{0,24}")  # empty: dimensionless
#: what a constant's default stands for: printable text without quotes or markup
_ASSUME = re.compile(r"[^\x00-\x1f\x7f\"'`<>&\\]{1,120}")
_CHANNEL_KEYS = ("components", "exact", "equations", "description")
_MODEL_KEYS = ("constraints", "equations", "alternatives", "derived", "initializer",
               "admissible", "description")
#: a model's keys that name an entry of the runtime's registry, and the entry's kind
NAMED_KEYS = (("initializer", "initializer"), ("admissible", "admission"))
_PHI_WORDS = ("aic", "ftest", "exp")
_SYMPY_FUNCS = tuple(f for f in FUNCTIONS.values() if isinstance(f, type))  # sqrt is a Pow


def load_spec(path: str | Path, limits: Limits = DEFAULT,
              initializers: Mapping | None = None) -> Family:
    """Read and validate a YAML spec file (within ``limits``: :mod:`.limits`).

    ``initializers`` maps the initialiser names a model may give to what each needs (an
    object with ``missing(parameter, constants, channels) -> str``: the runtime's registry,
    handed over as data by :func:`kanagen.load` and the command line); None leaves the
    names unchecked here (the runtime refuses an unknown one when the family is used).

    Examples
    --------
    >>> fam = load_spec("examples/line.yaml")  # doctest: +SKIP
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > limits.max_bytes:
            raise SpecError(f"the spec is {size} bytes, more than {limits.max_bytes} (limit "
                            "max_bytes)", str(path))
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SpecError(f"cannot read spec: {exc.strerror}", str(path)) from None
    except UnicodeDecodeError as exc:
        raise SpecError(f"the spec is not UTF-8 text ({exc.reason} at byte {exc.start})",
                        str(path)) from None
    return parse_spec(text, source=str(path), limits=limits, initializers=initializers)


def parse_spec(text: str, source: str = "<spec>", limits: Limits = DEFAULT,
               initializers: Mapping | None = None) -> Family:
    """Validate a YAML spec given as text; ``source`` names it in errors; ``limits`` bound
    what it may cost (:mod:`.limits`); ``initializers`` as in :func:`load_spec`."""
    return _Builder(read_yaml(text, source, limits), sha256_text(text), limits,
                    initializers).family()


def family_from_data(data: Mapping, source: str = "<python>",
                     limits: Limits = DEFAULT, initializers: Mapping | None = None) -> Family:
    """Validate a spec given as Python data: the YAML layout, with SymPy expressions or text
    (``initializers`` as in :func:`load_spec`).

    Symbols may be given as ``sympy.Symbol`` or as names, anywhere a name is expected.

    Examples
    --------
    >>> import sympy as sp
    >>> a, b, x, y = sp.symbols("a b x y")
    >>> fam = family_from_data({
    ...     "name": "line", "parameter": {a: 1.0, b: 0.0},
    ...     "channels": {"pt": {"components": [x, y], "equations": [y - a * x - b]}},
    ...     "models": {"line": {"constraints": []}}})
    >>> fam.parameter_names
    ('a', 'b')
    """
    plain = _plain(data)
    digest = hashlib.sha256(sp.srepr(_sympy_only(plain)).encode("utf-8")).hexdigest()
    return _Builder(Located(plain, {}, source), digest, limits, initializers).family()


def registry_problem(registry: Mapping, name: str, kind: str, parameter, constants,
                     channels: Mapping) -> str | None:
    """What is wrong with a model naming ``name``, an entry of ``kind`` of ``registry``
    (names only, never executable text), for a family of those ``parameter`` and
    ``constants`` names and ``channels`` (name -> components); None when nothing. The
    spec reader and ``kanagen.load`` (a family built without the registry) both ask."""
    entry = registry.get(name)
    if entry is None or getattr(entry, "kind", "initializer") != kind:
        names_of = getattr(registry, "names_of", None)  # the runtime's: imports nothing
        known = names_of(kind) if names_of else sorted(registry)
        return f"unknown {kind} {name!r} (known: {', '.join(known)})"
    missing = entry.missing(parameter=list(parameter), constants=list(constants),
                            channels=channels)
    return f"{kind} {name!r} needs {missing}" if missing else None


def _plain(value):
    """Names for symbols, recursively; SymPy expressions kept as they are."""
    if isinstance(value, sp.Symbol):
        return value.name
    if isinstance(value, Mapping):
        return {_plain(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, sp.MatrixBase):
        return [[value[i, j] for j in range(value.cols)] for i in range(value.rows)]
    return value


def _sympy_only(value):
    if isinstance(value, Mapping):
        return sp.Tuple(*(sp.Tuple(sp.Symbol(str(k)), _sympy_only(v)) for k, v in value.items()))
    if isinstance(value, list):
        return sp.Tuple(*(_sympy_only(v) for v in value))
    if isinstance(value, sp.Basic):
        return value
    return sp.Symbol(repr(value))


class _Builder:
    def __init__(self, located: Located, digest: str, limits: Limits = DEFAULT,
                 initializers: Mapping | None = None):
        self.src = located
        self.digest = digest
        self.limits = limits
        self.initializers = initializers  # name -> needs (missing(...)); None: unchecked
        self.derived_names: set[str] = set()  # to say so when one uses another

    def error(self, message: str, *path) -> SpecError:
        return SpecError(message, self.src.source, self.src.line(*path))

    # -- typed accessors ---------------------------------------------------------------------
    def mapping(self, value, what, *path, empty_ok=True) -> dict:
        if value is None and empty_ok:
            return {}
        if not isinstance(value, Mapping):
            raise self.error(f"{what} must be a mapping, got {type(value).__name__}", *path)
        if not value and not empty_ok:
            raise self.error(f"{what} must not be empty", *path)
        return dict(value)

    def sequence(self, value, what, *path) -> list:
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.error(f"{what} must be a list, got {type(value).__name__}", *path)
        return value

    def keys(self, mapping, allowed, what, *path):
        for key in mapping:
            if key not in allowed:
                raise self.error(
                    f"unknown key {key!r} in {what} (allowed: {', '.join(allowed)})", *path, key
                )

    def number(self, value, what, *path) -> float:
        if isinstance(value, bool) or value is None or isinstance(value, list | Mapping):
            raise self.error(f"{what} must be a real number, got {value!r}", *path)
        expr = self.expression(value, {}, *path)
        if not expr.is_number or not expr.is_real:
            raise self.error(f"{what} must be a real number, got {value!r}", *path)
        number = float(expr)
        if number != number or number in (float("inf"), float("-inf")):
            raise self.error(f"{what} must be finite, got {value!r}", *path)
        return number

    def expression(self, value, allowed: Mapping[str, sp.Symbol], *path) -> sp.Expr:
        """A scalar expression."""
        expr = self.value(value, allowed, *path)
        if isinstance(expr, Matrix):
            raise self.error(f"expected a scalar, got a {shape_text(expr)}: {value!r}", *path)
        return expr

    def value(self, value, allowed: Mapping[str, sp.Symbol], *path) -> sp.Expr | Matrix:
        """A scalar or matrix expression; YAML lists are vectors, lists of rows matrices.

        ``allowed`` maps names to symbols and to the helper definitions in scope; the
        symbols a definition brings must themselves be allowed here (a definition that uses
        a channel's components cannot enter a constraint).
        """
        if isinstance(value, list):
            return self.listed(value, allowed, *path)
        if isinstance(value, sp.Basic):
            expr = self.check_sympy(value, allowed, *path)
        else:
            expr = parse_expression(value, allowed, self.src.source, self.src.line(*path),
                                    self.limits)
        if expr.has(sp.zoo, sp.oo, -sp.oo, sp.nan):
            raise self.error(f"expression {value!r} is not finite (division by zero?)", *path)
        symbols = {v for k, v in allowed.items() if isinstance(v, sp.Symbol) and v.name == k}
        stray = sorted(s.name for s in expr.free_symbols - symbols)
        if stray:
            raise self.error(f"symbol {stray[0]!r} (through a definition) is not available "
                             f"here, in expression {value!r}", *path)
        return expr

    def listed(self, value: list, allowed, *path) -> Matrix:
        """A YAML list of scalar expressions (a column vector) or of rows (a matrix)."""
        if value and all(isinstance(row, list) for row in value):
            widths = {len(row) for row in value}
            if len(widths) != 1 or 0 in widths:
                raise self.error("matrix rows of unequal length", *path)
            return Matrix([[self.expression(e, allowed, *path, i, j) for j, e in enumerate(row)]
                           for i, row in enumerate(value)])
        if not value or any(isinstance(e, list) for e in value):
            raise self.error("expected an expression, a list of expressions or a list of rows",
                             *path)
        return Matrix([[self.expression(e, allowed, *path, i)] for i, e in enumerate(value)])

    def check_sympy(self, expr, allowed, *path) -> sp.Expr:
        names = {s.name for s in expr.free_symbols}
        unknown = sorted(names - set(allowed))
        if unknown:
            raise self.error(f"unknown symbol {unknown[0]!r} in expression {expr}", *path)
        for node in sp.preorder_traversal(expr):
            ok = (
                node.is_Symbol
                or node.is_Number
                or node in CONSTANTS.values()
                or isinstance(node, (sp.Add, sp.Mul, sp.Pow, *_SYMPY_FUNCS))
            )
            if not ok:
                raise self.error(f"{type(node).__name__} not allowed in expression {expr}", *path)
        for s in expr.free_symbols:
            if isinstance(allowed[s.name], Matrix):
                raise self.error(f"definition {s.name!r} is a matrix: a SymPy expression may "
                                 "not use it as a symbol", *path)
        expr = expr.xreplace({s: allowed[s.name] for s in expr.free_symbols})
        if tree_size(expr, self.limits.max_nodes) > self.limits.max_nodes:
            raise self.error(f"expression of more than {self.limits.max_nodes} terms and "
                             "factors (limit max_nodes)", *path)
        return expr

    # -- the family --------------------------------------------------------------------------
    def family(self) -> Family:
        top = self.mapping(self.src.data, "the spec")
        self.keys(top, _TOP_KEYS, "the spec")
        for key in ("name", "parameter", "channels", "models"):
            if key not in top:
                raise self.error(f"missing required key {key!r}")
        name = check_identifier(top["name"], "family", self.src.source, self.src.line("name"))
        seen: dict[str, str] = {}

        def declare(item, what, *path):
            item = check_identifier(item, what, self.src.source, self.src.line(*path))
            # channels may share component names (each channel's equations see its own)
            shared = what == "component" and seen.get(item) == "component" and \
                item not in declare.channel
            if item in seen and not shared:
                where = " of this channel" if item in declare.channel else ""
                raise self.error(f"duplicate name {item!r} (already a {seen[item]}{where})",
                                 *path)
            seen[item] = what
            if what == "component":
                declare.channel.add(item)
            return item

        declare.channel = set()  # the components of the channel being declared

        parameter = tuple(
            (declare(k, "parameter", "parameter", k), self.number(v, f"default of {k}",
                                                                 "parameter", k))
            for k, v in self.mapping(top["parameter"], "parameter", "parameter",
                                     empty_ok=False).items()
        )
        constants, self.assumed = [], []
        for k, v in self.mapping(top.get("constants"), "constants", "constants").items():
            k = declare(k, "constant", "constants", k)
            if isinstance(v, Mapping):  # {value: 320, assume: "what the default stands for"}
                v = self.assumption(k, v)
            constants.append((k, self.number(v, f"value of {k}", "constants", k)))
        constants = tuple(constants)
        base = {n: symbol(n) for n, _ in parameter + constants}
        channel_specs = self.mapping(top["channels"], "channels", "channels", empty_ok=False)
        components = {c: symbol(c) for spec in channel_specs.values()
                      if isinstance(spec, Mapping) and isinstance(spec.get("components"), list)
                      for c in spec["components"] if isinstance(c, str)}
        defined = self.definitions(top.get("define"), {**base, **components}, declare)
        channels = tuple(
            self.channel(cname, spec, base, declare, defined)
            for cname, spec in channel_specs.items()
        )
        base = {**base, **defined}
        by_channel = {c.name: c for c in channels}
        models_spec = self.mapping(top["models"], "models", "models", empty_ok=False)
        self.slacks, self.clauses = {}, {}
        models = tuple(
            self.model(mname, spec, base, by_channel, models_spec, declare)
            for mname, spec in models_spec.items()
        )
        self.check_acyclic(models)
        parameter, models, slack_fields = self.add_slacks(parameter, constants, models)
        derived_specs = self.mapping(top.get("derived"), "derived", "derived")
        self.derived_names = {n for n in derived_specs if isinstance(n, str)}
        derived = tuple(
            self.derived(dname, spec, base, declare) for dname, spec in derived_specs.items()
        )
        self.check_model_extras(models, derived, parameter, constants, channels)
        null_model = top.get("null_model", models[0].name)
        if null_model not in models_spec:
            raise self.error(f"null_model {null_model!r} is not a declared model", "null_model")
        self.check_reachable(models, null_model)
        units = self.units(top.get("units"), [n for n, _ in parameter
                                                    if n not in slack_fields.get("slack", ())]
                           + [n for n, _ in constants] + [d.name for d in derived]
                           + [c for ch in channels for c in ch.components])
        return Family(
            name=name,
            units=units,
            assumed=tuple(self.assumed),
            **slack_fields,
            parameter=parameter,
            constants=constants,
            channels=channels,
            models=models,
            derived=derived,
            null_model=null_model,
            source=self.src.source,
            sha256=self.digest,
        )

    def definitions(self, value, allowed, declare) -> dict[str, sp.Expr | Matrix]:
        """Helper definitions (``define:``): named scalars, vectors and matrices of the
        parameter, the constants, the channels' components and earlier definitions. They are
        substituted where used; nothing of them reaches the IR."""
        out: dict[str, sp.Expr | Matrix] = {}
        for name, spec in self.mapping(value, "define", "define").items():
            name = declare(name, "definition", "define", name)
            out[name] = self.value(spec, {**allowed, **out}, "define", name)
        return out

    def channel(self, name, spec, base, declare, defined) -> Channel:
        path = ("channels", name)
        name = declare(name, "channel", *path)
        spec = self.mapping(spec, f"channel {name!r}", *path, empty_ok=False)
        self.keys(spec, _CHANNEL_KEYS, f"channel {name!r}", *path)
        comps = self.sequence(spec.get("components"), "components", *path, "components")
        declare.channel = set()
        if not comps:
            raise self.error(f"channel {name!r} needs at least one component", *path)
        components = tuple(
            declare(c, "component", *path, "components", i) for i, c in enumerate(comps)
        )
        exact = tuple(self.sequence(spec.get("exact"), "exact", *path, "exact"))
        for i, c in enumerate(exact):
            if c not in components:
                raise self.error(f"exact component {c!r} is not a component of {name!r}",
                                 *path, "exact", i)
        if len(set(exact)) == len(components):
            raise self.error(f"channel {name!r} has no component to correct (all are exact)",
                             *path, "exact")
        allowed = {**base, **{c: symbol(c) for c in components}, **defined}
        equations = self.equations(spec.get("equations"), allowed, *path, "equations")
        if not equations:
            raise self.error(f"channel {name!r} needs at least one equation", *path)
        return Channel(name, components, exact, equations)

    def equations(self, value, allowed, *path) -> tuple[sp.Expr, ...]:
        """Scalar equations; a vector or matrix expression stands for its entries."""
        out = []
        for i, e in enumerate(self.sequence(value, "equations", *path)):
            expr = self.value(e, allowed, *path, i)
            out.extend(expr if isinstance(expr, Matrix) else [expr])
        return tuple(out)

    def model(self, name, spec, base, channels, all_models, declare) -> Model:
        path = ("models", name)
        name = declare(name, "model", *path)
        spec = self.mapping(spec, f"model {name!r}", *path)
        self.keys(spec, _MODEL_KEYS, f"model {name!r}", *path)
        constraints, slacks = self.constraints(name, spec.get("constraints"), base, declare,
                                               *path, "constraints")
        overrides = []
        for cname, eqs in self.mapping(spec.get("equations"), "equations", *path,
                                       "equations").items():
            if cname not in channels:
                raise self.error(f"model {name!r} overrides unknown channel {cname!r}",
                                 *path, "equations", cname)
            allowed = {**base, **{c: symbol(c) for c in channels[cname].components}}
            overrides.append((cname, self.equations(eqs, allowed, *path, "equations", cname)))
            if not overrides[-1][1]:
                raise self.error(f"model {name!r} gives no equation for channel {cname!r}",
                                 *path, "equations", cname)
        order = list(channels)
        overrides.sort(key=lambda item: order.index(item[0]))
        self.slacks[name] = slacks
        derived = spec.get("derived")
        if derived is not None:
            derived = tuple(self.sequence(derived, "derived", *path, "derived"))
        initializer = spec.get("initializer")
        if initializer is not None and not isinstance(initializer, str):
            raise self.error(f"initializer must be a name, got {initializer!r}", *path,
                             "initializer")
        admissible = spec.get("admissible")
        if admissible is not None and not (isinstance(admissible, str)
                                           and admissible.isidentifier()):
            raise self.error(f"admissible must be the name of a registered test, got "
                             f"{admissible!r}", *path, "admissible")
        return Model(name, constraints, tuple(overrides),
                     self.alternatives(spec.get("alternatives"), all_models, name, *path),
                     derived, initializer, admissible)

    def constraints(self, model, value, base, declare, *path):
        """Constraint equations of a model, formulas compiled (appendix F), and their slacks.

        A list labels its items ``<model><i>``; a mapping names them (slacks ``s_<name>``).
        """
        if isinstance(value, Mapping):
            items = [(str(k), v, path + (k,)) for k, v in value.items()]
        else:
            items = [(f"{model}{i + 1}", v, path + (i,))
                     for i, v in enumerate(self.sequence(value, "constraints", *path))]
        equations, slacks, clauses = [], [], []
        for label, text, where in items:
            if is_formula(text):
                line = self.src.line(*where)
                formula = (text if isinstance(text, sp.Basic)
                           else parse_formula(text, base, self.src.source, line, self.limits))
                compiled = compile_formula(formula, label, self.src.source, line, self.limits)
                for slack in compiled.slacks:
                    declare(slack.name, "slack component", *where)
                # an equation an earlier constraint already states is dropped (a repeated
                # equation only makes the constraint Jacobian rank-deficient)
                equations.extend(e for e in compiled.equations
                                 if not any(sp.expand(e - f) == 0 for f in equations))
                clauses.extend(tuple(len(slacks) + i for i in c) for c in compiled.clauses)
                slacks.extend(compiled.slacks)
            else:
                value = self.value(text, base, *where)
                equations.extend(value if isinstance(value, Matrix) else [value])
        self.clauses[model] = tuple(clauses)
        return tuple(equations), tuple(slacks)

    def alternatives(self, value, all_models, owner, *path) -> tuple[Alternative, ...]:
        path = path + ("alternatives",)
        if isinstance(value, Mapping):
            items = [(k, v, path + (k,)) for k, v in value.items()]
        else:
            items = []
            for i, entry in enumerate(self.sequence(value, "alternatives", *path)):
                if isinstance(entry, Mapping) and len(entry) == 1:
                    (k, v), = entry.items()
                    items.append((k, v, path + (i,)))
                else:
                    items.append((entry, 1.0, path + (i,)))
        out = []
        for target, phi, where in items:
            if not isinstance(target, str) or target not in all_models:
                raise self.error(f"model {owner!r} names an unknown alternative {target!r}",
                                 *where)
            if target == owner:
                raise self.error(f"model {owner!r} names itself as an alternative", *where)
            out.append(Alternative(target, self.phi(phi, *where)))
        return tuple(out)

    def phi(self, value, *path) -> float | str:
        if isinstance(value, int | float) and not isinstance(value, bool):
            if value <= 0:
                raise self.error(f"cost factor must be positive, got {value}", *path)
            return float(value)
        if isinstance(value, str):
            word, _, arg = value.partition(":")
            if word in _PHI_WORDS and (word != "exp" or arg) and (word != "aic" or not arg) \
                    and (not value.endswith(":")):
                number = self.number(arg, f"argument of {word}", *path) if arg else None
                if word == "ftest" and number is not None and not 0 < number < 1:
                    raise self.error(f"the confidence P of {word}:P is in (0, 1), got {arg}",
                                     *path)
                return value
        raise self.error(
            f"cost factor {value!r} not understood (a number, 'aic', 'ftest', 'ftest:P' "
            "or 'exp:kappa')",
            *path,
        )

    def add_slacks(self, parameter, constants, models):
        """Slack components join the parameter (after the declared ones), starting from the
        spec's default point; a model that does not use a slack pins it (``s − s0 = 0``), so
        each slack adds one component and one equation to every model and ``d`` is right.

        Returns the parameter, the models and the :class:`Family` fields of the slacks.
        """
        values = {symbol(n): v for n, v in parameter + constants}
        owned = [(m.name, sl) for m in models for sl in self.slacks[m.name]]
        if not owned:
            return parameter, models, {}
        starts = tuple((sl.name, slack_start(sl, values)) for _, sl in owned)
        pinned = []
        for m in models:
            pins = tuple(symbol(sl.name) - v for (owner, sl), (_, v) in zip(owned, starts,
                                                                           strict=True)
                         if owner != m.name)
            pinned.append(replace(m, constraints=m.constraints + pins))
        offsets, total = {}, 0
        for m in models:
            offsets[m.name], total = total, total + len(self.slacks[m.name])
        fields = {
            "slack": tuple(sl.name for _, sl in owned),
            "slack_relations": tuple((sl.kind, sl.measure) for _, sl in owned),
            "slack_owner": tuple(owner for owner, _ in owned),
            "slack_clauses": tuple(
                (m.name, tuple(tuple(offsets[m.name] + i for i in c)
                               for c in self.clauses[m.name]))
                for m in models if self.clauses[m.name]),
        }
        return parameter + starts, tuple(pinned), fields

    def check_model_extras(self, models, derived, parameter, constants, channels):
        """A model's ``derived`` names declared quantities; its ``initializer`` and
        ``admissible`` are names of the registry handed over (names only: never executable
        text), of their kind, whose needs (parameter, constants, channel) the family
        meets."""
        names = {d.name for d in derived}
        for m in models:
            for i, d in enumerate(m.derived or ()):
                if d not in names:
                    raise self.error(f"model {m.name!r} reports an unknown derived quantity "
                                     f"{d!r}", "models", m.name, "derived", i)
            if self.initializers is None:
                continue
            for key, kind in NAMED_KEYS:
                name = getattr(m, key)
                problem = None if name is None else registry_problem(
                    self.initializers, name, kind, [n for n, _ in parameter],
                    [n for n, _ in constants], {c.name: c.components for c in channels})
                if problem:
                    raise self.error(problem, "models", m.name, key)

    def check_acyclic(self, models):
        edges = {m.name: [a.model for a in m.alternatives] for m in models}
        state: dict[str, int] = {}

        def visit(node, trail):
            state[node] = 1
            for nxt in edges[node]:
                if state.get(nxt) == 1:
                    cycle = " -> ".join(trail[trail.index(nxt):] + [nxt])
                    raise self.error(f"cycle in the model lattice: {cycle}", "models", node,
                                     "alternatives")
                if nxt not in state:
                    visit(nxt, trail + [nxt])
            state[node] = 2

        for model in models:
            if model.name not in state:
                visit(model.name, [model.name])

    def check_reachable(self, models, null_model):
        """Every model is the null model or the target of an alternative of a model the
        search reaches from it: another would silently never be tried (issue 20). A family
        whose models name no alternatives at all declares no lattice: a set of models each
        fitted on its own (``kanagen.fit``), which the lattice search refuses by name."""
        edges = {m.name: [a.model for a in m.alternatives] for m in models}
        if not any(edges.values()):
            return
        reached, todo = {null_model}, [null_model]
        while todo:
            for nxt in edges[todo.pop()]:
                if nxt not in reached:
                    reached.add(nxt)
                    todo.append(nxt)
        for model in models:
            if model.name in reached:
                continue
            parents = [m for m, targets in edges.items() if model.name in targets]
            how = (f"its parent(s) {', '.join(map(repr, parents))} are not reached either"
                   if parents else "no model names it among its alternatives")
            raise self.error(
                f"model {model.name!r} is never tried: the lattice search starts at the null "
                f"model {null_model!r} and no chain of alternatives leads to it ({how}); "
                f"add it to the alternatives of a model, or remove it", "models", model.name)

    def assumption(self, name: str, spec: Mapping):
        """A constant given as ``{value: v, assume: text}``: its default ``v`` stands for
        something of the data (an image's principal point), so a fit that relies on it says
        so — ``text`` names what to give. Returns ``v``."""
        self.keys(spec, ("value", "assume"), f"constant {name!r}", "constants", name)
        if "value" not in spec:
            raise self.error(f"constant {name!r}: missing its value", "constants", name)
        text = spec.get("assume")
        if not isinstance(text, str) or not _ASSUME.fullmatch(text):
            raise self.error(f"constant {name!r}: assume must be short text (up to 120 "
                             f"printable characters, no quotes or angle brackets), got "
                             f"{text!r}", "constants", name)
        self.assumed.append((name, text))
        return spec["value"]

    def units(self, value, names: list[str]) -> tuple[tuple[str, str], ...]:
        """``units:``: a unit (text shown beside values, nothing converted) per parameter
        component, constant, derived quantity or measured component."""
        out = []
        for name, unit in self.mapping(value, "units", "units").items():
            if name not in names:
                raise self.error(f"units: {name!r} is not a parameter component, constant, "
                                 f"derived quantity or measured component", "units", name)
            unit = "" if unit is None else unit  # ``n:`` alone: dimensionless, as ``""``
            if not isinstance(unit, str) or not _UNIT.fullmatch(unit):
                raise self.error(f"units: the unit of {name!r} must be short text (up to 24 "
                                 f"letters, digits, spaces and µΩ°%²³·/^*().-; empty: "
                                 f"dimensionless), got {unit!r}", "units", name)
            out.append((name, unit))
        return tuple(out)

    def derived(self, name, spec, base, declare) -> Derived:
        path = ("derived", name)
        name = declare(name, "derived quantity", *path)
        try:
            value = self.value(spec, base, *path)
        except SpecError as exc:
            used = re.match(r"unknown symbol '(\w+)'", exc.message)
            if not used or used[1] not in self.derived_names:
                raise
            raise SpecError(
                f"derived quantity {name!r} uses the derived quantity {used[1]!r}: derived "
                f"quantities cannot use each other; name the shared expression under define: "
                f"and use that name in both", exc.source, exc.line) from None
        if not isinstance(value, Matrix):
            return Derived(name, (), (value,))
        shape = (value.rows,) if value.cols == 1 else value.shape
        return Derived(name, tuple(shape), tuple(value))
