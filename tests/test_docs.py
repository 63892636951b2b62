"""The README and docs/ stay true: short README, its examples parse and run, links resolve, and the
generated CLI reference matches the parser."""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import pytest

from wbmpc.cli import build_parser
from wbmpc.cli_reference import render

ROOT = Path(__file__).parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def code_blocks(text: str, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", text, re.S)


def test_readme_is_short_and_its_links_resolve():
    assert len(README.splitlines()) <= 200
    links = re.findall(r"\]\(([^)#]+)\)", README)
    assert links, "the README links to docs/"
    for link in links:
        assert (ROOT / link).is_file(), link
    for page in (ROOT / "docs").rglob("*.md"):
        for link in re.findall(r"\]\(([^)#:]+\.md)\)", page.read_text(encoding="utf-8")):
            assert (page.parent / link).is_file(), (page, link)


def test_readme_commands_parse():
    """Every `wbmpc ...` example of the README is a valid command line (parsed, not run)."""
    parser = build_parser()
    commands = []
    for block in code_blocks(README, "bash"):
        for line in block.splitlines():
            line = line.split("#")[0]
            for part in re.split(r"&&|&", line):
                words = shlex.split(part)
                if words[:1] == ["wbmpc"]:
                    commands.append(words[1:])
    assert len(commands) >= 12
    for argv in commands:
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"README example `wbmpc {' '.join(argv)}` does not parse (exit {exc.code})")


def test_readme_python_example_runs(capsys):
    (example,) = [block for block in code_blocks(README, "python")]
    exec(compile(example, "README.md", "exec"), {})
    out = capsys.readouterr().out
    status, iterations = out.split()[:2]
    assert status == "Solve_Succeeded" and int(iterations) >= 1, out


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason="argparse's help layout differs between Python versions; "
                    "docs/cli.md is generated with Python 3.11")
def test_cli_reference_is_up_to_date():
    written = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert written == render(), "docs/cli.md is out of date: python -m wbmpc.cli_reference --write docs/cli.md"
