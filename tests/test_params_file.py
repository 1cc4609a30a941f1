"""params.yaml as DVC rewrites it: `dvc exp run -S key=value` loads the file through
ruamel.yaml's round trip, applies the override to a plain copy and merges it back
(``dvc.utils.hydra.apply_overrides``), which turns every list into a block list and drops
what hung on the old one. The file is laid out in the form that survives, so that one
setting changes one line (and a real `dvc exp run -S`: tests/test_daily_loop.py); so are
bench/params.yaml and stress/params.yaml, the default params files of `make bench` and
`make stress` (DVC projects of their own)."""

import difflib
import shutil
from pathlib import Path

import pytest
from dvc.utils.hydra import apply_overrides

ROOT = Path(__file__).resolve().parents[1]


def set_param(tmp_path: Path, override: str, name: str = "params.yaml") -> list[str]:
    """The lines of the params file ``name`` that `-S override` changes: out with -, in
    with +."""
    path = tmp_path / "params.yaml"
    shutil.copy(ROOT / name, path)
    apply_overrides(path, [override])  # what `dvc exp run -S` calls on the file
    before = (ROOT / name).read_text().splitlines()
    after = path.read_text().splitlines()
    return [line for line in difflib.unified_diff(before, after, lineterm="", n=0)
            if line[:1] in "+-" and not line.startswith(("+++", "---"))]


@pytest.mark.parametrize("name, override", [
    ("params.yaml", "sim.seed=20230529"),
    ("bench/params.yaml", "bench.seed=42"),
    ("stress/params.yaml", "stress.seed=0"),
])
def test_dvc_writes_params_files_back_unchanged(tmp_path, name, override):
    # a setting set to its own value: every list, comment and blank line as written
    assert set_param(tmp_path, override, name) == []


@pytest.mark.parametrize("name, override, changed", [
    ("params.yaml", "sim_board.faults.log=faults.txt", 2),
    ("params.yaml", "cv.schemes.0=conditions", 2),
    ("params.yaml", "train.localise.model.two_force=extra_trees", 2),
    ("params.yaml", "scenes.two_force.nodes_x=[1,6]", 1),  # one item fewer
    ("bench/params.yaml", "soak.kill_at=[0.33,0.5]", 2),
    ("bench/params.yaml", "bench.tasks.force.sparse_gp.n_inducing=250", 2),
    ("stress/params.yaml", "stress.noise_scene.samples=3", 2),
])
def test_one_setting_changes_its_own_lines_of_its_params_file(tmp_path, name, override,
                                                              changed):
    lines = set_param(tmp_path, override, name)
    assert len(lines) == changed, "\n".join(lines)


def test_the_sim_section_names_every_simulator_parameter():
    """config declares the sim section itself (so that a physics edit reruns only what
    reads the physics); it must name exactly SkinParams' fields, each required."""
    import dataclasses

    from eskin.config.acquisition import Sim
    from eskin.device.physics import SkinParams

    fields = {f.name for f in dataclasses.fields(SkinParams)}
    assert set(Sim.model_fields) == fields
    assert all(field.is_required() for field in Sim.model_fields.values())
