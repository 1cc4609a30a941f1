"""The report, from predictions and scores only.

Public: :func:`eskin.reporting.report.report` (the publish stage's step),
:mod:`~eskin.reporting.presentation` (each kind's headline rows and figures),
:mod:`~eskin.reporting.figures` and :mod:`~eskin.reporting.page`."""
