"""Export: a scene's whole trained stack as one ONNX file, run by onnxruntime.

A robot-side process needs the estimates, not eskin: the file takes ``counts`` (n × the
skin's channels, float64, in its order: x1..xR then y1..yC on a row/column skin, 20 on the
paper's) and gives one output per estimate,
named as :attr:`eskin.deploy.stack.SkinStack.columns` (``contact`` is boolean, the rest float64),
with the same gating as the scikit-learn stack (no contact: x and y NaN, force 0). Its
metadata (``metadata_props``) carries the scene, its kind, the board the training data
came from, the untouched readings (per stretch) a tare is taken against, the md5 of every model
file it was made from, and the skin (``eskin.skin``, as params.yaml declares it) when it is
not the paper's. Loading it takes onnxruntime and numpy only::

    import onnxruntime, numpy
    session = onnxruntime.InferenceSession("models/single_force/stack.onnx")
    force = session.run(["force"], {"counts": numpy.array([frame], dtype=numpy.float64)})[0]

The conversion is skl2onnx's, with converters (registered in its registry, for this
process) for what it lacks: eskin's own transformers
(:class:`~eskin.learning.estimators.ForceProfile`,
:class:`~eskin.learning.estimators.ActiveTerminals`,
:class:`~eskin.learning.estimators.PeakWindow`,
:class:`~eskin.learning.features.BaselineDelta`), the rounding ``FunctionTransformer``
of ``eskin.learning.estimators._scaled``, LinearSVC and eskin's
Gaussian processes in float64, and the tree ensembles (random forests, extra trees,
histogram gradient boosting). skl2onnx 1.20 writes those as ``ai.onnx.ml`` opset 1 tree
ensembles, whose thresholds and outputs are float32 (and fails to build them for
histogram gradient boosting); here they are opset 5's ``TreeEnsemble``, in float64 as
scikit-learn computes, so a split falls the same way. Every model of the registry
exports (tests/test_export.py).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper
from sklearn.ensemble import (
    ExtraTreesClassifier,
    ExtraTreesRegressor,
    HistGradientBoostingClassifier,
    HistGradientBoostingRegressor,
    RandomForestClassifier,
    RandomForestRegressor,
)
from sklearn.preprocessing import FunctionTransformer

from eskin.data.schema import skin_metadata
from eskin.errors import EskinError
from eskin.kinds import get_kind
from eskin.learning.estimators import (
    ActiveTerminals,
    ForceProfile,
    PeakWindow,
    row_column_skin,
)
from eskin.learning.features import BaselineDelta

OPSETS = {"": 21, "ai.onnx.ml": 5}
# skl2onnx converts up to ai.onnx.ml opset 3, and every ai.onnx.ml operator it writes is
# the same in 5; the one operator of 5 used here (TreeEnsemble) is added under it and the
# stack's graph declares 5.
CONVERTER_OPSETS = {"": 21, "ai.onnx.ml": 3}
INPUT = "counts"


class ExportError(EskinError, ValueError):
    """A stack this module cannot write as ONNX."""


# ---------------------------------------------------------------- graph building


class _Nodes:
    """Adds nodes and constants to a skl2onnx container under unique names."""

    def __init__(self, scope, container) -> None:
        self.scope, self.container = scope, container

    def const(self, value, dtype=np.float64) -> str:
        array = np.asarray(value, dtype=dtype)
        name = self.scope.get_unique_variable_name("c")
        self.container.add_initializer(name, helper.np_dtype_to_tensor_dtype(array.dtype),
                                       list(array.shape), array.ravel().tolist())
        return name

    def op(self, op_type: str, *inputs: str, out: str | None = None, outputs: int = 1,
           domain: str = "", **attrs) -> Any:
        names = [out] if out else [self.scope.get_unique_variable_name(op_type.lower())
                                   for _ in range(outputs)]
        self.container.add_node(op_type, list(inputs), names, op_domain=domain,
                                op_version=CONVERTER_OPSETS[domain],
                                name=self.scope.get_unique_operator_name(op_type), **attrs)
        return names[0] if outputs == 1 else names

    def columns(self, x: str, start: int, stop: int) -> str:
        return self.op("Slice", x, self.const([start], np.int64), self.const([stop], np.int64),
                       self.const([1], np.int64))

    def row_sum(self, x: str, width: int) -> str:
        """Each row's sum, added in numpy's order, so that it is numpy's to the last bit
        (a different order moves a sum by an ulp, and a tree split can fall the other
        way): in sequence below 8 terms; from 8 to 128, numpy's pairwise sum — eight
        running sums, combined as a tree, then the remainder in sequence."""
        terms = [self.columns(x, i, i + 1) for i in range(width)]
        if width < 8:
            total = terms[0]
            for term in terms[1:]:
                total = self.op("Add", total, term)
            return total
        if width > 128:
            raise ExportError(f"no numpy-order sum of {width} terms (more than 128)")
        running = terms[:8]
        whole = width - width % 8
        for start in range(8, whole, 8):
            running = [self.op("Add", r, t) for r, t in zip(running, terms[start:start + 8],
                                                            strict=True)]
        pairs = [self.op("Add", running[i], running[i + 1]) for i in range(0, 8, 2)]
        total = self.op("Add", self.op("Add", pairs[0], pairs[1]),
                        self.op("Add", pairs[2], pairs[3]))
        for term in terms[whole:]:
            total = self.op("Add", total, term)
        return total

    def round(self, x: str, decimals: int, out: str | None = None) -> str:
        # numpy's round(x, d): x·10^d, to nearest even, ÷10^d — the same three steps
        scale = self.const(10.0 ** decimals)
        return self.op("Div", self.op("Round", self.op("Mul", x, scale)), scale, out=out)


def _same_shape(operator, width: int) -> None:
    from skl2onnx.common.data_types import DoubleTensorType

    operator.outputs[0].type = DoubleTensorType([operator.inputs[0].get_first_dimension(),
                                                 width])


def _function_transformer_shape(operator) -> None:
    operator.outputs[0].type = operator.inputs[0].type.__class__(
        operator.inputs[0].type.shape)


def _function_transformer(scope, operator, container) -> None:
    model, nodes = operator.raw_operator, _Nodes(scope, container)
    x, out = operator.inputs[0].full_name, operator.outputs[0].full_name
    if model.func is None:
        nodes.op("Identity", x, out=out)
    elif model.func is np.round:
        nodes.round(x, int((model.kw_args or {}).get("decimals", 0)), out=out)
    else:
        raise ExportError(f"no ONNX form for FunctionTransformer({model.func!r})")


def _baseline_delta(scope, operator, container) -> None:
    nodes = _Nodes(scope, container)
    nodes.op("Sub", operator.inputs[0].full_name, nodes.const(operator.raw_operator.baseline_),
             out=operator.outputs[0].full_name)


def _force_profile(scope, operator, container) -> None:
    """:meth:`ForceProfile.transform`, step for step, on each axis of its skin."""
    model, nodes = operator.raw_operator, _Nodes(scope, container)
    skin = row_column_skin(model)
    axes = ((0, skin.rows), (skin.rows, skin.terminals))  # (first, last + 1) of x, then y
    level = nodes.round(nodes.op("Div", nodes.op("Sub", operator.inputs[0].full_name,
                                                 nodes.const(model.rest_mean_)),
                                 nodes.const(model.rest_sd_)), 6)
    lowest = [nodes.op("Div", nodes.row_sum(nodes.op(
        "TopK", nodes.columns(level, start, stop), nodes.const([model.quiet], np.int64),
        outputs=2, axis=1, largest=0, sorted=1)[0], model.quiet), nodes.const(model.quiet * 1.0))
              for start, stop in axes]
    stretch = nodes.op("Div", nodes.op("Add", *lowest), nodes.const(2.0))
    change = nodes.op("Sub", level, stretch)
    columns = [change, stretch]
    for start, stop in axes:
        axis = nodes.columns(change, start, stop)
        top = nodes.op("ArgMax", axis, axis=1, keepdims=1)
        padded = nodes.op("Pad", axis, nodes.const([0, 1, 0, 1], np.int64))
        around = [nodes.op("GatherElements", padded,
                           nodes.op("Add", top, nodes.const([[shift]], np.int64)), axis=1)
                  for shift in (0, 1, 2)]
        columns += [nodes.op("GatherElements", axis, top, axis=1),
                    nodes.row_sum(nodes.op("Relu", axis), stop - start),
                    nodes.op("Add", nodes.op("Add", around[0], around[1]), around[2]),
                    nodes.op("Cast", top, to=TensorProto.DOUBLE)]
    nodes.op("Concat", *columns, out=operator.outputs[0].full_name, axis=1)


def _active_terminals(scope, operator, container) -> None:
    """:meth:`ActiveTerminals.transform`, step for step, on each axis of its skin. The two
    strongest peaks are ``argsort(kind="stable")[-2:]``, which breaks a tie towards the
    higher terminal; TopK breaks it towards the lower index, so it runs on the axis
    reversed."""
    model, nodes = operator.raw_operator, _Nodes(scope, container)
    change = nodes.round(nodes.op("Div", nodes.op("Sub", operator.inputs[0].full_name,
                                                  nodes.const(model.rest_)),
                                  nodes.const(model.unit_)), 6)
    skin = row_column_skin(model)
    minus_inf = nodes.const([[-np.inf]])
    columns, signs = [change], []
    for start, width in ((0, skin.rows), (skin.rows, skin.columns)):
        axis = nodes.columns(change, start, start + width)
        n = nodes.op("Shape", axis, start=0, end=1)
        edge = nodes.op("Expand", minus_inf, nodes.op("Concat", n, nodes.const([1], np.int64),
                                                      axis=0))
        left = nodes.op("Concat", edge, nodes.columns(axis, 0, width - 1), axis=1)
        right = nodes.op("Concat", nodes.columns(axis, 1, width), edge, axis=1)
        peak = nodes.op("And", nodes.op("GreaterOrEqual", axis, left),
                        nodes.op("GreaterOrEqual", axis, right))
        masked = nodes.op("Where", peak, axis, nodes.const(-np.inf))
        reversed_ = nodes.op("Slice", masked, nodes.const([-1], np.int64),
                             nodes.const([-(2**62)], np.int64), nodes.const([1], np.int64),
                             nodes.const([-1], np.int64))
        _, at = nodes.op("TopK", reversed_, nodes.const([2], np.int64), outputs=2,
                         axis=1, largest=1, sorted=1)
        at = nodes.op("Sub", nodes.const([[width - 1]], np.int64), at)
        first, second = nodes.columns(at, 0, 1), nodes.columns(at, 1, 2)
        top = nodes.op("Concat", nodes.op("Min", first, second),
                       nodes.op("Max", first, second), axis=1)
        amplitude = nodes.op("GatherElements", axis, top, axis=1)
        floor = nodes.const(1e-3)
        ratio = nodes.op("Log", nodes.op("Div",
                                         nodes.op("Max", nodes.columns(amplitude, 0, 1), floor),
                                         nodes.op("Max", nodes.columns(amplitude, 1, 2), floor)))
        signs.append(nodes.op("Sign", ratio))
        columns += [nodes.op("Cast", top, to=TensorProto.DOUBLE), amplitude, ratio]
    columns.append(nodes.op("Cast", nodes.op("Equal", *signs), to=TensorProto.DOUBLE))
    nodes.op("Concat", *columns, out=operator.outputs[0].full_name, axis=1)


def _peak_window(scope, operator, container) -> None:
    """:meth:`PeakWindow.predict`, step for step: the highest terminal of its axis (the
    first of equals, as numpy's argmax), the window around it with the axis's ends
    repeated, the offset model's scores (x·w + b) and their best offset, then the nearest
    node training saw. The scores are the second output."""
    model, nodes = operator.raw_operator, _Nodes(scope, container)
    start, stop = model.axis_
    width, reach = stop - start, model.window
    level = nodes.round(nodes.op("Div", nodes.op("Sub", operator.inputs[0].full_name,
                                                 nodes.const(model.mean_)),
                                 nodes.const(model.scale_)), 6)
    axis = nodes.columns(level, start, stop)
    top = nodes.op("ArgMax", axis, axis=1, keepdims=1)
    padded = nodes.op("Pad", axis, nodes.const([0, reach, 0, reach], np.int64), mode="edge")
    around = nodes.op("GatherElements", padded, nodes.op(
        "Add", top, nodes.const([list(range(2 * reach + 1))], np.int64)), axis=1)
    quiet = min(3, width)
    lowest = nodes.op("TopK", axis, nodes.const([quiet], np.int64), outputs=2, axis=1,
                      largest=0, sorted=1)[0]
    base = nodes.op("Div", nodes.row_sum(lowest, quiet), nodes.const(float(quiet)))
    around = nodes.op("Sub", around, base)
    relative = nodes.op("Div", around, nodes.op("Max", nodes.columns(around, reach, reach + 1),
                                                nodes.const(1e-3)))
    near = nodes.const(reach + 1, np.int64)
    ends = nodes.op("Cast", nodes.op("Concat", nodes.op("Min", top, near), nodes.op(
        "Min", nodes.op("Sub", nodes.const(width - 1, np.int64), top), near), axis=1),
                    to=TensorProto.DOUBLE)
    which = nodes.op("Cast", nodes.op("Equal", top, nodes.const([list(range(width))], np.int64)),
                     to=TensorProto.DOUBLE)
    features = nodes.op("Concat", around, relative, ends, base, which, axis=1)
    offsets = model.offset_model_
    if len(offsets.classes_) < 2:  # one offset, always (a DummyClassifier): a score of 0
        coef, intercept = np.zeros((1, features_width(model))), np.zeros(1)
    else:
        coef, intercept = offsets.coef_, offsets.intercept_
    offset = _linear_labels(nodes, features, coef, intercept, offsets.classes_,
                            scores_out=operator.outputs[1].full_name)
    node = nodes.op("Add", nodes.op("Reshape", top, nodes.const([-1], np.int64)),
                    nodes.op("Add", offset, nodes.const(1, np.int64)))
    classes = np.asarray(model.classes_)
    distance = nodes.op("Abs", nodes.op("Sub", nodes.op("Cast", nodes.op(
        "Unsqueeze", node, nodes.const([1], np.int64)), to=TensorProto.DOUBLE),
                                        nodes.const([classes.astype(float)])))
    nodes.op("Gather", nodes.const(classes.astype(np.int64), np.int64),
             nodes.op("ArgMin", distance, axis=1, keepdims=0),
             out=operator.outputs[0].full_name, axis=0)


def _peak_window_shape(operator) -> None:
    from skl2onnx.common.data_types import DoubleTensorType, Int64TensorType

    n = operator.inputs[0].get_first_dimension()
    operator.outputs[0].type = Int64TensorType([n])
    offsets = operator.raw_operator.offset_model_
    operator.outputs[1].type = DoubleTensorType(
        [n, offsets.coef_.shape[0] if len(offsets.classes_) > 1 else 1])


def features_width(model) -> int:
    """The columns of :class:`PeakWindow`'s offset features: the window twice, the two
    ends, the level and one per terminal of its axis."""
    start, stop = model.axis_
    return 2 * (2 * model.window + 1) + 3 + (stop - start)


class _Trees:
    """Trees gathered into one opset-5 ``TreeEnsemble`` (float64 splits and leaves; the
    outputs summed per target, tree by tree)."""

    def __init__(self, n_targets: int) -> None:
        self.n_targets = n_targets
        self.roots: list[int] = []
        self.branches: dict[str, list] = {key: [] for key in (
            "modes", "features", "splits", "missing", "true", "true_leaf", "false",
            "false_leaf")}
        self.leaf_targets: list[int] = []
        self.leaf_weights: list[float] = []

    def _leaf(self, target: int, weight: float) -> int:
        self.leaf_targets.append(target)
        self.leaf_weights.append(weight)
        return len(self.leaf_weights) - 1

    def _branch(self, feature: int, split: float, missing_true: int) -> int:
        b = self.branches
        b["modes"].append(0)  # BRANCH_LEQ: x <= split goes the true way (left), as scikit-learn
        b["features"].append(feature)
        b["splits"].append(split)
        b["missing"].append(missing_true)
        for key in ("true", "true_leaf", "false", "false_leaf"):
            b[key].append(0)
        return len(b["modes"]) - 1

    def add_leaf_tree(self, target: int, weight: float) -> None:
        """A tree that is one leaf (a root must be a branch: both its ways lead there)."""
        at = self._branch(0, 0.0, 1)
        leaf = self._leaf(target, weight)
        b = self.branches
        b["true"][at], b["true_leaf"][at], b["false"][at], b["false_leaf"][at] = leaf, 1, leaf, 1
        self.roots.append(at)

    def add(self, left, right, feature, threshold, missing_left, value, target: int) -> None:
        """One tree in scikit-learn's arrays: node ``i`` is a leaf where ``left[i]`` is -1
        (or ``left[i] == right[i] == 0``), else splits on ``feature[i] <= threshold[i]``."""
        def is_leaf(i: int) -> bool:
            return left[i] < 0 or left[i] == right[i]

        if is_leaf(0):
            self.add_leaf_tree(target, float(value[0]))
            return
        b = self.branches
        placed = {0: self._branch(int(feature[0]), float(threshold[0]), int(missing_left[0]))}
        self.roots.append(placed[0])
        pending = [0]
        while pending:
            i = pending.pop()
            for child, (ids, leaf_flags) in ((left[i], ("true", "true_leaf")),
                                             (right[i], ("false", "false_leaf"))):
                if is_leaf(child):
                    b[ids][placed[i]] = self._leaf(target, float(value[child]))
                    b[leaf_flags][placed[i]] = 1
                else:
                    placed[child] = self._branch(int(feature[child]), float(threshold[child]),
                                                 int(missing_left[child]))
                    b[ids][placed[i]] = placed[child]
                    pending.append(child)

    def node(self, nodes: _Nodes, x: str) -> str:
        b = self.branches
        return nodes.op(
            "TreeEnsemble", x, domain="ai.onnx.ml", n_targets=self.n_targets,
            aggregate_function=1, post_transform=0, tree_roots=self.roots,
            nodes_modes=numpy_helper.from_array(np.array(b["modes"], np.uint8)),
            nodes_featureids=b["features"],
            nodes_splits=numpy_helper.from_array(np.array(b["splits"], np.float64)),
            nodes_truenodeids=b["true"], nodes_trueleafs=b["true_leaf"],
            nodes_falsenodeids=b["false"], nodes_falseleafs=b["false_leaf"],
            nodes_missing_value_tracks_true=b["missing"], leaf_targetids=self.leaf_targets,
            leaf_weights=numpy_helper.from_array(np.array(self.leaf_weights, np.float64)))


def _tree_ensemble(nodes: _Nodes, model, x: str) -> str:
    """The raw scores of a fitted histogram gradient boosting (n × trees per iteration).
    The baseline is the first tree, a single leaf, so that the sum starts where
    scikit-learn's does."""
    from sklearn._loss.link import IdentityLink, LogitLink, MultinomialLogit

    if not isinstance(model._loss.link, IdentityLink | LogitLink | MultinomialLogit):
        raise ExportError(f"no ONNX form for the loss {type(model._loss).__name__}")
    per_iteration = model.n_trees_per_iteration_
    trees = _Trees(per_iteration)
    baseline = np.broadcast_to(np.asarray(model._baseline_prediction, np.float64).ravel(),
                               (per_iteration,))
    for target, value in enumerate(baseline):
        trees.add_leaf_tree(target, float(value))
    for iteration in model._predictors:
        for target, predictor in enumerate(iteration):
            tree = predictor.nodes
            if tree["is_categorical"].any():
                raise ExportError("no ONNX form for categorical splits")
            left = np.where(tree["is_leaf"], -1, tree["left"].astype(np.int64))
            trees.add(left, tree["right"], tree["feature_idx"], tree["num_threshold"],
                      tree["missing_go_to_left"], tree["value"], target)
    return trees.node(nodes, x)


def _forest(nodes: _Nodes, model, x: str) -> str:
    """A random forest's (or extra trees') prediction: for a regressor the mean of its
    trees' leaves, for a classifier the mean of their class fractions (n × classes).
    scikit-learn's trees read the input as float32, and so does this."""
    from sklearn.utils.validation import check_is_fitted

    check_is_fitted(model)
    classifier = hasattr(model, "classes_")
    if getattr(model, "n_outputs_", 1) != 1:
        raise ExportError("no ONNX form for a forest with several outputs")
    n_targets = len(model.classes_) if classifier else 1
    trees = _Trees(n_targets)
    for estimator in model.estimators_:
        tree = estimator.tree_
        values = tree.value[:, 0, :]
        if classifier:  # as DecisionTreeClassifier.predict_proba normalises
            normalizer = values.sum(axis=1)[:, None]
            normalizer[normalizer == 0.0] = 1.0
            values = values / normalizer
        missing = getattr(tree, "missing_go_to_left", np.zeros(tree.node_count, np.uint8))
        for target in range(n_targets):
            trees.add(tree.children_left, tree.children_right, tree.feature, tree.threshold,
                      missing, values[:, target], target)
    as_float32 = nodes.op("Cast", nodes.op("Cast", x, to=TensorProto.FLOAT),
                          to=TensorProto.DOUBLE)
    return nodes.op("Div", trees.node(nodes, as_float32),
                    nodes.const(float(len(model.estimators_))))


def _forest_regressor(scope, operator, container) -> None:
    nodes = _Nodes(scope, container)
    nodes.op("Identity", _forest(nodes, operator.raw_operator, operator.inputs[0].full_name),
             out=operator.outputs[0].full_name)


def _forest_classifier(scope, operator, container) -> None:
    nodes = _Nodes(scope, container)
    probabilities = _forest(nodes, operator.raw_operator, operator.inputs[0].full_name)
    _labels(nodes, operator, probabilities)


def _labels(nodes: _Nodes, operator, probabilities: str) -> None:
    """A classifier's two outputs from its class probabilities: the most probable class
    (the first of equals, as numpy's argmax), and the probabilities."""
    nodes.op("Identity", probabilities, out=operator.outputs[1].full_name)
    best = nodes.op("ArgMax", probabilities, axis=1, keepdims=0)
    classes = np.asarray(operator.raw_operator.classes_)
    if classes.dtype.kind not in "biu":
        raise ExportError(f"no ONNX form for class labels of type {classes.dtype}")
    nodes.op("Gather", nodes.const(classes.astype(np.int64), np.int64), best,
             out=operator.outputs[0].full_name, axis=0)


def _regressor_shape(operator) -> None:
    _same_shape(operator, 1)


def _hgb_regressor(scope, operator, container) -> None:
    nodes = _Nodes(scope, container)
    nodes.op("Identity", _tree_ensemble(nodes, operator.raw_operator,
                                        operator.inputs[0].full_name),
             out=operator.outputs[0].full_name)


def _hgb_classifier(scope, operator, container) -> None:
    """Labels and probabilities as scikit-learn computes them: the logistic of the score
    (two classes), or its softmax; the label is the most probable class (the first of
    equals)."""
    model, nodes = operator.raw_operator, _Nodes(scope, container)
    score = _tree_ensemble(nodes, model, operator.inputs[0].full_name)
    if model.n_trees_per_iteration_ == 1:
        positive = nodes.op("Sigmoid", score)
        probabilities = nodes.op("Concat", nodes.op("Sub", nodes.const([[1.0]]), positive),
                                 positive, axis=1)
    else:
        probabilities = nodes.op("Softmax", score, axis=1)
    _labels(nodes, operator, probabilities)


def _classifier_shape(operator) -> None:
    """Labels (int64) and float64 probabilities, whatever skl2onnx's parser declared
    (it declares float32 for a random forest's)."""
    from skl2onnx.common.data_types import DoubleTensorType, Int64TensorType

    n = operator.inputs[0].get_first_dimension()
    classes = len(operator.raw_operator.classes_)
    operator.outputs[0].type = Int64TensorType([n])
    operator.outputs[1].type = DoubleTensorType([n, classes])


def _linear_svc(scope, operator, container) -> None:
    """LinearSVC's decision (skl2onnx 1.20 has none in float64): x·w + b, positive for the
    second of two classes, else the highest score's class; the scores as second output."""
    model, nodes = operator.raw_operator, _Nodes(scope, container)
    _linear_labels(nodes, operator.inputs[0].full_name, model.coef_, model.intercept_,
                   model.classes_, scores_out=operator.outputs[1].full_name,
                   out=operator.outputs[0].full_name)


def _linear_labels(nodes: _Nodes, x: str, coef, intercept, classes, *, scores_out: str,
                   out: str | None = None) -> str:
    """A linear classifier's labels as scikit-learn's ``predict`` gives them: the scores
    x·w + b (written to ``scores_out``), positive for the second of two classes, else the
    highest score's class (the first of equals); one class (a constant model, its score
    0) is always that class."""
    scores = nodes.op("Add", nodes.op("MatMul", x, nodes.const(np.asarray(coef).T)),
                      nodes.const(intercept))
    nodes.op("Identity", scores, out=scores_out)
    if len(classes) == 1:
        best = nodes.op("Cast", nodes.op("Reshape", nodes.op("Mul", scores, nodes.const(0.0)),
                                         nodes.const([-1], np.int64)), to=TensorProto.INT64)
    elif len(classes) == 2:
        best = nodes.op("Cast", nodes.op("Greater", nodes.op("Reshape", scores, nodes.const(
            [-1], np.int64)), nodes.const(0.0)), to=TensorProto.INT64)
    else:
        best = nodes.op("ArgMax", scores, axis=1, keepdims=0)
    return nodes.op("Gather", nodes.const(np.asarray(classes).astype(np.int64), np.int64), best,
                    out=out, axis=0)


def _linear_svc_shape(operator) -> None:
    from skl2onnx.common.data_types import DoubleTensorType, Int64TensorType

    n = operator.inputs[0].get_first_dimension()
    operator.outputs[0].type = Int64TensorType([n])
    operator.outputs[1].type = DoubleTensorType([n, operator.raw_operator.coef_.shape[0]])


def _standardised_rbf(scope, operator, container) -> None:
    """eskin.learning.gp's Gaussian processes, as ``_StandardisedRBF.predict`` computes them:
    k(x, centres) · weights, back in the target's units (the matrix products are
    onnxruntime's, so the last bits differ)."""
    model, nodes = operator.raw_operator, _Nodes(scope, container)
    z = nodes.op("Div", nodes.op("Div", nodes.op("Sub", operator.inputs[0].full_name,
                                                 nodes.const(model.x_mean_)),
                                 nodes.const(model.x_scale_)), nodes.const(model.length_scale_))
    centres = np.asarray(model.centres_, dtype=np.float64)
    k = nodes.op("Mul", nodes.op("MatMul", z, nodes.const(centres.T)), nodes.const(-2.0))
    k = nodes.op("Add", k, nodes.row_sum(nodes.op("Mul", z, z), centres.shape[1]))
    k = nodes.op("Add", k, nodes.const((centres * centres).sum(1)[None, :]))
    k = nodes.op("Exp", nodes.op("Mul", nodes.op("Max", k, nodes.const(0.0)),
                                 nodes.const(-0.5)))
    k = nodes.op("Mul", k, nodes.const(model.hyperparameters_["signal_variance"]))
    out = nodes.op("MatMul", k, nodes.const(np.asarray(model.weights_)[:, None]))
    nodes.op("Add", nodes.op("Mul", out, nodes.const(model.y_scale_)),
             nodes.const(model.y_mean_), out=operator.outputs[0].full_name)


def _subsampled_gp(scope, operator, container) -> None:
    """The paper's GP: its inner scaler and scikit-learn GP, by skl2onnx's converters."""
    from skl2onnx.algebra.onnx_operator import OnnxSubEstimator

    OnnxSubEstimator(operator.raw_operator.model_, operator.inputs[0],
                     op_version=CONVERTER_OPSETS[""],
                     output_names=[operator.outputs[0].full_name]).add_to(scope, container)


def _register() -> None:
    from skl2onnx import update_registered_converter
    from sklearn.svm import LinearSVC

    from eskin.learning.estimators import SubsampledGaussianProcess
    from eskin.learning.gp import FixedKernelGaussianProcess, SparseGaussianProcess

    update_registered_converter(FunctionTransformer, "SklearnFunctionTransformer",
                                _function_transformer_shape, _function_transformer)
    update_registered_converter(BaselineDelta, "EskinBaselineDelta",
                                lambda op: _same_shape(op, op.raw_operator.n_features_in_),
                                _baseline_delta)
    update_registered_converter(ForceProfile, "EskinForceProfile",
                                lambda op: _same_shape(op, op.raw_operator.n_features_in_ + 9),
                                _force_profile)
    update_registered_converter(ActiveTerminals, "EskinActiveTerminals",
                                lambda op: _same_shape(op, op.raw_operator.n_features_in_ + 11),
                                _active_terminals)
    update_registered_converter(LinearSVC, "SklearnLinearSVC", _linear_svc_shape, _linear_svc,
                                options={"zipmap": [False], "nocl": [False]})
    update_registered_converter(PeakWindow, "EskinPeakWindow", _peak_window_shape,
                                _peak_window, options={"zipmap": [False], "nocl": [False]})
    for gp in (SparseGaussianProcess, FixedKernelGaussianProcess):
        update_registered_converter(gp, f"Eskin{gp.__name__}", _regressor_shape,
                                    _standardised_rbf)
    update_registered_converter(SubsampledGaussianProcess, "EskinSubsampledGaussianProcess",
                                _regressor_shape, _subsampled_gp)
    for regressor in (RandomForestRegressor, ExtraTreesRegressor):
        update_registered_converter(regressor, f"Sklearn{regressor.__name__}",
                                    _regressor_shape, _forest_regressor)
    for classifier in (RandomForestClassifier, ExtraTreesClassifier):
        update_registered_converter(classifier, f"Sklearn{classifier.__name__}",
                                    _classifier_shape, _forest_classifier,
                                    options={"zipmap": [True, False, "columns"],
                                             "nocl": [True, False]})
    update_registered_converter(HistGradientBoostingRegressor,
                                "SklearnHistGradientBoostingRegressor",
                                _regressor_shape, _hgb_regressor)
    update_registered_converter(HistGradientBoostingClassifier,
                                "SklearnHistGradientBoostingClassifier",
                                _classifier_shape, _hgb_classifier,
                                options={"zipmap": [True, False, "columns"],
                                         "nocl": [True, False]})


# ---------------------------------------------------------------- the stack


def _convert(model, name: str, width: int) -> onnx.ModelProto:
    """One fitted model (or pipeline) with input ``name``; a classifier gives its label
    and its probabilities (or, without them, its scores)."""
    from skl2onnx.common.data_types import DoubleTensorType

    last = model.steps[-1][1] if hasattr(model, "steps") else model
    inputs = [(name, DoubleTensorType([None, width]))]
    with warnings.catch_warnings():
        # skl2onnx reads attributes scikit-learn has deprecated (SVC's probA_): not ours
        warnings.simplefilter("ignore", FutureWarning)
        return _convert_quietly(model, last, inputs)


def _convert_quietly(model, last, inputs) -> onnx.ModelProto:
    from skl2onnx import convert_sklearn
    from sklearn.base import is_classifier

    try:
        if is_classifier(last):
            try:  # probabilities as a tensor, not a list of maps
                return convert_sklearn(model, initial_types=inputs, target_opset=CONVERTER_OPSETS,
                                       options={id(last): {"zipmap": False}})
            except NameError:  # a converter without the option: its scores are a tensor
                pass
        return convert_sklearn(model, initial_types=inputs, target_opset=CONVERTER_OPSETS)
    except (RuntimeError, NotImplementedError, TypeError) as error:
        raise ExportError(f"cannot export {type(last).__name__}: {error}") from None


def stack_to_onnx(stack) -> onnx.ModelProto:
    """One ONNX model for a :class:`~eskin.deploy.stack.SkinStack`: ``counts`` in, one output per
    estimate column."""
    _register()
    parts: list[onnx.ModelProto] = []
    graph_nodes: list[onnx.NodeProto] = []
    initializers: list[onnx.TensorProto] = []

    def include(model, prefix: str, source: str) -> list[str]:
        """``model``'s graph fed from ``source``; its outputs' names."""
        converted = onnx.compose.add_prefix(_convert(model, "input", stack.skin.terminals),
                                            prefix)
        graph_nodes.append(helper.make_node("Identity", [source], [f"{prefix}input"]))
        graph_nodes.extend(converted.graph.node)
        initializers.extend(converted.graph.initializer)
        parts.append(converted)
        return [output.name for output in converted.graph.output]

    (features,) = include(stack.featurizer, "featurizer/", INPUT)
    built = _Builder(graph_nodes, initializers)
    n = built.node("Shape", INPUT, start=0, end=1)
    outputs: dict[str, str] = {}

    def regression(task: str, target: str) -> str:
        model = stack.models.get(task, {}).get(target)
        if model is None:
            return built.node("ConstantOfShape", n, value=helper.make_tensor(
                "nan", TensorProto.DOUBLE, [1], [np.nan]))
        (value,) = include(model, f"{task}.{target}/", features)
        return built.node("Reshape", value, built.const([-1], np.int64))

    def label(task: str, target: str) -> tuple[str, str] | None:
        model = stack.models.get(task, {}).get(target)
        if model is None:
            return None
        predicted, probabilities = include(model, f"{task}.{target}/", features)
        return built.node("Cast", predicted, to=TensorProto.DOUBLE), probabilities

    def located(task: str, target: str) -> str:
        found = label(task, target)
        if found is None:
            return regression(task, target)  # NaN
        return found[0]

    kind = get_kind(stack.kind)
    outputs["stretch"] = regression("stretch", "stretch")
    if "contact" not in stack.columns:  # two contacts on every frame: nothing counted
        for target in kind.node_columns:
            outputs[target] = located("localise", target)
        for target in kind.force_columns:
            outputs[target] = regression("force", target)
    elif "contacts" in stack.columns:
        _counted_outputs(stack, kind, built, outputs, label, located, regression)
    else:
        detected = label("detect", "contact")
        if detected is None:  # no detector: every frame has a contact, as SkinStack says
            contact = built.node("ConstantOfShape", n, value=helper.make_tensor(
                "one", TensorProto.BOOL, [1], [True]))
            probability = regression("detect", "contact")
        else:
            detector = stack.models["detect"]["contact"]
            contact = built.node("Cast", detected[0], to=TensorProto.BOOL)
            if hasattr(detector, "predict_proba"):
                positive = built.node("Gather", detected[1], built.const(
                    [list(detector.classes_).index(True)], np.int64), axis=1)
                probability = built.node("Reshape", positive, built.const([-1], np.int64))
            else:  # the paper's SVM gives no probability, as SkinStack says
                probability = built.node("ConstantOfShape", n, value=helper.make_tensor(
                    "nan", TensorProto.DOUBLE, [1], [np.nan]))
        outputs["contact"], outputs["contact_probability"] = contact, probability
        nan, zero = built.const(np.nan), built.const(0.0)
        for target in kind.node_columns:
            outputs[target] = built.node("Where", contact, located("localise", target), nan)
        for target in kind.force_columns:
            outputs[target] = built.node("Where", contact, regression("force", target), zero)
    for name, value in outputs.items():
        graph_nodes.append(helper.make_node("Identity", [value], [name]))
    graph = helper.make_graph(
        graph_nodes, f"eskin_{stack.scene}",
        [helper.make_tensor_value_info(INPUT, TensorProto.DOUBLE, [None, stack.skin.terminals])],
        [helper.make_tensor_value_info(name, TensorProto.BOOL if name == "contact"
                                       else TensorProto.DOUBLE, [None])
         for name in stack.columns],
        initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid(domain, version)
                                                    for domain, version in OPSETS.items()],
                              producer_name="eskin")
    model.ir_version = min(p.ir_version for p in parts)
    onnx.checker.check_model(model, full_check=True)
    return model


def _counted_outputs(stack, kind, built: _Builder, outputs: dict[str, str], label, located,
                     regression) -> None:
    """A counting stack's outputs, as :meth:`SkinStack._predict` gives them: how many
    contacts press (the detector's label), whether any does, the probability that any does
    (1 − that of none), and each contact's place and force where that many press."""
    counter = stack.models["detect"][kind.detect_target]
    predicted, probabilities = label("detect", kind.detect_target)
    count = built.node("Cast", predicted, to=TensorProto.DOUBLE)
    none = built.node("Gather", probabilities, built.const(
        [list(np.asarray(counter.classes_).astype(np.int64)).index(0)], np.int64), axis=1)
    probability = built.node("Sub", built.const(1.0), built.node(
        "Reshape", built.node("Cast", none, to=TensorProto.DOUBLE),
        built.const([-1], np.int64)))
    outputs["contact"] = built.node("Greater", count, built.const(0.0))
    outputs["contact_probability"], outputs["contacts"] = probability, count
    nan, zero = built.const(np.nan), built.const(0.0)
    for k, (x, y) in enumerate(kind.positions.values(), start=1):
        present = built.node("GreaterOrEqual", count, built.const(float(k)))
        for target in (x, y):
            outputs[target] = built.node("Where", present, located("localise", target), nan)
        for force, weighs in kind.weighed_contacts.items():
            if weighs == [x]:
                outputs[force] = built.node("Where", present, regression("force", force), zero)
    for force in kind.force_columns:  # a total force: wherever any contact presses
        if force not in outputs:
            outputs[force] = built.node("Where", outputs["contact"],
                                        regression("force", force), zero)


class _Builder:
    """Nodes of the stack's own graph (outside skl2onnx), named in order."""

    def __init__(self, nodes: list, initializers: list) -> None:
        self.nodes, self.initializers = nodes, initializers

    def _name(self, stem: str) -> str:
        return f"stack/{stem}_{len(self.nodes) + len(self.initializers)}"

    def const(self, value, dtype=np.float64) -> str:
        name = self._name("const")
        self.initializers.append(numpy_helper.from_array(np.asarray(value, dtype), name))
        return name

    def node(self, op_type: str, *inputs: str, **attrs) -> str:
        name = self._name(op_type.lower())
        self.nodes.append(helper.make_node(op_type, list(inputs), [name], **attrs))
        return name


def metadata(stack, sources: dict[str, str]) -> dict[str, str]:
    """What the file says of itself (``metadata_props``, all strings): the skin only when
    it is not the paper's, as a dataset records it (:func:`eskin.data.schema.skin_metadata`),
    so that the paper's stacks keep their bytes."""
    return {"eskin.scene": stack.scene, "eskin.kind": stack.kind,
            "eskin.columns": json.dumps(stack.columns),
            "eskin.device": json.dumps(stack.device),
            "eskin.rest_table": json.dumps(None if stack.rest is None
                                           else stack.rest.as_dict()),
            "eskin.skipped": json.dumps(stack.skipped),
            "eskin.sources_md5": json.dumps(sources, sort_keys=True),
            **{f"eskin.{key}": json.dumps(value, sort_keys=True)
               for key, value in skin_metadata(stack.skin).items()}}


def write_stack(stack, path: Path, sources: dict[str, str]) -> Path:
    model = stack_to_onnx(stack)
    helper.set_model_props(model, metadata(stack, sources))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, path)
    return path


# ---------------------------------------------------------------- checked against the stack

# The exported stack must give the scikit-learn stack's estimates: within TOLERANCE (in
# the estimate's units, or relative where it is over 1) and the same labels, on all but
# MAX_DIFFERING of the scene's frames. Both compute in float64 and the file's sums run in
# numpy's order, so what remains is the last bits of a sum over trees, a logistic, a
# softmax or a Gaussian process's matrix products — and numpy itself: its sum
# over a row is blocked differently when the row sits across its buffers in a large batch,
# so that the scikit-learn stack's force for one frame can differ by batch (2 of the
# single-force scene's 24,240 frames). A frame that differs is predicted again alone.
TOLERANCE = 1e-9
MAX_DIFFERING = 1e-3


def compare(exported, reference, counts: np.ndarray) -> dict[str, Any]:
    """Per estimate: the largest difference, the frames differing in one batch, and those
    still differing when the scikit-learn stack predicts each of them alone."""
    ours, theirs = exported.predict(counts), reference.predict(counts)
    report: dict[str, Any] = {"frames": len(counts), "tolerance": TOLERANCE, "estimates": {}}
    for name in reference.columns:
        differing = _differing(ours[name].to_numpy(), theirs[name].to_numpy())
        rows = np.flatnonzero(differing)
        alone = [row for row in rows if _differing(
            ours[name].to_numpy()[row:row + 1],
            reference.predict(counts[row:row + 1])[name].to_numpy())[0]]
        a = ours[name].to_numpy(dtype=np.float64)
        b = theirs[name].to_numpy(dtype=np.float64)
        both = ~(np.isnan(a) | np.isnan(b))
        report["estimates"][name] = {
            "max_abs_difference": float(np.abs(a[both] - b[both]).max()) if both.any() else 0.0,
            "differing_in_batch": int(len(rows)),
            "differing_alone": len(alone)}
    return report


def _differing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    same_nan = np.isnan(a) & np.isnan(b)
    with np.errstate(invalid="ignore"):
        return ~(same_nan | (np.abs(a - b) <= TOLERANCE * np.maximum(1.0, np.abs(b))))
