"""The trained stack on the robot side.

Public: :class:`eskin.deploy.stack.SkinStack` (a scene's models as one object;
``ExportedStack``: its ONNX),
:func:`eskin.deploy.export.export_scene` (the export stage's step: ONNX),
:mod:`~eskin.deploy.live` (``eskin live``) and :mod:`~eskin.deploy.view` (its page)."""
