"""The trained stack on the robot side.

Public: :class:`eskin.deploy.stack.SkinStack` (a scene's models as one object;
``ExportedStack``: its ONNX),
:func:`eskin.deploy.export.stack_to_onnx` (a stack as ONNX),
:mod:`~eskin.deploy.live` (``eskin live``) and :mod:`~eskin.deploy.view` (its page)."""
