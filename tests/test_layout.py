"""docs/layout.md names every module of the three packages, each in its own folder, and no
module that is gone: a module added or removed without the map fails here."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("esim_lite", "datagen", "model")
FOLDER = re.compile(r"^( *)([\w]+)/(?=\s|$)")
MODULE = re.compile(r"(?<![\w/.])([\w]+\.py)\b")


def layout_block(text: str) -> list[str]:
    """The lines of the first fenced block of layout.md: the tree."""
    start = text.index("```\n") + 4
    return text[start:text.index("```", start)].splitlines()


def documented(lines: list[str]) -> set[str]:
    """``pkg/sub/mod.py`` for every ``mod.py`` in the tree. A line opening with ``name/``
    at indent 2k is folder k deep; a line opening with a module at indent 2k holds a
    module of the folder k deep; the modules after a folder's name, and on the lines
    continuing it (indented past the names), belong to that folder."""
    folders: list[str] = []
    out = set()
    for line in lines:
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        folder = FOLDER.match(line)
        rest = line
        if folder:
            folders = folders[:indent // 2] + [folder.group(2)]
            rest = line[folder.end():]
            here = folders
        elif MODULE.match(line.strip()) and indent < 20:
            here = folders[:indent // 2]
        else:
            here = folders
        out |= {"/".join(here + [m]) for m in MODULE.findall(rest)}
    return {p for p in out if p.split("/")[0] in PACKAGES}


def modules() -> set[str]:
    return {p.relative_to(ROOT).as_posix() for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
            if p.name != "__init__.py" and "__pycache__" not in p.parts}


def test_the_layout_names_every_module_and_only_modules_that_exist():
    named = documented(layout_block((ROOT / "docs" / "layout.md").read_text()))
    missing, gone = sorted(modules() - named), sorted(named - modules())
    assert not missing, f"modules docs/layout.md does not place: {missing}"
    assert not gone, f"docs/layout.md places modules that do not exist: {gone}"


def test_the_parser_reads_folders_modules_and_continuations():
    tree = ["model/              top",
            "  config.py         the record",
            "  data/             dataset.py (samples), cache.py",
            "                    flow.py",
            "  inference/        run.py",
            "  cli.py            the commands (not datagen/cli.py)"]
    assert documented(tree) == {"model/config.py", "model/data/dataset.py",
                                "model/data/cache.py", "model/data/flow.py",
                                "model/inference/run.py", "model/cli.py"}
