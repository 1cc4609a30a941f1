"""`dvc exp show` and `dvc metrics show` in a 120-column terminal (issue 38).

`dvc exp show` lists every key of params.yaml, DVC's default params file, whatever the
stages declare (dvc/repo/params/show.py, ``_collect_params``), and every dependency of
every stage: params.yaml holds the pipeline's knobs only. With no options the table does
not fit 120 columns (docs/experiments.md says why); the daily loop's view is the README's
``dvc exp show --only-changed --drop 'Created|models|.*/' --no-pager``: the
experiment's name, the params that differ and the headline scores that differ, each
dependency's hash left out.

DVC's metrics are a file a scene, reports/metrics/<scene>.json (the publish stage writes
them), one conditions-CV number a question, named by its target (two contacts: as a set),
no entry for a skipped task.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, copy_small_pipeline, run_checked

from eskin.catalog import PAIRS, scores_path

METRICS_DIR = "reports/metrics"
EXP_SHOW = ["dvc", "exp", "show", "--only-changed", "--drop", "Created|models|.*/",
            "--no-pager"]
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


def test_the_readme_gives_the_exp_show_tested_here():
    readme = (ROOT / "README.md").read_text()
    assert "dvc exp show --only-changed --drop 'Created|models|.*/' --no-pager" \
        in readme


@pytest.mark.starts
def test_exp_show_names_the_experiment_its_changed_param_and_score_in_120_columns(experiment):
    root, env = experiment
    table = shown(EXP_SHOW, root, env)
    assert not too_wide(table), table
    score = json.loads((root / METRICS_DIR / "single_force.json").read_text())["stretch"]
    row = next(line for line in table.splitlines() if f"[{EXPERIMENT}]" in line)
    assert VALUE in row and f"{score:.5g}" in row, table  # DVC shows 5 significant digits
    assert KNOB in table and "stretch" in table, table
    assert "/" not in table and "Created" not in table, table  # no dependency's hash


@pytest.mark.starts
def test_metrics_show_is_a_row_a_scene_that_fits_120_columns(experiment):
    """A file a scene, a row each: one number a question, named by its target (a
    two-contact scene's as a set), none for a task the scene skips; the table fits 120
    columns, and so does `dvc metrics diff --all`."""
    root, env = experiment
    table = shown(["dvc", "metrics", "show"], root, env)
    assert not too_wide(table), table
    header, *rows = table.splitlines()
    names = header.split()[1:]
    by_scene = {row.split()[0]: dict(zip(names, row.split()[1:], strict=True)) for row in rows}
    assert set(by_scene) == {f"{METRICS_DIR}/{scene}.json" for scene in SCENES}, table
    one, two = by_scene[f"{METRICS_DIR}/single_force.json"], by_scene[
        f"{METRICS_DIR}/two_force.json"]
    assert {k for k, v in one.items() if v != "-"} == {"stretch", "force", "contact", "x", "y"}
    # the default two_force scene counts its contacts (contact_counts): the count's too
    assert {k for k, v in two.items() if v != "-"} == {"contacts", "pairs", "pair_force"}
    written = json.loads((root / METRICS_DIR / "two_force.json").read_text())
    pairs = json.loads((root / scores_path("two_force", PAIRS)).read_text())
    counted = json.loads((root / scores_path("two_force", "detect")).read_text())
    assert written == {"contacts": counted["conditions"]["contacts"]["accuracy"],
                       "pairs": pairs["conditions"]["pair_accuracy"],
                       "pair_force": pairs["conditions"]["force_r2"]}

    listing = shown(["dvc", "metrics", "diff", "--all"], root, env)
    assert not too_wide(listing), listing
    assert all(name in listing for name in names), listing
