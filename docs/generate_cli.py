"""Write the command reference (``docs/cli.md``) from the installed ``sb3-memret`` command's own help.

The console script is found through its entry point (what ``pip install`` put on PATH), and every command and
sub-command's ``--help`` text is copied as click prints it, so the page says what the command accepts today.
Run by ``docs/conf.py`` before Sphinx reads the pages; ``python docs/generate_cli.py OUT.md`` writes it alone.
"""

from __future__ import annotations

import sys
from importlib.metadata import entry_points
from pathlib import Path

import click

SCRIPT = "sb3-memret"
HEADER = """# Command reference

Every command of `{script}` with its options, as `{script} COMMAND --help` prints them (this page is generated
from the installed command when the documentation is built). The guides say when to use which: [getting
started](getting-started.md), [training](training.md), [the benchmark](benchmark.md).
"""


def console_script(name: str = SCRIPT) -> click.Command:
    """The click command the console script ``name`` runs."""
    (entry,) = [e for e in entry_points(group="console_scripts") if e.name == name]
    return entry.load()


def _sections(command: click.Command, path: list[str], parent: click.Context | None) -> list[str]:
    ctx = click.Context(command, info_name=path[-1], parent=parent, terminal_width=100, max_content_width=100)
    title = "#" * min(len(path) + 1, 4) + f" `{' '.join(path)}`"
    lines = [title, "", "```text", command.get_help(ctx), "```", ""]
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
