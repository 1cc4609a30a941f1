"""Data we did not make, through the whole pipeline under real DVC and a real MLflow server.

One scratch project with three scenes declared in params.yaml only:

* ``lab_single`` — a single-force CSV written the way a lab writes it: a header
  in the paper's own names (x1..x10, y1..y10, force, x, y, stretch), two
  stretch levels;
* ``lab_pairs`` — a two-force CSV with no header and no stretch column;
* ``board_day1`` — a single-force session recorded over a loopback socket from
  ``tests/hostile_board.py``, a board that imports nothing of eskin, at one
  stretch level (so its stretch task is skipped, with the reason).

`dvc repro` runs through to the report; `eskin compare`, `eskin audit` and
`eskin reproduce` work on the result; `make bench`'s stages run per scene and say
where there is no Bayes bound; every stage that ran read exactly the params it
declares; removing a scene from params removes its stages.
"""

from __future__ import annotations

import copy
import csv
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import params_trace_dir, quick_params, scratch_project
from conftest import run_checked as run
from hostile_board import HostileBoard, Served
from test_stage_deps import params_mismatches

from eskin.catalog import scores_path

# Each test here starts a pipeline or a server: `make check` leaves them out.
pytestmark = pytest.mark.starts

NODES = (1, 5, 10)
SAMPLES = 4


def channels(rng, presses, stretch):
    """A plausible reading: every terminal's baseline, a rise under each press, a drift
    with stretch, noise. (Any function would do: the test is about the plumbing.)"""
    x = np.full(10, 310.0) + 12 * (stretch - 1) * 100
    y = np.full(10, 290.0) + 9 * (stretch - 1) * 100
    for force, px, py in presses:
        if force > 0 and px > 0:
            x[px - 1] += 18 * force
            y[py - 1] += 15 * force
    return list(np.round(np.concatenate([x, y]) + rng.normal(0, 1.5, 20), 3))


def write_lab_single(path: Path) -> int:
    rng = np.random.default_rng(1)
    header = ([f"x{i}" for i in range(1, 11)] + [f"y{i}" for i in range(1, 11)]
              + ["force", "x", "y", "stretch"])
    rows = []
    for stretch in (1.0, 1.1):
        for force in (0.0, 2.0, 4.0):
            for px in NODES if force else (0,):
                for py in NODES if force else (0,):
                    rows += [channels(rng, [(force, px, py)], stretch) + [force, px, py, stretch]
                             for _ in range(SAMPLES)]
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    return len(rows)


def write_lab_pairs(path: Path) -> int:
    rng = np.random.default_rng(2)
    nodes = [(x, y) for x in NODES for y in NODES]
    rows = []
    for i, first in enumerate(nodes):
        for second in nodes[i + 1:]:
            for f1, f2 in ((1.5, 3.0), (3.0, 1.5)):
                rows += [channels(rng, [(f1, *first), (f2, *second)], 1.0)
                         + [f1, *first, f2, *second] for _ in range(SAMPLES)]
    with path.open("w", newline="") as handle:
        csv.writer(handle).writerows(rows)
    return len(rows)


def scenes(lab_single: Path, lab_pairs: Path, port: str) -> dict:
    return {
        "lab_single": {"kind": "single_force", "source": "import",
                       "import": {"path": str(lab_single)}},
        "lab_pairs": {"kind": "two_force", "source": "import",
                      "import": {"path": str(lab_pairs)}},
        "board_day1": {"kind": "single_force", "source": "serial", "port": port,
                       "stretches": [1.0], "forces": [0.0, 3.2536], "samples": 3},
    }


@pytest.fixture(scope="module")
def project(tmp_path_factory, repo_params, repo_bench_params, mlflow_server):
    root = tmp_path_factory.mktemp("foreign")
    files = tmp_path_factory.mktemp("lab_files")
    rows = {"lab_single": write_lab_single(files / "lab_single.csv"),
            "lab_pairs": write_lab_pairs(files / "lab_pairs.csv")}
    board = HostileBoard(device_id="lab-board-7")
    with Served(board, "socket") as served:
        params = copy.deepcopy(repo_params)
        params["scenes"] = scenes(files / "lab_single.csv", files / "lab_pairs.csv", served.port)
        params["acquire"]["indenters"] = "board"
        # Conditions CV only: the plumbing, not the paper's scheme, is under test (CI time).
        quick_params(params, folds=3, conditions_only=True)
        # make bench, small: every candidate the train section names, one conditions fold.
        bench_params = copy.deepcopy(repo_bench_params)
        bench_params["bench"].update(schemes=["conditions"], evaluate_folds=1,
                                     scaling_fractions=[0.5, 1.0], tasks={
                                         task: {name: {"model": name, **hyper}
                                                for name, hyper in settings.items()
                                                if name != "model"}
                                         for task, settings in params["train"].items()
                                         if task != "configuration"})
        env = scratch_project(root, params, mlflow_server, bench_params=bench_params)
        repro = run(["dvc", "repro"], root, env).stdout
    run(["git", "add", "-A"], root, env)
    run(["git", "commit", "-qm", "repro"], root, env)
    return root, env, params, rows, served.port, repro


def scores(root: Path, scene: str, task: str) -> dict:
    return json.loads((root / scores_path(scene, task)).read_text())


def test_every_scene_gets_its_stages_from_params_alone(project):
    root, env, *_ = project
    listed = run(["dvc", "stage", "list", "--name-only"], root, env).stdout.split()
    for scene in ("lab_single", "lab_pairs", "board_day1"):
        assert {f"acquire@{scene}", f"prepare@{scene}"} <= set(listed)
        assert f"train@{scene}" in listed
    assert not [s for s in listed if "single_force" in s or "two_force" in s], listed


def test_each_scene_trains_what_its_data_supports_and_says_why_it_skips_the_rest(project):
    root, *_ = project
    for task in ("stretch", "force", "detect", "localise"):
        assert scores(root, "lab_single", task)["status"] == "trained", task
    assert scores(root, "lab_single", "stretch")["conditions"]["stretch"]["r2"] > 0.9
    # a one-contact scene has no pairs to score, and no file: the results say why
    assert not (root / scores_path("lab_single", "pairs")).exists()
    assert ("lab_single/pairs skipped: a single_force scene has one contact"
            in (root / "reports/results.md").read_text())
    pairs = {task: scores(root, "lab_pairs", task) for task in
             ("stretch", "force", "detect", "localise", "pairs")}
    assert pairs["force"]["status"] == "trained"
    assert set(pairs["force"]["conditions"]) == {"force1", "force2"}
    assert pairs["localise"]["status"] == "trained" and pairs["pairs"]["status"] == "scored"
    assert "two or more stretch levels" in pairs["stretch"]["reason"]
    assert "every sample of this scene has 2" in pairs["detect"]["reason"]
    board = scores(root, "board_day1", "stretch")
    assert board["status"] == "skipped" and "this scene has one (λ = 1)" in board["reason"]
    assert scores(root, "board_day1", "force")["status"] == "trained"


def test_the_datasets_name_their_sources(project):
    root, _, _, rows, port, _ = project
    single = scores(root, "lab_single", "force")
    assert single["dataset_rows"] == rows["lab_single"]
    assert single["source"].startswith("import ") and "lab_single.csv (sha256 " in \
        single["source"]
    board = scores(root, "board_day1", "force")
    assert board["source"] == f"serial {port}, device lab-board-7 firmware hostile-1.0"


def test_the_report_has_a_section_and_figures_per_scene(project):
    root, *_ = project
    page = (root / "reports/index.html").read_text()
    for scene in ("lab_single", "lab_pairs", "board_day1"):
        assert f'id="scene-{scene}"' in page
    assert page.index('id="scene-lab_single"') < page.index('id="scene-lab_pairs"') < \
        page.index('id="scene-board_day1"')  # the order of params.yaml
    figures = {p.relative_to(root / "reports/figures").as_posix()
               for p in (root / "reports/figures").rglob("*.png")}
    assert {"lab_single/stretch_parity_conditions.png", "lab_single/force_parity_conditions.png",
            "lab_pairs/force_parity_conditions.png", "board_day1/force_parity_conditions.png",
            "board_day1/detection_conditions.png"} <= figures
    assert not any(f.startswith("board_day1/stretch") for f in figures)
    results = (root / "reports" / "results.md").read_text()
    assert "## board_day1 (single force)" in results
    assert "board_day1/stretch skipped: stretch regression needs two or more" in results
    plots = json.loads(run(["dvc", "plots", "show", "--json"], root, project[1]).stdout)
    assert any("lab_pairs_force1.csv" in key for key in json.dumps(plots).split('"'))


def test_compare_audit_and_reproduce_work_on_foreign_data(project, monkeypatch):
    root, env, _, _, port, _ = project
    monkeypatch.setenv("MLFLOW_TRACKING_URI", env["MLFLOW_TRACKING_URI"])
    compare = run([sys.executable, "-m", "eskin", "compare", "--format", "csv"], root, env)
    header = compare.stdout.splitlines()[0].split(",")
    # Two single-force scenes log the same metric names: their columns carry the scene.
    assert "lab_single: force R²" in header and "board_day1: force R²" in header, header
    assert "force1 R²" in header  # one scene only: no prefix
    import mlflow

    found = mlflow.search_runs(experiment_names=["eskin"], output_format="list")
    runs = {f"{r.data.tags.get('eskin.scene')}/{r.data.tags.get('eskin.task')}": r.info.run_id
            for r in found}
    audit = run([sys.executable, "-m", "eskin", "audit", "--run", runs["lab_single/force"]],
                root, env).stdout
    assert "lab_single.csv (sha256 " in audit and "dataset in workspace  ok" in audit, audit
    audit = run([sys.executable, "-m", "eskin", "audit", "--run", runs["board_day1/force"]],
                root, env).stdout
    assert f"serial {port}, device lab-board-7" in audit, audit
    reproduced = run([sys.executable, "-m", "eskin", "reproduce", "lab_pairs.force.force2"],
                     root, env, ok=False)
    assert reproduced.returncode == 0 and "  reproduced" in reproduced.stdout, (
        reproduced.stdout + reproduced.stderr)


def test_removing_a_scene_from_params_removes_its_stages(project, tmp_path):
    root, env, params, *_ = project
    fewer = copy.deepcopy(params)
    del fewer["scenes"]["board_day1"]
    (root / "params.yaml").rename(tmp_path / "params.yaml")
    try:
        (root / "params.yaml").write_text(yaml.safe_dump(fewer, sort_keys=False))
        listed = run(["dvc", "stage", "list", "--name-only"], root, env).stdout.split()
    finally:
        (tmp_path / "params.yaml").replace(root / "params.yaml")
    assert not [s for s in listed if "board_day1" in s] and "train@lab_single" in listed


@pytest.fixture(scope="module")
def benched(project):
    """`make bench`'s per-scene stages on the imported scenes (bench/dvc.yaml, a DVC
    project of its own)."""
    root, env, *_ = project
    run(["dvc", "repro", "summary@lab_single", "summary@lab_pairs"], root / "bench", env)
    return root


def test_the_benchmark_runs_per_scene_and_says_where_there_is_no_bayes_bound(benched):
    bench = benched / "reports/benchmark"
    single = (bench / "lab_single/summary.md").read_text()
    assert single.startswith("# Benchmark: lab_single")
    assert "no Bayes bound: no simulator made this data (source: import)" in single
    summary = json.loads((bench / "lab_single/summary.json").read_text())
    assert summary["defaults"] == {"stretch": "paper", "force": "physics_profile",
                                   "detect": "hist_gradient_boosting", "localise": "logistic"}
    assert 0 < summary["targets"]["cost_on_doubling"]["growth_per_doubling"][0]
    force = json.loads((bench / "lab_pairs/force.json").read_text())
    assert set(force["schemes"]["conditions"]["variants"]["paper"]["scores"]) == {"force1",
                                                                               "force2"}
    pairs = json.loads((bench / "lab_pairs/summary.json").read_text())
    assert pairs["defaults"]["localise"] == "active_terminals"  # two-force default (train.localise)
    assert "two or more stretch levels" in pairs["skipped"]["stretch"]
    assert "every sample of this scene has 2" in pairs["skipped"]["detect"]
    assert sorted(p.name for p in (bench / "lab_pairs/figures").iterdir()) == \
        ["force.png", "localise.png"]
    assert len(list((bench / "lab_single/figures").glob("*.png"))) == 4
    # the page the report links: every table of the Markdown, each task's plot beside it
    page = (bench / "lab_single/summary.html").read_text()
    assert page.count("<table>") == single.count("| variant |") > 0
    images = re.findall(r'<img src="([^"]+)"', page)
    assert sorted(images) == sorted(f"figures/{p.name}"
                                    for p in (bench / "lab_single/figures").iterdir())


def test_each_stage_reads_exactly_the_params_it_declares(benched):
    """The pipeline's stages and the bench stages, on data no simulator made (so the
    Bayes bound's stages here all take the short path: no simulator settings to read)."""
    assert params_mismatches(benched, params_trace_dir(benched),
                             partly_run={"bench/dvc.yaml:bound"}) == []
