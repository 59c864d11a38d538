"""The viewer's one HTML file: the template, style and script of this package with the data
inlined, so the page opens from disk with no server and no network."""

from __future__ import annotations

import html
import json
from importlib import resources

ASSETS = ("viewer.html", "viewer.css", "viewer.js")  # package data (setup.cfg package_data)


def asset(name: str) -> str:
    """The text of one of the package's page files."""
    return resources.files("pipeline.viewer").joinpath(name).read_text(encoding="utf-8")


def script_json(value: object) -> str:
    """JSON safe inside a <script> element: no "<", ">" or "&" (escaped as \\u00XX), so no
    string in the data (a file name, a title) can close the element."""
    text = json.dumps(value, allow_nan=False, separators=(",", ":"), ensure_ascii=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def render_page(spec: dict, header: dict, blob: str) -> str:
    """The page's HTML: the template with the title, style, description, arrays and script."""
    script, style = asset("viewer.js"), asset("viewer.css")
    if "</script" in script.lower() or "</style" in style.lower():
        raise ValueError("the viewer's script or style closes its own element")
    parts = {
        "{{TITLE}}": html.escape(spec["title"]),
        "{{STYLE}}": style,
        "{{SPEC}}": script_json({**spec, "arrays": header}),
        "{{BLOB}}": blob,  # base64: letters, digits, "+", "/", "="
        "{{SCRIPT}}": script,
    }
    page = asset("viewer.html")
    for key, value in parts.items():
        if page.count(key) != 1:
            raise ValueError(f"the viewer template must hold {key} exactly once")
        before, after = page.split(key)
        page = before + value + after
    return page
