"""Griffe extension for the API reference: Sphinx roles in docstrings become links.

graphcal's docstrings are numpy style and cross-reference with Sphinx roles
(``:func:`graphcal.analysis.crlb.crlb```, ``:class:`~graphcal.data.dataset.Dataset```,
``:meth:`bias```).  mkdocstrings does not read those roles, so this extension
rewrites each one, when the docstrings are loaded, into an optional
cross-reference of mkdocs-autorefs: a link where the target is documented,
plain code where it is not (a private or outside name), never a warning.  A
name without dots is looked up beside the object (a method of the same class,
a function of the same module).  An RST literal-block marker ``::`` at the end
of a line becomes ``:``, the indented block after it staying a code block.

It also corrects one reading of numpy-style sections: parameters listed
together without a type (``cross, robust, robust_scale``) would all get the
first one's type and default; each gets its own from the signature instead.

The docstrings in graphcal/ are not changed; mkdocs.yml loads this file with
the python handler's ``extensions`` option.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|exc|obj|const):`(~?)([^`<>]+)`")
LITERAL_MARKER = re.compile(r"(?<=\S)::$", flags=re.MULTILINE)
UNTYPED_GROUP = re.compile(r"^[ \t]*(\w+(?:, \w+)+)[ \t]*$", flags=re.MULTILINE)


def _target(obj: griffe.Object, name: str) -> str:
    name = name.strip().lstrip(".")
    if "." in name:
        return name
    if obj.kind in (griffe.Kind.CLASS, griffe.Kind.MODULE) or obj.parent is None:
        return f"{obj.path}.{name}"
    return f"{obj.parent.path}.{name}"


def rewrite(obj: griffe.Object, text: str) -> str:
    """The docstring ``text`` of ``obj`` with its roles as optional cross-references."""

    def link(match: re.Match[str]) -> str:
        short, name = match.group(1) == "~", match.group(2).strip()
        shown = name.rsplit(".", 1)[-1] if short else name
        return (
            f'<autoref identifier="{_target(obj, name)}" optional>'
            f"<code>{shown}</code></autoref>"
        )

    return LITERAL_MARKER.sub(":", ROLE.sub(link, text))


class SphinxRoles(griffe.Extension):
    """Rewrite Sphinx roles in every loaded docstring (see the module docstring)."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = rewrite(obj, obj.docstring.value)

    def on_function(self, *, func: griffe.Function, **kwargs: Any) -> None:
        docstring = func.docstring
        if docstring is None:
            return
        grouped = {name for m in UNTYPED_GROUP.finditer(docstring.value)
                   for name in m.group(1).split(", ")}
        if not grouped:
            return
        sections = docstring.parse()
        for section in sections:
            if section.kind is not griffe.DocstringSectionKind.parameters:
                continue
            for parameter in section.value:
                if parameter.name in grouped and parameter.name in func.parameters:
                    own = func.parameters[parameter.name]
                    parameter.annotation = own.annotation
                    parameter.value = own.default
        docstring.__dict__["parsed"] = sections  # Docstring.parsed is a cached property
