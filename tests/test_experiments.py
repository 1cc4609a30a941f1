"""`eskin compare` and `eskin audit` tables, from frames shaped like mlflow.search_runs."""

import io

import numpy as np
import pandas as pd
import pytest

from eskin.tracking import compare

T0 = pd.Timestamp("2026-11-23 10:00", tz="UTC")


def run(run_id, minute, seconds, **fields):
    start = T0 + pd.Timedelta(minutes=minute)
    row = {"run_id": run_id, "start_time": start, "end_time": start + pd.Timedelta(seconds=seconds)}
    row.update({k.replace("__", "."): v for k, v in fields.items()})
    return row


def pipeline(run_id, minute, name, force_model, seed=1, commit="c0ffee00aa"):
    return run(run_id, minute, 0, **{"tags.eskin.kind": "pipeline", "tags.mlflow.runName": name,
                                     "tags.eskin.git_commit": commit,
                                     "params.train.force.model": force_model,
                                     "params.sim.seed": str(seed), "params.cv.folds": "10"})


def task(run_id, minute, seconds, parent, scene, name, digest, **metrics):
    return run(run_id, minute, seconds, **{
        "tags.eskin.kind": "task", "tags.mlflow.parentRunId": parent, "tags.eskin.scene": scene,
        "tags.eskin.task": name, "tags.eskin.dataset_digest": digest,
        "tags.eskin.git_commit": "c0ffee00aa", "tags.eskin.model": "m",
        "tags.eskin.dataset_rows": "2020", "tags.eskin.dataset_source": "simulated (seed 1)",
        **{f"metrics.{k.replace('__', '.')}": v for k, v in metrics.items()}})


@pytest.fixture
def runs():
    rows = [
        pipeline("P1", 0, "repro 1a2b", "hist_gradient_boosting"),
        task("a", 1, 2.0, "P1", "single_force", "force", "d1", conditions__force__r2=0.60,
             conditions__force__r2_std=0.1, stratified__force__r2=0.95, wall_seconds=12.0),
        task("b", 2, 1.0, "P1", "single_force", "detect", "d1", conditions__contact__accuracy=0.99),
        pipeline("P2", 5, "force-rf", "random_forest"),
        task("c", 6, 30.0, "P2", "single_force", "force", "d1", conditions__force__r2=0.10),
        task("d", 7, 20.0, "P2", "single_force", "force", "d1", conditions__force__r2=0.58),
        pipeline("P3", 9, "seed7", "hist_gradient_boosting", seed=7),
        task("e", 10, 3.0, "P3", "single_force", "force", "d2", conditions__force__r2=0.55),
        task("f", 11, 0.5, "P3", "two_force", "pairs", "t1", conditions__pair_accuracy=0.76),
    ]
    return pd.DataFrame(rows)


def test_compare_keeps_the_latest_run_per_task_and_shows_only_differing_params(runs):
    table = compare.variant_table(runs, scheme="conditions")
    assert list(table["variant"]) == ["repro 1a2b", "force-rf", "seed7"]
    assert "cv.folds" not in table  # the same everywhere
    assert list(table["train.force.model"]) == [
        "hist_gradient_boosting", "random_forest", "hist_gradient_boosting"]
    assert list(table["sim.seed"]) == ["1", "1", "7"]
    assert table["force R²"].tolist() == [0.60, 0.58, 0.55]  # force-rf: its newer run
    assert np.isnan(table["contact acc"].iloc[1]) and table["contact acc"].iloc[0] == 0.99
    assert table["pairs acc"].iloc[2] == 0.76
    # The step's own clock where it logged one, else the run's duration.
    assert table["run time s"].tolist() == [13.0, 20.0, 3.5]
    assert "force R²_std" not in table and "force_std R²" not in table
    assert table["datasets"].iloc[2] == "single_force:d2 two_force:t1"
    # Score columns follow the pipeline's order: single force before two forces.
    columns = list(table.columns)
    assert columns.index("force R²") < columns.index("contact acc") < columns.index("pairs acc")


def test_compare_shows_a_param_one_variant_has_and_the_other_lacks(monkeypatch):
    """`-S train.force.model=hist_gradient_boosting` against the per-kind default: each
    form's keys are in one pipeline run's params only; every one of them differs."""
    per_kind = pipeline("P1", 0, "default", None)
    del per_kind["params.train.force.model"]
    per_kind.update({"params.train.force.model.single_force": "physics_profile",
                     "params.train.force.model.two_force": "active_terminals"})
    every_kind = pipeline("P2", 5, "hgb", "hist_gradient_boosting")
    runs = pd.DataFrame([
        per_kind, task("a", 1, 2.0, "P1", "single_force", "force", "d1", conditions__force__r2=0.6),
        every_kind, task("b", 6, 2.0, "P2", "single_force", "force", "d1",
                         conditions__force__r2=0.5)])
    table = compare.variant_table(runs).set_index("variant")
    model = ["train.force.model", "train.force.model.single_force",
             "train.force.model.two_force"]
    assert [c for c in table.columns if c.startswith("train.")] == model
    assert table.loc["hgb", model].tolist()[0] == "hist_gradient_boosting"
    assert table.loc["hgb", model[1:]].isna().all()
    assert table.loc["default", model].tolist()[1:] == ["physics_profile", "active_terminals"]
    assert pd.isna(table.loc["default", "train.force.model"])
    assert "sim.seed" not in table  # the same in both
    monkeypatch.setenv("COLUMNS", "250")
    shown = compare.render(table.reset_index(), "table")
    hgb = next(line for line in shown.splitlines() if line.startswith("hgb"))
    assert "hist_gradient_boosting" in hgb and hgb.count("—") == 2, shown


def test_compare_picks_variants_by_name_or_recency(runs):
    picked = compare.variant_table(runs, variants=["force-rf", "seed7"])
    assert list(picked["variant"]) == ["force-rf", "seed7"]
    assert "train.force.model" in picked and "pairs acc" in picked
    newest = compare.variant_table(runs, last=1)
    assert list(newest["variant"]) == ["seed7"]
    assert "sim.seed" not in newest and "force R²" in newest  # nothing differs in one row
    with pytest.raises(compare.NoRunsError, match="no variant named nope"):
        compare.variant_table(runs, variants=["nope"])


def test_compare_under_the_other_scheme(runs):
    table = compare.variant_table(runs, scheme="stratified")
    assert table["force R²"].iloc[0] == 0.95
    assert table["force R²"].iloc[1:].isna().all()


def test_audit_groups_runs_by_dataset_version_and_marks_the_workspace(runs):
    versions = compare.dataset_versions(runs, workspace={"single_force": "d2"},
                                            committed={"d1": "2026-11-22 abc1234"})
    by_digest = versions.set_index("dataset md5")
    assert by_digest.loc["d1", "runs"] == 4
    assert by_digest.loc["d1", "variants"] == "force-rf, repro 1a2b"
    assert by_digest.loc["d1", "committed"] == "2026-11-22 abc1234"
    assert by_digest.loc["d1", "first used"] == T0 + pd.Timedelta(minutes=1)
    assert by_digest.loc["d2", "workspace"] == "yes" and by_digest.loc["d1", "workspace"] == ""
    assert by_digest.loc["t1", "scene"] == "two_force"
    assert by_digest.loc["d2", "source"] == "simulated (seed 1)"
    used = compare.runs_of_dataset(runs, "d1")
    assert list(used["run"]) == ["a", "b", "c", "d"]
    assert list(used["variant"]) == ["repro 1a2b"] * 2 + ["force-rf"] * 2


@pytest.mark.parametrize("fmt", ["table", "markdown", "csv"])
def test_tables_render_in_every_format(runs, fmt, monkeypatch):
    monkeypatch.setenv("COLUMNS", "250")  # a row per variant (narrower: tested below)
    text = compare.render(compare.variant_table(runs), fmt)
    # to the second in a file, to the minute on a terminal
    assert "force-rf" in text and ("2026-11-23 10:07" + ("" if fmt == "table" else ":20")) in text
    if fmt == "csv":
        back = pd.read_csv(io.StringIO(text))
        assert back["force R²"].tolist() == [0.60, 0.58, 0.55]
    if fmt == "markdown":
        assert text.splitlines()[1].startswith("|:")
    if fmt != "csv":
        assert "nan" not in text and "—" in text


def test_the_table_fits_the_terminal_and_keeps_every_column(runs, monkeypatch):
    table = compare.variant_table(runs)
    monkeypatch.setenv("COLUMNS", "80")
    text = compare.render(table, "table")
    assert max(len(line) for line in text.splitlines()) <= 80, text
    for name in ("variant", "commit", "force-rf"):
        assert name in text  # wrapped to fit, not cut off
    assert "0.6" in text


@pytest.mark.starts
def test_an_empty_store_is_a_clear_error():
    with pytest.raises(compare.NoRunsError, match="dvc repro"):
        compare.variant_table(pd.DataFrame())
    with pytest.raises(ValueError, match="format"):
        compare.render(pd.DataFrame({"a": [1]}), "html")


def test_params_come_back_from_their_mlflow_strings():
    assert compare.parse_param("['stratified', 'conditions']") == ["stratified", "conditions"]
    assert compare.parse_param("10") == 10
    assert compare.parse_param("random_forest") == "random_forest"


@pytest.mark.parametrize("fmt", ["table", "markdown"])
def test_a_column_of_scores_has_one_number_format(fmt, monkeypatch):
    """0.94 beside 0.8585 read as two precisions: every number of a column has the digits
    its largest needs for 4 significant ones."""
    monkeypatch.setenv("COLUMNS", "250")
    rows = [pipeline("P1", 0, "default", "physics_profile"),
            task("a", 1, 171.6, "P1", "single_force", "force", "d1", conditions__force__r2=0.94,
                 conditions__force1__r2=-12.5),
            pipeline("P2", 5, "force-rf", "random_forest"),
            task("b", 6, 9.0, "P2", "single_force", "force", "d1",
                 conditions__force__r2=0.858512, conditions__force1__r2=0.5)]
    text = compare.render(compare.variant_table(pd.DataFrame(rows)), fmt)
    cells = {line[0]: line for line in (row.replace("|", " ").split()
                                        for row in text.splitlines()) if line}
    assert {"0.9400", "-12.50", "171.6"} <= set(cells["default"]), text
    assert {"0.8585", "0.50", "9.0"} <= set(cells["force-rf"]), text


def test_the_audit_fits_120_columns_without_breaking_a_cell(monkeypatch, capsys):
    """`eskin audit` at 120 columns, on a store whose runs have the pipeline's longest
    names (two_force/localise, hist_gradient_boosting): every cell on one line, whole."""
    from eskin import cli

    parent = "f" * 32
    rows = [run(parent, 0, 0, **{"tags.eskin.kind": "pipeline",
                                 "tags.mlflow.runName": "repro-5fe26a26"})]
    names = [("single_force", "stretch", "paper"), ("single_force", "force", "physics_profile"),
             ("single_force", "detect", "hist_gradient_boosting"),
             ("single_force", "localise", "logistic"), ("two_force", "force", "active_terminals"),
             ("two_force", "localise", "active_terminals")]
    for k, (scene, name, model) in enumerate(names):
        rows.append(run(f"{k:032x}", k + 1, 37, **{
            "tags.eskin.kind": "task", "tags.mlflow.parentRunId": parent,
            "tags.eskin.scene": scene, "tags.eskin.task": name, "tags.eskin.model": model,
            "tags.eskin.dataset_digest": ("a60afd9562901fe9a35d926161ab5790" if k < 4
                                          else "b60899891a86e54d9bd4781c10d960f5"),
            "tags.eskin.git_commit": "cf46b9c8aa", "tags.eskin.dataset_rows": "24240",
            "tags.eskin.dataset_source": "simulated (seed 20230529)"}))
    monkeypatch.setattr(compare, "load_runs", lambda: pd.DataFrame(rows))
    monkeypatch.setattr(compare, "workspace_digests", lambda root, scenes: {})
    monkeypatch.setattr(compare, "commit_dates", lambda root, digests: {
        d: "2026-11-26 160d4d1" for d in digests})
    monkeypatch.setenv("COLUMNS", "120")
    assert cli.main(["audit"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(map(len, lines)) <= 120, "\n".join(lines)
    cells = {f"{k:032x}" for k in range(len(names))} | {f"{s}/{t}" for s, t, _ in names} | \
        {m for _, _, m in names} | {"simulated (seed 20230529)", "2026-11-26 160d4d1",
                                    "repro-5fe26a26"} | \
        {f"2026-11-23 10:{k:02d}" for k in range(1, len(names) + 1)}
    broken = {cell for cell in cells if not any(cell in line for line in lines)}
    assert not broken, "\n".join(lines)
