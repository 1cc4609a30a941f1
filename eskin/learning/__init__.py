"""Features, estimators and training.

Public: :mod:`~eskin.learning.features` (the featurize step),
:func:`eskin.learning.train.train_task` (one task trained, in memory),
:func:`eskin.learning.estimators.build_model` (models by name), :mod:`~eskin.learning.choice`
and :mod:`~eskin.learning.settings` (which model a task trains), and
:mod:`~eskin.learning.saved` (models loaded by their md5)."""
