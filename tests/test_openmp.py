"""OpenMP's idle threads wait passively in every eskin process (eskin/__init__.py): a
spinning thread beside another busy process holds the core the work needs (issue 55)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SHOW = ("import eskin.learning.estimators, os; "  # loads scikit-learn, and with it OpenMP
        "print(os.environ['OMP_WAIT_POLICY'])")


@pytest.mark.parametrize(("given", "seen"), [(None, "PASSIVE"), ("active", "active")])
def test_an_eskin_process_waits_passively_unless_told_otherwise(given, seen):
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if given is not None:
        env["OMP_WAIT_POLICY"] = given
    shown = subprocess.run([sys.executable, "-c", SHOW], env=env, capture_output=True,
                           text=True, check=True).stdout.strip()
    assert shown == seen
