"""Self-contained HTML pages: tables, pictures embedded as base64, links to files beside the page."""

from __future__ import annotations

import base64
import html
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

STYLE = """
body { font-family: sans-serif; max-width: 1150px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
th { background: #f2f2f2; }
.warn { background: #fff1e6; border-left: 5px solid #d9480f; padding: 0.5em 1em; margin: 0.8em 0; }
.ok { background: #ebfbee; border-left: 5px solid #2b8a3e; padding: 0.5em 1em; margin: 0.8em 0; }
code, pre { background: #f5f5f5; padding: 0.1em 0.3em; }
pre { padding: 0.6em; overflow-x: auto; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
"""


def esc(text: Any) -> str:
    return html.escape(str(text))


def heading(text: str, level: int = 2) -> str:
    return f"<h{level}>{esc(text)}</h{level}>"


def paragraph(text: str, kind: Literal["ok", "warn"] | None = None) -> str:
    """A paragraph (escaped); `kind` "warn" or "ok" draws it as a coloured note."""
    return f'<p class="{kind}">{esc(text)}</p>' if kind else f"<p>{esc(text)}</p>"


def code(text: str) -> str:
    return f"<pre><code>{esc(text)}</code></pre>"


def table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A table of already formatted cells."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def figure(path: str | os.PathLike, caption: str) -> str:
    """`path`'s PNG embedded as base64 with its caption; nothing when the file does not exist."""
    path = Path(path)
    if not path.is_file():
        return ""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure><img alt="{esc(path.name)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{esc(caption)}</figcaption></figure>"
    )


def links(folder: str | os.PathLike, names: Sequence[str], also: Sequence[str | os.PathLike] = ()) -> str:
    """Relative links to those of `names` that exist in `folder` (or in one of `also`, folders
    whose files are moved into `folder` with the page)."""
    where = [Path(folder), *map(Path, also)]
    found = [n for n in names if any((w / n).exists() for w in where)]
    items = "".join(f'<li><a href="{esc(n)}">{esc(n)}</a></li>' for n in found)
    return f"<p>Files beside this page:</p><ul>{items}</ul>" if found else ""


def page(title: str, blocks: Sequence[str]) -> str:
    """A whole HTML document."""
    body = "\n".join(b for b in blocks if b)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
        f"<style>{STYLE}</style></head>\n<body>\n<h1>{esc(title)}</h1>\n{body}\n</body></html>\n"
    )
