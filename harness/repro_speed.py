"""The loop's speed (issues 38 and 55): the default pipeline's `dvc repro` from an empty
cache, a one-knob experiment and a headline-label edit, each against the plain script
that runs the same fits (the yardstick, harness/plain_fits.py) and against a baseline
revision's pipeline, all timed here, one after the other; and the conditions-CV headline
scores of both revisions, beside their fold spreads.

Each revision runs in a scratch copy: the project's files (the working tree's git-tracked
files for the current pipeline, ``git archive <revision>`` for the baseline), a fresh git
repository, no DVC cache and an MLflow store of its own (SQLite). In that copy, in turn:

1. ``dvc repro --force``, so every stage runs: acquisition, training, scoring, export, the
   report. A stage's time runs from DVC's "Running stage" line to the next stage's (or to
   the end). The headline scores are read now, before the experiment changes them.
2. The yardstick of the repro: the plain script's fits of every scene's tasks, as one
   process (the current revision only).
3. ``dvc exp run -S <knob>``: one force hyperparameter of the single-force scene's
   default model, as a whole process, and the stages DVC ran for it; then the yardstick:
   the plain script's fits of the tasks DVC retrained, with the knob set.
4. ``python -m stages.train single_force stretch`` (a linear regression: little but the
   stage's fixed cost), as a whole process, the median of 3.
5. A headline label edited (the current revision only): the stages DVC then calls stale,
   and the `dvc repro` that reruns them, as a whole process.

Then the floor, in a scratch project of its own that holds none of eskin's code: what DVC
and Python cost before any of eskin's work. A chain of stages, each a Python process that
imports what every training stage needs (pandas and scikit-learn) and writes a few bytes,
as many as the current pipeline's repro ran; ``dvc repro`` of the chain, then a
``dvc exp run -S`` that reruns as many of them as the current experiment ran; and that
import alone, the median of 3.

The targets (issue 55) are the current pipeline's wall over the yardstick's: the repro
over the plain fits of every task plus the repro's own acquisition stages, the experiment
over the plain fits of what it retrained; the label edit's rerun in seconds, and its
stale stages. The load average is recorded beside them.

    PYTHONPATH=. python -m harness.repro_speed <baseline revision> [--json FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from pathlib import Path

from eskin.catalog import scores_path
from eskin.config.base import load_params
from eskin.config.params import Params

ROOT = Path(__file__).resolve().parents[1]
RUNNING = re.compile(r"^Running stage '([^']+)'")
# issue 55's targets: the pipeline's wall over the yardstick's (the plain script's fits
# of the same tasks; for the repro, plus the repro's own acquisition stages), at most
TARGETS = {"repro": 1.5, "experiment": 2.0}
# ... and a headline label edited: only these stages stale, rerun in at most this long (s)
LABEL_EDIT_STAGES = ("publish",)
LABEL_EDIT_SECONDS = 5.0
# The yardstick (harness/plain_fits.py), given the scene/task pairs to fit (none: all)
PLAIN = ["python", "-m", "harness.plain_fits"]
# A headline label of the report, edited: (file, text, replacement), the first occurrence
LABEL_EDIT = ("eskin/reporting/presentation.py", 'Headline("stretch R²"',
              'Headline("stretch R² (edited)"')
TRAIN_STAGE = re.compile(r"^train@(.+)-([a-z_]+)$")  # a revision with a stage per task
# the lines the train step prints for a task it trained (its refit, then its scores; none
# for a task it kept or skipped)
TRAINED = re.compile(r"^(\S+)/([a-z_]+) \[[^\]]*\]: ")
# a force hyperparameter of the single-force scene's default model, in both revisions'
# params.yaml (54c14f9's and after)
KNOB = "train.force.physics_profile.max_iter=150"
# the stretch stage of params.yaml's first scene (the paper's one-contact scene, in both
# revisions)
FIXED_COST_STAGE = ["python", "-m", "stages.train",
                    next(iter(load_params(Params, ROOT / "params.yaml").scenes)), "stretch"]
# The median of 3: on a machine shared with other work, one run in three caught by a
# burst of load does not move it, and three runs of a stage that should take about a
# second keep the bench short.
FIXED_COST_RUNS = 3
# The floor's stages import what every training stage imports (crossval's estimators need
# scikit-learn's base, which imports scipy.stats; the features are pandas frames).
FLOOR_IMPORTS = "import pandas, sklearn.base"
FLOOR_STAGE = """import sys
{imports}
source, out, knob = sys.argv[1:]
open(out, "w").write((open(source).read() if source != "-" else "") + knob)
"""
MEASUREMENTS = {"repro": "full `dvc repro --force`, empty cache",
                "experiment": "one-knob experiment, `dvc exp run -S {knob}`",
                "fixed_cost": "per-stage fixed cost, `{command}`, median of {runs}"}
YARDSTICKS = {"repro": "the plain fits of every task, plus the repro's acquisition stages",
              "experiment": "the plain fits of the tasks it retrained"}


def tracked_copy(dest: Path, revision: str | None = None, *, root: Path = ROOT) -> None:
    """The project as git has it: ``revision``'s tree, or (None) the working tree's
    tracked files, edits included; untracked and ignored files (data, caches) left out."""
    dest.mkdir(parents=True, exist_ok=True)
    if revision is not None:
        archive = subprocess.run(["git", "archive", "--format=tar", revision], cwd=root,
                                 capture_output=True, check=True, timeout=120).stdout
        with tempfile.TemporaryFile() as tar_file:
            tar_file.write(archive)
            tar_file.seek(0)
            with tarfile.open(fileobj=tar_file) as tar:
                tar.extractall(dest, filter="data")
        return
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True,
                            check=True, timeout=60).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = root / name
        if source.is_file():  # a tracked file deleted in the working tree is left out
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest / name)


def scratch_env(project: Path) -> dict[str, str]:
    """The environment a user's `dvc repro` has, with the project's own MLflow store and
    its own code (PYTHONPATH: the venv's editable install would import another checkout's
    eskin in any process not started in the copy); none of the calling DVC stage's
    variables."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DVC_", "MLFLOW_"))}
    bin_dir = str(Path(sys.executable).parent)  # dvc, and the python DVC's stages call
    return {**env, "PATH": f"{bin_dir}{os.pathsep}{env.get('PATH', '')}",
            "PYTHONPATH": str(project),
            "DVC_NO_ANALYTICS": "1", "MLFLOW_ENABLE_TELEMETRY": "false", "DO_NOT_TRACK": "1",
            "MLFLOW_TRACKING_URI": f"sqlite:///{project / 'mlflow.db'}",
            "GIT_AUTHOR_NAME": "bench", "GIT_AUTHOR_EMAIL": "bench@localhost",
            "GIT_COMMITTER_NAME": "bench", "GIT_COMMITTER_EMAIL": "bench@localhost"}


def timed_run(args: list[str], project: Path, *, timeout: float, log=print) -> dict:
    """``args`` run in ``project`` as a whole process: its seconds, and each DVC stage's it
    ran (from DVC's "Running stage" lines; none for a command that is not DVC's)."""
    command = shlex.join(args)
    started = time.perf_counter()
    marks: list[tuple[str, float]] = []
    trained: list[str] = []
    tail: list[str] = []
    # its own process group: at the deadline, DVC and the stage it runs are killed together
    # (the stage holds the output pipe open)
    with subprocess.Popen(args, cwd=project, env=scratch_env(project), stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, start_new_session=True) as proc:
        def kill() -> None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)

        deadline = threading.Timer(timeout, kill)  # a stage that hangs, silent
        deadline.start()
        try:
            for line in proc.stdout:  # type: ignore[union-attr]
                found = RUNNING.match(line)
                if found:
                    marks.append((found.group(1), time.perf_counter() - started))
                    log(f"  {marks[-1][1]:6.1f} s  {found.group(1)}")
                trained.extend(trained_tasks([line]))
                tail = (tail + [line.rstrip()])[-20:]
        finally:
            deadline.cancel()
            if proc.poll() is None:
                kill()
        code = proc.wait(timeout=60)
    total = time.perf_counter() - started
    if total >= timeout:
        raise TimeoutError(f"{project}: {command} still running after {timeout:.0f} s; killed")
    if code != 0:
        raise RuntimeError(f"{project}: {command} exited {code}:\n" + "\n".join(tail))
    ends = [t for _, t in marks[1:]] + [total] * bool(marks)  # a command not DVC's: none
    return {"seconds": total, "trained": list(dict.fromkeys(trained)),
            "stages": {name: end - start for (name, start), end in zip(marks, ends, strict=True)}}


def timed_repro(project: Path, *, timeout: float, log=print) -> dict:
    """`dvc repro --force` in ``project`` (committed to a fresh git repository first, as a
    clone is): total seconds and each stage's, from DVC's own output."""
    env = scratch_env(project)
    for args in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "copy"]):
        subprocess.run(args, cwd=project, env=env, check=True, capture_output=True, timeout=120)
    return timed_run(["dvc", "repro", "--force"], project, timeout=timeout, log=log)


def timed_experiment(project: Path, knob: str, *, timeout: float, log=print) -> dict:
    """`dvc exp run -S <knob>` in ``project``, after its repro: seconds, and the stages
    DVC ran (in order; each one's seconds)."""
    return {"knob": knob,
            **timed_run(["dvc", "exp", "run", "-S", knob], project, timeout=timeout, log=log)}


def fixed_cost(project: Path, command: list[str], *, runs: int = FIXED_COST_RUNS,
               timeout: float, log=print) -> dict:
    """``command`` (one stage) run ``runs`` times in ``project``: the median seconds."""
    seconds = [timed_run(command, project, timeout=timeout, log=log)["seconds"]
               for _ in range(runs)]
    log(f"  {shlex.join(command)}: " + ", ".join(f"{s:.2f} s" for s in seconds))
    return {"command": shlex.join(command), "runs": seconds, "seconds": statistics.median(seconds)}


def score_name(scene: str, task: str, target: str | None, score: str) -> str:
    """``<scene>.<task>[.<target>].<score>``: the target left out where it is the task
    (or, for pairs, where the scores have none), as reports/metrics.json names them."""
    return ".".join([scene, task, *([target] if target not in (None, task) else []), score])


def headline_keys(project: Path) -> list[tuple[str, str, str | None, str]]:
    """Each conditions-CV headline score of ``project`` as (scene, task, target, score), from
    its headline metrics: one reports/metrics.json (``<scene>.<task>[.<target>].<score>``)
    or, before it, reports/metrics/<scene>/<task>.json (``conditions.[<target>.]<score>``).
    A target None: the score sits in the task's scores without one (a single-target task
    written without its target, or pairs)."""
    def flatten(scene: str, task: str, entry: dict) -> list[tuple[str, str, str | None, str]]:
        return [key for name, value in entry.items()
                for key in ([(scene, task, name, score) for score in value]
                            if isinstance(value, dict) else [(scene, task, None, name)])]

    one_file = project / "reports" / "metrics.json"
    if one_file.is_file():
        return [key for scene, tasks in json.loads(one_file.read_text()).items()
                for task, entry in tasks.items() for key in flatten(scene, task, entry)]
    return [key for path in sorted((project / "reports" / "metrics").glob("*/*.json"))
            for key in flatten(path.parent.name, path.stem,
                               _headline_scheme(json.loads(path.read_text())))]


def _headline_scheme(doc: dict) -> dict:
    """A scores document's held-out-conditions scores; a baseline revision older than
    issue 41 named that scheme ``grouped``."""
    return doc.get("conditions", doc.get("grouped", {}))


def fold_scores(project: Path) -> dict[str, dict[str, float]]:
    """Each conditions-CV headline score of ``project`` (:func:`headline_keys`) with its fold
    spread, from the scores files (reports/scores/<scene>/<task>.json, ``<score>_std``):
    ``{name: {"mean": …, "std": …}}``."""
    out = {}
    for scene, task, target, score in headline_keys(project):
        path = project / "reports" / "scores" / scene / f"{task}.json"
        if not path.exists():  # pairs, since the report scores them (reports/pairs/)
            path = project / scores_path(scene, task)
        headline = _headline_scheme(json.loads(path.read_text()))
        if target is None and isinstance(headline.get(task), dict):
            target = task
        scores = headline if target is None else headline[target]
        out[score_name(scene, task, target, score)] = {"mean": scores[score],
                                                       "std": scores[f"{score}_std"]}
    return out


def compare_scores(baseline: dict[str, dict], current: dict[str, dict]) -> dict[str, dict]:
    """Every headline score of either: whether the current mean lies within the baseline's
    mean ± its fold spread (None where one revision lacks the score)."""
    return {name: {"within": (abs(current[name]["mean"] - baseline[name]["mean"])
                              <= baseline[name]["std"])
                   if name in baseline and name in current else None}
            for name in dict.fromkeys([*baseline, *current])}


def trained_tasks(lines: list[str]) -> list[str]:
    """The scene/task pairs the train step's ``lines`` say it trained, each once (it
    prints two lines for each: the yardstick fitted a task twice when both counted)."""
    return list(dict.fromkeys(f"{m.group(1)}/{m.group(2)}" for m in map(TRAINED.match, lines)
                              if m))


def retrained(run: dict) -> list[str]:
    """The scene/task pairs ``run`` (:func:`timed_run`) trained: its training stages'
    names in a revision with a stage per task, else the tasks the train step said it
    trained (a scene's stage keeps the tasks it need not train)."""
    named = [f"{m.group(1)}/{m.group(2)}" for m in map(TRAIN_STAGE.match, run["stages"]) if m]
    return named or list(run.get("trained", []))


def plain_fits(project: Path, plain: list[str], tasks: list[str] | None, *, timeout: float,
               log=print) -> dict:
    """The yardstick in ``project``: ``plain`` given ``tasks`` (None: all), as a whole
    process."""
    args = [*plain, *(tasks or [])]
    log(f"  {shlex.join(args)} …")
    return {"tasks": tasks, **timed_run(args, project, timeout=timeout, log=log)}


def stale_stages(project: Path) -> list[str]:
    """The stages `dvc status` calls stale in ``project``, in its order."""
    shown = subprocess.run(["dvc", "status", "--json"], cwd=project, env=scratch_env(project),
                           capture_output=True, text=True, timeout=300)
    if shown.returncode != 0:
        raise RuntimeError(f"{project}: dvc status exited {shown.returncode}: "
                           f"{shown.stderr.strip()[-500:]}")
    return [name.split(":")[-1] for name in json.loads(shown.stdout or "{}")]


def label_edit(project: Path, edit: tuple[str, str, str], *, timeout: float,
               log=print) -> dict:
    """``edit`` (file, text, replacement) made in ``project``: the stages DVC then calls
    stale, and the `dvc repro` that reruns them, timed."""
    path, text, replacement = edit
    source = project / path
    content = source.read_text()
    if text not in content:
        raise ValueError(f"{path}: no {text!r} to edit (harness/repro_speed.py LABEL_EDIT)")
    source.write_text(content.replace(text, replacement, 1))
    stale = stale_stages(project)
    log(f"  a headline label edited: stale {', '.join(stale) or 'nothing'}; dvc repro …")
    return {"file": path, "stale": stale,
            **timed_run(["dvc", "repro"], project, timeout=timeout, log=log)}


def measure_revision(project: Path, *, knob: str, stage: list[str], timeout: float,
                     plain: list[str] | None = None,
                     edit: tuple[str, str, str] | None = None, log=print) -> dict:
    """One copy's measurements, in the order they must run: the repro (its scores read
    before the experiment changes them) and its yardstick, the experiment and its
    yardstick, the stage alone, then the label edit. ``plain`` (the yardstick's command)
    and ``edit``: the current revision's only (None: not measured)."""
    repro = timed_repro(project, timeout=timeout, log=log)
    scores = fold_scores(project)
    out: dict = {"repro": repro, "scores": scores}
    if plain is not None:
        out["plain_repro"] = plain_fits(project, plain, None, timeout=timeout, log=log)
    log(f"  dvc exp run -S {knob} …")
    out["experiment"] = timed_experiment(project, knob, timeout=timeout / 3, log=log)
    if plain is not None:
        out["plain_experiment"] = plain_fits(
            project, plain, retrained(out["experiment"]), timeout=timeout, log=log)
    log(f"  {shlex.join(stage)} × {FIXED_COST_RUNS} …")
    out["fixed_cost"] = fixed_cost(project, stage, timeout=300, log=log)
    if edit is not None:
        out["label_edit"] = label_edit(project, edit, timeout=timeout / 3, log=log)
    return out


def acquisition_seconds(repro: dict) -> float:
    """The seconds of a repro's acquisition stages (``acquire@<scene>``)."""
    return sum(s for name, s in repro["stages"].items() if name.split("@")[0] == "acquire")


def yardstick_ratios(current: dict) -> dict[str, dict]:
    """Each target's eskin wall, its yardstick's and their ratio."""
    repro_yard = current["plain_repro"]["seconds"] + acquisition_seconds(current["repro"])
    return {"repro": {"eskin": current["repro"]["seconds"], "yardstick": repro_yard,
                      "acquisition": acquisition_seconds(current["repro"]),
                      "ratio": current["repro"]["seconds"] / repro_yard},
            "experiment": {"eskin": current["experiment"]["seconds"],
                           "yardstick": current["plain_experiment"]["seconds"],
                           "ratio": current["experiment"]["seconds"]
                           / current["plain_experiment"]["seconds"]}}


def floor(project: Path, *, stages: int, rerun: int, imports: str = FLOOR_IMPORTS,
          timeout: float = 600, log=print) -> dict:
    """The floor (see the module's text) in a new project at ``project``: a chain of
    ``stages`` stages, each ``python stage.py`` importing ``imports``; its `dvc repro`;
    a `dvc exp run -S knob=2` whose knob the ``rerun``-th stage from the end reads, so that
    it and those after it run again; and ``python -c <imports>``, the median of 3."""
    if not 0 < rerun <= stages:
        raise ValueError(f"the floor's experiment reruns {rerun} of {stages} stages")
    project.mkdir(parents=True)
    (project / "stage.py").write_text(FLOOR_STAGE.format(imports=imports))
    (project / "params.yaml").write_text("knob: 1\n")
    knobbed = stages - rerun
    lines = ["stages:"]
    for index in range(stages):
        source = f"s{index - 1:02d}.txt" if index else "-"
        lines += [f"  s{index:02d}:",
                  f"    cmd: python stage.py {source} s{index:02d}.txt "
                  + ("${knob}" if index == knobbed else "0"),
                  "    deps: [stage.py" + (f", {source}]" if index else "]"),
                  *(["    params: [knob]"] if index == knobbed else []),
                  f"    outs: [s{index:02d}.txt]"]
    (project / "dvc.yaml").write_text("\n".join(lines) + "\n")
    env = scratch_env(project)
    for args in (["git", "init", "-q"], ["dvc", "init", "-q"], ["git", "add", "-A"],
                 ["git", "commit", "-qm", "floor"]):
        subprocess.run(args, cwd=project, env=env, check=True, capture_output=True,
                       timeout=120)
    repro = timed_run(["dvc", "repro"], project, timeout=timeout, log=log)
    experiment = timed_run(["dvc", "exp", "run", "-S", "knob=2"], project, timeout=timeout,
                           log=log)
    process = fixed_cost(project, ["python", "-c", imports], timeout=120, log=log)
    return {"imports": imports, "repro": repro, "experiment": experiment,
            "process": process}


def measure(baseline: str, *, knob: str = KNOB, stage: list[str] = FIXED_COST_STAGE,
            timeout: float = 3600, floor_imports: str = FLOOR_IMPORTS, root: Path = ROOT,
            plain: list[str] = PLAIN, edit: tuple[str, str, str] = LABEL_EDIT,
            label_stages: tuple[str, ...] = LABEL_EDIT_STAGES, log=print) -> dict:
    """The baseline revision's pipeline, then the working tree's, each from scratch.
    ``timeout``: a repro's deadline, for a hang, not a target (on 2 cores at load
    average 10, the baseline's repro took 22 minutes)."""
    commit = subprocess.run(["git", "rev-parse", "--verify", f"{baseline}^{{commit}}"],
                            cwd=root, capture_output=True, text=True, timeout=30)
    if commit.returncode != 0:
        raise ValueError(f"bench.repro_baseline: {baseline!r} is not a commit of this "
                         "repository (a shallow clone lacks history: git fetch --unshallow)")
    result: dict = {"targets": TARGETS,
                    "label_edit_target": {"stages": list(label_stages),
                                          "seconds": LABEL_EDIT_SECONDS},
                    "cores": os.cpu_count(), "load_average": {"start": os.getloadavg()[0]}}
    with tempfile.TemporaryDirectory(prefix="eskin-repro-") as scratch:
        for name, revision in (("baseline", commit.stdout.strip()), ("current", None)):
            project = Path(scratch) / name
            tracked_copy(project, revision, root=root)
            log(f"{name} ({revision or 'working tree'}): dvc repro from an empty cache …")
            mine = revision is None
            result[name] = {"revision": revision or "working tree",
                            **measure_revision(project, knob=knob, stage=stage,
                                               timeout=timeout, plain=plain if mine else None,
                                               edit=edit if mine else None, log=log)}
            result["load_average"][f"after {name}"] = os.getloadavg()[0]
        current = result["current"]
        log(f"the floor: {len(current['repro']['stages'])} stages that import "
            f"{floor_imports!r} …")
        result["floor"] = floor(Path(scratch) / "floor", imports=floor_imports,
                                stages=len(current["repro"]["stages"]),
                                rerun=len(current["experiment"]["stages"]), log=log)
    result["ratios"] = yardstick_ratios(result["current"])
    result["vs_baseline"] = {what: result["current"][what]["seconds"]
                             / result["baseline"][what]["seconds"]
                             for what in ("repro", "experiment", "fixed_cost")}
    edited = result["current"]["label_edit"]
    result["met"] = {**{what: result["ratios"][what]["ratio"] <= target
                        for what, target in TARGETS.items()},
                     "label_edit": (sorted(edited["stale"]) == sorted(label_stages)
                                    and edited["seconds"] <= LABEL_EDIT_SECONDS)}
    result["scores"] = compare_scores(result["baseline"]["scores"], result["current"]["scores"])
    return result


def render(result: dict) -> str:
    base, current = result["baseline"], result["current"]
    load = ", ".join(f"{when} {value:.1f}" for when, value in result["load_average"].items())
    labels = {what: MEASUREMENTS[what].format(knob=current["experiment"]["knob"],
                                              command=current["fixed_cost"]["command"],
                                              runs=len(current["fixed_cost"]["runs"]))
              for what in MEASUREMENTS}
    verdict = {True: "met", False: "MISSED"}
    lines = [f"The baseline ({base['revision'][:7]}) then the working tree, each in a scratch "
             f"copy, minutes apart; load average (1 min) on {result['cores']} cores: {load}.",
             "", "Against the yardstick: the plain script (harness/plain_fits.py) that runs "
             "the same fits in one process, in the same copy, minutes apart:", "",
             "| measurement | eskin | yardstick | eskin / yardstick | target | |",
             "|---|---|---|---|---|---|"]
    for what, target in result["targets"].items():
        found = result["ratios"][what]
        lines.append(f"| {labels[what]} | {found['eskin']:.1f} s | {found['yardstick']:.1f} s "
                     f"({YARDSTICKS[what]}"
                     + (f": fits {found['yardstick'] - found['acquisition']:.1f} s, acquisition "
                        f"{found['acquisition']:.1f} s" if "acquisition" in found else "")
                     + f") | **{found['ratio']:.2f}×** | ≤ {target:g}× | "
                     f"{verdict[result['met'][what]]} |")
    edited, wanted = current["label_edit"], result["label_edit_target"]
    lines.append(f"| a headline label edited ({edited['file']}): `dvc repro` of what is stale "
                 f"({', '.join(edited['stale']) or 'nothing'}) | {edited['seconds']:.1f} s | — | "
                 f"— | only {', '.join(wanted['stages'])}, ≤ {wanted['seconds']:g} s | "
                 f"{verdict[result['met']['label_edit']]} |")
    lines += ["", "Against the baseline revision's pipeline:", "",
              "| measurement | baseline | current | current / baseline |", "|---|---|---|---|"]
    for what, ratio in result["vs_baseline"].items():
        digits = 2 if what == "fixed_cost" else 1
        lines.append(f"| {labels[what]} | {base[what]['seconds']:.{digits}f} s | "
                     f"**{current[what]['seconds']:.{digits}f} s** | {ratio:.2f}× |")
    lines += ["", "The fixed cost's runs: " + "; ".join(
        f"{label} " + ", ".join(f"{s:.2f}" for s in run["fixed_cost"]["runs"]) + " s"
        for label, run in (("baseline", base), ("current", current))) + "."]
    if "floor" in result:
        lines += ["", *render_floor(result)]
    lines += ["", "The stages the experiment ran:", ""]
    lines += [f"- {label} ({len(run['experiment']['stages'])}): "
              + ", ".join(f"{name} {s:.1f} s" for name, s in run["experiment"]["stages"].items())
              for label, run in (("baseline", base), ("current", current))]

    def seconds(run: dict, name: str) -> str:
        return f"{run['repro']['stages'][name]:.1f} s" if name in run["repro"]["stages"] else "—"

    names = list(dict.fromkeys([*current["repro"]["stages"], *base["repro"]["stages"]]))
    lines += ["", "The full repro, stage by stage:", "",
              "| stage | baseline | current |", "|---|---|---|"]
    lines += [f"| {name} | {seconds(base, name)} | {seconds(current, name)} |" for name in names]
    lines.append(f"| **total** | **{base['repro']['seconds']:.1f} s** | "
                 f"**{current['repro']['seconds']:.1f} s** |")

    def spread(run: dict, name: str) -> str:
        found = run["scores"].get(name)
        return f"{found['mean']:.4f} ± {found['std']:.4f}" if found else "—"

    within = {True: "yes", False: "**no**", None: "—"}
    lines += ["", "The conditions-CV headline scores, mean ± standard deviation over the folds "
              "(after the full repro, default params):", "",
              "| score | baseline | current | current within the baseline's mean ± std |",
              "|---|---|---|---|"]
    lines += [f"| {name} | {spread(base, name)} | {spread(current, name)} | "
              f"{within[compared['within']]} |" for name, compared in result["scores"].items()]
    return "\n".join(lines)


def render_floor(result: dict) -> list[str]:
    """The floor under each measurement: what DVC and Python cost before eskin's work."""
    found, current = result["floor"], result["current"]
    rows = {"repro": (f"full `dvc repro`, {len(found['repro']['stages'])} stages",
                      found["repro"]["seconds"]),
            "experiment": (f"`dvc exp run -S`, {len(found['experiment']['stages'])} of them "
                           "rerun", found["experiment"]["seconds"]),
            "fixed_cost": (f"`python -c \"{found['imports']}\"`, median of "
                           f"{len(found['process']['runs'])}", found["process"]["seconds"])}
    lines = ["The floor: DVC and Python alone, in a project with none of eskin's code, as "
             "many stages as the current pipeline ran, each running "
             f"`{found['imports']}` and writing a few bytes:", "",
             "| floor of | floor | current |", "|---|---|---|"]
    for what, (label, seconds) in rows.items():
        digits = 2 if what == "fixed_cost" else 1
        lines.append(f"| {label} | {seconds:.{digits}f} s | "
                     f"{current[what]['seconds']:.{digits}f} s |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("baseline")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    result = measure(args.baseline)
    print(render(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
