"""The params files' schemas and their loader, a module a section, so that a stage imports
(and so, in dvc.yaml, depends on) only the sections it reads: :mod:`~eskin.config.base`
(the loader, :func:`~eskin.config.base.load_params` and
:func:`~eskin.config.base.sections`), :mod:`~eskin.config.acquisition` (``sim``,
``sim_board``, ``acquire``), :mod:`~eskin.config.scenes`, :mod:`~eskin.config.ingest`,
:mod:`~eskin.config.featurize`, :mod:`~eskin.config.cv`, :mod:`~eskin.config.train`,
:mod:`~eskin.config.report`, :mod:`~eskin.config.live`, :mod:`~eskin.config.planning`
(bench/params.yaml's ``learning_curve``) and :mod:`~eskin.config.params` (params.yaml
whole)."""
