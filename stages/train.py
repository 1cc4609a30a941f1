"""DVC stage: features and folds of a scene, and the models its settings name → each
task's scores, predictions, models, and the run's record for the publish stage (a task
trained from the same inputs and code is kept); then the scene's stack as one ONNX file
for a robot-side process, checked against the scikit-learn stack (a stack exported from
the same models, dataset and code is kept). In one process: a knob of one model pays
one process and one of DVC's stages, not two. ``python -m stages.train <scene> <task>``:
that task alone, and no export."""

import sys

from eskin.errors import TASKS_KEPT, run_friendly
from eskin.steps import train


def main(scene: str, task: str | None = None) -> str:
    said = train.run(scene, task)
    if task is not None:
        return said
    from eskin.steps import export  # ONNX's converters: only the stage's run needs them

    return said + "\n" + export.export_at(scene, recorded=export.trained_md5s(scene), keep=True)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(*sys.argv[1:3])), interrupted=TASKS_KEPT))
