"""The report: figures, plot data, the page (opened in headless Chromium), the results page."""

import functools
import html
import json
import re
from pathlib import Path
from types import SimpleNamespace
from urllib.parse import parse_qs, urlsplit

import numpy as np
import pandas as pd
import pytest
from conftest import headless_chromium, needs_chromium
from PIL import Image

from eskin.catalog import SCHEME_NOTES, SCHEMES
from eskin.config.report import Report
from eskin.kinds import get_kind
from eskin.reporting import presentation, report
from eskin.reporting.page import (
    Provenance,
    headline_markdown,
    headline_rows,
    render_page,
    results_markdown,
)
from eskin.reporting.presentation import (
    DETECTION,
    FORCE_PARITY,
    LOCALISATION_CONFUSION,
    STRETCH_PARITY,
)
from eskin.skin import PAPER_SKIN, Skin, skin_from_dict
from eskin.tracking import connection

# The commit the fixture's report says it ran on top of (a plain `dvc repro`).
COMMIT = "0123456789abcdef0123456789abcdef01234567"


def fake_outputs(root):
    """Predictions and scores shaped like the training stages' (small)."""
    rng = np.random.default_rng(0)

    def write(scene, task, frame, metrics):
        for sub in ("predictions", "scores"):
            (root / sub / scene).mkdir(parents=True, exist_ok=True)
        frame.to_parquet(root / "predictions" / scene / f"{task}.parquet")
        (root / "scores" / scene / f"{task}.json").write_text(json.dumps(
            {"scene": scene, "kind": scene, "task": task, "status": "trained",
             "dataset_md5": "0" * 32,
             "dataset_rows": 120, "source": "simulated", "model": "paper",
             "model_md5": f"{task:0>32}", **metrics}))

    n = 120
    schemes = np.repeat(["stratified", "conditions"], n // 2)
    stretch = rng.choice([1.0, 1.07921, 1.15842], n)
    force = rng.choice([0.0, 1.2936, 3.2536, 5.2136], n)
    node = rng.integers(1, 11, (n, 4))
    scores = {"stratified": {}, "conditions": {}}

    def regression(target, values):
        # each scheme its own numbers, so that a figure's score says which scheme it is
        return {s: {target: {"r2": r2, "r2_std": 0.01, "mse": 1e-5, "mse_std": 1e-6,
                             "rmse": 0.1, "rmse_std": 0.01}}
                for s, r2 in (("stratified", 0.9), ("conditions", 0.8))}

    def accuracy(*targets):
        return {s: {t: {"accuracy": value, "accuracy_std": 0.01, "balanced_accuracy": value,
                        "balanced_accuracy_std": 0.01} for t in targets}
                for s, value in (("stratified", 0.96), ("conditions", 0.93))}

    base = pd.DataFrame({"scheme": schemes, "stretch": stretch, "trial": np.arange(n).astype(str),
                         "sample": 0, "fold": np.arange(n) % 5})
    write("single_force", "stretch", base.assign(stretch_true=stretch,
                                                 stretch_pred=stretch + rng.normal(0, .01, n)),
          regression("stretch", stretch))
    write("single_force", "force",
          base.assign(force_true=force, force_pred=force + rng.normal(0, .3, n)),
          regression("force", force))
    contact = force > 0
    write("single_force", "detect", base.assign(contact_true=contact, contact_pred=contact,
                                                contact_score=contact + rng.normal(0, .3, n)),
          accuracy("contact"))
    write("single_force", "localise", base.assign(x_true=node[:, 0], x_pred=node[:, 0],
                                                  y_true=node[:, 1], y_pred=node[:, 1]),
          accuracy("x", "y"))
    two = base.assign(**{f"{c}_true": node[:, i] for i, c in enumerate(["x1", "y1", "x2", "y2"])},
                      **{f"{c}_pred": node[:, i] for i, c in enumerate(["x1", "y1", "x2", "y2"])})
    write("two_force", "localise", two, accuracy("x1", "y1", "x2", "y2"))
    write("two_force", "force", base.assign(force1_true=force + 1, force1_pred=force + 1.2,
                                            force2_true=force, force2_pred=force + 0.1),
          {s: {**regression("force1", force)[s], **regression("force2", force)[s]}
           for s in scores})
    (root / "scores" / "two_force" / "stretch.json").write_text(json.dumps(
        {"scene": "two_force", "kind": "two_force", "task": "stretch", "status": "skipped",
         "reason": "stretch regression needs two or more stretch levels; this scene has one"}))
    return root


SETTINGS = Report(schemes=["stratified", "conditions"], plots_scheme="stratified", dpi=60,
                  page_dpi=50)
# the report reads each scene's kind and skin only (none: the paper's)
SCENES = {"single_force": SimpleNamespace(kind="single_force", skin=None),
          "two_force": SimpleNamespace(kind="two_force", skin=None)}
# The MLflow experiment the fixture's page links its models' runs in.
EXPERIMENT_ID = "7"


def build(root, out, run):
    return report.report(report=SETTINGS, scenes=SCENES, scores_dir=root / "scores",
                         predictions_dir=root / "predictions", figures_dir=out / "figures",
                         plots_dir=out / "plots", page_path=out / "index.html",
                         results_path=out / "results.md", metrics_path=out / "metrics.json",
                         scene_metrics_dir=out / "metrics", run=run,
                         model_runs=functools.partial(connection.model_runs_url, EXPERIMENT_ID))


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = fake_outputs(tmp_path_factory.mktemp("report"))
    # as under `dvc exp run`: the page names the experiment and its baseline commit
    result = build(root, root, Provenance(commit=COMMIT, experiment="tidy-fern"))
    assert result.figures > 0
    return root, result.summary


@pytest.mark.heavy
def test_every_figure_is_written_as_png_and_svg_per_scheme(built):
    root, summary = built
    names = {p.relative_to(root / "figures").with_suffix("").as_posix()
             for p in (root / "figures").rglob("*.png")}
    # one naming scheme, <figure>_<scheme>, whatever the scene's kind
    expected = {f"{scene}/{fid}_{scheme}" for scheme in ("stratified", "conditions")
                for scene, fids in (("single_force", ("stretch_parity", "force_parity",
                                                      "localisation_confusion", "detection")),
                                    ("two_force", ("localisation_confusion", "force_parity")))
                for fid in fids}
    assert names == expected, summary
    assert {p.relative_to(root / "figures").with_suffix("").as_posix()
            for p in (root / "figures").rglob("*.svg")} == expected


@pytest.mark.heavy
def test_dvc_metrics_are_a_file_a_scene_one_number_a_target_without_skipped_tasks(built):
    root, _ = built
    assert json.loads((root / "metrics" / "single_force.json").read_text()) == {
        "stretch": 0.8, "force": 0.8, "contact": 0.93, "x": 0.93, "y": 0.93}
    # the report scores a two-contact scene's contacts as a set (from its predictions, the
    # file written beside its scores in a direct run), and the set stands for each
    # contact's own targets; a one-contact scene has no pairs file
    pairs = json.loads((root / "scores" / "two_force" / "pairs.json").read_text())
    assert pairs["status"] == "scored"
    assert json.loads((root / "metrics" / "two_force.json").read_text()) == {
        "pairs": pairs["conditions"]["pair_accuracy"],
        "pair_force": pairs["conditions"]["force_r2"]}
    assert not (root / "scores" / "single_force" / "pairs.json").exists()


def test_the_headline_is_one_table_named_by_scene_and_task_without_skipped_tasks(built):
    root, _ = built
    metrics = json.loads((root / "metrics.json").read_text())
    pairs = json.loads((root / "scores" / "two_force" / "pairs.json").read_text())["conditions"]
    assert metrics == {
        "single_force": {"stretch": {"r2": 0.8}, "force": {"r2": 0.8},
                         "detect": {"contact": {"accuracy": 0.93}},
                         "localise": {"x": {"accuracy": 0.93}, "y": {"accuracy": 0.93}}},
        "two_force": {"force": {"force1": {"r2": 0.8}, "force2": {"r2": 0.8}},
                      "localise": {t: {"accuracy": 0.93} for t in ("x1", "y1", "x2", "y2")},
                      "pairs": {name: pairs[name]
                                for name in ("pair_accuracy", "ghost_share", "force_r2")}}}


def test_dvc_plot_data_has_the_columns_dvc_yaml_names(built):
    root, _ = built
    confusion = pd.read_csv(root / "plots" / "confusion" / "single_force_x.csv")
    assert list(confusion.columns) == ["actual", "predicted", "count", "panel"]
    assert set(confusion["panel"]) == {"single_force: x terminal"}  # the panel's title
    assert confusion["count"].sum() == 60  # every stratified prediction, counted
    contact = pd.read_csv(root / "plots" / "confusion" / "single_force_contact.csv")
    assert set(contact["actual"]) <= {"contact", "none"}
    parity = pd.read_csv(root / "plots" / "parity" / "single_force_force.csv")
    assert list(parity.columns) == ["actual", "predicted", "stretch", "panel"]
    assert len(parity) == 60  # the stratified half only
    assert {p.stem for p in (root / "plots").rglob("*.csv")} == {
        "single_force_stretch", "single_force_force", "two_force_force1", "two_force_force2",
        "single_force_contact", "single_force_x", "single_force_y",
        *(f"two_force_{t}" for t in ("x1", "y1", "x2", "y2"))}


def test_results_page_has_each_scene_in_order(built):
    root, _ = built
    results = (root / "results.md").read_text()
    assert results.startswith("# Results\n")
    assert "| force R² [paper] | 0.900 ± 0.010 | 0.800 ± 0.010 | 0.827 |" in results
    assert results.index("## single_force (single force)") < results.index(
        "## two_force (two force)")
    assert "two_force/stretch skipped: stretch regression needs two or more" in results


def test_missing_and_skipped_tasks_say_so_in_the_table():
    rows = headline_rows("single_force", {"stretch": {"status": "skipped"}})
    by_label = {r[0]: r for r in rows}
    assert by_label["stretch R²"][1:3] == ["skipped", "skipped"]
    assert by_label["force R²"][1:3] == ["missing", "missing"]


def test_the_paper_column_is_only_beside_the_papers_kind_on_its_skin():
    """Issue 59: a magnetic array's force R² sat beside the paper's capacitive 0.827."""
    force = {"model": "m", "stratified": {"force": {"r2": 0.9, "r2_std": 0.01}},
             "conditions": {"force": {"r2": 0.8, "r2_std": 0.02}}}
    array = skin_from_dict({"channels": [f"m{i}" for i in range(15)], "grid": [3, 3]})
    tables = {name: headline_markdown(kind, {"force": force}, skin).splitlines()
              for name, kind, skin in [("paper", "single_force", PAPER_SKIN),
                                       ("two", "two_force", PAPER_SKIN),
                                       ("array", "single_force", array),
                                       ("16x16", "single_force", Skin(16, 16)),
                                       ("total", "two_force_total", PAPER_SKIN)]}
    assert tables["paper"][0].endswith("| paper |")
    assert tables["two"][0].endswith("| paper |")
    assert "| 0.827 |" in next(line for line in tables["paper"] if "force R²" in line)
    for name in ("array", "16x16", "total"):
        assert tables[name][0] == ("| metric | stratified CV (the paper's) | conditions CV "
                                   "(whole conditions out) |"), name
        assert all(line.count("|") == 4 for line in tables[name]), name
        assert "0.827" not in "\n".join(tables[name]) and "0.96" not in "\n".join(tables[name])
    results = results_markdown([("paper", "single_force", PAPER_SKIN, {"force": force}),
                                ("magnetic", "single_force", array, {"force": force})])
    paper, magnetic = results.split("## magnetic")
    assert "| paper |" in paper and "| paper |" not in magnetic and "0.827" not in magnetic


def test_a_scene_scored_under_trials_gets_its_column_and_others_do_not():
    force = {"model": "m", "stratified": {"force": {"r2": 0.9, "r2_std": 0.01}},
             "conditions": {"force": {"r2": 0.8, "r2_std": 0.02}}}
    once = headline_markdown("single_force", {"force": force}).splitlines()[0]
    assert once == ("| metric | stratified CV (the paper's) | conditions CV (whole conditions out) "
                    "| paper |")
    twice = {"force": {**force, "trials": {"force": {"r2": 0.85, "r2_std": 0.03}}}}
    table = headline_markdown("single_force", twice).splitlines()
    assert table[0].endswith("| trials CV (new trials of seen conditions) | paper |")
    assert table[1] == "|---|---|---|---|---|"
    row = next(line for line in table if line.startswith("| force R²"))
    assert "| 0.900 ± 0.010 | 0.800 ± 0.020 | 0.850 ± 0.030 |" in row


@needs_chromium
@pytest.mark.starts
def test_the_page_loads_every_image_in_headless_chromium(built):
    root, _ = built
    with headless_chromium() as browser:
        page = browser.new_page()
        page.goto((root / "index.html").as_uri())
        page.wait_for_load_state("load")
        widths = page.eval_on_selector_all("img", "imgs => imgs.map(i => i.naturalWidth)")
        headline = page.eval_on_selector_all(
            "#scene-single_force table tbody tr", "rows => rows.map(r => r.cells[0].innerText)")
        skipped = page.inner_text("#scene-two_force ul")
        models = page.inner_text("h2:text('Models') + p + table")
    assert len(widths) == 12 and all(w > 0 for w in widths), widths
    rows = presentation.headlines(get_kind("single_force"))
    # every row but the position error in mm, which a skin placed in mm alone has
    assert [h.split(' [')[0] for h in headline] == [row.label for row in rows
                                                    if not row.optional]
    assert "stretch: stretch regression needs two or more stretch levels" in skipped
    assert headline[0] == f"{rows[0].label} [paper]"
    assert "00000000000000000000000000force" in models


# The headline score each figure states, by scheme (the fixture's scores files).
HEADLINE = {("single_force", STRETCH_PARITY): ("stretch", "stretch R² {r2}"),
            ("single_force", FORCE_PARITY): ("force", "force R² {r2}"),
            ("single_force", LOCALISATION_CONFUSION): ("localise", "accuracy: x {acc}, y {acc}"),
            ("single_force", DETECTION): ("detect", "contact accuracy {acc}"),
            ("two_force", LOCALISATION_CONFUSION): ("localise", "accuracy: x1 {acc}, y1 {acc}"),
            ("two_force", FORCE_PARITY): ("force", "R²: force1 {r2}, force2 {r2}")}
SCORES = {"stratified": {"r2": "0.900 ± 0.010", "acc": "0.960 ± 0.010"},
          "conditions": {"r2": "0.800 ± 0.010", "acc": "0.930 ± 0.010"}}
NOTES = {"stratified": "the paper's: stratified on the node",
         "conditions": "whole conditions held out"}


def svg_metadata(path):
    """(<title>, dc:description) of a matplotlib SVG."""
    text = path.read_text()
    title = re.search(r"<title>(.*?)</title>", text, re.S)
    description = re.search(r"<dc:description>(.*?)</dc:description>", text, re.S)
    unescape = {"&amp;": "&", "&lt;": "<", "&gt;": ">", "&quot;": '"', "&#x27;": "'",
                "&apos;": "'"}

    def clean(match):
        value = match.group(1) if match else ""
        for entity, char in unescape.items():
            value = value.replace(entity, char)
        return value

    return clean(title), clean(description)


def test_every_figure_file_says_its_scene_task_scheme_n_and_score(built):
    """Opened from a folder, MLflow or a slide, a figure says what it shows: its PNG and
    SVG metadata (what is also written at its top) name the scene, the task, the CV
    scheme, n and the scheme's own headline score."""
    root, _ = built
    assert set(SCHEME_NOTES) == set(SCHEMES)  # every scheme says what it holds out
    checked = 0
    for (scene, fid), (task, score) in HEADLINE.items():
        for scheme in ("stratified", "conditions"):
            png = root / "figures" / scene / f"{fid}_{scheme}.png"
            with Image.open(png) as image:
                title, description = image.text.get("Title", ""), image.text.get("Description", "")
            svg_title, svg_description = svg_metadata(png.with_suffix(".svg"))
            expected_score = score.format(**SCORES[scheme])
            for where, (head, body) in (("png", (title, description)),
                                        ("svg", (svg_title, svg_description))):
                assert scene in head and f"{scheme} CV" in head, (where, png, head)
                assert f"{scene} · {task} · {scheme} CV" in body, (where, png, body)
                assert NOTES[scheme] in body, (where, png, body)
                assert "n = 60 out-of-fold predictions" in body, (where, png, body)
                assert expected_score in body, (where, png, expected_score, body)
            checked += 1
    assert checked == 12


@pytest.mark.heavy
def test_the_report_names_the_experiment_and_is_the_same_on_a_rerun(built, tmp_path):
    """An experiment's page names it and its baseline commit; a rerun gives the same
    bytes; a plain run's page names no commit, so it is the same at every commit."""
    root, _ = built
    build(root, tmp_path, Provenance(commit=COMMIT, experiment="tidy-fern"))
    for name in ["index.html", *(p.relative_to(root).as_posix()
                                 for p in (root / "figures").rglob("*.*"))]:
        assert (tmp_path / name).read_bytes() == (root / name).read_bytes(), name
    page = (root / "index.html").read_text()
    assert (f"<title>eskin report: experiment tidy-fern, run on top of commit {COMMIT[:8]}"
            "</title>") in page
    assert "<code>tidy-fern</code>" in page
    assert "force physics_profile" not in page and "force paper" in page  # the models used
    plain = render_page([], {}, Provenance())
    assert "<title>eskin report: the checked-out pipeline, no experiment</title>" in plain
    assert "none: a plain <code>dvc repro</code>" in plain


def test_provenance_is_what_dvc_exp_run_gives_and_nothing_under_a_plain_repro(tmp_path):
    under_exp = report.provenance({"DVC_EXP_NAME": "tidy-fern",
                                   "DVC_EXP_BASELINE_REV": COMMIT})
    assert (under_exp.experiment, under_exp.commit) == ("tidy-fern", COMMIT)
    assert report.provenance({}) == Provenance()


@needs_chromium
@pytest.mark.starts
def test_the_page_has_contents_schemes_side_by_side_and_its_commit_in_the_title(built):
    root, _ = built
    with headless_chromium() as browser:
        # wide enough for every figure side by side, 10-class confusion matrices too
        page = browser.new_page(viewport={"width": 2400, "height": 1000})
        page.goto((root / "index.html").as_uri())
        page.wait_for_load_state("load")
        title, heading = page.title(), page.inner_text("h1")
        links = page.eval_on_selector_all("nav#contents a", "as => as.map(a => a.hash)")
        assert links, "no table of contents (nav#contents)"
        targets = page.evaluate(
            "hashes => hashes.map(h => document.getElementById(h.slice(1)) !== null)", links)
        rows = page.eval_on_selector_all("section.figure", """sections => sections.map(s => [
            s.id, [...s.querySelectorAll('figure')].map(f => {
                const r = f.getBoundingClientRect();
                return [f.dataset.scheme, Math.round(r.top), Math.round(r.left)]; })])""")
        page.click("nav#contents a[href='#single_force-force_parity']")
        page.wait_for_timeout(200)
        jumped = page.evaluate(
            "document.getElementById('single_force-force_parity').getBoundingClientRect().top")
    assert COMMIT[:8] in title and COMMIT[:8] in heading, (title, heading)
    assert all(targets) and len(links) == len(targets)
    expected = {f"#{scene}-{fid}" for (scene, fid) in HEADLINE} | {
        "#scene-single_force", "#scene-two_force", "#models"}
    assert expected <= set(links), links
    assert len(rows) == 6, rows
    for row_id, shown in rows:
        assert [s for s, _, _ in shown] == ["stratified", "conditions"], (row_id, shown)
        (_, top1, left1), (_, top2, left2) = shown
        assert top1 == top2 and left2 > left1, (row_id, shown)  # one row, side by side
    assert abs(jumped) < 5, jumped  # the contents' link lands on its figure


def model_links(page: str) -> dict[str, tuple[str, str]]:
    """scene/task → (md5, link) of each row of the page's models table."""
    return {task: (md5, html.unescape(href)) for task, href, md5 in re.findall(
        r'<tr><td>([^<]+)</td><td>[^<]*</td><td><a href="([^"]+)"><code>([^<]+)</code>',
        page)}


def test_each_models_md5_links_to_the_mlflow_runs_that_carry_it(built):
    """The report is written before the publish stage: no run id, so a model's link is
    the experiment's runs table filtered by the model's md5 tag, on the UI's runs route
    (from the experiment's, the UI redirects there and drops the filter), sorted by name
    (sorted by date, the UI nests a task run, closed, under its pipeline run)."""
    root, _ = built
    links = model_links((root / "index.html").read_text())
    expected = {f"{scene}/{task}": json.loads(path.read_text())["model_md5"]
                for scene in SCENES for path in sorted((root / "scores" / scene).glob("*.json"))
                if (task := path.stem) and "model_md5" in json.loads(path.read_text())}
    assert {task: md5 for task, (md5, _) in links.items()} == expected
    for task, (md5, link) in links.items():
        url = urlsplit(link)
        route, _, query = url.fragment.partition("?")
        assert f"{url.scheme}://{url.netloc}" == connection.ui_base(), link
        assert route == f"/experiments/{EXPERIMENT_ID}/runs", link
        assert parse_qs(query) == {"searchFilter": [f"tags.`eskin.model_md5` = '{md5}'"],
                                   "orderByKey": ["tags.`mlflow.runName`"],
                                   "orderByAsc": ["true"],
                                   "workflowType": ["machine_learning"]}, (task, link)


@needs_chromium
@pytest.mark.starts
def test_a_models_link_opens_the_mlflow_ui_on_its_runs_alone(built, mlflow_server,
                                                              monkeypatch, tmp_path):
    """On a real `mlflow server`, the experiment found as the publish stage finds it, runs
    logged as the publish stage logs them (a pipeline run, a task run under it per model):
    the page's link of a model, clicked in headless Chromium, lists the runs of that
    model's md5 and no other (the fixture's force models of both scenes share theirs)."""
    import mlflow

    root, _ = built
    monkeypatch.setenv("MLFLOW_TRACKING_URI", mlflow_server)
    experiment = connection.ensure_experiment()
    client = mlflow.MlflowClient(mlflow_server)
    scores = {scene: {path.stem: json.loads(path.read_text())
                      for path in (root / "scores" / scene).glob("*.json")} for scene in SCENES}
    pipeline = client.create_run(experiment, run_name="repro-0123abcd").info.run_id
    named = {}  # run name: model md5
    for scene, by_task in scores.items():
        for task, document in by_task.items():
            if "model_md5" in document:
                name = f"{scene}/{task} @repro-0123abcd"
                named[name] = document["model_md5"]
                run = client.create_run(experiment, run_name=name,
                                        tags={"mlflow.parentRunId": pipeline,
                                              "eskin.model_md5": document["model_md5"]})
                client.set_terminated(run.info.run_id)
    client.set_terminated(pipeline)
    page_path = tmp_path / "index.html"
    page_path.write_text(render_page(
        [(scene, scene, PAPER_SKIN, by_task) for scene, by_task in scores.items()], {},
        Provenance(), model_runs=functools.partial(connection.model_runs_url, experiment)))
    md5, link = model_links(page_path.read_text())["single_force/force"]
    assert link.startswith(f"{mlflow_server}/#/experiments/{experiment}/runs?"), link
    with headless_chromium() as browser:
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto(page_path.as_uri())
        page.click(f"#models-table a[href*='{md5}']")
        page.wait_for_selector("text=single_force/force @repro-0123abcd", timeout=60_000)
        listed = page.eval_on_selector_all("a[href*='/runs/']", "as => as.map(a => a.innerText)")
        footer = page.inner_text("text=matching run")  # "1 matching run", "6 matching runs"
    expected = sorted(name for name, its in named.items() if its == md5)
    assert expected == ["single_force/force @repro-0123abcd", "two_force/force @repro-0123abcd"]
    assert [name for name in listed if "repro-" in name] == expected, listed
    assert footer.split()[0] == "2", footer


def smallest_text_pt(figure) -> float:
    """The smallest font size (points) of the text drawn in ``figure``: every visible,
    non-empty text of a visible axes (or of the figure) that takes room when drawn."""
    from matplotlib.text import Text

    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    return min(text.get_fontsize() for text in figure.findobj(Text)
               if text.get_visible() and text.get_text().strip()
               and (text.axes is None or text.axes.get_visible())
               and text.get_window_extent(renderer).width > 0)


@needs_chromium
@pytest.mark.starts
def test_every_text_of_every_figure_is_at_least_10_px_on_the_page_at_1400_px(built):
    """The smallest text of each figure, as shown on the page in a 1,400 px window: its
    size in points (from the figure drawn again from the same predictions) times the
    CSS px per inch the page shows the figure at (the image's width in Chromium over
    its width in inches: natural px / page dpi). Bar labels were 7 px, a 10-class
    confusion matrix's counts 6.4 px."""
    import matplotlib.pyplot as plt

    from eskin.config.scenes import scene_skin
    from eskin.reporting import figures

    root, _ = built
    with headless_chromium() as browser:
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto((root / "index.html").as_uri())
        page.wait_for_load_state("load")
        assert page.evaluate("window.devicePixelRatio") == 1
        shown = {row[0]: row[1:] for row in page.eval_on_selector_all(
            "figure img", """imgs => imgs.map(i => [i.closest('figure').id, i.clientWidth,
                i.naturalWidth, Math.round(i.getBoundingClientRect().top)])""")}
    assert len(shown) == 12, shown
    sizes, tops = {}, {}
    for scene, conf in SCENES.items():
        for spec in presentation.figures(get_kind(conf.kind)):
            path = root / "predictions" / scene / f"{spec.task}.parquet"
            if not path.exists():
                continue
            document = json.loads((root / "scores" / scene / f"{spec.task}.json").read_text())
            for scheme in SETTINGS.schemes:
                frame = pd.read_parquet(path)
                oof = frame[frame["scheme"] == scheme]
                drawn = report.draw(spec, oof, scene_skin(conf))
                figures.identify(drawn, report.identity(scene, spec, scheme, oof,
                                                        document).heading)
                width_px, natural_px, top = shown[f"{scene}-{spec.id}_{scheme}"]
                inches = natural_px / SETTINGS.page_dpi
                assert inches == pytest.approx(drawn.get_figwidth(), abs=1 / SETTINGS.page_dpi)
                sizes[(scene, spec.id, scheme)] = smallest_text_pt(drawn) / 72 * width_px / inches
                tops.setdefault((scene, spec.id), []).append(top)
                plt.close(drawn)
    assert len(sizes) == 12
    small = {k: round(v, 1) for k, v in sizes.items() if v < 10}
    assert not small, small
    # the layout that gives it: page-wide figures side by side, but a 10-class confusion
    # matrix (5 pt counts) one under the other
    stacked = {key for key, (first, second) in tops.items() if first != second}
    assert stacked == {("single_force", LOCALISATION_CONFUSION),
                       ("two_force", LOCALISATION_CONFUSION)}, tops


def test_a_continuous_force_is_summarised_in_a_few_bins():
    """A load cell's force (an imported recording) has a distinct value per row: its
    spread panel has a bar per bin, not per value."""
    from eskin.reporting import figures

    rng = np.random.default_rng(0)
    true = rng.uniform(0.0, 5.0, 3000)
    oof = pd.DataFrame({"force_true": true, "force_pred": true + rng.normal(0, 0.2, 3000),
                        "stretch": 1.0})
    drawn = figures.force_parity(oof)
    parity, spread = drawn.axes
    assert len(spread.patches) == figures.LEVEL_BINS
    assert len(spread.get_xticklabels()) == figures.LEVEL_BINS
    assert spread.get_title() == "spread per bin"
    # every level a bin's centre, inside the range of the true force
    centres = [float(label.get_text()) for label in spread.get_xticklabels()]
    assert 0.0 < min(centres) < 0.5 and 4.5 < max(centres) < 5.0
    # a few levels (the paper's weights) stay levels
    levels = oof.assign(force_true=np.repeat([0.0, 1.2936, 3.2536, 5.2136], 750))
    assert figures.force_parity(levels).axes[1].get_title() == "spread per level"


def _cached(cache, function: str) -> set:
    """The calls of ``function`` a cache holds: joblib's Memory keeps each call's output in
    a folder, under one a function."""
    return {path.parent.name for path in cache.rglob(f"{function}/*/output.pkl")}


def _cached_figures(cache) -> set:
    return _cached(cache, "draw_figure")


@pytest.mark.heavy
def test_the_figure_cache_redraws_only_the_figures_whose_data_changed(tmp_path):
    """An experiment that changes one model changes its task's predictions only: the
    report then draws that task's figures and scores that scene's pairs, reads the rest
    from the cache, and every file is byte for byte what drawing and scoring them all
    gives."""
    root = fake_outputs(tmp_path / "in")
    cache = tmp_path / "cache"

    def files(out):
        return {p.relative_to(out).as_posix(): p.read_bytes()
                for p in sorted(out.rglob("*")) if p.is_file()}

    def run(out, cache):
        return report.report(
            report=SETTINGS, scenes=SCENES, scores_dir=root / "scores",
            predictions_dir=root / "predictions", figures_dir=out / "figures",
            plots_dir=out / "plots", page_path=out / "index.html",
            results_path=out / "results.md", metrics_path=out / "metrics.json",
            run=Provenance(commit=COMMIT), cache=cache)

    drawn = run(tmp_path / "drawn", None)
    run(tmp_path / "first", cache)
    assert len(_cached_figures(cache)) == drawn.figures
    assert files(tmp_path / "first") == files(tmp_path / "drawn")
    before, scored = _cached_figures(cache), _cached(cache, "scored_pairs")
    assert len(scored) == len(SCENES)  # each scene's localise predictions, paired
    run(tmp_path / "again", cache)  # nothing changed: nothing drawn, nothing scored
    assert _cached_figures(cache) == before
    assert _cached(cache, "scored_pairs") == scored
    assert files(tmp_path / "again") == files(tmp_path / "drawn")

    # one model's predictions change (the single-force scene's force task)
    path = root / "predictions" / "single_force" / "force.parquet"
    changed = pd.read_parquet(path)
    changed["force_pred"] = changed["force_pred"] + 0.05
    changed.to_parquet(path)
    run(tmp_path / "changed", cache)
    force_figures = sum(spec.task == "force" for spec in
                        presentation.figures(get_kind("single_force"))) * len(SETTINGS.schemes)
    assert len(_cached_figures(cache) - before) == force_figures > 0
    assert len(_cached(cache, "scored_pairs") - scored) == 1  # that scene's only
    assert files(tmp_path / "changed") == files(run(tmp_path / "redrawn", None).figures_dir.parent)


def test_a_project_of_one_contact_scenes_still_has_its_pairs_directory(tmp_path):
    """reports/pairs is the publish stage's DVC output: DVC refuses a stage whose output is
    missing, so the directory is made (empty) where no scene has two contacts — as a lab
    with one-contact skins only found (`dvc repro`: "output 'reports/pairs' does not
    exist")."""
    pairs_dir = tmp_path / "reports" / "pairs"
    report._score_pairs({"lab8": {"stretch": {}}}, {"lab8": {}}, pairs_dir, tmp_path / "scores")
    assert pairs_dir.is_dir() and not any(pairs_dir.iterdir())


def test_every_kinds_figure_names_a_registered_drawer_and_a_typo_is_named():
    """A kind's figure names its drawer (presentation.py); the report draws through the
    registry, and a name nobody registered is one line naming the figure and the fix."""
    from eskin.kinds import KINDS
    from eskin.reporting import figures

    for kind in KINDS.values():
        for spec in presentation.figures(kind):
            assert spec.draw in figures.DRAWERS, f"{kind.name}: {spec.id} names {spec.draw!r}"
    typo = presentation.Figure(presentation.DETECTION, "detect", "", "detektion", ())
    with pytest.raises(ValueError, match="'detektion'.*@drawer.*detection"):
        report.draw(typo, pd.DataFrame(), PAPER_SKIN)


def test_the_pairs_code_version_reads_every_module_the_scoring_imports(monkeypatch):
    """The pairs' cache key names the scoring code by its sources: every eskin module
    pairs.py imports, at any depth (eskin.steps.code finds them), is read for it."""
    from eskin.steps.code import code_files

    read = set()
    original = Path.read_bytes

    def spy(self):
        read.add(self.resolve())
        return original(self)

    monkeypatch.setattr(Path, "read_bytes", spy)
    report.pairs_code()
    pairs = Path(report.__file__).parents[1] / "evaluation" / "pairs.py"
    # the packages' __init__ files hold no scoring (eskin's sets the thread environment)
    assert {path for path in code_files(str(pairs)) if path.name != "__init__.py"} <= read
