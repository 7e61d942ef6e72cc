"""YAML reading that keeps the line of every item and refuses duplicate keys."""

from __future__ import annotations

from dataclasses import dataclass

import yaml

from .errors import SpecError
from .limits import DEFAULT, Limits


@dataclass(frozen=True)
class Located:
    """Plain YAML data (dicts, lists, scalars) plus a map from item path to 1-based line."""

    data: object
    lines: dict[tuple, int]
    source: str

    def line(self, *path) -> int | None:
        """The line of the item at ``path``, or of its closest enclosing item."""
        path = tuple(path)
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path[:-1]
        return self.lines.get(())


_PLAIN_TAGS = frozenset(
    "tag:yaml.org,2002:" + t for t in ("str", "int", "float", "bool", "null", "map", "seq")
) | {"!"}


def read_yaml(text: str, source: str, limits: Limits = DEFAULT) -> Located:
    """Parse YAML text (safe loader only) into :class:`Located` data, within ``limits``: its
    size, and its nodes once aliases are expanded (a recursive alias and the merge key
    ``<<`` are refused)."""
    if len(text) > limits.max_bytes:
        raise SpecError(f"the spec has {len(text)} characters, more than {limits.max_bytes} "
                        "(limit max_bytes)", source)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise SpecError(f"invalid YAML: {problem}", source, line) from None
    except RecursionError:
        raise SpecError("YAML nested too deeply", source) from None
    if node is None:
        raise SpecError("empty spec", source, 1)
    lines: dict[tuple, int] = {}
    constructor = yaml.SafeLoader("")
    budget = _Budget(limits.max_yaml_nodes, set())
    try:
        data = _convert(node, (), lines, source, constructor, budget)
    except RecursionError:
        raise SpecError("YAML nested too deeply", source) from None
    return Located(data, lines, source)


@dataclass
class _Budget:
    """Nodes left to convert (aliases expanded), and the collections being converted (an
    alias to one of them is a cycle)."""

    left: int
    open: set


def _convert(node, path, lines, source, constructor, budget: _Budget):
    line = node.start_mark.line + 1
    budget.left -= 1
    if budget.left < 0:
        raise SpecError("more YAML nodes than the limit once aliases are expanded (an alias "
                        "bomb? limit max_yaml_nodes)", source, line)
    if id(node) in budget.open:
        raise SpecError("recursive YAML alias", source, line)
    lines[path] = line
    if isinstance(node, yaml.MappingNode | yaml.SequenceNode) and node.tag not in _PLAIN_TAGS:
        raise SpecError(f"YAML tag {node.tag!r} not allowed", source, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        out = {}
        budget.open.add(id(node))
        for key_node, value_node in node.value:
            key_line = key_node.start_mark.line + 1
            if not isinstance(key_node, yaml.ScalarNode):
                raise SpecError("mapping keys must be plain names", source, key_line)
            if key_node.tag == "tag:yaml.org,2002:merge":
                raise SpecError("YAML merge keys ('<<') are not allowed: write the entries",
                                source, key_line)
            key = _scalar(constructor, key_node, source)
            if key in out:
                raise SpecError(f"duplicate name {key!r}", source, key_line)
            out[key] = _convert(value_node, path + (key,), lines, source, constructor, budget)
            lines[path + (key,)] = key_line
        budget.open.discard(id(node))
        return out
    if isinstance(node, yaml.SequenceNode):
        budget.open.add(id(node))
        out = [
            _convert(item, path + (i,), lines, source, constructor, budget)
            for i, item in enumerate(node.value)
        ]
        budget.open.discard(id(node))
        return out
    if node.tag in _PLAIN_TAGS:
        return _scalar(constructor, node, source)
    raise SpecError(f"YAML tag {node.tag!r} not allowed", source, node.start_mark.line + 1)


def _scalar(constructor, node, source):
    try:
        return constructor.construct_object(node)
    except (yaml.YAMLError, ValueError, OverflowError) as exc:
        raise SpecError(f"invalid YAML value: {str(exc).splitlines()[0][:120]}", source,
                        node.start_mark.line + 1) from None
