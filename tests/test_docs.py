"""The manual cannot rot: the documentation's examples run, and what its pages name exists.

- Python blocks marked ``% runnable`` run, page by page in one namespace, in a folder holding the page's blocks marked
  ``% file: NAME`` (``% runnable: slow`` blocks run with the slow tests; a file block named ``test_*.py`` runs as the
  user's test would); every Python block's ``from sb3_memret... import`` names exist.
- Every ``sb3-memret`` command line on the pages and in the README (fenced or inline) names a command and options the
  command has; every ``make`` target exists; every ``scripts/`` file, repository path, ``sb3_memret.`` object and
  ``{py:mod}``/``{py:class}`` target they name exists.
- The results generator names each table's file and a command the benchmark accepts.
- The lab's index (``lab/README.md``) lists every study folder, and only those.
- With Sphinx installed (``make docs`` installs it), the guide pages build with warnings as errors (the API reference,
  which imports every module, is ``make docs``'s and CI's).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import json
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path

import click
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GENERATED = {"cli.md", "task_list.md"}  # written by the build (git-ignored): checked through their generators
PAGES = sorted(p for p in DOCS.glob("*.md") if p.name not in GENERATED)
ALL_TEXTS = [*PAGES, ROOT / "README.md"]
PYTHON_LANGS = {"python", "py"}
SHELL_LANGS = {"bash", "sh", "shell", "console", ""}


@dataclass
class Block:
    page: Path
    line: int
    lang: str
    text: str
    marks: dict[str, str] = field(default_factory=dict)

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


CODE_DIRECTIVE = re.compile(r"\{code-block\}\s*(\w*)")  # ```{code-block} python, with options such as :caption:


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of a Markdown page (```python, or ```{code-block} python with its ``:option:`` lines),
    each with the ``% key: value`` marks on the lines just above it."""
    lines, found, marks, i = page.read_text().splitlines(), [], {}, 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("% "):
            key, _, value = line[2:].partition(":")
            marks[key.strip()] = value.strip()
        elif line.startswith("```"):  # a code block (```python) or a MyST directive (```{toctree}): skipped whole
            end = next(j for j in range(i + 1, len(lines)) if lines[j].strip() == "```")
            info = line.strip()[3:]
            if re.fullmatch(r"\w*", info):
                found.append(Block(page, i + 1, info, "\n".join(lines[i + 1:end]), marks))
            elif directive := CODE_DIRECTIVE.fullmatch(info):
                start = i + 1
                while start < end and lines[start].startswith(":"):  # the directive's options
                    start += 1
                if start < end and not lines[start].strip():  # the blank line that ends them
                    start += 1
                found.append(Block(page, start, directive.group(1), "\n".join(lines[start:end]), marks))
            marks, i = {}, end
        elif line.strip():
            marks = {}
        i += 1
    return found


def _runnable_pages(slow: bool) -> list[Path]:
    return [p for p in PAGES if any(("runnable" in b.marks) and (b.marks["runnable"] == "slow") == slow
                                    for b in blocks(p))]


def _run_page(page: Path, folder: Path, monkeypatch: pytest.MonkeyPatch, slow: bool) -> int:
    """Write the page's file blocks into ``folder`` and run its runnable blocks there; how many ran."""
    page_blocks = blocks(page)
    for block in page_blocks:
        if "file" in block.marks:
            (folder / block.marks["file"]).write_text(block.text + "\n")
    monkeypatch.chdir(folder)
    monkeypatch.syspath_prepend(str(folder))
    namespace: dict[str, object] = {"__name__": f"docs_{page.stem}"}
    ran = 0
    for block in page_blocks:
        if "runnable" not in block.marks or (block.marks["runnable"] == "slow") != slow:
            continue
        name = block.marks.get("file", "")
        if name.startswith("test_") and name.endswith(".py"):  # the user's test file: run its tests
            spec = importlib.util.spec_from_file_location(name[:-3], folder / name)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            tests = [getattr(module, t) for t in dir(module) if t.startswith("test_")]
            assert tests, f"{block.where}: {name} holds no test"
            for test in tests:
                test()
        else:
            exec(compile(block.text, block.where, "exec"), namespace)
        ran += 1
    return ran


@pytest.mark.parametrize("page", _runnable_pages(slow=False), ids=lambda p: p.name)
def test_the_runnable_examples_run(page, tmp_path, monkeypatch):
    assert _run_page(page, tmp_path, monkeypatch, slow=False) > 0


@pytest.mark.slow
@pytest.mark.parametrize("page", _runnable_pages(slow=True), ids=lambda p: p.name)
def test_the_slow_runnable_examples_run(page, tmp_path, monkeypatch):
    assert _run_page(page, tmp_path, monkeypatch, slow=True) > 0


def test_some_examples_are_marked_runnable():
    assert _runnable_pages(slow=False), "no page marks a Python block '% runnable'"


# ------------------------------------------------------------------------------------------ names that must exist
def _python_blocks() -> list[Block]:
    return [b for page in ALL_TEXTS for b in blocks(page) if b.lang in PYTHON_LANGS]


def test_every_python_example_imports_names_that_exist():
    checked = 0
    for block in _python_blocks():
        for node in ast.walk(ast.parse(block.text, block.where)):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in (
                    "sb3_memret", "stable_baselines3", "gymnasium"):
                module = importlib.import_module(node.module)
                for alias in node.names:
                    assert hasattr(module, alias.name), f"{block.where}: {node.module} has no {alias.name}"
                    checked += 1
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.startswith("sb3_memret"):
                        importlib.import_module(alias.name)
                        checked += 1
    assert checked > 10


def _cli() -> click.Command:
    (entry,) = [e for e in entry_points(group="console_scripts") if e.name == "sb3-memret"]
    return entry.load()


def _inline_code(page: Path) -> list[tuple[int, str]]:
    """Inline code spans outside fenced blocks, with their line numbers."""
    spans, fenced = [], False
    for number, line in enumerate(page.read_text().splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            spans += [(number, span) for span in re.findall(r"`([^`]+)`", line)]
    return spans


def _shell_commands(text: str) -> list[tuple[int, str]]:
    """A shell block's commands, each with the line it starts on: a line ending in `` \\`` goes on in the next."""
    commands, parts, start = [], [], 1
    for k, line in enumerate(text.splitlines(), 1):
        if not parts:
            start = k
        if line.endswith(" \\") and not line.lstrip().startswith("#"):  # a comment's backslash continues nothing
            parts.append(line[:-2].strip())
            continue
        commands.append((start, " ".join([*parts, line.strip()])))
        parts = []
    if parts:
        commands.append((start, " ".join(parts)))
    return commands


def _command_lines() -> list[tuple[str, str]]:
    """Every shell command (its continuation lines joined) and inline code span of the pages and the README, with
    where it is."""
    found = []
    for page in ALL_TEXTS:
        for block in blocks(page):
            if block.lang in SHELL_LANGS:
                found += [(f"{block.where}+{k}", line) for k, line in _shell_commands(block.text)]
        found += [(f"{page.relative_to(ROOT)}:{n}", span) for n, span in _inline_code(page)]
    return found


def _options(command: click.Command) -> set[str]:
    names = {"--help", "-h"}
    for param in command.params:
        names.update(param.opts)
        names.update(param.secondary_opts)
    return names


def check_command(tokens: list[str], where: str, cli: click.Command) -> int:
    """Check one ``sb3-memret ...`` token list against the command; the number of options checked."""
    command, rest = cli, list(tokens)
    while isinstance(command, click.Group) and rest and not rest[0].startswith("-"):
        sub = command.get_command(click.Context(command), rest[0])
        if sub is None:
            if rest[0].isupper() or rest[0] in ("COMMAND", "..."):  # a placeholder: `sb3-memret COMMAND --help`
                return 0
            pytest.fail(f"{where}: `{' '.join(tokens)}`: no command {rest[0]!r} (has {command.list_commands(None)})")
        command, rest = sub, rest[1:]
    checked = 0
    for token in rest:
        token = token.strip("[]")
        if token.startswith("--"):
            option = token.split("=")[0]
            assert option in _options(command), \
                f"{where}: `{' '.join(tokens)}`: {command.name} has no option {option} ({sorted(_options(command))})"
            checked += 1
    return checked


def _make_targets() -> set[str]:
    return set(re.findall(r"^([\w.-]+):(?!=)", (ROOT / "Makefile").read_text(), re.M))


def test_every_command_the_pages_show_has_the_options_they_give():
    cli, targets, options, makes = _cli(), _make_targets(), 0, 0
    for where, line in _command_lines():
        try:
            tokens = shlex.split(line, comments=True)
        except ValueError:  # an inline span quoting a fragment
            tokens = line.split()
        for i, token in enumerate(tokens):
            if Path(token).name == "sb3-memret":
                options += check_command([t for t in tokens[i + 1:] if t != "&"], where, cli)
            elif token == "make" and i == 0:
                named = [t for t in tokens[1:] if "=" not in t and not t.startswith("-") and t != "..."]
                for target in named:
                    assert target in targets, f"{where}: `{line}`: the Makefile has no target {target!r}"
                    makes += 1
            elif token.startswith("scripts/"):
                assert (ROOT / token).is_file(), f"{where}: `{line}`: no file {token}"
    assert options > 50 and makes > 5, (options, makes)


PATH = re.compile(r"^((?:sb3_memret|scripts|zoo_configs|tests|envs|callbacks|docs)/[\w./-]*[\w/])")
OBJECT = re.compile(r"^~?(sb3_memret(?:\.\w+)+)(?:\(.*\))?$")
ROLE = re.compile(r"\{py:(?:mod|class|func|meth|obj)\}`~?([\w.]+)`")


def _resolve(dotted: str) -> object:
    """The object a dotted name names: the longest importable module prefix, then attributes."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(dotted)


def test_every_path_and_object_the_pages_name_exists():
    paths = objects = 0
    for page in ALL_TEXTS:
        text = page.read_text()
        for n, span in _inline_code(page):
            where = f"{page.relative_to(ROOT)}:{n}"
            if (match := PATH.match(span)) and not any(c in span for c in "*<>") and "_build" not in span and (
                    match.group(1).endswith("/") or "." in match.group(1).rsplit("/", 1)[-1]):
                assert (ROOT / match.group(1)).exists(), f"{where}: no file or folder {match.group(1)}"
                paths += 1
            elif (match := OBJECT.match(span)) and " " not in span:
                try:
                    _resolve(match.group(1))
                except (ImportError, AttributeError) as err:
                    pytest.fail(f"{where}: `{span}` names nothing ({err})")
                objects += 1
        for target in ROLE.findall(text):
            _resolve(target)
            objects += 1
    assert paths > 20 and objects > 20, (paths, objects)



def test_the_lab_index_lists_every_study_and_only_studies_that_exist():
    """lab/README.md's table links each study folder once, and each link is a study with its own README.md."""
    lab = ROOT / "lab"
    linked = re.findall(r"\]\(([^)/]+)/README\.md\)", (lab / "README.md").read_text())
    studies = sorted(p.name for p in lab.iterdir() if p.is_dir() and p.name[:4].isdigit())
    assert sorted(linked) == studies, (set(studies) ^ set(linked))
    assert all((lab / name / "README.md").is_file() for name in linked)

# ------------------------------------------------------------------------------------------ generated pages
def test_the_results_pages_name_each_tables_file_and_a_command_the_benchmark_accepts(tmp_path):
    sys.path.insert(0, str(DOCS))
    try:
        import generate_results
    finally:
        sys.path.remove(str(DOCS))
    pages = generate_results.main(ROOT, tmp_path)
    runs = sorted((ROOT / "benchmarks").glob("**/results.json"))
    sweeps = generate_results.sweeps(ROOT)
    learners = generate_results.learners_folders(ROOT)
    assert len(pages) == 1 + len(runs) + len(sweeps) + len(learners)
    cli = _cli()
    for page, folder in zip(pages[1 + len(runs) + len(sweeps):], learners):  # a learners folder: a row a task
        text = page.read_text()
        tasks = json.loads((folder / "learners.json").read_text())["tasks"]
        assert all(re.search(rf"^\| {task} \| ", text, re.M) for task in tasks), page
        (command,) = re.findall(r"^sb3-memret benchmark learners .*$", text, re.M)
        assert check_command(shlex.split(command)[1:], page.name, cli) >= 2
    for page, folder in zip(pages[1 + len(runs):], sweeps):  # a seed sweep: its table from its runs' files
        text = page.read_text()
        assert f"Source: `{folder.relative_to(ROOT).as_posix()}/*/evaluations.jsonl`" in text, page
        assert (folder / "about.md").read_text().strip() in text  # what the controller reads, where choices were made
        assert len(re.findall(r"^\| seed\d+ \| \d+ \|", text, re.M)) == len(list(folder.glob("*/summary.json")))
        (command,) = re.findall(r"^sb3-memret train recall .*$", text, re.M)
        assert check_command(shlex.split(command)[1:], page.name, cli) == 4
        assert (tmp_path / f"{page.stem}.png").is_file()
    for page, results in zip(pages[1:1 + len(runs)], runs):
        text = page.read_text()
        source = f"Source: `{results.relative_to(ROOT).as_posix()}`."
        tables = len(re.findall(r"^\|---", text, re.M))
        assert tables and text.count(source) >= tables - 1, page  # the episode log's table names its own file
        (command,) = re.findall(r"^sb3-memret benchmark mikasa .*$", text, re.M)
        assert check_command(shlex.split(command)[1:], page.name, cli) >= 6
        assert (tmp_path / f"{page.stem}.png").is_file()


@pytest.mark.skipif(importlib.util.find_spec("sphinx") is None or importlib.util.find_spec("myst_parser") is None,
                    reason="Sphinx is not installed: `make docs` installs docs/requirements.txt")
def test_the_guide_builds_without_a_warning(tmp_path):
    """The pages (every guide, the generated results, command and task pages) with warnings as errors; the API
    reference is left to `make docs`, as it imports every module."""
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "dummy", "-d", str(tmp_path / "doctrees"),
         "-D", "autosummary_generate=0", "-D", "exclude_patterns=_build,requirements.txt,task_list.md,api.md,_autosummary",
         "-D", "suppress_warnings=toc.excluded", str(DOCS), str(tmp_path / "out")],
        capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-4000:]
