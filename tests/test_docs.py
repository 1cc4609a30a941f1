"""The README is a door, the rest is the documentation site (docs/, mkdocs.yml).

The README stays short and names what a newcomer types; the site builds under
``mkdocs build --strict`` (no broken link or anchor, no page outside the nav), and
every page is in the nav.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
MKDOCS_YML = ROOT / "mkdocs.yml"
README_MAX_LINES = 250


def nav_pages(nav) -> list[str]:
    """Every page a nav names, at any depth."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [page for item in nav for page in nav_pages(item)]
    if isinstance(nav, dict):
        return [page for value in nav.values() for page in nav_pages(value)]
    return []


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines, at most {README_MAX_LINES}: "
        "move the detail to a page under docs/")


def test_readme_names_the_commands():
    text = README.read_text(encoding="utf-8")
    for needed in ("make repro", "make test", "reports/index.html",
                   "mlflow ui --backend-store-uri sqlite:///mlflow.db",
                   "dvc exp run -S", "eskin compare"):
        assert needed in text, f"README.md does not mention {needed!r}"


def test_readme_links_to_pages_that_exist():
    text = README.read_text(encoding="utf-8")
    targets = re.findall(r"\]\((docs/[^)#\s]+)(?:#[^)]*)?\)", text)
    assert targets, "README.md links to no docs page"
    missing = sorted({t for t in targets if not (ROOT / t).is_file()})
    assert not missing, f"README.md links to missing files: {missing}"


def test_every_page_is_in_the_nav():
    config = yaml.safe_load(MKDOCS_YML.read_text(encoding="utf-8"))
    listed = set(nav_pages(config["nav"]))
    pages = {path.relative_to(DOCS).as_posix() for path in DOCS.rglob("*.md")}
    assert pages - listed == set(), f"pages missing from mkdocs.yml's nav: {sorted(pages - listed)}"
    assert listed - pages == set(), f"nav entries with no page: {sorted(listed - pages)}"


@pytest.mark.heavy
def test_site_builds_strict(tmp_path):
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    result = subprocess.run(
        # not --quiet: it silences the warnings --strict counts (a broken anchor passed)
        [sys.executable, "-m", "mkdocs", "build", "--strict",
         "--config-file", str(MKDOCS_YML), "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert (tmp_path / "site" / "index.html").is_file()


# Numbers in the docs come from the outputs (issue 58). The outputs whose measurements the
# pages quote: the pipeline's scores and metrics, the bench's learning curves and plan
# checks. A decimal of three or four places typed in docs/ that equals one of their values
# at the places typed is a quoted output typed by hand: it must be read at build time
# ({{ output(...) }}, docs_macros.py), or sit in a paragraph, list item or
# section marked "History, at <commit>" (below), or be listed here as no measurement.
QUOTED_OUTPUTS = ("reports/scores/*/*.json", "reports/pairs/*.json", "reports/metrics/*.json",
                  "reports/learning_curve/*.json", "reports/plan_check/*.json",
                  "reports/localise_cost.json")
# Every history marker in docs/, by page and commit: figures no output holds, typed from
# the run of that commit. A new one is added here, so that each is seen.
HISTORY = {
    ("getting-started.md", "4a4d39e"), ("getting-started.md", "c00665b"),
    ("benchmark.md", "5662b67"), ("benchmark.md", "a04e336"), ("benchmark.md", "47c6cc5"),
    ("benchmark.md", "5d5c46c"), ("benchmark.md", "12765ac"), ("benchmark.md", "008bced"),
    ("benchmark.md", "6452867"), ("benchmark.md", "004a3ca"), ("benchmark.md", "9510804"),
    ("benchmark.md", "894f906"), ("benchmark.md", "cf46b9c"), ("benchmark.md", "7de7013"),
    ("benchmark.md", "486b34c"), ("results.md", "486b34c"),
    ("results.md", "160d4d1"), ("results.md", "ceed7ef"), ("results.md", "47c6cc5"),
    ("results.md", "cf46b9c"), ("results.md", "6452867"), ("results.md", "9510804"),
    ("simulator.md", "486b34c"), ("stress.md", "fec03be"),
    ("benchmark.md", "71ad41d"), ("benchmark.md", "a73c8ac"), ("benchmark.md", "4d2acf5"),
    ("learning.md", "3c4916e"), ("benchmark.md", "f8eb704"), ("live.md", "7ce2c8f"),
    ("live.md", "bd50136"), ("live.md", "e839d46"), ("live.md", "b4596a0"),
    ("testing.md", "dab3cd0"), ("testing.md", "9d023a6"), ("live.md", "84fe2e0"),
}
# Typed decimals that equal an output's value by coincidence: not that measurement.
NOT_MEASURED = {
    ("simulator.md", "0.004"): "the real skin's drift rate in pF/√s, from the literature",
    ("results.md", "0.771"): "the paper's own two-contact force R²",
    ("benchmark.md", "0.001"): "the bound's convergence threshold, a setting",
    ("hostile-input.md", "0.002"): "a soak's reset and vanish fault rates, settings",
    ("reports.md", "0.056"): "a label's text sized in a figure cell, not a score",
}
HISTORY_MARK = re.compile(r"[Hh]istory\*{0,2},?\s+at\s+([0-9a-f]{7,12})\b")
DECIMAL = re.compile(r"(?<![\w.])(\d+\.\d{3,4})(?![\d])")


def output_values() -> set[str]:
    """Every value of the quoted outputs (spreads, times, lists and fits left out), at 3
    and 4 places."""
    def numbers(node):
        # lists (each held-out draw's, each new recording's score) and the fits'
        # parameters are quoted through their summaries, if at all
        if isinstance(node, dict):
            for key, value in node.items():
                if not key.endswith("_std") and key not in ("seconds", "fit", "low_fit"):
                    yield from numbers(value)
        elif isinstance(node, float):
            yield node

    values = set()
    for pattern in QUOTED_OUTPUTS:
        for path in ROOT.glob(pattern):
            for value in numbers(json.loads(path.read_text())):
                values |= {f"{value:.3f}", f"{value:.4f}"}
    return values


def blocks(text: str) -> list[tuple[tuple[str, ...], str]]:
    """A page's paragraphs and list items (an item with its indented paragraphs, tables
    and sub-items), each with the headings it is under; code blocks and {{ … }} / {% … %}
    left out (what they print is read from outputs)."""
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    text = re.sub(r"\{\{.*?\}\}|\{%.*?%\}", "", text, flags=re.S)
    out: list[tuple[tuple[str, ...], str]] = []
    headings: list[str] = []
    current: list[str] = []

    def close() -> None:
        if not current:
            return
        if out and current[0][:1].isspace() and out[-1][0] == tuple(headings):
            out[-1] = (out[-1][0], out[-1][1] + "\n" + "\n".join(current))  # indented: the item's
        else:
            out.append((tuple(headings), "\n".join(current)))
        current.clear()

    for line in text.splitlines() + [""]:
        heading = re.match(r"(#+)\s+(.*)", line)
        if heading:
            close()
            del headings[len(heading.group(1)) - 1:]
            headings += [""] * (len(heading.group(1)) - 1 - len(headings)) + [heading.group(2)]
            continue
        if not line.strip() or re.match(r"(?:[-*]|\d+\.)\s", line):
            close()
        if line.strip():
            current.append(line)
    close()
    return out


def typed_quotes(page: Path, values: set[str]) -> list[str]:
    """The decimals typed on ``page`` that an output holds, outside history: a block that
    names "History, at <commit>", or a section whose first block opens with it (and the
    sections under it)."""
    found, history, seen = [], set(), set()
    for headings, block in blocks(page.read_text(encoding="utf-8")):
        first, seen = headings not in seen, seen | {headings}
        if any(headings[:depth] in history for depth in range(1, len(headings) + 1)):
            continue
        if HISTORY_MARK.search(block):
            if first and block.startswith("History"):
                history.add(headings)
            continue
        block = re.sub(r"`[^`]*`", "", block)
        found += [number for number in DECIMAL.findall(block)
                  if number in values and (page.name, number) not in NOT_MEASURED]
    return found


def test_no_measured_number_is_typed_where_an_output_holds_it():
    values = output_values()
    assert len(values) > 100, "no outputs in reports/: `dvc checkout` first"
    typed = {page.name: typed_quotes(page, values) for page in sorted(DOCS.glob("*.md"))}
    typed = {name: numbers for name, numbers in typed.items() if numbers}
    assert not typed, ("numbers typed in docs/ that an output in reports/ holds: read them "
                       f"with {{{{ output(...) }}}} or mark them as history: {typed}")


def test_every_history_mark_names_its_commit_and_is_listed():
    marked = {(page.name, commit) for page in DOCS.glob("*.md")
              for commit in HISTORY_MARK.findall(page.read_text(encoding="utf-8"))}
    assert marked == HISTORY, (f"history marks not listed in HISTORY: {marked - HISTORY}; "
                               f"listed but gone: {HISTORY - marked}")
    if (ROOT / ".git").exists() and not (ROOT / ".git" / "shallow").exists():
        for _, commit in sorted(HISTORY):
            # An ancestor of HEAD, not merely an object here: a rewritten history leaves
            # the old commits in this checkout but not in a fresh clone.
            known = subprocess.run(["git", "merge-base", "--is-ancestor", commit, "HEAD"],
                                   cwd=ROOT, capture_output=True)
            assert known.returncode == 0, f"history at {commit}: not a commit of this branch"


def test_the_build_fails_when_a_quoted_output_is_missing(tmp_path):
    """The site reads its measured numbers from reports/ at build time: without one of
    the files it quotes, `mkdocs build --strict` fails and names it."""
    for name in ("docs", "reports"):
        shutil.copytree(ROOT / name, tmp_path / name,
                        ignore=shutil.ignore_patterns("*.parquet", "index.html"))
    for name in ("mkdocs.yml", "params.yaml", "bench/params.yaml", "docs_macros.py"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, tmp_path / name)
    (tmp_path / "reports" / "learning_curve" / "two_force.json").unlink()
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
         str(tmp_path / "site")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode != 0
    assert "reports/learning_curve/two_force.json, which is missing" in (result.stdout
                                                                        + result.stderr)
