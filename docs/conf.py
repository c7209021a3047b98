"""Sphinx configuration of sb3-memret's documentation (``make docs``: warnings are errors).

Why Sphinx with MyST: the API reference must come from the docstrings (autodoc and autosummary import the
package and render what its modules say, as stable-baselines3's and ManiSkill's manuals do), and the hand-written
pages stay Markdown like the README they came from (MyST-parser). Both are plain pip packages pinned in
``docs/requirements.txt``; the build needs no other tool (no Graphviz, no Mermaid, no network): the figures are
committed PNGs or SVGs written by hand.

Before Sphinx reads a page, ``generate_results.py`` writes ``docs/results/`` from the result files committed under
``benchmarks/`` (never typed), ``generate_cli.py`` writes the command reference from the installed command's own
help, and ``generate_tasks.py`` the table of tasks from the task registry, so none can drift from what it describes.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS))

import generate_cli  # noqa: E402  (docs/, on the path above)
import generate_results  # noqa: E402
import generate_tasks  # noqa: E402

import sb3_memret  # noqa: E402

generate_results.main(DOCS.parent, DOCS / "results")
generate_cli.main(DOCS / "cli.md")
generate_tasks.main(DOCS / "task_list.md")


def drop_stale_api_pages(folder: Path) -> list[Path]:
    """Delete the API pages (``docs/_autosummary/*.rst``, git-ignored) of modules that no longer exist, and of every
    package.

    autosummary writes a page for every module it finds and rewrites the ones it knows, but never deletes the page of
    a module that was moved or removed; Sphinx would then fail on that page (its module does not import, and no
    toctree names it), or on the page of its package, which still lists it. A module's page whose module is still
    there is kept, so an unchanged page is not read again; a package's page is written afresh."""
    dropped = []
    for page in sorted(folder.glob("sb3_memret*.rst")):
        try:
            spec = importlib.util.find_spec(page.stem)
        except ImportError:  # a parent package that is gone
            spec = None
        if spec is None or spec.submodule_search_locations is not None:
            page.unlink()
            dropped.append(page)
    return dropped


drop_stale_api_pages(DOCS / "_autosummary")

project = "sb3-memret"
author = "the sb3-memret authors"
copyright = f"2026, {author}"  # noqa: A001  (Sphinx's name; the theme's footer prints it)
release = version = sb3_memret.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.viewcode",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "requirements.txt", "task_list.md"]  # task_list.md: included by tasks.md
templates_path = ["_templates"]

myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: one page per module (docs/_templates/autosummary/module.rst), members defined in that module only
# (``ignore-module-all``: a package that re-exports a name does not document it twice). Every optional stack is
# installed by `make install` (torch, ManiSkill, SAPIEN, lerobot, ray, optuna, openpi-client, mikasa-robo-suite), so
# nothing is mocked: a module that does not import fails the build.
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True, "ignore-module-all": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_inherit_docstrings = False  # an override without a docstring of its own shows none (not gymnasium's, torch's)
autodoc_mock_imports: list[str] = []
# two task families name a gains class alike (PressGains: BlinkCount's and TraceShapeSeq's); a module that imports
# one for a signature makes its short name ambiguous to Sphinx, which then links the first. Renaming either would
# change code that committed benchmark cells were played with (their digests), so the ambiguity is not a failure.
suppress_warnings = ["ref.python"]

html_theme = "furo"
html_title = f"sb3-memret {release}"
html_static_path = ["_static"]
html_css_files = ["tables.css"]  # the registered-tasks table, a little smaller (docs/tasks.md)
