"""The views keep what they would make again. The train stage exports its scene's stack,
and keeps one exported from the same models, dataset and code (eskin/steps/export.py):
an experiment that changes one scene's model exports that scene only; an edit of the
export's code, or of the file itself, exports it again. (Its models are keyed as its
code is: their md5s, in the same record.) The publish stage keeps its report likewise
(eskin/steps/report.py)."""

from __future__ import annotations

import pytest

from eskin.catalog import EXPORT_CACHE, stack_path
from eskin.data.schema import md5_file
from eskin.steps import export
from tests.conftest import copy_small_pipeline

pytestmark = pytest.mark.starts  # a reproduced pipeline


@pytest.fixture
def workspace(small_pipeline, tmp_path):
    root = tmp_path / "project"
    copy_small_pipeline(small_pipeline, root, f"sqlite:///{tmp_path / 'mlflow.db'}",
                        track=False)
    return root


def export_kept(root, monkeypatch) -> str:
    monkeypatch.chdir(root)
    return export.export_at("single_force", root, recorded=export.trained_md5s("single_force",
                                                                             root), keep=True)


def test_the_pipeline_recorded_what_each_stack_was_exported_from(workspace):
    for scene in ("single_force", "two_force"):
        assert (workspace / EXPORT_CACHE / f"{scene}.json").exists()


def test_a_stack_from_the_same_inputs_is_kept_and_any_change_exports_it_again(
        workspace, monkeypatch):
    stack = workspace / stack_path("single_force")
    before = md5_file(stack)
    assert "stack kept" in export_kept(workspace, monkeypatch)
    # the code: another md5 of the export's modules
    monkeypatch.setattr(export.code, "code_md5", lambda script: "0" * 32)
    assert "stack →" in export_kept(workspace, monkeypatch)
    assert md5_file(stack) == before, "the same models give the same file"
    assert "stack kept" in export_kept(workspace, monkeypatch)
    # the file itself, edited (DVC would rerun the stage): exported again, not kept
    stack.write_bytes(stack.read_bytes() + b"\0")
    assert "stack →" in export_kept(workspace, monkeypatch)
    assert md5_file(stack) == before


def test_a_forced_publish_keeps_a_report_it_would_write_again(small_pipeline, tmp_path):
    """The publish stage's report is kept when written from the same predictions, scores,
    params and code (eskin/steps/report.py): logged again, as to another store, the page
    and dvc.lock do not move; an edit of the report's code writes it again."""
    from tests.conftest import run_checked

    root = tmp_path / "project"
    env = copy_small_pipeline(small_pipeline, root, f"sqlite:///{tmp_path / 'other.db'}",
                              track=False)
    forced = ["dvc", "repro", "--force", "--single-item", "publish"]
    assert "report: kept" in run_checked(forced, root, env).stdout
    assert run_checked(["git", "status", "--porcelain"], root, env).stdout == ""
    edited = root / "eskin" / "reporting" / "presentation.py"
    edited.write_text(edited.read_text() + "# one more line\n")
    assert "report: kept" not in run_checked(forced, root, env).stdout
