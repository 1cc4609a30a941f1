"""MLflow and the planner.

Public: :mod:`~eskin.tracking.connection` (the store, its experiment, the UI's links),
:func:`eskin.tracking.runs.track_pipeline` (the publish stage's step),
:mod:`~eskin.tracking.compare` (``eskin compare``, ``eskin audit``),
:mod:`~eskin.tracking.registry` (``eskin promote``, ``eskin reproduce``),
:mod:`~eskin.tracking.lab` (a lab's server) and :mod:`~eskin.tracking.planning`
(``eskin plan``)."""
