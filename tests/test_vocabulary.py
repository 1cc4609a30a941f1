"""One vocabulary: a kind of scene and the skin's size are each defined in one place."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from eskin.kinds import DATASET_KINDS, get_kind
from eskin.skin import PAPER_SKIN, Skin

ROOT = Path(__file__).resolve().parents[1]
# The catalog of kinds is the one place their names are written; the fuzzer writes files
# the way another lab would, knowing nothing of eskin's kinds.
ALLOWED = {ROOT / "eskin/kinds.py", ROOT / "harness/fuzz.py"}


def _code_files():
    for package in ("eskin", "stages", "harness"):
        yield from (p for p in (ROOT / package).rglob("*.py") if "__pycache__" not in p.parts)


def test_no_kind_name_is_written_outside_the_catalog():
    found = []
    for path in _code_files():
        if path in ALLOWED:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and node.value in DATASET_KINDS:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}")
    assert not found, "kind names outside eskin/kinds.py:\n" + "\n".join(found)


def test_skins_are_built_only_where_they_are_declared():
    """A skin comes from params.yaml (config.scene_skin), a dataset (schema.dataset_skin)
    or the paper's: every Skin and ChannelArray is built in eskin/skin.py."""
    built = []
    for path in _code_files():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) in (
                    "Skin", "ChannelArray"):
                built.append(str(path.relative_to(ROOT)))
    assert set(built) == {"eskin/skin.py"}, built
    assert _line_of("PAPER_SKIN = Skin(rows=10, columns=10)")


def _line_of(text: str) -> int:
    lines = (ROOT / "eskin/skin.py").read_text().splitlines()
    return next(i for i, line in enumerate(lines, 1) if line.startswith(text))


def test_the_paper_skin_is_the_papers():
    assert PAPER_SKIN.terminals == 20 and PAPER_SKIN.n_nodes == 100
    assert PAPER_SKIN.channels[:2] == ["cx1", "cx2"] and PAPER_SKIN.channels[-1] == "cy10"
    assert PAPER_SKIN.node_id(np.array([0, 1, 10]), np.array([0, 1, 10])).tolist() == [0, 1, 100]


def test_a_rectangular_skin_numbers_its_nodes_x_major():
    skin = Skin(rows=3, columns=5)
    assert skin.terminals == 8 and skin.channels[3:] == ["cy1", "cy2", "cy3", "cy4", "cy5"]
    ids = skin.node_id(np.array([x for x, _ in skin.nodes()]),
                       np.array([y for _, y in skin.nodes()]))
    assert ids.tolist() == list(range(1, 16))


@pytest.mark.parametrize("rows", [1, 33])
def test_a_skin_outside_2_to_32_terminals_is_refused(rows):
    with pytest.raises(ValueError, match="2 to 32 rows"):
        Skin(rows=rows, columns=4)


def test_kinds_say_their_columns_widths_and_outputs():
    one, two = get_kind("single_force"), get_kind("two_force")
    assert one.labels == ["force", "x", "y", "stretch"]
    assert two.labels == ["force1", "x1", "y1", "force2", "x2", "y2", "stretch"]
    assert one.file_widths(PAPER_SKIN) == (24,) and two.file_widths(PAPER_SKIN) == (26, 27)
    for counted in (True, False):  # one contact: the same, with a detector or without
        assert one.stack_outputs(counted) == ["stretch", "contact", "contact_probability",
                                              "x", "y", "force"]
    assert two.stack_outputs(False) == ["stretch", "x1", "y1", "x2", "y2", "force1", "force2"]
    assert two.stack_outputs(True) == ["stretch", "contact", "contact_probability", "contacts",
                                       "x1", "y1", "x2", "y2", "force1", "force2"]
    assert (one.detect_target, two.detect_target) == ("contact", "contacts")
    with pytest.raises(ValueError, match="unknown scene kind 'three_force'"):
        get_kind("three_force")


def test_strata_are_the_node_or_the_pair_of_nodes():
    frame = pd.DataFrame({"x1": [0, 1, 10], "y1": [0, 2, 10], "x2": [0, 3, 1], "y2": [0, 4, 1]})
    expected = [0, 2 * 101 + 24, 100 * 101 + 1]
    assert get_kind("two_force").strata(frame, PAPER_SKIN).tolist() == expected
    single = pd.DataFrame({"x": [0, 2], "y": [0, 3]})
    assert get_kind("single_force").strata(single, PAPER_SKIN).tolist() == [0, 13]
