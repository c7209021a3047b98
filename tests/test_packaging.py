"""The distribution ships every package: a wheel built from setup.cfg holds each folder that has an __init__.py."""

import configparser
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _setup() -> configparser.ConfigParser:
    config = configparser.ConfigParser()
    config.read(ROOT / "setup.cfg")
    return config


def test_every_package_folder_is_listed():
    options = _setup()["options"]
    listed = set(options["packages"].split())
    mapping = dict(line.split(" = ") for line in options.get("package_dir", "").strip().splitlines()) \
        or {"sb3_memret": "sb3_memret"}
    on_disk = set()
    for package, folder in mapping.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            relative = init.parent.relative_to(ROOT / folder).parts
            name = ".".join((package, *relative))
            if not any(name.startswith(other + ".") and other != package and other in mapping for other in mapping):
                on_disk.add(name)
    assert on_disk <= listed, f"packages missing from setup.cfg: {sorted(on_disk - listed)}"
    assert listed <= on_disk | set(mapping), f"setup.cfg lists packages with no folder: {sorted(listed - on_disk)}"


def test_the_command_line_entry_point_names_the_cli_package():
    scripts = _setup()["options.entry_points"]["console_scripts"]
    assert "sb3-memret = sb3_memret.cli:main" in scripts
    assert (ROOT / "sb3_memret" / "cli" / "__init__.py").is_file()
