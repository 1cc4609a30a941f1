"""A scene's trained stack → one ONNX file, checked against the scikit-learn stack.

The train stage exports its scene's stack after training, in its own process: a stack
exported from the same models, dataset and code is kept, not exported again (its inputs
and outputs recorded by md5 in ``.cache/export/``), so that a knob of one scene's model
exports only that scene's stack.

:func:`export_at` reads and writes; the conversion is
:func:`eskin.deploy.export.stack_to_onnx` and the check :func:`~eskin.deploy.export.compare`,
which do neither."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from eskin.catalog import (
    EXPORT_CACHE,
    TASK_NAMES,
    export_report_path,
    featurizer_path,
    model_path,
    processed_path,
    stack_path,
)
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.scenes import Scenes, get_scene
from eskin.data.schema import md5_file
from eskin.deploy.export import MAX_DIFFERING, TOLERANCE, ExportError, compare, write_stack
from eskin.deploy.stack import ExportedStack, SkinStack, locked_md5s
from eskin.steps import code
from eskin.steps.keep import kept, write_record


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    get_scene(load_params(sections(scenes=Scenes), params_path), scene, params_path)
    return export_at(scene)


def trained_md5s(scene: str, root: Path = Path(".")) -> dict[str, str]:
    """The md5s of ``scene``'s featurizer (as dvc.lock records it: the prepare stage's)
    and of its task models as the workspace holds them: the train stage's, which DVC
    records only once the stage ends."""
    return {**locked_md5s(root), **{model_path(scene, task).as_posix():
                                    md5_file(Path(root) / model_path(scene, task))
                                    for task in TASK_NAMES}}


def export_at(scene: str, root: Path = Path("."), *, check: bool = True,
              recorded: dict[str, str] | None = None, keep: bool = False) -> str:
    """The workspace's stack of ``scene`` → ``models/<scene>/stack.onnx``, checked against
    the scikit-learn stack on the scene's dataset (``reports/export/<scene>.json``).

    ``recorded``: the md5 each model file must have (default: dvc.lock's). ``keep``: a
    stack exported, and checked, from these models, this dataset and this code is left as
    it is."""
    root = Path(root)
    recorded = locked_md5s(root) if recorded is None else recorded
    sources = {p.as_posix(): recorded[p.as_posix()] for p in
               [featurizer_path(scene)] + [model_path(scene, task) for task in TASK_NAMES]}
    inputs = {"sources_md5": sources, "dataset_md5": md5_file(root / processed_path(scene)),
              "code_md5": code.code_md5(__file__), "check": check}
    record = root / EXPORT_CACHE / f"{scene}.json"
    outputs = [stack_path(scene), *([export_report_path(scene)] if check else [])]
    if keep and kept(root, record, inputs, outputs):
        return (f"{scene}: stack kept, exported from these models, dataset and code "
                f"({stack_path(scene)})")
    said = _export(scene, root, recorded, sources, check)
    if keep:
        write_record(root, record, inputs, outputs)
    return said


def _export(scene: str, root: Path, recorded: dict[str, str], sources: dict[str, str],
            check: bool) -> str:
    stack = SkinStack.from_workspace(scene, root, recorded)
    out = write_stack(stack, root / stack_path(scene), sources)
    if not check:
        return f"{scene}: stack → {out}"
    counts = pd.read_parquet(root / processed_path(scene),
                             columns=stack.skin.channels).to_numpy(dtype=np.float64)
    report = compare(ExportedStack.from_file(out), stack, counts)
    report["bytes"] = out.stat().st_size
    path = root / export_report_path(scene)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")
    worst = max(report["estimates"].items(), key=lambda item: item[1]["differing_alone"])
    if worst[1]["differing_alone"] > MAX_DIFFERING * len(counts):
        raise ExportError(f"{out}: its {worst[0]} differs from the scikit-learn stack's on "
                          f"{worst[1]['differing_alone']} of {len(counts)} frames (more than "
                          f"{MAX_DIFFERING:.1%}): see {path}")
    estimates = report["estimates"].values()
    alone = sum(e["differing_alone"] for e in estimates)
    batch_only = sum(e["differing_in_batch"] for e in estimates) - alone
    return (f"{scene}: stack → {out} ({report['bytes'] / 1e6:.2f} MB); on {len(counts)} frames "
            f"its estimates are the scikit-learn stack's within {TOLERANCE:g}"
            + (f" but {alone}" if alone else "")
            + (f" ({batch_only} only as that stack predicts the frame alone: its own batch "
               "sums differ)" if batch_only else ""))
