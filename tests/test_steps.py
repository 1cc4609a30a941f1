"""A command and its stage are one step (eskin.steps): `eskin acquire`, `ingest`,
`featurize` and `train` write the bytes that the stages `dvc repro` runs write, each in
its own process, as a user and DVC run them."""

import shutil
import subprocess
import sys

import pytest
import yaml
from conftest import ROOT, eskin, quick_params, small_scenes, write_params

from eskin.catalog import features_path, folds_path, scores_path, settings_path

pytestmark = pytest.mark.starts  # the simulated board, and a process per step


def run_stage(module: str, *args: str, cwd) -> None:
    done = subprocess.run([sys.executable, "-m", f"stages.{module}", *args], cwd=cwd,
                          text=True, capture_output=True, timeout=300)
    assert done.returncode == 0, f"stages.{module}: {done.stdout}\n{done.stderr}"


def test_the_commands_and_the_stages_write_the_same_bytes(tmp_path):
    params = quick_params(small_scenes(yaml.safe_load((ROOT / "params.yaml").read_text())),
                          folds=2)
    params["scenes"]["single_force"].update(stretches=[1.0, 1.07921], forces=[0.0, 3.2536],
                                            samples=2)
    by_command, by_stage = tmp_path / "command", tmp_path / "stage"
    for root in (by_command, by_stage):
        write_params(root, params)
    shutil.copytree(ROOT / "stages", by_stage / "stages")  # run from the project root
    scene, task = "single_force", "stretch"
    for args in (["acquire", scene, "--no-progress"], ["ingest", scene], ["featurize", scene],
                 ["train", scene, task]):
        done = eskin(args, by_command)
        assert done.returncode == 0, f"eskin {' '.join(args)}: {done.stdout}\n{done.stderr}"
    for module, args in (("acquire", [scene]), ("prepare", [scene]), ("settings", []),
                         ("train", [scene, task])):
        run_stage(module, *args, cwd=by_stage)
    written = [f"data/raw/{scene}/acquisition.log", f"data/processed/{scene}.parquet",
               features_path(scene), folds_path(scene), settings_path(scene, task),
               scores_path(scene, task)]
    for path in written:
        assert (by_command / path).read_bytes() == (by_stage / path).read_bytes(), path
