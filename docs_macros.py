"""The documentation's measured numbers, read from the outputs at build time (issue 58).

mkdocs-macros (mkdocs.yml) loads this module: a page quotes a measurement as
``{{ output("learning_curve/single_force").tasks.force.bound.headline | f(4) }}``, the
JSON under ``reports/`` (paths relative to the project's root, where mkdocs runs). A
missing file fails the build with its name; a missing key is an undefined variable, which
mkdocs.yml makes an error too. So a number the docs quote cannot outlive the output that
holds it. Figures no output holds are marked on their page as history, with the commit at
which they were measured (tests/test_docs.py lists them).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

REPORTS = Path("reports")


@cache
def output(name: str) -> dict[str, Any]:
    """``reports/<name>.json``, parsed (``name`` without the suffix)."""
    path = REPORTS / f"{name}.json"
    if not path.is_file():
        raise FileNotFoundError(f"the docs quote {path}, which is missing: run the stage that "
                                f"writes it (make repro, make bench) or `dvc checkout`")
    return json.loads(path.read_text())


def fixed(value: float, digits: int = 3) -> str:
    """``value`` with ``digits`` decimals: 0.9752."""
    return f"{float(value):.{digits}f}"


def percent(value: float, digits: int = 0) -> str:
    """A share as a percentage: 0.223 → 22.3 % (with ``digits`` = 1)."""
    return f"{100 * float(value):.{digits}f} %"


def plan_said(scene: str, target: str) -> str:
    """What `eskin plan <scene> --target <target>` prints, from the curves in reports/."""
    from eskin.catalog import learning_curve_path
    from eskin.config.base import BENCH_PARAMS, load_params, sections
    from eskin.config.planning import LearningCurve
    from eskin.tracking import planning

    name, _, value = target.partition("=")
    settings = load_params(sections(BENCH_PARAMS, learning_curve=LearningCurve)).learning_curve
    curves = planning.read_curves(learning_curve_path(scene), scene)
    return planning.describe(planning.plan(curves, name, float(value), settings), settings)


def define_env(env) -> None:
    """mkdocs-macros' hook: the page's ``output`` and ``plan_said``, the filters ``f`` and
    ``pct``."""
    env.macro(output)
    env.macro(plan_said)
    env.filter(fixed, "f")
    env.filter(percent, "pct")
