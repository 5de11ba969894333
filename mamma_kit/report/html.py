"""The report page: sections of figures, tables and notes rendered as one self-contained
HTML file (images and the video embedded as base64 data URIs, inline CSS, no network).

Every figure is ``<figure data-figure="NAME"><img src="data:image/png;base64,..."><figcaption>``;
a small inline script counts the images the browser decoded on window load and writes
``document.body.dataset.figuresLoaded = "loaded/total"`` (read by the headless-browser test).
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml",
        ".mp4": "video/mp4"}


@dataclass
class Figure:
    name: str  # data-figure attribute: the PNG's path under report/ without suffix
    path: Path
    caption: str = ""


@dataclass
class Video:
    name: str
    path: Path
    caption: str = ""
    width: int | None = None  # px, so the caption wraps at the video's width


@dataclass
class Table:
    columns: list[str]
    rows: list[list[Any]]
    caption: str = ""


@dataclass
class Note:
    text: str
    kind: str = "info"  # info | missing | warn


@dataclass
class Embed:
    """A self-contained piece of page made by this package (the 3D view) and its caption."""

    name: str
    html: str
    caption: str = ""


Block = Union[Figure, Video, Table, Note, Embed]


@dataclass
class Section:
    id: str
    title: str
    blocks: list[Block] = field(default_factory=list)

    def figure(self, name: str, path: Path, caption: str = "") -> None:
        self.blocks.append(Figure(name, Path(path), caption))

    def video(self, name: str, path: Path, caption: str = "", width: int | None = None) -> None:
        self.blocks.append(Video(name, Path(path), caption, width))

    def table(self, columns: list[str], rows: list[list[Any]], caption: str = "") -> None:
        if rows:
            self.blocks.append(Table(list(columns), rows, caption))

    def note(self, text: str, kind: str = "info") -> None:
        self.blocks.append(Note(text, kind))

    def embed(self, name: str, html_text: str, caption: str = "") -> None:
        self.blocks.append(Embed(name, html_text, caption))

    def missing(self, what: str, command: str) -> None:
        """A line saying which input is missing and which command makes it."""
        self.blocks.append(Note(f"{what}: run <code>{html.escape(command)}</code>", "missing"))

    @property
    def figures(self) -> list[Figure]:
        return [b for b in self.blocks if isinstance(b, Figure)]

    @property
    def missing_lines(self) -> list[str]:
        return [_strip_tags(b.text) for b in self.blocks if isinstance(b, Note) and b.kind == "missing"]

    @property
    def has_content(self) -> bool:
        return any(not isinstance(b, Note) for b in self.blocks)


def _strip_tags(text: str) -> str:
    return html.unescape(text.replace("<code>", "`").replace("</code>", "`"))


def fmt(v: Any) -> str:
    """A table cell: numbers to a few significant digits, None/NaN as a dash."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "—"
        a = abs(v)
        if a >= 1000:
            return f"{v:,.0f}"
        if a >= 100:
            return f"{v:.1f}"
        if a >= 0.01 or a == 0:
            return f"{v:.3g}"
        return f"{v:.2e}"
    if isinstance(v, (list, tuple)) and v and all(isinstance(x, (list, tuple)) for x in v):
        return f"[{len(v)}x{len(v[0])} values]"
    if isinstance(v, (list, tuple)):
        return ", ".join(fmt(x) for x in v) if len(v) <= 6 else f"[{len(v)} values]"
    if isinstance(v, dict):
        return ", ".join(f"{k}: {fmt(x)}" for k, x in v.items()) if len(v) <= 4 else f"{{{len(v)} entries}}"
    return str(v)


def png_width(path: Path) -> int | None:
    """Width in px from a PNG's IHDR chunk (None if not a PNG)."""
    with open(path, "rb") as f:
        head = f.read(24)
    return int.from_bytes(head[16:20], "big") if head[:8] == b"\x89PNG\r\n\x1a\n" else None


def _cap_width(width: int | None) -> str:
    # a figure is no wider than its picture, so its caption wraps under it and small pictures pair up
    return f' style="max-width:{width}px"' if width else ""


def data_uri(path: Path) -> str:
    mime = MIME.get(Path(path).suffix.lower(), "application/octet-stream")
    return f"data:{mime};base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


CSS = """
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0; color: #1d232b;
       background: #f4f5f7; }
header { background: #1f3b57; color: #fff; padding: 18px 32px 14px; }
header h1 { margin: 0 0 4px; font-size: 26px; }
header .sub { opacity: .85; font-size: 13px; }
main { max-width: 1180px; margin: 0 auto; padding: 8px 24px 48px; }
nav { background: #fff; border: 1px solid #dde1e6; border-radius: 6px; padding: 10px 18px; margin: 18px 0; }
nav ol { margin: 4px 0; padding-left: 22px; columns: 2; }
nav a { color: #1f5f99; text-decoration: none; }
section { background: #fff; border: 1px solid #dde1e6; border-radius: 6px; padding: 6px 22px 18px; margin: 18px 0; }
h2 { border-bottom: 2px solid #e3e7ec; padding-bottom: 4px; font-size: 20px; }
figure { margin: 14px 0; }
figure img, figure video { max-width: 100%; height: auto; border: 1px solid #e3e7ec; border-radius: 3px;
                           display: block; }
figcaption { font-size: 13px; color: #4a5561; margin-top: 4px; }
table { border-collapse: collapse; margin: 10px 0 16px; font-size: 13px; }
caption { text-align: left; font-weight: 600; padding: 2px 0 6px; color: #2b3642; }
th, td { border: 1px solid #dde1e6; padding: 3px 9px; text-align: left; }
th { background: #eef1f4; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.tables { display: flex; flex-wrap: wrap; gap: 0 28px; align-items: flex-start; }
.gallery { display: flex; flex-wrap: wrap; gap: 0 20px; align-items: flex-start; }
.gallery figure { flex: 0 1 auto; max-width: 100%; }
.note { padding: 6px 10px; border-radius: 4px; margin: 8px 0; font-size: 14px; }
.note.missing { background: #fff6e0; border-left: 4px solid #e0a800; }
.note.warn { background: #fdecea; border-left: 4px solid #d9534f; }
.note.info { background: #eef4fa; border-left: 4px solid #5b8fc7; }
code { background: #eef1f4; padding: 0 4px; border-radius: 3px; font-size: 13px; }
.status-missing { color: #b07500; }
footer { color: #6b7480; font-size: 12px; text-align: center; padding: 12px; }
"""

# Counts decoded images (and videos with a decoded frame) so a headless browser's DOM dump
# shows whether everything rendered.
SCRIPT = """
function countVideos() {
  var vids = Array.prototype.slice.call(document.querySelectorAll("video"));
  var ok = vids.filter(function (v) { return v.readyState >= 2; }).length;
  document.body.dataset.videosLoaded = ok + "/" + vids.length;
}
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.dataset.figuresLoaded = ok + "/" + imgs.length;
  countVideos();
});
document.querySelectorAll("video").forEach(function (v) { v.addEventListener("loadeddata", countVideos); });
"""


def _cell(v: Any) -> str:
    num = isinstance(v, (int, float)) and not isinstance(v, bool)
    return f'<td class="num">{html.escape(fmt(v))}</td>' if num else f"<td>{html.escape(fmt(v))}</td>"


def _table(t: Table) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in t.columns)
    body = "".join("<tr>" + "".join(_cell(v) for v in row) + "</tr>" for row in t.rows)
    cap = f"<caption>{html.escape(t.caption)}</caption>" if t.caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _block(b: Block) -> str:
    if isinstance(b, Figure):
        alt = html.escape(b.name)
        return (f'<figure data-figure="{alt}"{_cap_width(png_width(b.path))}>'
                f'<img alt="{alt}" src="{data_uri(b.path)}">'
                f"<figcaption>{html.escape(b.caption)}</figcaption></figure>")
    if isinstance(b, Video):
        return (f'<figure data-video="{html.escape(b.name)}"{_cap_width(b.width)}>'
                f'<video controls autoplay loop muted playsinline preload="auto" src="{data_uri(b.path)}"></video>'
                f"<figcaption>{html.escape(b.caption)}</figcaption></figure>")
    if isinstance(b, Table):
        return _table(b)
    if isinstance(b, Embed):
        return (f'<figure data-embed="{html.escape(b.name)}">{b.html}'
                f"<figcaption>{html.escape(b.caption)}</figcaption></figure>")
    return f'<p class="note {b.kind}">{b.text}</p>'  # note texts are built by this package (may hold <code>)


def _section(s: Section) -> str:
    parts, run, kind = [], [], None
    for b in s.blocks:  # consecutive tables (figures) sit side by side where they fit
        k = "tables" if isinstance(b, Table) else ("gallery" if isinstance(b, (Figure, Video)) else None)
        if run and k != kind:
            parts.append(f'<div class="{kind}">{"".join(run)}</div>')
            run = []
        if k is None:
            parts.append(_block(b))
        else:
            run.append(_block(b))
            kind = k
    if run:
        parts.append(f'<div class="{kind}">{"".join(run)}</div>')
    return f'<section id="{s.id}" data-section="{s.id}"><h2>{html.escape(s.title)}</h2>{"".join(parts)}</section>'


def render_page(title: str, subtitle: str, overview: Table, sections: list[Section], footer: str) -> str:
    toc = "".join(f'<li><a href="#{s.id}">{html.escape(s.title)}</a>'
                  + ("" if s.has_content else ' <span class="status-missing">(missing inputs)</span>') + "</li>"
                  for s in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>"
        f"<header><h1>{html.escape(title)}</h1><div class=\"sub\">{html.escape(subtitle)}</div></header><main>"
        f"<nav><strong>Contents</strong><ol>{toc}</ol></nav>"
        f"<section id=\"overview\" data-section=\"overview\"><h2>What ran</h2>{_table(overview)}</section>"
        + "".join(_section(s) for s in sections)
        + f"</main><footer>{html.escape(footer)}</footer><script>{SCRIPT}</script></body></html>\n"
    )
