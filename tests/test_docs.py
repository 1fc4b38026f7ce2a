"""The documentation site: its registry reference is the registries, and it builds with no warning.

The reference (docs/reference/, written by docs/_ext/registry_reference.py when Sphinx starts) must list every
registry of ``rmpfusion.registry``, every entry of each and every parameter of each entry's model, with its default
and range; an entry registered later (a plugin) appears without a page written for it. The strict build
(``make docs``: warnings are errors) runs in the slow suite, with a broken link shown to fail it.
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys

import pytest
from conftest import ROOT
from pydantic import Field

from rmpfusion.core.gds import GDS
from rmpfusion.registry import LEAF_RMPS, Params, Registry


def _load_extension(name: str):
    """A module of docs/_ext, the folder Sphinx loads the site's extensions from, loaded from its file."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "docs" / "_ext" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pydantic look their module up by name
    spec.loader.exec_module(module)
    return module


ref = _load_extension("registry_reference")


@pytest.fixture(scope="module")
def pages() -> dict[str, str]:
    return ref.reference_pages()


def test_every_registry_has_a_page_listed_in_the_index(pages):
    from rmpfusion import registry

    found = {name for name, obj in vars(registry).items() if isinstance(obj, Registry)}
    assert len(found) >= 10
    for name in found:
        assert f"{ref.page_name(name)}.md" in pages, name
        assert f"]({ref.page_name(name)}.md)" in pages["index.md"], name
    assert set(pages) == {f"{ref.page_name(n)}.md" for n in found} | {"index.md"}


def test_every_entry_and_parameter_is_on_its_registrys_page(pages):
    for attribute, reg in ref.registries().items():
        page = pages[f"{ref.page_name(attribute)}.md"]
        for entry in reg.entries():
            assert f"\n## {entry.name}\n" in page, (attribute, entry.name)
            section = page.split(f"\n## {entry.name}\n", 1)[1].split("\n## ", 1)[0]
            for name, field in entry.params.model_fields.items():
                assert f"| `{name}` |" in section, (attribute, entry.name, name)
                if field.is_required():
                    assert f"| `{name}` |" in section and "required" in section, (entry.name, name)


def test_ranges_and_defaults_come_from_the_pydantic_model():
    class Knob(Params):
        gain: float = Field(2.5, gt=0, le=10, description="how hard it pulls")
        width: list[int] = Field(default_factory=lambda: [32, 32], min_length=1)
        mode: str

    rows = {r[0]: r for r in ref.parameter_rows(Knob)}
    assert rows["gain"] == ("gain", "float", "> 0, ≤ 10", "`2.5`", "how hard it pulls")
    assert rows["width"][1:4] == ("list[int]", "length ≥ 1", "`[32, 32]`")
    assert rows["mode"][3] == "required"


def test_an_entry_registered_later_appears_without_a_page_written_for_it():
    @LEAF_RMPS.register("docs_test_spring")
    class DocsTestSpring(GDS):
        """A spring registered by a test, as a plugin would be."""

        class Params(Params):
            stiffness: float = Field(3.0, gt=0)

    try:
        page = ref.reference_pages()["leaf-rmps.md"]
        assert "\n## docs_test_spring\n" in page and "A spring registered by a test" in page
        assert "| `stiffness` | float | > 0 | `3.0` |" in page
    finally:
        LEAF_RMPS.unregister("docs_test_spring")
    assert "docs_test_spring" not in ref.reference_pages()["leaf-rmps.md"]


def _build(src, out) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-n", "-q", "-b", "html", str(src), str(out)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_the_site_builds_with_no_warning_and_a_broken_link_fails_it(tmp_path):
    src = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", src, ignore=shutil.ignore_patterns("_build", "reference"))
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")  # getting-started includes it
    r = _build(src, tmp_path / "html")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    for page in ("index", "getting-started", "reference/index", "reference/task-maps", "tutorials/your-robot"):
        assert (tmp_path / "html" / f"{page}.html").is_file(), page
    assert "sphere_distance" in (tmp_path / "html" / "reference" / "task-maps.html").read_text()

    (src / "layout.md").write_text((src / "layout.md").read_text() + "\nSee [the missing page](missing.md).\n")
    r = _build(src, tmp_path / "html2")
    assert r.returncode != 0 and "missing.md" in r.stderr, r.stderr[-3000:]
