"""The stack as one ONNX file (eskin.deploy.export) against the scikit-learn stack it came from.

Synthetic stacks built to reach every converter and its corners: ties between terminals
(which peak TopK picks), rows with fewer than two peaks, NaN readings (the trees' missing
branch), a tree that is a single leaf, two and three classes, each featurizer. The stacks
trained on the simulated skin are checked by the train stage's export itself (tests of the
pipeline) and live in tests/test_live.py.
"""

from __future__ import annotations

import numpy as np
import onnx
import pandas as pd
import pytest
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.ensemble import HistGradientBoostingClassifier, HistGradientBoostingRegressor

from eskin.deploy.export import ExportError, compare, stack_to_onnx, write_stack
from eskin.deploy.stack import ExportedStack, RestTable, SkinStack
from eskin.evaluation.crossval import channel_frame
from eskin.learning.estimators import REGISTRY, ActiveTerminals, ForceProfile, build_model
from eskin.learning.features import make_featurizer
from eskin.skin import PAPER_SKIN, ChannelArray, Skin

CHANNELS = PAPER_SKIN.channels


def readings(n: int, seed: int, skin: Skin = PAPER_SKIN) -> np.ndarray:
    """ADC-like counts of ``skin``'s terminals: integers, so that neighbours tie; a press
    lifts a few terminals of each axis."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(500, 504, size=(n, skin.terminals)).astype(float)
    for row in range(n):
        for start, width in ((0, skin.rows), (skin.rows, skin.columns)):
            for _ in range(rng.integers(0, 3)):  # 0, 1 or 2 presses: 0 to 2 peaks
                at = start + rng.integers(0, width)
                counts[row, at] += rng.integers(1, 40)
    return counts


def fitted(role: str, name: str, X, y, **hyper):
    return build_model(role, name, hyper, PAPER_SKIN).fit(pd.DataFrame(X, columns=CHANNELS), y)


def exported(stack: SkinStack, tmp_path) -> ExportedStack:
    return ExportedStack.from_file(write_stack(stack, tmp_path / "stack.onnx", sources={}))


def assert_same(stack: SkinStack, onnx_stack: ExportedStack, X: np.ndarray) -> None:
    report = compare(onnx_stack, stack, X)
    for name, found in report["estimates"].items():
        assert found["differing_alone"] == 0, (name, found)


@pytest.mark.parametrize("featurizer", ["raw", "standardise", "baseline"])
def test_a_single_force_stack_exports_with_the_same_estimates(featurizer, tmp_path):
    X = readings(1500, seed=1)
    press = X.max(axis=1) - np.median(X, axis=1)
    contact = press > 20
    force = np.where(contact, press / 10, 0.0)
    stretch = 1 + (X.sum(axis=1) % 7) / 100
    where = np.argmax(X[:, :10], axis=1) + 1
    transform = make_featurizer(featurizer).fit(pd.DataFrame(X, columns=CHANNELS))
    F = np.asarray(transform.transform(pd.DataFrame(X, columns=CHANNELS)))
    models = {
        "stretch": {"stretch": fitted("stretch", "paper", F, stretch)},
        "force": {"force": fitted("force", "physics_profile", F, force, max_iter=30)},
        "detect": {"contact": fitted("detect", "hist_gradient_boosting", F, contact,
                                     max_iter=20)},
        "localise": {"x": fitted("localise", "logistic", F, where),
                     "y": fitted("localise", "hist_gradient_boosting", F, where % 3,
                                 max_iter=10)},
    }
    stack = SkinStack("synthetic", "single_force", PAPER_SKIN, transform, models,
                      rest=RestTable(np.array([1.0]), X[~contact].mean(axis=0)[None, :]))
    onnx_stack = exported(stack, tmp_path)
    assert_same(stack, onnx_stack, readings(800, seed=2))
    assert onnx_stack.columns == stack.columns and onnx_stack.kind == "single_force"
    assert onnx_stack.rest.as_dict() == stack.rest.as_dict()


def test_a_two_force_stack_exports_with_the_same_estimates(tmp_path):
    X = readings(1500, seed=3)
    peaks = np.argsort(X[:, :10], axis=1, kind="stable")[:, -2:]
    models = {
        "localise": {f"x{i + 1}": fitted("localise", "active_terminals", X,
                                          np.sort(peaks, axis=1)[:, i] // 4, max_iter=15)
                     for i in range(2)},  # three classes
        "force": {"force1": fitted("force", "hist_gradient_boosting", X, X[:, 4] - 500,
                                   max_iter=15),
                  "force2": fitted("force", "random_forest", X, X[:, 14], n_estimators=5)},
    }
    stack = SkinStack("synthetic", "two_force", PAPER_SKIN, make_featurizer("raw").fit(
        pd.DataFrame(X, columns=CHANNELS)), models, skipped={"stretch": "one level"})
    onnx_stack = exported(stack, tmp_path)
    test = readings(800, seed=4)
    assert_same(stack, onnx_stack, test)
    estimates = onnx_stack.predict(test)
    assert estimates["stretch"].isna().all() and estimates["y1"].isna().all()


def test_a_counting_two_force_stack_places_only_the_contacts_it_counts(tmp_path):
    """A two-contact stack trained with fewer contacts on some samples counts them (0, 1
    or 2), and places and weighs that many, in scikit-learn and in ONNX alike."""
    X = readings(1500, seed=5)
    lifted = X[:, :10] - 500
    count = np.clip((lifted > 10).sum(axis=1), 0, 2)  # what the peaks say, capped at two
    peaks = np.sort(np.argsort(X[:, :10], axis=1, kind="stable")[:, -2:], axis=1)
    models = {
        "detect": {"contacts": fitted("detect", "hist_gradient_boosting", X, count,
                                      max_iter=20)},
        "localise": {f"{axis}{i + 1}": fitted("localise", "active_terminals", X,
                                               np.where(count > i, peaks[:, i] // 4 + 1, 0),
                                               max_iter=15)
                     for i in range(2) for axis in "xy"},
        "force": {f"force{i + 1}": fitted("force", "hist_gradient_boosting", X,
                                          np.where(count > i, lifted.max(axis=1) / 10, 0.0),
                                          max_iter=15) for i in range(2)},
    }
    stack = SkinStack("counting", "two_force", PAPER_SKIN, make_featurizer("raw").fit(
        pd.DataFrame(X, columns=CHANNELS)), models, skipped={"stretch": "one level"})
    assert stack.columns[:4] == ["stretch", "contact", "contact_probability", "contacts"]
    onnx_stack = exported(stack, tmp_path)
    assert onnx_stack.columns == stack.columns
    test = readings(800, seed=6)
    assert_same(stack, onnx_stack, test)
    estimates = stack.predict(test)
    counted = estimates["contacts"].to_numpy()
    assert set(np.unique(counted)) == {0, 1, 2}, "the readings press 0, 1 and 2 terminals"
    assert (estimates["contact"] == (counted > 0)).all()
    for k in (1, 2):  # contact k is placed and weighed exactly where k or more press
        placed = estimates[f"x{k}"].notna().to_numpy()
        np.testing.assert_array_equal(placed, counted >= k)
        assert (estimates.loc[~placed, f"force{k}"] == 0).all()
    probability = estimates["contact_probability"].to_numpy()
    assert probability[counted == 0].max() < 0.5 <= probability[counted > 0].min()


def test_a_missing_value_takes_the_branch_each_split_learnt(tmp_path):
    import onnxruntime

    from eskin.deploy.export import OPSETS, _convert, _register

    _register()
    X = readings(1500, seed=10)
    X[::5, 2] = np.nan  # seen in training: each split on x3 learns where NaN goes
    y = np.nan_to_num(X[:, 2], nan=560.0) + X[:, 11]
    for model in (HistGradientBoostingRegressor(max_iter=10).fit(X, y),
                  HistGradientBoostingClassifier(max_iter=10).fit(X, y > np.median(y))):
        converted = _convert(model, "x", 20)
        for opset in converted.opset_import:
            opset.version = OPSETS[opset.domain]
        session = onnxruntime.InferenceSession(converted.SerializeToString())
        test = readings(400, seed=11)
        test[::3, 2] = np.nan
        ours = session.run(None, {"x": test})
        if hasattr(model, "classes_"):
            np.testing.assert_array_equal(ours[0], model.predict(test))
            np.testing.assert_allclose(ours[1], model.predict_proba(test), rtol=0, atol=1e-15)
        else:
            np.testing.assert_allclose(ours[0].ravel(), model.predict(test), rtol=0, atol=1e-12)


@pytest.mark.parametrize("skin", [PAPER_SKIN, Skin(8, 12), Skin(16, 12), Skin(3, 4)],
                         ids=lambda skin: f"{skin.rows}x{skin.columns}")
def test_the_transformers_match_numpy_to_the_last_bit(skin):
    """ForceProfile's sums run in numpy's order, ActiveTerminals breaks ties as a stable
    argsort does: both give numpy's values exactly, on every row — but for the log of
    the amplitude ratio, whose last bit is onnxruntime's log (the next step rounds to 1e-6)
    — on each axis of any R × C skin."""
    import onnxruntime
    from skl2onnx import convert_sklearn
    from skl2onnx.common.data_types import DoubleTensorType

    from eskin.deploy.export import CONVERTER_OPSETS, _register

    _register()
    # Sums of non-integers, where order shows; by name, and in numpy's own (C) order
    X = channel_frame(readings(3000, seed=5, skin=skin) * 1.37, skin.channels)
    n = skin.terminals
    log_ratios = [n + 4, n + 9]
    for transformer in (ForceProfile(quiet=3).fit(X), ActiveTerminals().fit(X)):
        model = convert_sklearn(transformer, initial_types=[("x", DoubleTensorType([None, n]))],
                                target_opset=CONVERTER_OPSETS)
        session = onnxruntime.InferenceSession(model.SerializeToString())
        ours = session.run(None, {"x": X.to_numpy()[:500]})[0]  # 500 rows: in numpy's buffer
        theirs = transformer.transform(channel_frame(X.to_numpy()[:500], skin.channels))
        exact = [c for c in range(theirs.shape[1])
                 if not (isinstance(transformer, ActiveTerminals) and c in log_ratios)]
        np.testing.assert_array_equal(ours[:, exact], theirs[:, exact])
        np.testing.assert_allclose(ours, theirs, rtol=4.5e-16, atol=0)


SMALL = {("force", "paper"): {"subsample": 100},
         ("force", "sparse_gp"): {"n_inducing": 50, "hyper_subsample": 100},
         ("force", "exact_gp"): {"hyper_subsample": 100}}


@pytest.mark.parametrize("role, name", [(role, name) for role, models in REGISTRY.items()
                                        for name in models])
def test_every_model_of_the_registry_exports(role, name, tmp_path):
    """Any model params.yaml can choose (the paper's configuration included) goes into the
    file, with the scikit-learn model's estimates."""
    X = readings(600, seed=12)
    targets = {"stretch": X[:, 3] / 500, "force": X[:, 3] + X[:, 12] / 2,
               "detect": X.max(axis=1) - np.median(X, axis=1) > 20,
               "localise": np.argmax(X[:, :10], axis=1) % 4 + 1}
    task, target = {"stretch": ("stretch", "stretch"), "force": ("force", "force"),
                    "detect": ("detect", "contact"), "localise": ("localise", "x")}[role]
    models = {task: {target: fitted(role, name, X, targets[role], **SMALL.get((role, name), {}))}}
    stack = SkinStack("every", "single_force", PAPER_SKIN, make_featurizer("raw").fit(X), models)
    assert_same(stack, exported(stack, tmp_path), readings(300, seed=13))


class Channel3(RegressorMixin, BaseEstimator):
    """A model of the lab's own, which no converter knows."""

    def fit(self, X, y):  # noqa: N803
        self.n_features_in_ = X.shape[1]
        return self

    def predict(self, X):  # noqa: N803
        return np.asarray(X)[:, 3]


def test_a_model_without_an_onnx_form_is_one_clear_error():
    X = readings(200, seed=8)
    stack = SkinStack("own", "two_force", PAPER_SKIN, make_featurizer("raw").fit(X),
                      {"force": {"force1": Channel3().fit(X, X[:, 0])}})
    with pytest.raises(ExportError, match="cannot export Channel3: Unable to find a shape"):
        stack_to_onnx(stack)


def test_the_file_says_what_it_is(tmp_path):
    X = readings(300, seed=9)
    stack = SkinStack("meta", "two_force", PAPER_SKIN, make_featurizer("raw").fit(X),
                      {"force": {"force1": fitted("force", "hist_gradient_boosting", X, X[:, 0],
                                                  max_iter=3)}},
                      device={"id": "board-7"})
    path = write_stack(stack, tmp_path / "s.onnx", sources={"models/meta/force.joblib": "ab"})
    props = {p.key: p.value for p in onnx.load(path).metadata_props}
    assert props["eskin.scene"] == "meta" and '"board-7"' in props["eskin.device"]
    assert "eskin.skin" not in props  # the paper's: its stacks keep their bytes
    loaded = ExportedStack.from_file(path)
    assert loaded.skin == PAPER_SKIN
    loaded.check_board("board-7")
    with pytest.raises(ValueError, match="trained on device board-7"):
        loaded.check_board("board-8")


@pytest.mark.parametrize("skin", [Skin(8, 12), ChannelArray(("m1x", "m1y", "m2x"), 3, 2,
                                                            (0.0, 5.0, 10.0), (0.0, 5.0))],
                         ids=["8x12", "channel_array"])
def test_a_stack_is_as_wide_as_its_skin_and_names_it(skin, tmp_path):
    """The file's input is the skin's channels, its metadata names the skin, and a frame
    of another width is one line saying which skin the stack reads."""
    rng = np.random.default_rng(14)
    X = pd.DataFrame(rng.normal(500, 5, (200, skin.terminals)), columns=skin.channels)
    force = X.iloc[:, 0].to_numpy() - 495
    models = {"force": {"force1": build_model("force", "hist_gradient_boosting",
                                              {"max_iter": 5}, skin).fit(X, force)}}
    stack = SkinStack("wide", "two_force", skin, make_featurizer("raw").fit(X), models)
    path = write_stack(stack, tmp_path / "s.onnx", sources={})
    graph_input = onnx.load(path).graph.input[0].type.tensor_type.shape.dim
    assert graph_input[1].dim_value == skin.terminals
    loaded = ExportedStack.from_file(path)
    assert loaded.skin == skin
    assert_same(stack, loaded, X.to_numpy())
    for each in (stack, loaded):
        with pytest.raises(ValueError, match=rf"^the wide stack is for the .*: a frame has "
                                             rf"{skin.terminals} channels, got 21$"):
            each.predict(np.zeros((1, 21)))


def test_a_peak_window_with_one_offset_exports(tmp_path):
    """Where every highest terminal is its node, PeakWindow keeps one offset (a
    DummyClassifier, as there is nothing to learn): the file gives the same nodes."""
    from eskin.learning.estimators import PeakWindow

    X = readings(600, seed=12)
    level = np.round((X - X.mean(axis=0)) / np.where(X.std(axis=0) > 0, X.std(axis=0), 1), 6)
    model = PeakWindow().fit(pd.DataFrame(X, columns=CHANNELS), level[:, :10].argmax(1) + 1)
    assert len(model.offset_model_.classes_) == 1
    stack = SkinStack("one", "single_force", PAPER_SKIN, make_featurizer("raw").fit(X),
                      {"localise": {"x": model}})
    assert_same(stack, exported(stack, tmp_path), readings(300, seed=13))
