"""Command-line options generated from the configuration dataclasses, so every setting is reachable.

Each field of a frozen dataclass of ``int``, ``float``, ``bool`` or ``str`` becomes ``--field-name``
(``--field-name`` / ``--no-field-name`` for a bool), a range ``tuple[float, float]`` or ``tuple[int, int]``
``--field-name LOW HIGH``, its help text the field's line in the class docstring's ``Attributes:``
section, its default the value of the instance the command starts from. A field holding another such
dataclass gives that one's options, named ``--field-name-inner-name``. Only the options given on the
command line replace that instance's values.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
from typing import Any

_PARSERS = {"int": int, "float": float, "str": str}
_RANGES = {"tuple[float, float]": float, "tuple[int, int]": int}


def attribute_help(cls: type) -> dict[str, str]:
    """Each field's description in the Google-style ``Attributes:`` section of ``cls``'s docstring.

    A line ``a, b: text`` describes both fields; the text runs until the next such line.
    """
    doc = inspect.getdoc(cls) or ""
    section = doc.split("Attributes:", 1)[1] if "Attributes:" in doc else ""
    help_texts: dict[str, str] = {}
    names: list[str] = []
    for line in section.splitlines():
        match = re.match(r"^    ([a-z_][a-z0-9_, ]*):\s*(.*)$", line)
        if match:
            names = [name.strip() for name in match.group(1).split(",")]
            for name in names:
                help_texts[name] = match.group(2)
        elif line.startswith("        ") and names:
            for name in names:
                help_texts[name] += " " + line.strip()
        elif line.strip() and not line.startswith(" "):
            break
    return {name: re.sub(r":\w+:`~?([^`]+)`", r"\1", text).replace("``", "") for name, text in help_texts.items()}


def _option(prefix: str, name: str) -> str:
    return f"--{prefix}{name}".replace("_", "-")


def add_config_options(
    parser: argparse.ArgumentParser,
    defaults: Any,
    *,
    title: str,
    prefix: str = "",
    skip: tuple[str, ...] = (),
    aliases: dict[str, str] | None = None,
) -> None:
    """Add an option per scalar field of the dataclass instance ``defaults`` to a group ``title`` of ``parser``.

    Args:
        parser: the (sub)command's parser.
        defaults: the configuration the command uses when no option is given.
        title: the group's heading in ``--help``.
        prefix: put before each option's name (and destination), to keep two configurations apart.
        skip: fields the command sets by other means (``part.field`` for a nested configuration's).
        aliases: an extra option name per field (e.g. a shorter, established one).
    """
    aliases = aliases or {}
    help_texts = attribute_help(type(defaults))
    group = parser.add_argument_group(title)
    nested = []
    for field in dataclasses.fields(defaults):
        kind = field.type if isinstance(field.type, str) else getattr(field.type, "__name__", "")
        value = getattr(defaults, field.name)
        if field.name not in skip and dataclasses.is_dataclass(value):
            nested.append(field)
        if field.name in skip or kind not in (*_PARSERS, *_RANGES, "bool"):
            continue
        names = [_option(prefix, field.name), *([aliases[field.name]] if field.name in aliases else [])]
        text = f"{help_texts.get(field.name, field.name.replace('_', ' '))} (default: {value})"
        text = text.replace(". (default", " (default").replace("%", "%%")
        destination = f"{prefix.replace('-', '_')}{field.name}"
        if kind == "bool":
            group.add_argument(*names, dest=destination, action=argparse.BooleanOptionalAction, default=None, help=text)
        elif kind in _RANGES:
            group.add_argument(
                *names, dest=destination, type=_RANGES[kind], nargs=2, default=None, metavar=("LOW", "HIGH"), help=text
            )
        else:
            group.add_argument(
                *names, dest=destination, type=_PARSERS[kind], default=None, metavar=kind.upper(), help=text
            )
    # the inner configuration's options come after the outer one's, in a group of their own
    for field in nested:
        inner = getattr(defaults, field.name)
        inner_title = f"{help_texts.get(field.name, field.name.replace('_', ' ')).rstrip('.')} ({type(inner).__name__})"
        inner_skip = tuple(name.split(".", 1)[1] for name in skip if name.startswith(f"{field.name}."))
        add_config_options(parser, inner, title=inner_title, prefix=f"{prefix}{field.name}-", skip=inner_skip)


def config_from_options(args: argparse.Namespace, defaults: Any, *, prefix: str = "") -> Any:
    """``defaults`` with the fields given on the command line replaced.

    Raises:
        ValueError: a value the dataclass refuses, its message naming the option (``--corners-threshold``)
            where it names the field (``CornerConfig.threshold``, or the field's name first).
    """
    given = {}
    for field in dataclasses.fields(defaults):
        inner = getattr(defaults, field.name)
        if dataclasses.is_dataclass(inner):
            value = config_from_options(args, inner, prefix=f"{prefix}{field.name}-")
            value = None if value is inner else value
        else:
            value = getattr(args, f"{prefix.replace('-', '_')}{field.name}", None)
        if value is not None:
            given[field.name] = tuple(value) if isinstance(value, list) else value  # a range comes as a list
    if not given:
        return defaults
    try:
        return dataclasses.replace(defaults, **given)
    except ValueError as error:
        raise ValueError(_option_message(str(error), type(defaults).__name__, list(given), prefix)) from None


def _option_message(message: str, class_name: str, names: list[str], prefix: str) -> str:
    """A configuration's error message with the fields ``names`` it names as options: ``CornerConfig.threshold``,
    a part's ``corners.min_corners`` and a leading ``capacity`` become ``--corners-threshold``,
    ``--corners-min-corners`` and ``--capacity``."""
    for name in names:
        message = message.replace(f"{class_name}.{name}", _option(prefix, name))
        message = re.sub(
            rf"(?<![\w.-]){name}((?:\.\w+)+)", lambda match: _option(prefix, name + match[1].replace(".", "-")), message
        )
        message = re.sub(rf"^{name}(?= )", _option(prefix, name), message)
    return message


class _Renamed(argparse.Action):
    """An option that was renamed: using it is an error that names the new option."""

    def __init__(self, option_strings, dest, new_name: str, **kwargs):
        super().__init__(option_strings, dest, nargs="?", help=argparse.SUPPRESS, **kwargs)
        self.new_name = new_name

    def __call__(self, parser, namespace, values, option_string=None):
        parser.error(f"{option_string} is now {self.new_name}")


def add_renamed_options(parser: argparse.ArgumentParser, renamed: dict[str, str]) -> None:
    """Hidden options under the old names of ``renamed`` (``old_field: "part.field"``), each of which stops the
    command with a one-line error naming the option that replaced it (``--corner-threshold`` ->
    ``--corners-threshold``; a bool's ``--no-`` form likewise)."""
    for old, new in renamed.items():
        new_option = _option("", new.replace(".", "-"))
        if new_option == _option("", old):
            continue  # the option kept its name (``prior_wall_heights`` is ``--prior-wall-heights`` either way)
        parser.add_argument(_option("", old), dest=f"renamed_{old}", action=_Renamed, new_name=new_option)
        no_old, no_new = _option("no-", old), "--no-" + new_option[2:]
        parser.add_argument(no_old, dest=f"renamed_no_{old}", action=_Renamed, new_name=no_new)
