"""The daily loop: change one knob with `dvc exp run -S`, run it, compare the variants.

`-S key=value` goes through DVC's ``_update_params`` (dvc/repo/experiments/queue/base.py)
→ ``dvc.utils.hydra.apply_overrides``: the file is loaded with ruamel.yaml's round trip,
the override applied to a plain copy, and the copy merged back. Mappings are merged key
by key, but every list is replaced by a plain one, so a flow list comes back in block
style and whatever ruamel had hung on the old list (a comment, a blank line after it) is
lost. params.yaml is written in the form that survives; here a real `dvc exp run -S`,
in a scratch project whose one stage reads the changed param, checks that it does.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import pandas as pd
import pytest
from conftest import ROOT, copy_small_pipeline, run_checked

# Each test here starts a pipeline: `make check` leaves them out.
pytestmark = pytest.mark.starts

# Each key a stage of the scratch project reads (a list item: its list).
READ_KEYS = ("sim_board.faults.stall_s", "train.stretch.model", "train.force.model",
             "scenes.single_force.stretches")
SHOW_PARAMS = """\
import json, yaml

params = yaml.safe_load(open("params.yaml"))
def get(key):
    node = params
    for part in key.split("."):
        node = node[part]
    return node
json.dump({key: get(key) for key in KEYS}, open("shown.json", "w"))
"""


def git_env() -> dict:
    bin_dir = str(Path(sys.executable).parent)  # dvc, and the python the stage runs
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
           "DVC_NO_ANALYTICS": "1", "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t",
           "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t"}
    env.pop("DVC_ROOT", None)
    return env


@pytest.fixture(scope="module")
def params_project(tmp_path_factory):
    """A git + DVC project holding the repo's params.yaml and one stage that reads a few
    of its keys (in a second): reproduced and committed, the baseline of every test."""
    root = tmp_path_factory.mktemp("params_project")
    env = git_env()
    shutil.copy(ROOT / "params.yaml", root / "params.yaml")
    (root / "show.py").write_text(f"KEYS = {READ_KEYS!r}\n" + SHOW_PARAMS)
    (root / "dvc.yaml").write_text(
        "stages:\n  show:\n    cmd: python show.py\n    deps:\n      - show.py\n"
        "    params:\n" + "".join(f"      - {key}\n" for key in READ_KEYS) +
        "    outs:\n      - shown.json:\n          cache: false\n")
    for args in (["git", "init", "-q"], ["dvc", "init", "-q"], ["dvc", "repro", "-q"],
                 ["git", "add", "-A"], ["git", "commit", "-qm", "baseline"]):
        run_checked(args, root, env)
    return root


def changed_lines(root: Path, env: dict, *revisions: str) -> tuple[list[str], list[str]]:
    """(lines out, lines in) of params.yaml between ``revisions`` (git diff's own)."""
    diff = run_checked(["git", "diff", "--unified=0", *revisions, "--", "params.yaml"],
                       root, env).stdout.splitlines()
    out = [line[1:] for line in diff if line.startswith("-") and not line.startswith("---")]
    into = [line[1:] for line in diff if line.startswith("+") and not line.startswith("+++")]
    return out, into


@pytest.mark.parametrize("setting, out, into, shown", [
    # a scalar in a nested section
    ("sim_board.faults.stall_s=0.4", ["    stall_s: 0.5"], ["    stall_s: 0.4"], 0.4),
    # a model name
    ("train.stretch.model=ridge", ["    model: paper             # linear regression"],
     ["    model: ridge             # linear regression"], "ridge"),
    # a model chosen per kind of scene, for one kind
    ("train.force.model.single_force=hist_gradient_boosting",
     ["      single_force: physics_profile"], ["      single_force: hist_gradient_boosting"],
     {"single_force": "hist_gradient_boosting", "two_force": "active_terminals"}),
    # ... and for every kind at once: the per-kind lines go, one line comes in
    ("train.force.model=hist_gradient_boosting",
     ["    model:", "      single_force: physics_profile", "      two_force: active_terminals"],
     ["    model: hist_gradient_boosting"], "hist_gradient_boosting"),
    # an item of a list
    ("scenes.single_force.stretches.2=1.2", ["    - 1.15842"], ["    - 1.2"],
     [1.0, 1.07921, 1.2]),
])
def test_dvc_exp_run_set_param_changes_only_that_setting_in_params_yaml(
        params_project, tmp_path, setting, out, into, shown):
    root = tmp_path / "project"
    shutil.copytree(params_project, root, ignore=shutil.ignore_patterns("tmp"))
    env = git_env()
    run_checked(["dvc", "exp", "run", "-q", "-n", "knob", "-S", setting], root, env)
    key = setting.split("=")[0]
    read_key = next(k for k in READ_KEYS if key == k or key.startswith(f"{k}."))
    assert json.loads((root / "shown.json").read_text())[read_key] == shown  # it ran on it
    # The workspace holds the experiment (no --temp, no --queue) ...
    workspace = changed_lines(root, env, "HEAD")
    assert workspace == (out, into), workspace
    # ... and so does the experiment's commit.
    refs = [ref for ref in run_checked(["git", "for-each-ref", "--format=%(refname)",
                                        "refs/exps"], root, env).stdout.split()
            if not ref.startswith("refs/exps/exec/")]  # DVC's own executor refs
    assert [ref.rsplit("/", 1)[1] for ref in refs] == ["knob"], refs
    committed = changed_lines(root, env, "HEAD", refs[0])
    assert committed == (out, into), committed



@pytest.fixture(scope="module")
def two_experiments(tmp_path_factory, small_pipeline):
    """A scratch copy of the project (small scenes, MLflow in SQLite beside it) and two
    real experiments of its single-force force stage: the default, a force model given
    per kind of scene, and `-S train.force.model=hist_gradient_boosting`, one for all."""
    root = tmp_path_factory.mktemp("daily_loop")
    env = copy_small_pipeline(small_pipeline, root,
                              f"sqlite:///{root.parent / 'daily_loop.db'}", track=False)
    # The publish stage logs the runs eskin compare reads: the first experiment is the
    # reproduced pipeline, logged again by it; the second retrains only the force tasks.
    run_checked(["dvc", "exp", "run", "-n", "per-kind", "--force", "--single-item", "publish"],
                root, env)
    run_checked(["dvc", "exp", "run", "-n", "all-kinds", "-S",
                 "train.force.model=hist_gradient_boosting", "publish"], root, env)
    return root, env


def test_eskin_compare_shows_a_model_switched_for_every_kind(two_experiments):
    root, env = two_experiments
    csv = root / "compare.csv"
    run_checked([sys.executable, "-m", "eskin", "compare", "--format", "csv", "--output",
                 str(csv)], root, env)
    table = pd.read_csv(csv).set_index("variant")
    assert set(table.index) == {"per-kind", "all-kinds"}
    # each form's keys are in one run's params only: every one of them is shown
    assert table.loc["all-kinds", "train.force.model"] == "hist_gradient_boosting"
    assert pd.isna(table.loc["per-kind", "train.force.model"])
    assert table.loc["per-kind", "train.force.model.single_force"] == "physics_profile"
    assert table.loc["per-kind", "train.force.model.two_force"] == "active_terminals"
    assert table.loc["all-kinds", ["train.force.model.single_force",
                                   "train.force.model.two_force"]].isna().all()
    assert not any(c.startswith(("sim.", "cv.", "scenes.")) for c in table.columns), table
    # every task of both scenes has a score (a task DVC reused too): a wide terminal keeps
    # a row per variant
    printed = run_checked([sys.executable, "-m", "eskin", "compare"], root,
                          {**env, "COLUMNS": "500"}).stdout
    row = next(line for line in printed.splitlines() if line.startswith("all-kinds"))
    assert "hist_gradient_boosting" in row and row.count("—") == 2, printed
