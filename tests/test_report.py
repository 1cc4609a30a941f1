"""The report: figures, plot data, the page (opened in headless Chromium), the results page."""

import json
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import headless_chromium, needs_chromium

from eskin.config import Report
from eskin.kinds import get_kind
from eskin.reporting import report
from eskin.reporting.page import headline_rows


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
    schemes = np.repeat(["stratified", "grouped"], n // 2)
    stretch = rng.choice([1.0, 1.07921, 1.15842], n)
    force = rng.choice([0.0, 1.2936, 3.2536, 5.2136], n)
    node = rng.integers(1, 11, (n, 4))
    scores = {"stratified": {}, "grouped": {}}

    def regression(target, values):
        return {s: {target: {"r2": 0.9, "r2_std": 0.01, "mse": 1e-5, "mse_std": 1e-6,
                             "rmse": 0.1, "rmse_std": 0.01}} for s in scores}

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
          {s: {"contact": {"accuracy": 0.96, "accuracy_std": 0.01}} for s in scores})
    write("single_force", "localise", base.assign(x_true=node[:, 0], x_pred=node[:, 0],
                                                  y_true=node[:, 1], y_pred=node[:, 1]),
          {s: {"x": {"accuracy": 1.0, "accuracy_std": 0.0}} for s in scores})
    two = base.assign(**{f"{c}_true": node[:, i] for i, c in enumerate(["x1", "y1", "x2", "y2"])},
                      **{f"{c}_pred": node[:, i] for i, c in enumerate(["x1", "y1", "x2", "y2"])})
    write("two_force", "localise", two, {})
    write("two_force", "force", base.assign(force1_true=force + 1, force1_pred=force + 1.2,
                                            force2_true=force, force2_pred=force + 0.1),
          {s: {**regression("force1", force)[s], **regression("force2", force)[s]}
           for s in scores})
    (root / "scores" / "two_force" / "stretch.json").write_text(json.dumps(
        {"scene": "two_force", "kind": "two_force", "task": "stretch", "status": "skipped",
         "reason": "stretch regression needs two or more stretch levels; this scene has one"}))
    return root


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = fake_outputs(tmp_path_factory.mktemp("report"))
    settings = Report(schemes=["stratified", "grouped"], plots_scheme="stratified", dpi=60,
                      page_dpi=50)
    # the report reads each scene's kind only
    scenes = {"single_force": SimpleNamespace(kind="single_force"),
              "two_force": SimpleNamespace(kind="two_force")}
    result = report.report(report=settings, scenes=scenes, scores_dir=root / "scores",
                           predictions_dir=root / "predictions",
                           figures_dir=root / "figures", plots_dir=root / "plots",
                           page_path=root / "index.html", results_path=root / "results.md")
    assert result.figures > 0
    return root, result.summary


def test_every_figure_is_written_as_png_and_svg_per_scheme(built):
    root, summary = built
    names = {p.relative_to(root / "figures").with_suffix("").as_posix()
             for p in (root / "figures").rglob("*.png")}
    expected = {f"{scene}/{fid}_{scheme}" for scheme in ("stratified", "grouped")
                for scene, fids in (("single_force", ("stretch_parity", "force_parity",
                                                      "localisation_confusion", "detection")),
                                    ("two_force", ("two_force_localisation",
                                                   "two_force_parity")))
                for fid in fids}
    assert names == expected, summary
    assert {p.relative_to(root / "figures").with_suffix("").as_posix()
            for p in (root / "figures").rglob("*.svg")} == expected


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
    assert "| force R² [paper] | 0.900 ± 0.010 | 0.900 ± 0.010 | 0.827 |" in results
    assert results.index("## single_force (single force)") < results.index(
        "## two_force (two force)")
    assert "two_force/stretch skipped: stretch regression needs two or more" in results


def test_missing_and_skipped_tasks_say_so_in_the_table():
    rows = headline_rows("single_force", {"stretch": {"status": "skipped"}})
    by_label = {r[0]: r for r in rows}
    assert by_label["stretch R²"][1:3] == ["skipped", "skipped"]
    assert by_label["force R²"][1:3] == ["missing", "missing"]


@needs_chromium
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
    rows = get_kind("single_force").headlines
    assert [h.split(' [')[0] for h in headline] == [row.label for row in rows]
    assert "stretch: stretch regression needs two or more stretch levels" in skipped
    assert headline[0] == f"{rows[0].label} [paper]"
    assert "00000000000000000000000000force" in models
