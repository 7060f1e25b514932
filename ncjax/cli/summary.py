"""``summary.csv``: one line per image of ``ncjax reconstruct``, merged with an earlier summary of the folder."""

from __future__ import annotations

import csv
import io
import json
import math
import pathlib

from ..pipeline.types import FLAGGED_STATUSES, LayoutStatus


def failure_message(record: dict) -> str:
    """Why the layout of a JSON record is not ok, in one short line for the console: whether a layout was
    written, the status and the room height. What the status means (:attr:`~ncjax.LayoutStatus.reason`, a
    sentence or two) is summary.csv's ``reason`` column."""
    status = record["status"]
    if not record["floor_corners"]:
        return f"no layout found ({status})"
    sigma = record["room_height_sigma"]
    height = f"room height {record['room_height']:.2f} ± {sigma or math.inf:.2f} m"
    return f"layout of {FLAGGED_STATUSES[LayoutStatus[status]]} written ({status}; {height})"


SUMMARY_FILE = "summary.csv"


SUMMARY_COLUMNS = (
    "file",
    "name",
    "result",
    "status",
    "corners",
    "room_height_m",
    "room_height_sigma_m",
    "ceiling_height_m",
    "floor_height_m",
    "floor_area_m2",
    "perimeter_m",
    "branch",
    "rc_m",
    "scale_source",
    "message",
    "reason",
)
# summary.csv's columns taken from the JSON record's keys


SUMMARY_FIGURES = {
    "room_height_m": "room_height",
    "room_height_sigma_m": "room_height_sigma",
    "ceiling_height_m": "ceiling_height",
    "floor_height_m": "floor_height",
    "floor_area_m2": "floor_area",
    "perimeter_m": "perimeter",
    "rc_m": "rc",
}


def summary_row(path: str, record: dict | None, message: str = "") -> dict:
    """One image's line of ``summary.csv``: its layout's figures from the JSON record, or why it has none.

    Args:
        path: the input file as given.
        record: its JSON record (:func:`write_outputs`), or None when it has none (unreadable file,
            missing radius, failed batch).
        message: why the image has no ok layout, in short ("" when it has one).

    Returns:
        The row, keyed by ``SUMMARY_COLUMNS``. ``result`` is "ok", "uncertain scale", "low confidence" or
        "scale conflict" (geometry written, flagged: :data:`~ncjax.pipeline.types.FLAGGED_STATUSES`), "no layout" (the
        pipeline found none) or "error" (no record);
        :func:`skipped_row` makes the rows of "skipped" images. ``reason`` is what a status other than OK means
        (:attr:`~ncjax.LayoutStatus.reason`).
        Figures have 4 decimals; a layout's room-height sigma that the fit leaves open (JSON null)
        is "inf", as the CLI prints it; empty cells are figures the image does not have.
    """
    row = dict.fromkeys(SUMMARY_COLUMNS, "") | {"file": path, "name": pathlib.Path(path).stem, "message": message}
    if record is None:
        return row | {"result": "error"}
    written = bool(record["floor_corners"])
    figures = {column: "" if record[key] is None else f"{record[key]:.4f}" for column, key in SUMMARY_FIGURES.items()}
    if written and record["room_height_sigma"] is None:
        figures["room_height_sigma_m"] = "inf"
    return (
        row
        | figures
        | {
            "result": "ok"
            if record["ok"]
            else FLAGGED_STATUSES[LayoutStatus[record["status"]]]
            if written
            else "no layout",
            "status": record["status"],
            "corners": len(record["floor_corners"]) if written else "",
            "branch": record["branch"] if written else "",
            "scale_source": record.get("scale_source", "") if written else "",
            "reason": "" if record["ok"] else LayoutStatus[record["status"]].reason,
        }
    )


def skipped_row(path: str, record_path: str) -> dict:
    """The ``summary.csv`` line of an image that ``--skip-existing`` skips: result "skipped",
    the figures of its earlier JSON record where it is readable, and the earlier result in the message."""
    try:
        with open(record_path, encoding="utf-8") as file:
            row = summary_row(path, json.load(file))
        earlier = f"earlier result: {row['result']}"
    except (OSError, ValueError, KeyError, TypeError) as error:
        row = summary_row(path, None)
        earlier = f"its record is unreadable: {type(error).__name__}: {error}"
    return row | {"result": "skipped", "message": f"skipped: {record_path} exists ({earlier})"}


def read_summary(path: str) -> list[dict]:
    """The rows of an existing ``summary.csv`` (none when there is no file), keyed by ``SUMMARY_COLUMNS``.

    Raises:
        ValueError: the file is not a summary of ``ncjax reconstruct`` (it is then left as it is).
    """
    try:
        with open(path, newline="", encoding="utf-8") as file:
            reader = csv.DictReader(file)
            missing = {"file", "name", "result"} - set(reader.fieldnames or ())
            if missing:
                raise ValueError(
                    f"{path} exists and is not a summary of ncjax reconstruct (no {', '.join(sorted(missing))} "
                    "column); move it away or choose another --out"
                )
            return [{column: row.get(column) or "" for column in SUMMARY_COLUMNS} for row in reader]
    except FileNotFoundError:
        return []
    except (UnicodeDecodeError, csv.Error) as error:
        raise ValueError(f"{path} exists and is not a readable summary.csv ({error}); move it away") from None


def merge_summary(earlier: list[dict], rows: list[dict]) -> list[dict]:
    """An earlier summary's rows with this run's: a row of this run replaces the earlier row of its image
    (same ``name``, i.e. the same output files) in place, the others are appended in their order."""
    new = {row["name"]: row for row in rows}
    merged, placed = [], set()
    for row in earlier:
        name = row["name"]
        if name not in new:
            merged.append(row)
        elif name not in placed:
            merged.append(new[name])
            placed.add(name)
    return merged + [row for row in rows if row["name"] not in placed]


def write_summary(path: str, rows: list[dict]) -> None:
    """``summary.csv``: one line per image (:func:`summary_row`), written atomically."""
    from ..io.files import write_atomic

    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_atomic(path, text.getvalue().encode("utf-8"))


def update_summary(path: str, rows: list[dict]) -> None:
    """Write this run's rows into ``summary.csv``, keeping the rows of the images of an earlier
    summary in the same folder that this run did not touch (:func:`merge_summary`)."""
    write_summary(path, merge_summary(read_summary(path), rows))
