"""The index page of a folder of results: a row per ``<name>.json`` record, with its overlay as a thumbnail,
its status, room height and floor area, and links to its 3D viewer and files."""

from __future__ import annotations

import html
import json
import pathlib
import urllib.parse

from ..pipeline.types import FLAGGED_STATUSES, LayoutStatus

PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="generator" content="ncjax">
<link rel="icon" href="data:,">
<title>{title}</title>
<style>
  body {{ margin: 16px; font: 14px/1.4 system-ui, sans-serif; color: #1b1d22; }}
  table {{ border-collapse: collapse; }}
  th, td {{ padding: 6px 10px; border-bottom: 1px solid #ddd; text-align: left; vertical-align: middle; }}
  td.number {{ text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }}
  img {{ display: block; width: 256px; height: 128px; object-fit: cover; background: #eee; }}
  .ok {{ color: #1a7f37; }} .flagged {{ color: #9a6700; }} .failed {{ color: #cf222e; }}
</style>
</head>
<body>
<h1>{title}</h1>
<p>{count}</p>
<table>
<tr><th>panorama</th><th>name</th><th>status</th><th>room height</th><th>floor area</th><th>files</th></tr>
{rows}
</table>
</body>
</html>
"""


def read_records(folder: str | pathlib.Path) -> list[dict]:
    """The ncjax result records (``<name>.json`` with a ``schema_version``) of ``folder``, by name."""
    records = []
    for path in sorted(pathlib.Path(folder).glob("*.json")):
        try:
            record = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue  # a file being written, or not a record
        if isinstance(record, dict) and "schema_version" in record and record.get("name") == path.stem:
            records.append(record)
    return records


def _link(file: str, content: str) -> str:
    """A link to ``file`` of the folder around ``content`` (HTML)."""
    return f'<a href="{html.escape(urllib.parse.quote(file))}">{content}</a>'


def _status(record: dict) -> tuple[str, str]:
    """The record's status in words, and its class on the page (ok, flagged or failed)."""
    status = LayoutStatus[record["status"]]
    if record["ok"]:
        return "ok", "ok"
    if status in FLAGGED_STATUSES:
        return f"flagged: {FLAGGED_STATUSES[status]}", "flagged"
    return f"failed: {status.name}", "failed"


def _row(record: dict, folder: pathlib.Path) -> str:
    name = record["name"]
    status, kind = _status(record)
    height, area = record["room_height"], record["floor_area"]
    sigma = record.get("room_height_sigma")
    thumbnail = f'<img src="{html.escape(urllib.parse.quote(f"{name}_overlay.png"))}" alt="{html.escape(name)}">'
    viewer = f"{name}.html"
    links = ((viewer, "3D view"), (f"{name}.glb", "glb"), (f"{name}.json", "json"), (f"{name}_plan.png", "plan"))
    files = [_link(file, label) for file, label in links if (folder / file).is_file()]
    cells = [
        _link(viewer, thumbnail) if (folder / viewer).is_file() else thumbnail,
        html.escape(name),
        f'<span class="{kind}">{html.escape(status)}</span>',
        "" if height is None else f"{height:.3f} m" + ("" if sigma is None else f" ± {sigma:.3f}"),
        "" if area is None else f"{area:.2f} m²",
        " · ".join(files),
    ]
    classes = ["", "", "", ' class="number"', ' class="number"', ""]
    return "<tr>" + "".join(f"<td{c}>{cell}</td>" for c, cell in zip(classes, cells, strict=True)) + "</tr>"


def index_html(folder: str | pathlib.Path) -> str:
    """The index page of the results in ``folder`` (:func:`read_records`); its links are relative to the folder."""
    folder = pathlib.Path(folder)
    records = read_records(folder)
    ok = sum(record["ok"] for record in records)
    count = f"{len(records)} results, {ok} ok" if records else "no ncjax results (<name>.json) in this folder yet"
    return PAGE.format(
        title=html.escape(f"ncjax results: {folder.resolve().name}"),
        count=count,
        rows="\n".join(_row(record, folder) for record in records),
    )
