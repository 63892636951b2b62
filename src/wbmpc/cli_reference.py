"""The command-line reference (docs/cli.md), generated from the parser so that it cannot drift from it.

`python -m wbmpc.cli_reference --write docs/cli.md` regenerates the file; without `--write` the
reference goes to stdout. `tests/test_docs.py` fails while the file differs from the parser.
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

WIDTH = 100  # fixed, so that the text does not depend on the terminal it was generated in
HEADER = ("# Command-line reference\n\nGenerated from the parser by `python -m wbmpc.cli_reference --write docs/cli.md`"
          " (do not edit by hand; `tests/test_docs.py` checks it is up to date).\n")


def commands(parser: argparse.ArgumentParser):
    """(prog, parser) of the command and every subcommand, depth first, in the parser's order."""
    yield parser.prog, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from commands(sub)


def command(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    """The parser of the subcommand `name` ("run", "bench mpc", ...)."""
    for prog, sub in commands(parser):
        if prog.split(" ", 1)[-1] == name:
            return sub
    raise KeyError(f"no command '{name}'")


def arguments(parser: argparse.ArgumentParser) -> list[tuple[argparse.Action, str | None]]:
    """(action, title of its help group) of every argument of one command (subcommand choices aside)."""
    return [(action, group.title) for group in parser._action_groups for action in group._group_actions
            if not isinstance(action, argparse._SubParsersAction)]


def render() -> str:
    from wbmpc.cli import build_parser

    sections = [HEADER]
    for prog, parser in commands(build_parser()):
        formatter = parser.formatter_class
        parser.formatter_class = functools.partial(formatter, width=WIDTH, max_help_position=34)
        try:
            text = parser.format_help().rstrip()
        finally:
            parser.formatter_class = formatter
        sections.append(f"## `{prog}`\n\n```text\n{text}\n```\n")
    return "\n".join(sections)


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="python -m wbmpc.cli_reference", description=__doc__.splitlines()[0])
    cli.add_argument("--write", metavar="FILE", help="write the reference to FILE (e.g. docs/cli.md)")
    args = cli.parse_args(argv)
    text = render()
    if args.write:
        Path(args.write).write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
