"""YAML read with bounded work: the one loader of every manifest, config and world file.

PyYAML's safe loader shares the node of an anchor between its aliases, so a "billion laughs" document of a
few hundred bytes constructs quickly into a structure whose *expanded* size is astronomical — the first walk
over it (validation, freezing, JSON output) then runs for minutes. :func:`load_yaml` composes the node graph
first, counts what the aliases would expand to, and refuses more than :data:`MAX_ALIAS_EXPANSION` nodes
before constructing anything. Other failures of the parser (nesting deep enough to exhaust the recursion
limit, an integer of more digits than Python converts) are raised as :class:`YamlLimitError` too, a
``yaml.YAMLError``: the callers' existing ``except yaml.YAMLError`` names the file.
"""

from __future__ import annotations

from typing import Any

import yaml

__all__ = ["MAX_ALIAS_EXPANSION", "YamlLimitError", "expanded_size", "load_yaml"]

#: The most nodes that aliases may add to a document when expanded (a manifest written by factorloc has none).
MAX_ALIAS_EXPANSION = 100_000


class YamlLimitError(yaml.YAMLError):
    """A YAML document beyond what the loader is bounded to do (alias expansion, nesting, number size)."""


def expanded_size(root: yaml.Node) -> tuple[int, int]:
    """(distinct nodes, nodes once every alias is expanded) of a composed document; iterative, memoized.

    A node that contains itself through an alias (a recursive anchor) is infinite: :class:`YamlLimitError`.
    """
    size: dict[int, int] = {}
    in_progress: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            kids = _children(node)
            size[key] = 1 + sum(size[id(c)] for c in kids)
            in_progress.discard(key)
            continue
        if key in size:
            continue
        if key in in_progress:
            raise YamlLimitError("the document contains a recursive alias (an anchor that contains itself)")
        in_progress.add(key)
        stack.append((node, True))
        for c in _children(node):
            if id(c) in in_progress:
                raise YamlLimitError("the document contains a recursive alias (an anchor that contains itself)")
            if id(c) not in size:
                stack.append((c, False))
    return len(size), size[id(root)]


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def load_yaml(text: str, max_alias_expansion: int = MAX_ALIAS_EXPANSION) -> Any:
    """The Python value of one YAML document (the safe loader's types), with alias expansion bounded.

    Raises
    ------
    yaml.YAMLError
        The document is not YAML; :class:`YamlLimitError` (a subclass) when its aliases would expand to more
        than ``max_alias_expansion`` extra nodes, it nests too deep, or a number cannot be converted.
    """
    loader_cls = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    loader = loader_cls(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        distinct, total = expanded_size(node)
        if total - distinct > max_alias_expansion:
            raise YamlLimitError(
                f"aliases would expand the document by {total - distinct} nodes (more than {max_alias_expansion}): "
                "refused (an alias bomb?)"
            )
        return loader.construct_document(node)
    except RecursionError as exc:
        raise YamlLimitError("the document nests too deep to be read") from exc
    except (ValueError, OverflowError, MemoryError) as exc:
        raise YamlLimitError(f"a value cannot be converted: {' '.join(str(exc).split())[:200]}") from exc
    finally:
        loader.dispose()
