"""Acquisition: a scene's plan recorded from a board into its raw log.

Public: :func:`eskin.acquisition.acquire.acquire` (the acquire stage's step) and
:func:`~eskin.acquisition.acquire.check_scenes`; :mod:`~eskin.acquisition.runner` (the
conditions, requested and retried) and :mod:`~eskin.acquisition.session` (a board's
connection). The plan and the raw log are data's (:mod:`eskin.data.plan`,
:mod:`eskin.data.rawlog`)."""
