"""README starts with the jobs and stays short; the docs' links lead somewhere; README names only real commands.

A newcomer reads README's first lines for the two commands that set up and run the demo and the tests; the rest
is one short section per job, the results table and links. Measurement history lives in CHANGELOG.md and the
benchmark reports, not here. These checks parse files and the CLI's argparse tree; they run nothing.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from entitynet.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
MAX_README_LINES = 160
SETUP = "python3 -m venv .venv && .venv/bin/pip install -e '.[test,plot]' && npm ci && npm run build && "
FIRST_COMMANDS = (SETUP + ".venv/bin/entitynet demo", SETUP + ".venv/bin/python -m pytest")

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.S | re.M)
INLINE_CODE = re.compile(r"`([^`\n]+)`")
COMMAND = re.compile(r"(?<![\w/.-])(?:\S*/)?entitynet((?:[ \t]+[a-z][a-z0-9-]*)+)")


def markdown_files() -> list[Path]:
    return [README, ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]


def relative_links(text: str) -> list[str]:
    """Link and image targets that are paths in this repository (not URLs, not anchors in the same page)."""
    out = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue
        out.append(target.split("#", 1)[0])
    return out


def code_of(text: str) -> list[str]:
    """The code in a Markdown text: fenced blocks and inline spans (prose naming the project is not a command)."""
    blocks = FENCE.findall(text)
    prose = FENCE.sub("", text)
    return blocks + INLINE_CODE.findall(prose)


def named_commands(text: str) -> set[tuple[str, ...]]:
    """Every `entitynet WORD [WORD]` in the text's code: the words that name subcommands (lower case; options,
    placeholders in capitals and paths end the run)."""
    found = set()
    for code in code_of(text):
        for line in code.splitlines():
            for match in COMMAND.finditer(line):
                found.add(tuple(match.group(1).split()[:2]))
    return found


def _choices(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser | None] | None:
    """A parser's subcommands (name -> parser), or the choices of its first positional, or None."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
        if not action.option_strings and action.choices is not None:
            return {str(c): None for c in action.choices}
        if not action.option_strings and action.dest != "help":
            return None
    return None


def unknown_commands(words: tuple[str, ...], parser: argparse.ArgumentParser) -> str | None:
    """Why `entitynet WORDS` is not a command of this parser, or None when it is."""
    top = _choices(parser) or {}
    if words[0] not in top:
        return f"no subcommand {words[0]!r}"
    sub = top[words[0]]
    if len(words) > 1 and sub is not None:
        inner = _choices(sub)
        if inner is not None and words[1] not in inner:
            return f"{words[0]} has no {words[1]!r} (has {sorted(inner)})"
    return None


def test_readme_is_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines (at most {MAX_README_LINES})"


def test_readme_starts_with_the_two_commands():
    lines = README.read_text().splitlines()
    assert lines[0].startswith("# "), "README.md starts with its title"
    body = [line for line in lines[1:] if line.strip()]
    assert body[:3] == ["```sh", *FIRST_COMMANDS], body[:3]


def test_every_relative_link_leads_to_a_file():
    broken = []
    for md in markdown_files():
        if not md.exists():
            continue
        for target in relative_links(md.read_text()):
            if target and not (md.parent / target).exists():
                broken.append(f"{md.relative_to(ROOT)}: {target}")
    assert not broken, broken


def test_readme_names_only_commands_the_cli_has():
    parser = build_parser()
    named = named_commands(README.read_text())
    assert ("demo",) in named or any(w[0] == "demo" for w in named)  # the parse sees the first command
    wrong = {" ".join(w): why for w in sorted(named) if (why := unknown_commands(w, parser))}
    assert not wrong, wrong


# the checks check: they find what they are for


def test_the_link_check_sees_broken_links_and_skips_urls():
    text = "[a](docs/x.md) ![b](img.png#frag) [c](https://example.org) [d](#top) [e](mailto:x@y.z)"
    assert relative_links(text) == ["docs/x.md", "img.png"]


@pytest.mark.parametrize(("text", "words"), [
    ("`entitynet serve --topology X`", {("serve",)}),
    ("```sh\n.venv/bin/entitynet proxy siri --url U\nentitynet bench sim\n```", {("proxy", "siri"), ("bench", "sim")}),
    ("entitynet keeps entities visible (prose)", set()),
    ("`entitynet COMMAND --help` and `entitynet/client/`", set()),
])
def test_command_names_are_found_in_code_only(text, words):
    assert named_commands(text) == words


def test_unknown_commands_are_reported():
    parser = build_parser()
    assert unknown_commands(("serve",), parser) is None
    assert unknown_commands(("proxy", "siri"), parser) is None
    assert unknown_commands(("bench", "sim"), parser) is None
    assert unknown_commands(("serv",), parser) is not None
    assert unknown_commands(("proxy", "nope"), parser) is not None
    assert unknown_commands(("bench", "nope"), parser) is not None
