"""The project's vocabulary and where each artifact lives, defined once.

Scenes are declared in params.yaml (``scenes:``); their kinds are :mod:`eskin.kinds`,
the skin :mod:`eskin.skin`; tasks and CV schemes are named here (what a task means for
each kind is :mod:`eskin.evaluation.tasks`); every path a stage writes or
reads is a function of the scene (and task) below, so dvc.yaml, the stages,
the report, compare, audit and reproduce agree by construction (a test checks
dvc.yaml against these).
"""

from __future__ import annotations

from pathlib import Path

# Every kind has the same tasks (eskin/evaluation/tasks.py says what each means for each kind), so
# the stage graph is scenes × tasks; a task a scene's data cannot support is skipped.
TASK_NAMES: tuple[str, ...] = ("stretch", "force", "detect", "localise")
# CV schemes, by what a test fold holds out (eskin.evaluation.folds): samples (the paper's),
# conditions, or trials of conditions training has seen (a scene recorded twice or more).
SCHEMES: tuple[str, ...] = ("stratified", "conditions", "trials")
# What each scheme holds out, as the page, the figures and the results say it.
SCHEME_NOTES = {"stratified": "the paper's: stratified on the node",
                "conditions": "whole conditions held out",
                "trials": "new trials of conditions seen in training"}
# Where a scene's readings come from: the Python board, the firmware under simavr, a
# board on a port, or a file another lab wrote.
SOURCES: tuple[str, ...] = ("simulated", "emulated", "serial", "import")
# The report scores a two-force scene's localise and force predictions together, as sets.
PAIRS = "pairs"
SCORED_TASKS: tuple[str, ...] = (*TASK_NAMES, PAIRS)

# The one score a task is summarised by (MLflow compare, stage output, audit), by scorer.
HEADLINE_METRIC = {"regression": "r2", "detection": "accuracy", "localisation": "accuracy",
                   "counting": "accuracy"}
# The scheme DVC's metrics file holds (the one `make bench` chooses models by); every
# scheme's scores, with spreads and confusion counts, are in the scores files.
HEADLINE_SCHEME = "conditions"
# A two-force scene's contacts scored as sets: the pairs' headline scores.
PAIRS_HEADLINE = ("pair_accuracy", "ghost_share", "force_r2")

RAW_DIR = Path("data/raw")
PROCESSED_DIR = Path("data/processed")
FEATURES_DIR = Path("data/features")
FOLDS_DIR = Path("data/folds")
MODELS_DIR = Path("models")
# Every scene's and task's headline scores, `<scene>.<task>.<target>.<score>` (the report
# stage writes it; the publish stage logs it as the pipeline run's scores).
METRICS = Path("reports/metrics.json")
# DVC's metrics: a file a scene, `<scene>.json`, one headline number a question (a target
# of one contact; two contacts' as a set), so `dvc metrics show` is a row a scene that
# fits 120 columns and `dvc exp show` a short column a score.
SCENE_METRICS_DIR = Path("reports/metrics")
# What each training run did and when (not a DVC output: its times would change dvc.lock);
# the publish stage logs it to MLflow.
RUNS_DIR = Path("reports/runs")
# The publish stage's output: what it logged to MLflow, by content only (no run ids, no
# times), so its hash in dvc.lock is the same on every machine. Ignored by git: a fresh
# clone lacks it, so DVC runs the publish stage there once, and never twice.
TRACKED = RUNS_DIR / "tracked.json"
SCORES_DIR = Path("reports/scores")
PREDICTIONS_DIR = Path("reports/predictions")
# A two-contact scene's contacts scored as sets, a file a scene (the report writes them:
# scoring them is a view of the predictions, not a stage of its own)
PAIRS_DIR = Path("reports/pairs")
LINEAGE_DIR = Path("reports/lineage")
# Which model and hyperparameters each scene's task trains (the settings stage resolves
# params.yaml's train section once, so that each training stage depends on its own).
SETTINGS_DIR = Path("reports/settings")
FIGURES_DIR = Path("reports/figures")
PLOTS_DIR = Path("reports/plots")
# Figures already drawn, by a key of their data and drawing code (the publish stage's
# cache: not a DVC output, ignored by git; removing it costs only the drawing)
FIGURE_CACHE = Path(".cache/figures")
# What each scene's stack was exported from (the train stage keeps a stack made from the
# same models, dataset and code): not a DVC output, ignored by git
EXPORT_CACHE = Path(".cache/export")
# What the report was written from (the publish stage keeps a report written from the
# same predictions, scores, params and code): not a DVC output, ignored by git
REPORT_CACHE = Path(".cache/report.json")
BENCH_DIR = Path("reports/benchmark")
BOUND_DIR = Path("bench/bound")  # in bench/'s own DVC project, so in DVC's cache (not git)
LEARNING_CURVE_DIR = Path("reports/learning_curve")
PLAN_CHECK_DIR = Path("reports/plan_check")
SOAK_DIR = Path("reports/soak")
STRESS_DIR = Path("reports/stress")
EXPORT_DIR = Path("reports/export")
PAGE = Path("reports/index.html")
README = Path("README.md")


def raw_dir(scene: str) -> Path:
    return RAW_DIR / scene


def processed_path(scene: str) -> Path:
    return PROCESSED_DIR / f"{scene}.parquet"


def features_path(scene: str) -> Path:
    return FEATURES_DIR / f"{scene}.parquet"


def folds_path(scene: str) -> Path:
    """Every CV scheme's fold number of each of a scene's rows, drawn once for all tasks."""
    return FOLDS_DIR / f"{scene}.parquet"


def featurizer_path(scene: str) -> Path:
    return MODELS_DIR / scene / "featurizer.joblib"


def run_record_path(scene: str, task: str) -> Path:
    """When a task's training ran, for how long, and its scores per fold (the train stage
    writes it, the publish stage reads it; ignored by git and DVC)."""
    return RUNS_DIR / scene / f"{task}.json"


def scores_path(scene: str, task: str) -> Path:
    """A task's whole evaluation: every scheme, metric and spread, the confusion counts,
    and what was trained on what. (``pairs``: the scene's contacts scored as sets.)"""
    if task == PAIRS:
        return PAIRS_DIR / f"{scene}.json"
    return SCORES_DIR / scene / f"{task}.json"


def predictions_path(scene: str, task: str) -> Path:
    return PREDICTIONS_DIR / scene / f"{task}.parquet"


def model_path(scene: str, task: str) -> Path:
    return MODELS_DIR / scene / f"{task}.joblib"


def stack_path(scene: str) -> Path:
    """The scene's whole stack as one ONNX file (eskin/deploy/export.py)."""
    return MODELS_DIR / scene / "stack.onnx"


def export_report_path(scene: str) -> Path:
    """How the ONNX stack agrees with the scikit-learn stack it was made from."""
    return EXPORT_DIR / f"{scene}.json"


def bench_dir(scene: str) -> Path:
    """`make bench`'s reports for one scene: a JSON and a plot per task, the summary."""
    return BENCH_DIR / scene


def bayes_bound_path(scene: str) -> Path:
    """The simulator's Bayes bound for every sample of one scene (`make bench`)."""
    return BOUND_DIR / f"{scene}.parquet"


def learning_curve_path(scene: str) -> Path:
    """`make bench`'s learning curves of one scene (JSON; the markdown beside it), which
    `eskin plan` reads."""
    return LEARNING_CURVE_DIR / f"{scene}.json"


def plan_check_path(scene: str) -> Path:
    """`make bench`'s check of the planner's answers by recording (JSON; the markdown
    beside it)."""
    return PLAN_CHECK_DIR / f"{scene}.json"


def settings_path(scene: str, task: str) -> Path:
    """The model and hyperparameters the scene's task trains (eskin/learning/choice.py)."""
    return SETTINGS_DIR / scene / f"{task}.json"


def task_outputs(scene: str, task: str) -> dict[str, Path]:
    """Where one task reads its folds and writes its outputs (the paths dvc.yaml declares),
    and its run record."""
    return {"folds_path": folds_path(scene),
            "scores_path": scores_path(scene, task),
            "predictions_path": predictions_path(scene, task),
            "model_path": model_path(scene, task),
            "lineage_path": LINEAGE_DIR / scene / f"{task}.json",
            "record_path": run_record_path(scene, task)}
