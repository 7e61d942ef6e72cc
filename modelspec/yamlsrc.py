"""YAML reading that keeps the line of every item and refuses duplicate keys."""

from __future__ import annotations

from dataclasses import dataclass

import yaml

from .errors import SpecError


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


def read_yaml(text: str, source: str) -> Located:
    """Parse YAML text (safe loader only) into :class:`Located` data."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise SpecError(f"invalid YAML: {problem}", source, line) from None
    if node is None:
        raise SpecError("empty spec", source, 1)
    lines: dict[tuple, int] = {}
    constructor = yaml.SafeLoader("")
    data = _convert(node, (), lines, source, constructor)
    return Located(data, lines, source)


def _convert(node, path, lines, source, constructor):
    lines[path] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode | yaml.SequenceNode) and node.tag not in _PLAIN_TAGS:
        raise SpecError(f"YAML tag {node.tag!r} not allowed", source, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        out = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                raise SpecError("mapping keys must be plain names", source,
                                key_node.start_mark.line + 1)
            key = constructor.construct_object(key_node)
            if key in out:
                raise SpecError(f"duplicate name {key!r}", source, key_node.start_mark.line + 1)
            out[key] = _convert(value_node, path + (key,), lines, source, constructor)
            lines[path + (key,)] = key_node.start_mark.line + 1
        return out
    if isinstance(node, yaml.SequenceNode):
        return [
            _convert(item, path + (i,), lines, source, constructor)
            for i, item in enumerate(node.value)
        ]
    if node.tag in _PLAIN_TAGS:
        return constructor.construct_object(node)
    raise SpecError(f"YAML tag {node.tag!r} not allowed", source, node.start_mark.line + 1)
