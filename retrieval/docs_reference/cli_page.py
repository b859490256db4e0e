"""``docs/reference/cli.md``: every ``scenesearch`` command with its options, from the argparse parsers."""

from __future__ import annotations

import argparse
import functools

from retrieval.docs_reference.markdown import GENERATED, code, fence, page, table

#: Usage lines are wrapped at this width whatever the terminal, so that the page is the same everywhere.
WIDTH = 100


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _helps(parser: argparse.ArgumentParser) -> dict[str, str]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {choice.dest: choice.help or "" for choice in action._choices_actions}
    return {}


def _name(action: argparse.Action) -> str:
    if not action.option_strings:
        return code(action.metavar or action.dest)
    takes_value = action.nargs != 0
    metavar = action.metavar or action.dest.upper()
    if isinstance(metavar, tuple):
        metavar = " ".join(metavar)
    if action.choices is not None and action.metavar is None:
        metavar = "{" + ",".join(str(c) for c in action.choices) + "}"
    suffix = ""
    if takes_value:
        suffix = {"?": f" [{metavar}]", "*": f" [{metavar} ...]", "+": f" {metavar} [...]"}.get(
            str(action.nargs), f" {metavar}")
    return ", ".join(code(option + suffix) for option in action.option_strings)


def _default(action: argparse.Action) -> str:
    default = action.default
    if action.nargs == 0 or default in (None, argparse.SUPPRESS) or default == [] or default is False:
        return ""
    if isinstance(default, list | tuple):
        return code(" ".join(str(v) for v in default))
    return code(default)


def _rows(parser: argparse.ArgumentParser) -> list[list[str]]:
    formatter = parser._get_formatter()
    rows = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction | argparse._SubParsersAction) or action.help == argparse.SUPPRESS:
            continue
        text = formatter._expand_help(action) if action.help else ""
        rows.append([_name(action), _default(action), text])
    return rows


def _section(name: str, parser: argparse.ArgumentParser, help_text: str, level: int) -> list[str]:
    parser.formatter_class = functools.partial(argparse.HelpFormatter, width=WIDTH)
    lines = [f"{'#' * level} `{parser.prog}`", ""]
    description = parser.description or help_text
    if description:
        lines += [" ".join(description.split()), ""]
    lines += [*fence(parser.format_usage().removeprefix("usage: ").strip()), ""]
    rows = _rows(parser)
    if rows:
        lines += [*table(["argument", "default", "what it does"], rows), ""]
    if parser.epilog:
        lines += [" ".join(parser.epilog.split()), ""]
    helps = _helps(parser)
    for sub_name, sub in _subparsers(parser).items():
        lines += _section(sub_name, sub, helps.get(sub_name, ""), level + 1)
    return lines


def markdown() -> str:
    """The page (Markdown)."""
    from retrieval.cli import build_parser

    parser = build_parser()
    commands = _subparsers(parser)
    helps = _helps(parser)
    lines = ["# Command line: `scenesearch`", "", GENERATED, "",
             "Every command takes `-h` / `--help`. Exit status of the batch commands: 0 when everything was "
             "done, 1 when some inputs were skipped or failed, 2 when nothing was done "
             "(see the [reliability guide](../guide/reliability.md)).", ""]
    index = [[f"[`{name}`](#scenesearch-{name})", helps.get(name, "")] for name in commands]
    lines += [*table(["command", "what it does"], index), ""]
    for name, sub in commands.items():
        lines += _section(name, sub, helps.get(name, ""), 2)
    return page(lines)
