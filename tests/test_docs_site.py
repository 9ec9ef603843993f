"""The documentation site (docs/sphinx, built by `make docs` with warnings as
errors): every page of docs/ is in its table of contents, every public module
of the package in its API reference, the start page's example runs, and the
gallery shows an image of every method that applies to its scene."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import penumbra

REPO = Path(__file__).resolve().parents[1]
SITE = REPO / "docs" / "sphinx"


def _toctree_entries() -> set[str]:
    text = (SITE / "index.md").read_text(encoding="utf-8")
    entries = set()
    for block in re.findall(r"```\{toctree\}\n(.*?)```", text, re.S):
        entries |= {line.strip() for line in block.splitlines() if line.strip() and not line.startswith(":")}
    return entries


def test_every_docs_page_is_in_the_table_of_contents():
    entries = _toctree_entries()
    pages = {f"../{p.stem}" for p in (REPO / "docs").glob("*.md")}
    assert pages - entries == set(), "docs pages missing from docs/sphinx/index.md"
    assert {e for e in entries if e.startswith("../")} - pages == set(), "toctree entries without a page"
    assert {"gallery", "api"} <= entries


def test_every_public_module_is_in_the_api_reference():
    listed = set(re.findall(r"^\.\. automodule:: (\S+)", (SITE / "api.rst").read_text(encoding="utf-8"), re.M))
    package = Path(penumbra.__file__).parent
    # penumbra.x.y for x/y.py, penumbra.x for x/__init__.py; private modules (_native, __main__) are left out.
    modules = {".".join(("penumbra", *p.relative_to(package).with_suffix("").parts)).removesuffix(".__init__")
               for p in package.rglob("*.py") if not p.name.startswith("_") or p.name == "__init__.py"}
    assert modules - listed == set(), "modules missing from docs/sphinx/api.rst"
    assert listed - modules == set(), "api.rst names modules that do not exist"


def test_the_package_exports_what_the_docs_use():
    for name in penumbra.__all__:
        assert hasattr(penumbra, name), name
    for module in ("data", "imageio", "meshio", "methods", "procedural", "scenefile"):
        assert getattr(penumbra, module).__name__ == f"penumbra.{module}"


def test_the_start_pages_example_runs(tmp_path, monkeypatch):
    text = (SITE / "index.md").read_text(encoding="utf-8")
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/sphinx/index.md", "exec"), {})
    from PIL import Image

    png = Image.open(tmp_path / "ball.png")
    assert png.size == (320, 240)


def test_the_gallery_shows_every_method_of_its_scene():
    from penumbra.methods import applicable
    from penumbra.scenefile import load_scene

    gallery = (SITE / "gallery" / "gallery.md").read_text(encoding="utf-8")
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", gallery)
    for image in images:
        assert (SITE / "gallery" / image).is_file(), image
    desc = load_scene(REPO / "examples" / "scenes" / "shapes_sky.toml")
    for method in {"reference", *applicable(desc)}:
        assert f"{method}.png" in images, method


@pytest.mark.parametrize("target", ["docs"])
def test_make_builds_the_site_with_warnings_as_errors(target):
    makefile = (REPO / "Makefile").read_text(encoding="utf-8")
    rule = re.search(rf"^{target}:.*?(?=^\S|\Z)", makefile, re.M | re.S).group(0)
    assert "sphinx" in rule and " -W " in rule and "-c docs/sphinx docs" in rule
    assert "make test docs" in (REPO / ".ci" / "run").read_text()
