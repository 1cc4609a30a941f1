"""params.yaml as DVC rewrites it: `dvc exp run -S key=value` round-trips the file
through ruamel.yaml (DVC's `modify_yaml`), which re-wraps any flow mapping longer than
80 columns; the file is laid out so that one setting changes one line."""

import difflib
import shutil
from pathlib import Path

import pytest
from dvc.utils.serialize import modify_yaml

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("key, value", [
    ("train.force.model.single_force", "random_forest"),
    ("sim.seed", 7),
    ("soak.faults.drop", 0.02),
    ("bench.tasks.force.sparse_gp.n_inducing", 250),
    ("scenes.two_force.samples", 5),
])
def test_one_setting_changes_one_line_of_params_yaml(tmp_path, key, value):
    path = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", path)
    with modify_yaml(path) as params:  # what `dvc exp run -S key=value` does
        *parents, last = key.split(".")
        node = params
        for part in parents:
            node = node[part]
        node[last] = value
    before = (ROOT / "params.yaml").read_text().splitlines()
    after = path.read_text().splitlines()
    changed = [line for line in difflib.unified_diff(before, after, lineterm="", n=0)
               if line[:1] in "+-" and not line.startswith(("+++", "---"))]
    assert len(changed) == 2, "\n".join(changed)  # one line out, one line in


def test_the_sim_section_names_every_simulator_parameter():
    """config declares the sim section itself (so that a physics edit reruns only what
    reads the physics); it must name exactly SkinParams' fields, each required."""
    import dataclasses

    from eskin.config import Sim
    from eskin.device.physics import SkinParams

    fields = {f.name for f in dataclasses.fields(SkinParams)}
    assert set(Sim.model_fields) == fields
    assert all(field.is_required() for field in Sim.model_fields.values())
