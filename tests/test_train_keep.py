"""A scene's train step keeps a task trained from the same features, folds, settings and
code (eskin/steps/train.py), and trains it again when any of them differs or an output
is gone."""

from __future__ import annotations

import json

from eskin.steps.train import code_files, code_md5, kept, scene_inputs, task_inputs
from tests.test_stage_deps import ROOT, closure, implicit_init


def outputs(tmp_path):
    names = {"lineage_path": "lineage.json", "scores_path": "scores.json",
             "predictions_path": "predictions.parquet", "model_path": "model.joblib"}
    return {key: tmp_path / name for key, name in names.items()}


def inputs_at(tmp_path):
    for name in ("features.parquet", "folds.parquet", "settings.json"):
        (tmp_path / name).write_bytes(name.encode())
    return task_inputs(tmp_path / "settings.json",
                       scene_inputs(tmp_path / "features.parquet", tmp_path / "folds.parquet"))


def test_a_task_is_kept_only_when_its_lineage_records_these_inputs_and_its_outputs_are_there(
        tmp_path):
    inputs, out = inputs_at(tmp_path), outputs(tmp_path)
    for path in out.values():
        path.write_text("{}")
    assert not kept(inputs, out), "a lineage that records no inputs"
    out["lineage_path"].write_text(json.dumps({"status": "trained", **inputs}))
    assert kept(inputs, out)
    for name in inputs:
        assert not kept({**inputs, name: "0" * 32}, out), f"{name} changed"
    out["model_path"].unlink()
    assert not kept(inputs, out), "its model is gone"


def test_a_changed_settings_file_changes_the_inputs(tmp_path):
    before = inputs_at(tmp_path)
    (tmp_path / "settings.json").write_text('{"max_iter": 150}')
    after = task_inputs(tmp_path / "settings.json",
                        scene_inputs(tmp_path / "features.parquet", tmp_path / "folds.parquet"))
    assert {k for k in before if before[k] != after[k]} == {"settings_md5"}
    assert before["code_md5"] == code_md5()


def test_the_code_md5_covers_the_code_the_train_stage_runs():
    """The files hashed are the train stage's import closure (what dvc.yaml lists, checked
    by test_stage_deps) less its export's: an edit in any module training runs, a lazy
    import included, trains every task again; an edit of the export alone, none."""
    ran = {p for p in closure("eskin.steps.train") if p.parts[len(ROOT.parts)] == "eskin"}
    hashed = {p for p in code_files() if not implicit_init(p)}
    assert ran - {p for p in ran if implicit_init(p)} == hashed
