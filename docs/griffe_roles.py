"""A griffe extension (mkdocstrings-python, ``docs/mkdocs.yml``): Sphinx roles in docstrings become links.

The docstrings use Sphinx's cross-reference roles (``:func:`~factorloc.localize```,
``:class:`Panorama```, ``:meth:`from_images```, ``:mod:``, ``:data:``, ``:attr:``,
``:exc:``), which mkdocstrings does not read. Once the package is loaded, each role
is resolved as Sphinx would (the name itself, then relative to the object's class
and module, then to ``factorloc``) and replaced by an optional autorefs link
(``<autoref identifier=... optional>``): a link when the target is on the site,
plain code otherwise, never a warning. ``~`` keeps only the last component as the text.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(mod|func|meth|class|data|attr|exc|obj|const|file):`(~?)([^`<>]+?)(?:\s*<([^`>]+)>)?`")


def _exists(pkg: griffe.Module, path: str) -> griffe.Object | None:
    if path == pkg.path:
        return pkg
    if not path.startswith(pkg.path + "."):
        return None
    try:
        obj = pkg[path[len(pkg.path) + 1 :]]
    except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None
    try:
        return obj.final_target if obj.is_alias else obj
    except (griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None


def _scopes(obj: griffe.Object) -> list[str]:
    out = []
    cur: griffe.Object | None = obj
    while cur is not None:
        out.append(cur.path)
        cur = cur.parent
    return out


def resolve(pkg: griffe.Module, obj: griffe.Object, name: str) -> str | None:
    """The canonical path a role's target names, seen from ``obj``'s docstring (None when not in the package)."""
    name = name.strip().lstrip(".").removesuffix("()")
    for candidate in [name] + [f"{scope}.{name}" for scope in _scopes(obj)]:
        target = _exists(pkg, candidate)
        if target is not None:
            return target.canonical_path
    return None


def convert(pkg: griffe.Module, obj: griffe.Object, text: str) -> str:
    """``text`` with every Sphinx role replaced by an autorefs link (see the module docstring)."""

    def one(m: re.Match[str]) -> str:
        role, tilde, title, explicit = m.groups()
        if role == "file":
            return f"`{title}`"
        target_name = explicit or title
        shown = title if explicit else (target_name.strip().split(".")[-1] if tilde else target_name.strip())
        if role in ("func", "meth") and not shown.endswith("()"):
            shown += "()"
        path = resolve(pkg, obj, target_name)
        if path is None:
            return f"`{shown}`"
        return f'<autoref identifier="{path}" optional><code>{shown}</code></autoref>'

    return _ROLE.sub(one, text)


class SphinxRoles(griffe.Extension):
    """Rewrite the roles of every docstring of the package once it is loaded."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        seen: set[int] = set()

        def walk(obj: griffe.Object) -> None:
            if id(obj) in seen:
                return
            seen.add(id(obj))
            if obj.docstring is not None and ":" in obj.docstring.value:
                obj.docstring.value = convert(pkg, obj, obj.docstring.value)
            for member in obj.members.values():
                if not member.is_alias:
                    walk(member)

        walk(pkg)
