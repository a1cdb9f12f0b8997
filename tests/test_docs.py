"""The documentation's links work and it points only inside the repository.

README.md, docs/**/*.md and benchmarks/README.md: every relative markdown link (`[text](path)`,
`[text](path#anchor)`) names a file or folder that exists (an anchor is not checked, only its file), and
no page refers to a path outside the repository: a relative path that climbs out of the clone, or an
absolute path of one machine (`/work/...`, `/root/...`, `/home/...`). Paths in the user's home are fine
only for the examples the docs give of the user's own machine (`~/.venvs/...`, `~/adademo-bench`).
Reads text only: milliseconds.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", ROOT / "benchmarks" / "README.md", *(ROOT / "docs").rglob("*.md")])

# [text](target) or [text](target "title"); images too (![alt](target)).
LINK = re.compile(r"\[[^\]]*\]\(\s*<?([^)\s>]+)>?[^)]*\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)
# A relative path that starts by climbing: ../x, ../../x (in links, code and prose alike).
CLIMB = re.compile(r"(?<![\w./~-])((?:\.\./)+[\w.\-/]*)")
MACHINE_PATH = re.compile(r"(?<![\w.~-])/(?:work|root|home|Users)/[^\s`)\]]*")
HOME_PATH = re.compile(r"(?<!\w)~/([\w.\-/]*)")
HOME_EXAMPLES = (".venvs", "adademo-bench")


def page_id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def inside_repo(path: Path) -> bool:
    try:
        path.resolve().relative_to(ROOT)
    except ValueError:
        return False
    return True


def test_the_pages_exist():
    names = {page_id(p) for p in PAGES}
    assert {"README.md", "benchmarks/README.md", "docs/index.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=page_id)
def test_relative_links_resolve(page):
    text = FENCE.sub("", page.read_text())  # a link inside a code block is code, not a link
    broken = []
    for target in LINK.findall(text):
        if re.match(r"^(https?:|mailto:|#)", target):
            continue
        path = (page.parent / target.split("#", 1)[0]).resolve()
        if not inside_repo(path):
            broken.append(f"{target} (outside the repository)")
        elif not path.exists():
            broken.append(target)
    assert not broken, f"{page_id(page)}: links to nothing: {', '.join(broken)}"


@pytest.mark.parametrize("page", PAGES, ids=page_id)
def test_no_path_outside_the_repository(page):
    text = page.read_text()
    outside = [p for p in CLIMB.findall(text) if not inside_repo(page.parent / p)]
    outside += MACHINE_PATH.findall(text)
    outside += [f"~/{p}" for p in HOME_PATH.findall(text) if not p.startswith(HOME_EXAMPLES)]
    assert not outside, f"{page_id(page)} refers to paths outside the repository: {', '.join(outside)}"


def test_every_recipe_and_preset_is_listed():
    """docs/recipes.md has a row for each file of recipes/ and policies/: a new user finds them there."""
    text = (ROOT / "docs" / "recipes.md").read_text()
    files = [*(ROOT / "recipes").glob("*.yaml"), *(ROOT / "policies").glob("*.yaml")]
    unlisted = [f"{f.parent.name}/{f.name}" for f in files if f"(../{f.parent.name}/{f.name})" not in text]
    assert files and not unlisted, f"docs/recipes.md lists no row for {', '.join(sorted(unlisted))}"


def test_every_benchmark_script_is_listed():
    """benchmarks/README.md's table of scripts has a row for each script of benchmarks/ (a helper module starts
    with `_`): the row's first cell names it, a mention elsewhere on the page does not count."""
    text = (ROOT / "benchmarks" / "README.md").read_text()
    scripts = [p.name for p in (ROOT / "benchmarks").glob("*.py") if not p.name.startswith("_")]
    unlisted = [name for name in scripts if f"\n| `{name}" not in text]
    assert scripts and not unlisted, f"benchmarks/README.md has no row for {', '.join(sorted(unlisted))}"
