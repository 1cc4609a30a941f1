"""Run time against error: model variants side by side on the same folds.

For each task, every variant in ``bench.tasks.<task>`` is fitted and scored
on the same folds of the pipeline's split (``cv``), timed (fit + predict,
seconds per fold) and measured for peak memory (the process's peak resident
set, reset before each variant through ``/proc/self/clear_refs``). Variants
go through joblib (``bench.n_jobs``, ``bench.backend``), one at a time in this
process by default, so their times and memory are comparable; the ratios the
issue asks for are computed from these numbers, in one run. More jobs, or a
cluster backend, trade that comparability for throughput.

The Bayes bound (:mod:`harness.oracle`) is scored on the same folds, so each
task's table says how far each variant is from the best possible and what
share of the paper configuration's gap it closes.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.base import BaseEstimator, clone

from eskin.evaluation import metrics
from eskin.evaluation.crossval import cross_validate, parallel_backend
from eskin.evaluation.folds import FoldSplit, assign_folds, fold_splitter
from eskin.evaluation.tasks import Task, get_task
from eskin.kinds import get_kind
from eskin.learning.estimators import build_model
from eskin.skin import AnySkin

if TYPE_CHECKING:
    from eskin.config.acquisition import Sim
    from eskin.config.cv import CV
    from eskin.config.scenes import Scene
    from harness.params import Bench


def peak_memory_mb() -> float | None:
    """Peak resident set of this process since the last reset (Linux), in MiB."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def reset_peak_memory() -> None:
    try:
        with open("/proc/self/clear_refs", "w") as clear:
            clear.write("5")
    except OSError:
        pass


def variant_settings(spec: Any) -> tuple[str, dict[str, Any], bool]:
    """(model name, hyperparameters, share hyperparameters across folds) of a ``bench.tasks``
    entry (an :class:`eskin.config.Variant`, or a mapping as written)."""
    hyper = variant_spec(spec)
    model = hyper.pop("model")
    return model, hyper, bool(hyper.pop("share_hyperparameters", False))


def variant_spec(spec: Any) -> dict[str, Any]:
    """A ``bench.tasks`` entry as written: ``model`` and its hyperparameters."""
    return spec.model_dump() if hasattr(spec, "model_dump") else dict(spec)


def variant_estimator(role: str, spec: Any, skin: AnySkin) -> tuple[BaseEstimator, bool]:
    """(estimator, share hyperparameters across folds) from a ``bench.tasks`` entry, for
    ``skin``."""
    model, hyper, share = variant_settings(spec)
    return build_model(role, model, hyper, skin), share


def run_variant(task: Task, data: pd.DataFrame, splitter: FoldSplit,
                estimator: BaseEstimator, share: bool, *, skin: AnySkin) -> dict[str, Any]:
    """Score one variant on the splitter's folds (:func:`eskin.evaluation.folds.fold_splitter`
    over ``data``'s rows, the task's, readings of ``skin``): per-target mean scores, seconds,
    peak MiB. The folds run through the pipeline's fold runner
    (:func:`eskin.evaluation.crossval.cross_validate`), one after another in this process,
    so a variant's times and memory are its own; with ``share``, each target's
    hyperparameters are fitted on the first training fold (timed) and reused by the others,
    which only condition on their data."""
    reset_peak_memory()
    result = cross_validate(task, data, splitter.test_fold, estimator, "bench", skin,
                            n_folds=splitter.n_folds, share_hyperparameters=share)
    n = splitter.get_n_splits()
    fit_s, predict_s = result.fit_seconds, result.predict_seconds
    return {"scores": {name: result.summary[name] for name in task.targets},
            "fit_seconds_per_fold": fit_s / n, "predict_seconds_per_fold": predict_s / n,
            "seconds_per_fold": (fit_s + predict_s) / n, "peak_memory_mb": peak_memory_mb()}


def scaling(task: Task, data: pd.DataFrame, estimator: BaseEstimator, fractions: list[float],
            seed: int, skin: AnySkin) -> dict[str, Any]:
    """Fit time at each fraction of the data (readings of ``skin``), resampled with
    replacement (seeded)."""
    X = data[skin.channels]
    y = next(iter(task.target_values(data).values()))
    rng = np.random.default_rng(seed)
    times = {}
    for fraction in fractions:
        rows = rng.choice(len(data), size=int(round(fraction * len(data))), replace=True)
        start = time.perf_counter()
        clone(estimator).fit(X.iloc[rows], y[rows])
        times[str(fraction)] = time.perf_counter() - start
    ordered = [times[str(f)] for f in sorted(fractions)]
    return {"rows_at_1": len(data), "fit_seconds": times,
            "growth_per_doubling": [b / a for a, b in zip(ordered, ordered[1:], strict=False)]}


def bound_scores(task: Task, data: pd.DataFrame, oracle: pd.DataFrame,
                 splitter: FoldSplit) -> dict[str, dict[str, float]]:
    """The oracle's scores on the same folds (``oracle`` aligned with ``data``'s rows)."""
    score: Callable = metrics.SCORERS[task.scorer]
    out = {}
    for name, y in task.target_values(data).items():
        folds = []
        for _, test in splitter.split(data):
            extra = oracle["contact_probability"].to_numpy()[test] if name == "contact" else None
            folds.append(score(y[test], oracle[name].to_numpy()[test], extra))
        out[name] = metrics.summarise(folds)
    return out


def pareto_front(points: Mapping[str, tuple[float, float]]) -> list[str]:
    """Names not dominated in (seconds, error): nothing is both faster and more accurate."""
    front = []
    for name, (seconds, error) in points.items():
        if not any((s <= seconds and e <= error) and (s < seconds or e < error)
                   for other, (s, e) in points.items() if other != name):
            front.append(name)
    return sorted(front, key=lambda n: points[n][0])


def headline_error(task: Task, scores: Mapping[str, Mapping[str, float]]) -> float:
    """1 − the task's headline score (mean over its targets): lower is better."""
    return 1.0 - task.headline(scores)


def fold_spread(task: Task, scores: Mapping[str, Mapping[str, float]]) -> float:
    """The standard deviation over folds of the task's headline score (mean over targets)."""
    return float(np.mean([scores[target][f"{task.headline_metric}_std"]
                          for target in task.targets]))


def doc_task(doc: Mapping[str, Any]) -> Task:
    """The task a bench document scored (its scene's kind and the task's name)."""
    return get_task(doc["kind"], doc["task"])


def benchmark_task(task: Task, frame: pd.DataFrame, kind: str, variants: Mapping[str, Mapping],
                   *, skin: AnySkin, schemes: list[str], folds: int, seed: int,
                   evaluate_folds: int,
                   oracle: pd.DataFrame | None, n_jobs: int = 1,
                   log=print) -> dict[str, Any]:
    """Every variant of one task under each scheme, the bound, the front and the gaps."""
    rows = task.rows(frame)
    data = frame[rows].reset_index(drop=True)
    oracle_rows = oracle[rows].reset_index(drop=True) if oracle is not None else None
    doc: dict[str, Any] = {"task": task.name, "kind": kind, "rows": int(rows.sum()),
                           "evaluate_folds": evaluate_folds, "folds": folds, "schemes": {}}
    for scheme in schemes:
        # The first evaluate_folds folds of the scene's split, on this task's rows
        splitter = fold_splitter(assign_folds(frame, kind, scheme, folds, seed, skin=skin)[rows],
                                 evaluate_folds)
        log(f"  {task.name} {scheme}: {len(variants)} variants, "
            f"{splitter.get_n_splits()} folds …")
        runs = Parallel(n_jobs=n_jobs, return_as="generator")(
            delayed(run_variant)(task, data, splitter, *variant_estimator(task.role, spec, skin),
                                 skin=skin)
            for spec in variants.values())
        results = {}
        for (name, spec), outcome in zip(variants.items(), runs, strict=True):
            results[name] = {"spec": variant_spec(spec), **outcome}
            log(f"  {task.name} {scheme}: {name} {outcome['seconds_per_fold']:.2f} s/fold, "
                f"error {headline_error(task, outcome['scores']):.4f}")
        points = {n: (r["seconds_per_fold"], headline_error(task, r["scores"]))
                  for n, r in results.items()}
        entry: dict[str, Any] = {"variants": results, "pareto_front": pareto_front(points)}
        if oracle_rows is not None:
            bound = bound_scores(task, data, oracle_rows, splitter)
            bound_error = headline_error(task, bound)
            paper_error = points["paper"][1] if "paper" in points else float("nan")
            gap = paper_error - bound_error
            entry["bayes_bound"] = {"scores": bound, "error": bound_error}
            entry["gap_closed"] = {n: ((paper_error - e) / gap if gap > 0 else float("nan"))
                                   for n, (_, e) in points.items()}
        doc["schemes"][scheme] = entry
    return doc


# ---------------------------------------------------------------- pipeline steps

CONVERGENCE_ROWS = 200  # samples on which the one-contact bound doubles its grid (two: all)
MAX_DOUBLINGS = 2  # grids doubled, at most, until the one-contact bound converges


def bayes_bound(scene: str, settings: Scene, dataset_path: Path, out_path: Path, *, sim: Sim,
                seed: int, log=print) -> str:
    """The oracle's answers for every sample of a scene's dataset → Parquet.

    Only the simulator knows the answers (:mod:`harness.oracle` for one contact,
    :mod:`harness.pair_oracle` for two): for a scene it did not make, the file holds the
    sample keys alone and says why (``attrs["unavailable"]``), so the bench tables show
    "no bound" and the reason instead of stopping. ``settings`` is the scene's params
    section, ``sim`` the simulator's, ``seed`` ``bench.seed`` (the Sobol points of two
    contacts)."""
    from eskin.config.scenes import scene_skin
    from eskin.data.schema import read_dataset, read_metadata
    from eskin.device.physics import skin_params
    from harness import oracle, pair_oracle

    meta = read_metadata(dataset_path)
    frame = read_dataset(dataset_path)
    keys = frame[["session", "trial", "sample"]].reset_index(drop=True)
    source = meta.get("source", {}).get("kind")
    reason = None
    if source != "simulated":
        reason = (f"no simulator made this data (source: {source}), so no one knows the "
                  "answers' probabilities")
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    if reason is not None:
        keys.attrs["unavailable"] = reason
        keys.to_parquet(out_path, index=False)
        return f"{scene}: no Bayes bound — {reason} → {out_path}"
    last = [0.0]

    def progress(done: int, total: int) -> None:
        if done == total or time.perf_counter() - last[0] > 10:
            last[0] = time.perf_counter()
            log(f"  {scene} Bayes bound: {done:,}/{total:,} samples")

    # The plan's conditions: one contact (stretch, force, node) or two (a pair of nodes
    # from nodes_x × nodes_y, a force each).
    conditions = [settings.stretches, settings.forces]
    sim, skin = skin_params(sim), scene_skin(settings)
    if get_kind(meta["kind"]).several:
        # importance sampling: every sample's answer from each half of the points too
        found = pair_oracle.posterior_predictions(
            frame, sim, *conditions, settings.nodes_x, settings.nodes_y, skin=skin,
            seed=int(seed), progress=progress)
        answers, moves = found.all, pair_oracle.convergence(found, frame)
    else:
        # the finest grid needed: doubled while doubling it moves a score (a 2 × 2 skin's
        # placement offsets need twice the paper skin's points; issue 59)
        grid = oracle.FINE
        for doubling in range(MAX_DOUBLINGS + 1):
            log(f"  {scene} Bayes bound: doubling the grid on {CONVERGENCE_ROWS} samples")
            moves = oracle.convergence(frame, sim, *conditions, skin=skin, grid=grid,
                                       rows=CONVERGENCE_ROWS)
            if max(moves.values()) < oracle.CONVERGED or doubling == MAX_DOUBLINGS:
                break
            grid = grid.doubled()
        answers = oracle.posterior_predictions(frame, sim, *conditions, skin=skin, grid=grid,
                                               progress=progress)
    answers = pd.concat([keys, answers.reset_index(drop=True)], axis=1)
    answers.attrs["convergence"] = json.dumps(moves, sort_keys=True)
    answers.to_parquet(out_path, index=False)
    worst = max(moves, key=moves.get)
    verdict = ("converged" if moves[worst] < oracle.CONVERGED else "NOT converged")
    return (f"{scene} Bayes bound: {len(answers):,} samples → {out_path}; {verdict}: doubling "
            f"the integration moves {worst} by {moves[worst]:.4f}")


def read_bound(bound_path: Path, frame: pd.DataFrame) -> tuple[pd.DataFrame | None, str | None]:
    """(the oracle's answers aligned with ``frame``'s rows, or None; why there are none).

    The answers' ``attrs["convergence"]`` holds how far doubling the grid moved each score."""
    answers = pd.read_parquet(bound_path)
    if "unavailable" in answers.attrs:
        return None, str(answers.attrs["unavailable"])
    moves = json.loads(answers.attrs.get("convergence", "{}"))
    oracle = frame[["session", "trial", "sample"]].merge(
        answers, on=["session", "trial", "sample"], how="left", validate="one_to_one")
    oracle.attrs = {"convergence": moves}
    if oracle["stretch"].isna().any():
        raise ValueError(f"{bound_path}: does not cover every sample of the scene; "
                         "rerun `make bench`")
    return oracle, None


def bench(scene: str, task_name: str, features_path: Path, bound_path: Path, out_dir: Path, *,
          bench: Bench, cv: CV, log=print) -> str:
    """One task's variants on one scene's folds, with the bound → ``<out>/<task>.json``,
    with the ``bench`` section (its ``tasks.<task>`` variants) and the ``cv`` split.

    A task the scene's data cannot support is written as skipped, with the reason."""
    import json

    from eskin.data.schema import dataset_kind, dataset_skin, read_dataset, read_metadata

    settings = bench
    meta = read_metadata(features_path)
    frame = read_dataset(features_path)
    skin, kind = dataset_skin(features_path), dataset_kind(features_path).name
    task = get_task(kind, task_name)
    header = {"scene": scene, "kind": kind, "task": task_name,
              "dataset_md5": meta["dataset"]["md5"]}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    out_path = out_dir / f"{task_name}.json"
    reason = task.unsupported(frame)
    if reason is not None:
        out_path.write_text(json.dumps({**header, "status": "skipped", "reason": reason},
                                       indent=2, sort_keys=True) + "\n")
        return f"{scene}/{task_name}: skipped — {reason}"
    oracle, no_bound = read_bound(bound_path, frame)
    with parallel_backend(settings.backend):
        doc = benchmark_task(task, frame, kind, settings.tasks[task_name], skin=skin,
                             schemes=list(settings.schemes), folds=int(cv.folds),
                             seed=int(cv.seed), evaluate_folds=int(settings.evaluate_folds),
                             oracle=oracle, n_jobs=int(settings.n_jobs), log=log)
    doc.update(header)
    if no_bound is not None:
        doc["bayes_bound_unavailable"] = no_bound
    else:
        doc["bayes_bound_convergence"] = oracle.attrs.get("convergence", {})
    out_path.write_text(json.dumps(doc, indent=2, sort_keys=True, allow_nan=True) + "\n")
    return "\n".join(f"{scene}/{task_name}: {scheme} Pareto front "
                     f"{', '.join(entry['pareto_front'])}"
                     for scheme, entry in doc["schemes"].items())


def default_variant(train: Any, kind: str, task_name: str, variants: Mapping[str, Any]) -> str:
    """The bench variant whose model and hyperparameters the training stage uses by default
    for a scene of ``kind`` (``train``: the ``train`` section)."""
    from eskin.learning.choice import model_settings

    model, hyper = model_settings(getattr(train, task_name), train.configuration, kind)
    for name, spec in variants.items():
        if variant_settings(spec) == (model, hyper, False):
            return name
    raise ValueError(f"the default {task_name} model of {kind} scenes, {model} {hyper}, is not "
                     f"among the benchmark's variants (bench.tasks.{task_name}); add it there")


def summarise(scene: str, bench_dir: Path, features_path: Path, *, bench: Bench, train: Any,
              log=print) -> str:
    """One scene's targets (as ratios measured in its bench runs), tables, a plot per task,
    with the ``bench`` and ``train`` sections."""
    import json

    from eskin.catalog import TASK_NAMES
    from eskin.data.schema import dataset_kind, dataset_skin, read_dataset, read_metadata

    settings = bench
    bench_dir = Path(bench_dir)
    docs = {task: json.loads((bench_dir / f"{task}.json").read_text()) for task in TASK_NAMES}
    summary: dict[str, Any] = {"scene": scene, "defaults": {}, "targets": {},
                               "skipped": {t: d["reason"] for t, d in docs.items()
                                           if d.get("status") == "skipped"}}
    meta = read_metadata(features_path)
    figures = bench_dir / "figures"
    figures.mkdir(exist_ok=True)
    for stale in figures.glob("*.png"):
        stale.unlink()
    for task_name, doc in docs.items():
        if doc.get("status") == "skipped":
            continue
        variants = settings.tasks[task_name]
        doc["default"] = default_variant(train, meta["kind"], task_name, variants)
        summary["defaults"][task_name] = doc["default"]
        summary["targets"].update(targets(doc))
        figure = benchmark_figure(doc)
        figure.suptitle(f"{scene}: {task_name}", fontsize=9)
        figure.savefig(figures / f"{task_name}.png", dpi=150, metadata={"Software": None})
    if "force" in summary["defaults"]:
        # Cost on doubling: the default force model refitted at ½, 1 and 2× the data.
        task = get_task(dataset_kind(features_path).name, "force")
        frame = read_dataset(features_path)
        default = summary["defaults"]["force"]
        skin = dataset_skin(features_path)
        estimator, _ = variant_estimator("force", settings.tasks["force"][default], skin)
        log(f"{scene} scaling: {default} at {settings.scaling_fractions} × the data …")
        grown = scaling(task, frame[task.rows(frame)].reset_index(drop=True), estimator,
                        list(settings.scaling_fractions), seed=int(settings.seed), skin=skin)
        worst = max(grown["growth_per_doubling"])
        summary["targets"]["cost_on_doubling"] = {
            **grown, "met": bool(worst <= 2.3),
            "text": f"force default ({default}) fit time grows "
                    f"{' then '.join(f'{g:.2f}×' for g in grown['growth_per_doubling'])} per "
                    "doubling of the data (target ≤ 2.3×)"}
    (bench_dir / "summary.json").write_text(
        json.dumps(summary, indent=2, sort_keys=True, allow_nan=True) + "\n")
    markdown = summary_markdown(scene, docs, summary)
    (bench_dir / "summary.md").write_text(markdown)
    (bench_dir / "summary.html").write_text(
        summary_html(scene, markdown, sorted(p.stem for p in figures.glob("*.png"))))
    return "\n".join([f"{scene} target {'met ' if t['met'] else 'MISSED'}: {t['text']}"
                      for t in summary["targets"].values()]
                     + [f"{scene} skipped {t}: {why}" for t, why in summary["skipped"].items()])


def targets(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The issue's targets for one task, as ratios of numbers measured in one bench run."""
    out: dict[str, Any] = {}
    default = doc["default"]
    task = doc_task(doc)
    # a check against a bound whose integration has not converged is against an estimate
    caveat = ("" if "bayes_bound_unavailable" in doc
              else unconverged(doc.get("bayes_bound_convergence", {})))
    for scheme, entry in doc["schemes"].items():
        results = entry["variants"]
        if doc["task"] == "force" and "exact_gp" in results:
            ref, fast = results["exact_gp"], results[default]
            speedup = ref["seconds_per_fold"] / fast["seconds_per_fold"]
            r2_gap = task.headline(ref["scores"]) - task.headline(fast["scores"])
            out[f"force_speed_vs_exact_gp_{scheme}"] = {
                "speedup": speedup, "r2_below_reference": r2_gap,
                "met": bool(speedup >= 20 and r2_gap <= 0.01),
                "text": f"force default ({default}) {speedup:.1f}× faster than exact_gp "
                        f"(target ≥ 20×), R² {r2_gap:+.4f} below it (target ≤ 0.01), "
                        f"{scheme} CV"}
        if scheme == "conditions" and "bayes_bound" in entry:
            # A bound a model beats on held-out trials is no bound; beating it by less than
            # the folds' spread (of the variant's or the bound's score) is noise.
            bound = entry["bayes_bound"]
            noise = {n: max(fold_spread(task, r["scores"]), fold_spread(task, bound["scores"]))
                     for n, r in results.items()}
            beaten = {n: bound["error"] - headline_error(task, r["scores"])
                      for n, r in results.items()
                      if headline_error(task, r["scores"]) < bound["error"] - noise[n]}
            out[f"{doc['task']}_bound_holds_conditions"] = {
                "beaten_by": beaten, "met": not beaten,
                "text": f"{doc['task']}: " + (
                    "no variant beats the Bayes bound beyond fold noise, conditions CV"
                    if not beaten else "the Bayes bound is beaten beyond fold noise by "
                    + ", ".join(f"{n} ({d:.4f})" for n, d in beaten.items())) + caveat}
        if scheme == "conditions" and "gap_closed" in entry:
            closed = {n: v for n, v in entry["gap_closed"].items()
                      if n != "paper" and np.isfinite(v)}
            if closed:
                best = max(closed, key=lambda n: closed[n])
                out[f"{doc['task']}_gap_closed_conditions"] = {
                    "best": best, "share": closed[best], "default": default,
                    "default_share": entry["gap_closed"].get(default),
                    "met": bool(closed[best] >= 0.8),
                    "text": f"{doc['task']}: {best} closes {closed[best]:.0%} of the gap between "
                            f"paper and the Bayes bound, conditions CV (target ≥ 80%); default "
                            f"{default} {entry['gap_closed'].get(default, float('nan')):.0%}"
                            + caveat}
    return out


def unconverged(moves: Mapping[str, float]) -> str:
    """'' for a converged bound; else what doubling its integration grid moved."""
    from harness.oracle import CONVERGED

    if not moves:
        return ", convergence not checked"
    worst = max(moves, key=moves.get)
    if moves[worst] < CONVERGED:
        return ""
    return f", NOT converged: doubling the integration moves {worst} by {moves[worst]:.4f}"


SUMMARY_CSS = """body{font-family:sans-serif;max-width:60em;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:.5em 0 1.5em}th,td{border:1px solid #ccc;padding:.2em .6em}
th{background:#f3f3f3}td:nth-child(n+2){text-align:right}img{max-width:100%}"""


def summary_html(scene: str, markdown: str, figures: list[str]) -> str:
    """``summary.md`` as a page (the report page links this, not the Markdown): its tables
    rendered (markdown-it-py, CommonMark with tables), each task's plot (``figures/<task>.png``,
    beside the page) above the task's first table."""
    from markdown_it import MarkdownIt

    lines, shown = [], set()
    for line in markdown.splitlines():
        lines.append(line)
        task = line[3:].split()[0].rstrip(":") if line.startswith("## ") else None
        if task in figures and task not in shown:
            shown.add(task)
            lines += ["", f"![{scene} {task}: seconds a fold against error](figures/{task}.png)",
                      ""]
    body = MarkdownIt("commonmark").enable("table").render("\n".join(lines))
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>Benchmark: {scene}</title><style>{SUMMARY_CSS}</style></head>"
            f"<body>\n{body}</body></html>\n")


def summary_markdown(scene: str, docs: Mapping[str, Mapping],
                     summary: Mapping[str, Any]) -> str:
    """Per task and scheme: each variant's time, memory, error, gap closed; front marked."""
    lines = [f"# Benchmark: {scene}", "",
             "Seconds and peak memory per fold (fit + predict), error = 1 − the task's headline "
             "score, on the same folds for every variant. ★ default, ◆ on the Pareto front.", ""]
    for task_name, doc in docs.items():
        if doc.get("status") == "skipped":
            lines += [f"## {task_name}: skipped", "", doc["reason"], ""]
            continue
        task = doc_task(doc)
        for scheme, entry in doc["schemes"].items():
            bound = ("no Bayes bound: " + doc["bayes_bound_unavailable"]
                     if "bayes_bound_unavailable" in doc else
                     f"Bayes bound error {entry['bayes_bound']['error']:.4f}"
                     + unconverged(doc.get("bayes_bound_convergence", {})))
            lines += [f"## {task_name} — {scheme} CV ({bound})", "",
                      "| variant | s/fold | peak MiB | error | gap closed |",
                      "|---|---|---|---|---|"]
            for name, result in sorted(entry["variants"].items(),
                                       key=lambda kv: kv[1]["seconds_per_fold"]):
                mark = ("★" if name == doc["default"] else "") + \
                       ("◆" if name in entry["pareto_front"] else "")
                gap = entry.get("gap_closed", {}).get(name, float("nan"))
                memory = result.get("peak_memory_mb") or float("nan")
                lines.append(f"| {name} {mark} | {result['seconds_per_fold']:.3g} | "
                             f"{memory:,.0f} | {headline_error(task, result['scores']):.4f} "
                             f"| {'—' if np.isnan(gap) else f'{gap:.0%}'} |")
            lines.append("")
    lines += ["## Targets", ""] + [f"- {'met' if t['met'] else '**missed**'}: {t['text']}"
                                   for t in summary["targets"].values()]
    return "\n".join(lines) + "\n"


def benchmark_figure(doc: Mapping[str, Any]):
    """Seconds per fold (log) against error, per scheme; the front joined, the bound dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    task = doc_task(doc)
    schemes = list(doc["schemes"])
    figure, axes = plt.subplots(1, len(schemes), figsize=(4.2 * len(schemes), 3.6),
                                sharey=True, squeeze=False, layout="constrained")
    for ax, scheme in zip(axes[0], schemes, strict=True):
        entry = doc["schemes"][scheme]
        for name, result in entry["variants"].items():
            seconds = result["seconds_per_fold"]
            error = headline_error(task, result["scores"])
            memory = result.get("peak_memory_mb") or 0.0
            marker = "*" if name == doc["default"] else ("s" if name == "paper" else "o")
            ax.scatter(seconds, error, marker=marker, s=80 if marker == "*" else 30, zorder=3)
            ax.annotate(f"{name}\n{memory:,.0f} MiB", (seconds, error), fontsize=7,
                        xytext=(4, 2), textcoords="offset points")
        front = entry["pareto_front"]
        ax.plot([entry["variants"][n]["seconds_per_fold"] for n in front],
                [headline_error(task, entry["variants"][n]["scores"]) for n in front],
                color="grey", lw=1, ls="-", zorder=1, label="Pareto front")
        if "bayes_bound" in entry:
            caveat = unconverged(doc.get("bayes_bound_convergence", {}))
            ax.axhline(entry["bayes_bound"]["error"], color="black", ls="--", lw=1,
                       label="Bayes bound" + (f" ({caveat[2:].split(':')[0]})" if caveat else ""))
        ax.set_xscale("log")
        ax.set_xlabel("fit + predict, seconds per fold")
        ax.set_title(f"{doc['task']} — {scheme} CV")
        ax.legend(fontsize=7, loc="upper right")
    axes[0][0].set_ylabel(f"error (1 − mean {task.headline_metric} of "
                          f"{', '.join(task.targets)})")
    return figure
