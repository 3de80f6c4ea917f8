"""Tables and figures as the reports write them: Markdown (a cell's '|' shown as '/'), escaped HTML, and figures
embedded in the page (a report read from a copy, a mail or a screenshot tool in another folder still shows them)."""

from __future__ import annotations

import base64
import html
from pathlib import Path


def md_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
    return "\n".join(lines)


def html_table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def html_image(title: str, path: Path, cls: str = "", style: str = "") -> str:
    """A heading and the PNG at `path`, embedded as a data URI (no link the page depends on)."""
    t = html.escape(title)
    return (f"<h2>{t}</h2><img alt='{t}'{f' class={cls!r}' if cls else ''}{f' style={style!r}' if style else ''} "
            f"src='data:image/png;base64,{base64.b64encode(path.read_bytes()).decode()}'>")
