"""Hostile bytes never run: models load only after their hash matches; nothing that reads
serial or file input evaluates it; the simulated board listens on loopback only."""

import ast
import pathlib
import socket
from pathlib import Path

import joblib
import pytest

from eskin.data.schema import md5_file
from eskin.learning.saved import ModelIntegrityError, load_models

ROOT = Path(__file__).resolve().parents[1]


class Booby:
    """Unpickling this touches a file: proof that the bytes ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return pathlib.Path.touch, (self.marker,)


def test_a_model_file_is_unpickled_only_when_its_md5_matches(tmp_path):
    good = tmp_path / "force.joblib"
    joblib.dump({"force": [1, 2, 3]}, good)
    recorded = md5_file(good)
    marker = tmp_path / "ran"
    joblib.dump({"force": Booby(marker)}, good)  # swapped after the md5 was recorded
    with pytest.raises(ModelIntegrityError, match="force.joblib: md5 is .* but .* was recorded"):
        load_models(good, recorded)
    assert not marker.exists(), "the swapped file ran code"
    load_models(good, md5_file(good))  # the same bytes, trusted: they do run
    assert marker.exists()


def test_no_eval_or_exec_anywhere_in_the_library():
    calls = []
    for path in (ROOT / "eskin").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id in ("eval", "exec", "compile", "__import__"):
                calls.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.func.id}")
            if isinstance(node, ast.Attribute) and node.attr in ("loads", "load") \
                    and isinstance(node.value, ast.Name) and node.value.id in ("pickle", "marshal"):
                calls.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.value.id}.{node.attr}")
    assert calls == []


def test_simulated_board_socket_is_not_reachable_off_loopback():
    from eskin.acquisition.session import simulated_board
    from eskin.device.physics import SkinParams

    with simulated_board(SkinParams(), rest_length_mm=101.0, socket_port=0) as board:
        port = int(board.port.rsplit(":", 1)[1])
        assert board.port.startswith("socket://127.0.0.1:")
        outward = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            outward.connect(("192.0.2.1", 9))  # no packet sent: picks the outward address
            address = outward.getsockname()[0]
        finally:
            outward.close()
        if address.startswith("127."):
            pytest.skip("no non-loopback address on this machine")
        with pytest.raises(OSError):
            socket.create_connection((address, port), timeout=2).close()
