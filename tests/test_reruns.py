"""A one-line edit reruns only what it changes: in a copy of the small pipeline, one file
gets one more comment line, and `dvc status` names the stages whose deps changed.

The edits are a developer's daily ones: a headline label or a figure (the report's
presentation), a model's code, a params section's schema. Each stage's deps are its
import closure (tests/test_stage_deps.py), so what a stage runs decides what reruns it.
"""

from __future__ import annotations

import json

import pytest

from tests.conftest import copy_small_pipeline, run_checked

# (file edited, what the edit is, the stages it may mark: by name, without the
# foreach key, so ``train`` stands for every train@<scene>)
EDITS = [
    ("eskin/reporting/presentation.py", "a headline label or a figure's caption",
     {"publish"}),
    ("eskin/reporting/figures.py", "how a figure is drawn", {"publish"}),
    # the export and the tracking load the saved models, and unpickling runs their
    # classes' code
    ("eskin/learning/gp.py", "a model's code", {"train", "publish"}),
    ("eskin/deploy/export.py", "the ONNX export's code", {"train"}),
    ("eskin/config/train.py", "the train section's schema", {"settings", "train", "publish"}),
    ("eskin/config/live.py", "the live section's schema (no stage reads it)", {"publish"}),
]
ACQUIRE = "acquire"


def stale_stages(root, env) -> set[str]:
    """The stages whose deps `dvc status` finds changed, by name (``train@a`` → train)."""
    status = json.loads(run_checked(["dvc", "status", "--json"], root, env).stdout or "{}")
    return {address.split("@")[0] for address in status}


@pytest.fixture(scope="module")
def pipeline_copy(tmp_path_factory, small_pipeline):
    root = tmp_path_factory.mktemp("reruns") / "project"
    env = copy_small_pipeline(small_pipeline, root, f"sqlite:///{root.parent / 'mlflow.db'}",
                              track=False)
    assert stale_stages(root, env) == set(), "the copy starts up to date"
    return root, env


@pytest.mark.parametrize("path, what, allowed", EDITS, ids=[e[0] for e in EDITS])
@pytest.mark.starts
def test_a_one_line_edit_marks_only_the_stages_that_run_it(pipeline_copy, path, what,
                                                          allowed):
    root, env = pipeline_copy
    edited = root / path
    before = edited.read_bytes()
    try:
        edited.write_bytes(before + b"# one more line\n")
        stale = stale_stages(root, env)
    finally:
        edited.write_bytes(before)
    assert stale, f"an edit of {path} marks no stage: is it still a dep of any?"
    assert stale <= allowed, (f"an edit of {path} ({what}) marks {sorted(stale - allowed)} "
                              f"too (allowed: {sorted(allowed)})")
    assert ACQUIRE not in stale


def test_nothing_of_learning_or_reporting_reruns_an_acquisition():
    """An acquisition costs a lab hours at the bench: no edit downstream of it (learning,
    evaluation, reporting, tracking, deployment) may mark it stale."""
    from tests.test_stage_deps import ROOT, STAGES, declared_code

    downstream = [ROOT / "eskin" / name for name in
                  ("learning", "evaluation", "reporting", "tracking", "deploy")]
    for address, _, deps in STAGES:
        if address.split(":")[1].split("@")[0] != ACQUIRE:
            continue
        reached = sorted(str(p.relative_to(ROOT)) for p in declared_code(deps)
                         if any(p.is_relative_to(d) for d in downstream))
        assert not reached, f"{address} depends on {reached}"


@pytest.mark.starts
def test_a_knob_trains_only_its_task_and_a_cv_setting_that_moves_no_result_trains_none(
        pipeline_copy):
    """A scene's tasks train in one stage, which keeps a task trained from the same
    features, folds, settings and code: a hyperparameter of one task's model refits that
    task alone, and `cv.n_jobs` (folds in parallel: the same results) refits nothing.
    Last in the module: it leaves the copy on other params."""
    import yaml

    root, env = pipeline_copy
    params = yaml.safe_load((root / "params.yaml").read_text())
    chosen = json.loads((root / "reports/settings/single_force/force.json").read_text())
    model = chosen["train"]["model"]
    knob = next(k for k, v in chosen["train"][model].items()
                if isinstance(v, int) and not isinstance(v, bool) and k != "seed")
    params["train"]["force"][model][knob] = chosen["train"][model][knob] + 1
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    said = run_checked(["dvc", "repro"], root, env)
    out = said.stdout + said.stderr
    assert "Running stage 'train@single_force'" in out
    assert "Running stage 'train@two_force'" not in out, "its settings did not change"
    for task in ("stretch", "detect", "localise"):
        assert f"single_force/{task}: kept" in out, out
    assert "single_force/force: kept" not in out and "single_force/force [" in out

    params["cv"]["n_jobs"] = 1 + int(params["cv"]["n_jobs"] == 1)
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    said = run_checked(["dvc", "repro"], root, env)
    out = said.stdout + said.stderr
    assert "Running stage 'train@single_force'" in out and "Running stage 'train@two_force'" in out
    assert out.count(": kept, trained") == 8, out
    # and the views: each scene's stack, and the report
    assert out.count("stack kept") == 2 and "report: kept" in out, out
    assert stale_stages(root, env) == set()
