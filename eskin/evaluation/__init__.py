"""Scoring what learning trains.

Public: :mod:`~eskin.evaluation.tasks` (what each kind of scene learns),
:mod:`~eskin.evaluation.folds` (CV folds, drawn once),
:func:`eskin.evaluation.crossval.cross_validate` (the one fold runner),
:mod:`~eskin.evaluation.metrics`, and :mod:`~eskin.evaluation.pairs` (two contacts
scored as sets; ``score_scene_pairs``, the report's step)."""
