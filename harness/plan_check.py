"""make bench's check of the planner by recording (issue 58): does a lab that records what
`eskin plan` prints reach its target?

For each target of ``learning_curve.checks`` on a simulated scene, the planner's answer is
read from the scene's learning curves (reports/learning_curve/<scene>.json). The plan is
then recorded on the same simulated skin, by acquisition's own path, on repetitions the
curves never used: the scene's ``repeats`` grown past the curves' ``max(repeats) + 1``, so
the repetitions trained on here and the ``check_recordings`` scored on are fresh. The
pipeline's model is trained on ``r`` of them (the plan's count), once, and scored on each
new recording (every condition once) on its own. A plan is kept when at least
``reliability`` of the recordings reach the target (9 of 10 by default); the stage fails
when one is not.

A target the planner gives no count for (beyond the bound or the floor, reachable only on
average, or a count past the measured points: no promise) is written as such and not
recorded: there is nothing it promised.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.config.params import Params
from eskin.data.schema import dataset_kind, dataset_skin, read_dataset
from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.folds import fold_splitter
from eskin.evaluation.tasks import Task, get_task
from eskin.learning.estimators import build_model
from eskin.learning.features import featurize, fit_featurizer
from eskin.tracking import planning
from harness.benchmark import bound_scores
from harness.learning_curve import _model, record_repetitions, repetition


def recording_scores(task: Task, train: pd.DataFrame, recordings: Sequence[pd.DataFrame],
                     estimator, method: str, kind: str, skin) -> list[float]:
    """Fit on ``train`` once; the task's headline score on each of ``recordings`` alone."""
    featurizer = fit_featurizer(method, train, kind, skin)
    held = pd.concat(list(recordings), ignore_index=True)
    which = np.repeat(np.arange(len(recordings)), [len(r) for r in recordings])
    both = pd.concat([featurize(train, featurizer, skin), featurize(held, featurizer, skin)],
                     ignore_index=True)
    folds = np.r_[np.full(len(train), -1), np.zeros(len(held), dtype=np.int64)]
    result = cross_validate(task, both, folds, estimator, "trials", skin)
    task_rows = task.rows(both)
    label = np.r_[np.full(len(train), -1), which][task_rows]
    data = both[task_rows].reset_index(drop=True)
    scores = []
    for k in range(len(recordings)):
        keep = label == k
        predicted = pd.DataFrame({
            name: result.predictions[f"{name}_pred"].to_numpy()[keep].astype(float)
            for name in task.targets})
        scores.append(task.headline(bound_scores(
            task, data[keep].reset_index(drop=True), predicted,
            fold_splitter(np.zeros(int(keep.sum()), dtype=np.int64)))))
    return scores


def check_plans(scene: str, params: Params, curves: Mapping[str, Any],
                targets: Sequence[Any], settings: Any, *, recordings: int,
                scratch: Path | None = None,
                log: Callable[[str], None] = print) -> dict[str, Any]:
    """Each target's plan, recorded and scored on ``recordings`` new recordings (the
    document the stage writes)."""
    need = math.ceil(float(settings.reliability) * recordings - 1e-9)
    document: dict[str, Any] = {"scene": scene, "recordings": recordings, "need": need,
                                "reliability": float(settings.reliability), "checks": []}
    answers = [(t, planning.plan(curves, t.target, t.value, settings)) for t in targets]
    for target, answer in answers:
        if answer["verdict"] != "reliable":
            log(f"{scene}: {target.target} ≥ {target.value:g}: {answer['verdict']} — "
                "no promise to record")
    promised = [(t, a) for t, a in answers if a["verdict"] == "reliable"]
    # Repetitions the curves used are 0 … max(repeats); the check's are fresh past them.
    fresh = max(curves["repeats"]) + 1
    most = max((a["repeats"] for _, a in promised), default=0)
    frame = rep = None
    if promised:
        scene_settings = params.scenes[scene]
        if scene_settings.source != "simulated":
            raise ValueError(f"learning_curve.checks: scene {scene} is "
                             f"{scene_settings.source}, and a plan check records the plan "
                             f"anew: list simulated scenes only")
        total = fresh + most + recordings
        with tempfile.TemporaryDirectory(prefix="eskin-plan-check-", dir=scratch) as work:
            path = record_repetitions(scene, params, total - scene_settings.repeats,
                                      Path(work), log)
            frame, skin, the_kind = read_dataset(path), dataset_skin(path), dataset_kind(path)
        kind = the_kind.name
        rep = repetition(frame, kind)
        tested = [frame[rep == fresh + most + k].reset_index(drop=True)
                  for k in range(recordings)]
        document["trained_on"] = f"repetitions {fresh} … {fresh + most - 1} (the first r)"
        document["scored_on"] = f"repetitions {fresh + most} … {total - 1}, each alone"
    for target, answer in answers:
        check: dict[str, Any] = {"target": target.target, "value": target.value,
                                 "verdict": answer["verdict"], "why": answer["why"],
                                 "mean_repeats": answer.get("mean_repeats")}
        if answer["verdict"] == "reliable":
            r = answer["repeats"]
            task = get_task(kind, target.target.rsplit("_", 1)[0])
            name, hyper = _model(task, params, params.train.configuration, the_kind, skin)
            train = frame[(rep >= fresh) & (rep < fresh + r)].reset_index(drop=True)
            scores = recording_scores(task, train, tested, build_model(task.role, name, hyper,
                                                                       skin),
                                      params.featurize.method, kind, skin)
            reached = int(sum(score >= target.value for score in scores))
            check.update({"repeats": r, "model": name, "scores": scores, "reached": reached,
                          "mean": float(np.mean(scores)), "kept": reached >= need})
            log(f"{scene}: {target.target} ≥ {target.value:g} → {r} trial(s) per condition; "
                f"{reached} of {recordings} new recordings reach it "
                f"({min(scores):.4f}–{max(scores):.4f}, mean {np.mean(scores):.4f}): "
                + ("kept" if check["kept"] else "MISSED"))
        document["checks"].append(check)
    return document


def missed(document: Mapping[str, Any]) -> list[str]:
    """The targets whose plan fewer than ``need`` recordings reached, each as a phrase."""
    return [f"{c['target']} ≥ {c['value']:g} at {c['repeats']} trial(s) per condition: "
            f"{c['reached']} of {document['recordings']} new recordings reach it, "
            f"{document['need']} needed" for c in document["checks"] if c.get("kept") is False]


def render(document: Mapping[str, Any]) -> str:
    """The checks as markdown."""
    lines = [f"# The planner's answers, recorded: {document['scene']}", ""]
    if "trained_on" in document:
        lines += [f"Trained on fresh {document['trained_on']}; scored on "
                  f"{document['recordings']} new recordings, {document['scored_on']}. A plan "
                  f"is kept when {document['need']} of {document['recordings']} reach the "
                  f"target.", ""]
    lines += ["| target | plan | on average | new recordings reaching it | scores | mean | |",
              "|---|---|---|---|---|---|---|"]
    for c in document["checks"]:
        if "scores" not in c:
            lines.append(f"| {c['target']} ≥ {c['value']:g} | — | {c['mean_repeats'] or '—'} "
                         f"| — | — | — | {c['verdict']}: not recorded |")
            continue
        lines.append(f"| {c['target']} ≥ {c['value']:g} | {c['repeats']} | "
                     f"{c['mean_repeats'] or '—'} | {c['reached']} of "
                     f"{document['recordings']} | {min(c['scores']):.4f}–"
                     f"{max(c['scores']):.4f} | {c['mean']:.4f} | "
                     f"{'kept' if c['kept'] else '**missed**'} |")
    return "\n".join(lines) + "\n"
