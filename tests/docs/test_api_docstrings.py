"""Every object the API page documents has numpydoc Parameters that render right (griffe, as mkdocstrings reads them).

A documented parameter must be one of the signature's, and carry the signature's type: a grouped entry
(``reference, query``) gives every name the first one's type, which is how the API page came to show
``localize``'s ``query`` as a ``Reference``.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

griffe = pytest.importorskip("griffe")


def _documented(repo_root: Path):
    pkg = griffe.load("factorloc", search_paths=[str(repo_root)], docstring_parser="numpy", allow_inspection=False)
    idents = re.findall(r"^::: (\S+)", (repo_root / "docs" / "api.md").read_text(), re.M)
    seen: set[str] = set()
    out = []

    def walk(obj) -> None:  # noqa: ANN001 - griffe objects
        if obj.is_alias:
            try:
                obj = obj.final_target
            except Exception:  # noqa: BLE001 - an alias to outside the package
                return
        if obj.path in seen:
            return
        seen.add(obj.path)
        out.append(obj)
        for name, member in obj.members.items():
            if name.startswith("_") and name != "__init__":
                continue
            target = member
            if member.is_alias:
                try:
                    target = member.final_target
                except Exception:  # noqa: BLE001
                    continue
            if target.kind.value == "module" and not target.path.startswith(obj.path + "."):
                continue
            if target.kind.value in ("function", "class", "module"):
                walk(target)

    for ident in idents:
        walk(pkg if ident == "factorloc" else pkg[ident.removeprefix("factorloc.")])
    return out


def _signature(obj):  # noqa: ANN001, ANN202
    if obj.kind.value == "class":
        init = obj.members.get("__init__")
        if init is not None and not init.is_alias:
            return {p.name: p for p in init.parameters}
        return {p.name: p for p in obj.parameters} if hasattr(obj, "parameters") else {}
    return {p.name: p for p in obj.parameters}


def test_documented_parameters_are_the_signatures_with_their_types(repo_root: Path) -> None:
    problems = []
    for obj in _documented(repo_root):
        if obj.kind.value not in ("function", "class") or obj.docstring is None:
            continue
        raw = obj.docstring.value
        params = _signature(obj)
        for section in obj.docstring.parsed:
            if section.kind.value != "parameters":
                continue
            for line in re.findall(r"^(\w[\w, *]*)$", raw.split("Parameters\n")[-1].split("\n\n")[0], re.M):
                if "," in line and len({str(params[n.strip()].annotation) for n in line.split(",") if n.strip() in params}) > 1:
                    problems.append(f"{obj.path}: '{line}' groups parameters of different types")
            for p in section.value:
                name = p.name.lstrip("*")
                if name not in params:
                    problems.append(f"{obj.path}: documents '{p.name}', not a parameter of its signature")
                elif params[name].annotation is not None and str(p.annotation) != str(params[name].annotation):
                    problems.append(
                        f"{obj.path}: '{p.name}' shows type {p.annotation}, the signature says {params[name].annotation}"
                    )
    assert not problems, "\n".join(problems)
