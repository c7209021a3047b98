"""Write the command reference (``docs/cli.md``) from the installed ``sb3-memret`` command's own help.

The console script is found through its entry point (what ``pip install`` put on PATH), and every command and
sub-command's ``--help`` text is copied as click prints it, so the page says what the command accepts today.
Run by ``docs/conf.py`` before Sphinx reads the pages; ``python docs/generate_cli.py OUT.md`` writes it alone.
"""

from __future__ import annotations

import sys
import textwrap
from importlib.metadata import entry_points
from pathlib import Path

import click

SCRIPT = "sb3-memret"
WIDTH = 88  # the help is wrapped to this many characters: a longer line is clipped at the page's code-block edge
HEADER = """# Command reference

Every command of `{script}` with its options, as `{script} COMMAND --help` prints them (this page is generated
from the installed command when the documentation is built). The guides say when to use which: [getting
started](getting-started.md), [training](training.md), [the benchmark](benchmark.md).
"""


def console_script(name: str = SCRIPT) -> click.Command:
    """The click command the console script ``name`` runs."""
    (entry,) = [e for e in entry_points(group="console_scripts") if e.name == name]
    return entry.load()


def fit(help_text: str, width: int = WIDTH) -> str:
    """``help_text`` with no line wider than ``width``: click keeps the lines of a ``\\b`` paragraph as written, so
    such a paragraph (its lines equally indented) with a wider line is filled again to ``width``, options unbroken."""
    lines, out, i = help_text.splitlines(), [], 0
    text = [line.strip(" \b") for line in lines]  # a "\b" that is not its paragraph's first line is printed as is
    while i < len(lines):
        end = i + 1
        while text[i] and end < len(lines) and text[end]:
            end += 1
        paragraph = lines[i:end]
        indent = paragraph[0][: len(paragraph[0]) - len(paragraph[0].lstrip())]
        if any(len(line) > width for line in paragraph) and all(
                line.startswith(indent) and not line[len(indent)].isspace() for line in paragraph):
            paragraph = textwrap.wrap(" ".join(line.strip() for line in paragraph), width, initial_indent=indent,
                                      subsequent_indent=indent, break_long_words=False, break_on_hyphens=False)
        out += paragraph
        i = end
    return "\n".join(out)


def _sections(command: click.Command, path: list[str], parent: click.Context | None) -> list[str]:
    ctx = click.Context(command, info_name=path[-1], parent=parent, terminal_width=WIDTH, max_content_width=WIDTH)
    title = "#" * min(len(path) + 1, 4) + f" `{' '.join(path)}`"
    lines = [title, "", "```text", fit(command.get_help(ctx)), "```", ""]
    if isinstance(command, click.Group):
        for sub in command.list_commands(ctx):
            lines += _sections(command.get_command(ctx, sub), [*path, sub], ctx)
    return lines


def render(command: click.Command, name: str = SCRIPT) -> str:
    """The reference page of ``command``: its help, then each sub-command's, depth first."""
    return "\n".join([HEADER.format(script=name), *_sections(command, [name], None)])


def main(out: Path) -> Path:
    out = Path(out)
    text = render(console_script())
    if not out.is_file() or out.read_text() != text:  # unchanged pages keep their time stamp: no rebuild
        out.write_text(text)
    return out


if __name__ == "__main__":
    print(main(Path(sys.argv[1])))
