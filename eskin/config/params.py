"""params.yaml whole: every section's schema, for what reads the file whole (the
publish stage logs it; `eskin`'s commands check it before they start). A stage
reads only its own sections (eskin.config.base.sections)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from eskin.config.acquisition import Acquire, Sim, SimBoard
from eskin.config.base import Section
from eskin.config.cv import CV
from eskin.config.featurize import Featurize
from eskin.config.ingest import Ingest
from eskin.config.live import Live
from eskin.config.report import Report
from eskin.config.scenes import Scenes
from eskin.config.train import Train


class Params(Section):
    """params.yaml: the pipeline's knobs, every one read by a stage of dvc.yaml (`dvc exp
    show` lists the whole file)."""

    sim: Sim
    sim_board: SimBoard
    acquire: Acquire
    scenes: Scenes
    ingest: Ingest
    featurize: Featurize
    cv: CV
    train: Train  # type: ignore[valid-type]
    report: Report
    live: Live


# The sections `dvc repro` reads, which are params.yaml's (make bench's and make stress's
# have files of their own): the publish stage logs these to the pipeline's MLflow run.
# `live` is `eskin live`'s (and the bench's live hour's): no pipeline stage reads it.
PIPELINE_SECTIONS: tuple[str, ...] = tuple(name for name in Params.model_fields
                                           if name != "live")


def pipeline_params(params: Params) -> dict[str, Any]:
    """The sections the pipeline reads (:data:`PIPELINE_SECTIONS`), as written: keys the
    file leaves out stay out."""
    out: dict[str, Any] = {}
    for name in PIPELINE_SECTIONS:
        section = getattr(params, name)
        out[name] = ({key: spec.model_dump(exclude_unset=True) for key, spec in section.items()}
                     if isinstance(section, Mapping) else section.model_dump(exclude_unset=True))
    return out
