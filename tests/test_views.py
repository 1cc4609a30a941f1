"""`dvc exp show` and `dvc metrics show` in a 120-column terminal (issue 38).

`dvc exp show` lists every key of params.yaml, DVC's default params file, whatever the
stages declare (dvc/repo/params/show.py, ``_collect_params``), and every dependency of
every stage: params.yaml holds the pipeline's knobs only. With no options the table does
not fit 120 columns (docs/experiments.md says why); the daily loop's view is
``dvc exp show --only-changed --drop '.*/' --no-pager``: the experiment's name, the params
that differ and the headline scores that differ, each dependency's hash left out.

The headline scores are one file, reports/metrics.json (the report stage writes it),
keyed ``<scene>.<task>.<target>.<score>`` (conditions CV; the target left out where it is
the task), no entry for a skipped task.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, copy_small_pipeline, run_checked

HEADLINE = "reports/metrics.json"
EXP_SHOW = ["dvc", "exp", "show", "--only-changed", "--drop", ".*/", "--no-pager"]
WIDTH = 120
EXPERIMENT, KNOB, VALUE = "views-rf", "train.stretch.model", "random_forest"
SCENES, TASKS = ("single_force", "two_force"), ("stretch", "force", "detect", "localise",
                                                "pairs")

def shown(args: list[str], root: Path, env: dict) -> str:
    """What ``args`` print in a terminal of WIDTH columns."""
    return run_checked(args, root, {**env, "COLUMNS": str(WIDTH)}).stdout


def too_wide(text: str) -> list[str]:
    return [line for line in text.splitlines() if len(line) > WIDTH]


@pytest.fixture(scope="module")
def experiment(tmp_path_factory, small_pipeline):
    """A scratch copy of the project (small scenes) reproduced and committed, then one
    real `dvc exp run -S`; the workspace holds the experiment."""
    root = tmp_path_factory.mktemp("views")
    env = copy_small_pipeline(small_pipeline, root, f"sqlite:///{root.parent / 'views.db'}",
                              track=False)
    run_checked(["dvc", "exp", "run", "-q", "-n", EXPERIMENT, "-S", f"{KNOB}={VALUE}"], root,
                env)
    return root, env


def test_params_yaml_holds_only_what_the_pipelines_stages_read():
    """`dvc exp show` has a column for every key of params.yaml: each section of it is
    declared by a stage of dvc.yaml (make bench's and make stress's are in their own
    projects' params files), but ``live``: `eskin live`'s, which make bench's live hour
    (bench/dvc.yaml) declares from ../params.yaml."""
    from dvc.repo import Repo

    sections = set(yaml.safe_load((ROOT / "params.yaml").read_text()))
    with Repo(str(ROOT)) as repo:
        declared = {key.split(".")[0] for stage in repo.index.stages
                    for dep in stage.params for key in dep.params}
    bench = yaml.safe_load((ROOT / "bench" / "dvc.yaml").read_text())["stages"]
    live = bench["live_hour"]["do"]["params"][0]["../params.yaml"]
    assert sections - declared == {"live"} and "live" in live
    assert declared <= sections, sorted(declared - sections)


def test_exp_show_names_the_experiment_its_changed_param_and_score_in_120_columns(experiment):
    root, env = experiment
    table = shown(EXP_SHOW, root, env)
    assert not too_wide(table), table
    score = json.loads((root / HEADLINE).read_text())["single_force"]["stretch"]["r2"]
    row = next(line for line in table.splitlines() if f"[{EXPERIMENT}]" in line)
    assert VALUE in row and f"{score:.5g}" in row, table  # DVC shows 5 significant digits
    assert KNOB in table and "single_force.stretch.r2" in table, table
    assert "/" not in table, table  # no dependency's hash


def test_metrics_show_is_one_row_of_headline_scores_named_by_scene_and_task(experiment):
    """One file, one row: every score named <scene>.<task>..., none empty, no entry for a
    task the scene skips. DVC draws a column per score (dvc/compare.py, metrics_table), so
    the row is as wide as the names; `dvc metrics diff --all` is the same scores a row
    each, which fits 120 columns."""
    root, env = experiment
    header, *rows = shown(["dvc", "metrics", "show"], root, env).splitlines()
    assert len(rows) == 1 and rows[0].split()[0] == HEADLINE, rows
    names, values = header.split()[1:], rows[0].split()[1:]
    assert len(values) == len(names) and "-" not in values, (names, values)
    named = re.compile(rf"^({'|'.join(SCENES)})\.({'|'.join(TASKS)})\.")
    assert all(named.match(name) for name in names), names
    for skipped in ("single_force.pairs.", "two_force.stretch.", "two_force.detect."):
        assert not any(name.startswith(skipped) for name in names), names

    listing = shown(["dvc", "metrics", "diff", "--all"], root, env)
    assert not too_wide(listing), listing
    assert all(name in listing for name in names), listing
