"""A new kind of scene in at most four files (issue 54: a Kind that behaves).

The kind says its labels, tasks, outputs and counts; a plan, headline rows and figures are
registered beside their kind's (eskin.data.plan.PLANS, eskin.reporting.presentation). The
test adds a stretch-only kind (a skin stretched and never pressed: the stretch task alone)
to a scratch copy of the project, in the files a developer would touch, and reproduces
its pipeline with real DVC from acquisition to the report and MLflow."""

from __future__ import annotations

import copy
import json
import subprocess

import pytest
import yaml

from tests.conftest import quick_params, run_checked, scratch_project

# The change a developer makes, file by file: (path, text replaced, its replacement), or
# (path, None, text appended).
KIND = "stretch_only"
EDITS = [
    ("eskin/kinds.py",
     "KINDS: dict[str, Kind] = {kind.name: kind for kind in (ONE_CONTACT, TWO_CONTACTS)}",
     f'STRETCH_ONLY = Kind("{KIND}", contacts=0, stretch_column_optional=False)\n\n'
     "KINDS: dict[str, Kind] = {kind.name: kind for kind in (ONE_CONTACT, TWO_CONTACTS,\n"
     "                                                        STRETCH_ONLY)}"),
    ("eskin/data/plan.py", None, f'''

def _stretch_only_plan_of(name: str, scene: AcquiredScene, skin: AnySkin) -> ScenePlan:
    """Every stretch, nothing pressed."""
    conditions = [Condition(float(s), ()) for s in scene.stretches]
    return ScenePlan(name, "{KIND}", _repeated(conditions, scene.repeats), scene.samples,
                     skin, scene.repeats)


PLANS["{KIND}"] = _stretch_only_plan_of
'''),
    ("eskin/reporting/presentation.py", None, f'''

HEADLINES["{KIND}"] = (Headline("stretch R²", "stretch", "stretch", "r2"),
                       Headline("stretch MSE", "stretch", "stretch", "mse"))
FIGURES["{KIND}"] = (TWO_CONTACTS_STRETCH,)
'''),
]
SCENE = {"kind": KIND, "source": "simulated", "stretches": [1.0, 1.07921, 1.15842],
         "forces": [0.0], "samples": 20}


@pytest.mark.heavy
def test_a_stretch_only_kind_takes_four_files_and_runs_through_dvc_repro(tmp_path,
                                                                        repo_params):
    root = tmp_path / "project"
    root.mkdir()
    env = scratch_project(root, repo_params, f"sqlite:///{tmp_path / 'mlflow.db'}")
    for path, old, new in EDITS:
        text = (root / path).read_text()
        assert old is None or text.count(old) == 1, (path, old)
        (root / path).write_text(text + new if old is None else text.replace(old, new))
    params = quick_params(copy.deepcopy(repo_params), folds=3)
    params["scenes"] = {"stretchy": SCENE}
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    touched = subprocess.run(["git", "diff", "--name-only"], cwd=root, text=True,
                             capture_output=True, check=True).stdout.split()
    assert len(touched) <= 4, touched
    run_checked(["dvc", "repro"], root, env)
    scores = json.loads((root / "reports/scores/stretchy/stretch.json").read_text())
    assert scores["stratified"]["stretch"]["r2"] > 0.9  # conditions: one λ a fold
    for task in ("force", "detect", "localise"):
        skipped = json.loads((root / f"reports/scores/stretchy/{task}.json").read_text())
        assert skipped["status"] == "skipped", skipped
    results = (root / "reports/results.md").read_text()
    assert "stretch R²" in results and "stretchy" in results
    columns = json.loads(subprocess.run(
        ["python", "-c", "import json; from eskin.deploy.stack import ExportedStack; "
         "print(json.dumps(ExportedStack.from_file('models/stretchy/stack.onnx').columns))"],
        cwd=root, env=env, text=True, capture_output=True, check=True).stdout)
    assert columns == ["stretch"]
