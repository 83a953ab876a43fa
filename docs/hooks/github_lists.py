"""mkdocs hook: render GitHub-style Markdown of pages kept as they are.

GitHub starts a list or a table right after a paragraph line, nests lists by
two spaces and lets a fenced block touch the text around it; Python-Markdown
needs a blank line before lists, tables and fences and four spaces per level.
The pages written for this site follow Python-Markdown's rules; a page that
must stay byte for byte as it is (the dataset contract, shared with other
tools) is adapted here, at build time, instead.
"""

from __future__ import annotations

import re
from typing import Any

#: Pages (paths under docs/) rendered with GitHub's list rules.
GITHUB_PAGES = {"CONTRACT.md"}

ITEM = re.compile(r"^( *)([-*]|\d+\.) ")
FENCE = re.compile(r"^ *`{3,}")


def adapt(text: str) -> str:
    """GitHub-style lists, tables and fences -> Python-Markdown (see the module docstring)."""
    out: list[str] = []
    lines = text.split("\n")
    in_fence = in_list = False
    for i, line in enumerate(lines):
        previous = out[-1] if out else ""
        if in_fence:
            out.append(line)
            if FENCE.match(line):
                in_fence = False
                if i + 1 < len(lines) and lines[i + 1].strip():
                    out.append("")
            continue
        if FENCE.match(line):
            if previous.strip():
                out.append("")
            out.append(line)
            in_fence, in_list = True, False
            continue
        if not line.strip():
            out.append(line)
            following = next((later for later in lines[i + 1:] if later.strip()), "")
            if not (ITEM.match(following) or following.startswith(" ")):
                in_list = False
            continue
        item = ITEM.match(line)
        if item:
            indent = len(item.group(1))
            if indent == 0 and not in_list and previous.strip():
                out.append("")
            in_list = True
            out.append(" " * (indent // 2 * 4) + line[indent:])
            continue
        if in_list and line.startswith(" "):
            indent = len(line) - len(line.lstrip(" "))
            out.append(" " * (2 * indent - 2 if indent >= 2 else indent) + line.lstrip(" "))
            continue
        table_row = line.lstrip().startswith("|")
        if table_row and previous.strip() and not previous.lstrip().startswith("|"):
            out.append("")
        in_list = False
        out.append(line)
    return "\n".join(out)


def on_page_markdown(markdown: str, page: Any, **kwargs: Any) -> str:
    if page.file.src_uri in GITHUB_PAGES:
        return adapt(markdown)
    return markdown
