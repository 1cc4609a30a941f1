"""The README as a new user meets it: a fresh clone, `make repro`, then every command of
its "After `make repro`" section, as written and in order. A command that serves (the
MLflow UI, the live view) runs until its page answers in headless Chromium."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest
from conftest import ROOT, headless_chromium, needs_chromium

SECTION = re.compile(r"^## After `make repro`\n(.*?)^## ", re.S | re.M)
FENCE = re.compile(r"^```\n(.*?)^```", re.S | re.M)
# Commands that serve until stopped: the port each binds, the page to open there.
SERVING = {"mlflow ui": 5000, "eskin live": 8050}


def readme_commands(readme: str) -> list[str]:
    """Every line of the section's code blocks, its trailing comment cut."""
    section = SECTION.search(readme).group(1)
    return [re.sub(r"\s+#\s.*$", "", line).strip()
            for block in FENCE.findall(section) for line in block.splitlines()
            if line.strip()]


def test_the_readme_section_is_read_whole():
    commands = readme_commands((ROOT / "README.md").read_text())
    assert commands[0] == "source .venv/bin/activate"
    assert any(c.startswith("dvc exp run -n force-hgb") for c in commands)
    assert "eskin promote single_force --experiment force-hgb" in commands
    assert all("#" not in c for c in commands if not c.startswith("mlflow")), commands


def _wait_for_port(port: int, process: subprocess.Popen, deadline_s: float) -> None:
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise AssertionError(f"it ended with {process.returncode}: {process.stdout.read()}")
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.5)
    raise AssertionError(f"nothing answered on 127.0.0.1:{port} in {deadline_s:.0f} s")


def _bash(command: str) -> list[str]:
    return ["bash", "-c", f"source .venv/bin/activate && {command}"]


@needs_chromium
@pytest.mark.starts
def test_a_fresh_clone_runs_the_readme_after_make_repro(tmp_path):
    clone = tmp_path / "eskin"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, timeout=120)
    env = {k: v for k, v in os.environ.items()
           if k not in ("VIRTUAL_ENV", "DVC_ROOT", "MLFLOW_TRACKING_URI", "PYTHONPATH")}
    env["PATH"] = os.pathsep.join(p for p in env["PATH"].split(os.pathsep)
                                  if not p.startswith(str(ROOT)))
    repro = subprocess.run(["make", "repro"], cwd=clone, env=env, text=True,
                           capture_output=True, timeout=1800)
    assert repro.returncode == 0, repro.stdout[-3000:] + repro.stderr[-3000:]
    log = repro.stdout + repro.stderr
    assert "Running stage 'publish'" in log and "pipeline up to date" in log
    link = re.search(r"http://127\.0\.0\.1:5000/\S+", log).group(0)
    readme = (clone / "README.md").read_text()
    assert link in readme, f"the README's link is not the one the publish stage printed: {link}"

    import mlflow
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{clone / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("eskin")
    kinds = [r.data.tags.get("eskin.kind") for r in client.search_runs(
        [experiment.experiment_id], max_results=1000)]
    assert kinds.count("pipeline") == 1 and kinds.count("task") >= 6, kinds

    commands = readme_commands(readme)[1:]
    while commands:
        command = commands.pop(0)
        serving = next((port for prefix, port in SERVING.items()
                        if command.startswith(prefix)), None)
        if serving is None:
            _run(command, clone, env)
            continue
        process = subprocess.Popen(_bash(command), cwd=clone, env=env, text=True,
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   start_new_session=True)
        try:
            _wait_for_port(serving, process, 120)
            with headless_chromium() as browser:
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                if command.startswith("mlflow ui"):
                    page.goto(link)
                    page.wait_for_selector("text=conditions.single_force.force.r2",
                                           timeout=90_000)
                else:
                    page.goto(f"http://127.0.0.1:{serving}/")
                    page.wait_for_selector("text=frames/s", timeout=60_000)
                    # pressing waits for the tare, as the README says
                    page.wait_for_selector("#tared:has-text('frames at start')",
                                           timeout=60_000)
                    # the commands that talk to a running view ("from another terminal")
                    while commands and commands[0].startswith("eskin press"):
                        _run(commands.pop(0), clone, env)
                        page.wait_for_selector("#contact.touch", timeout=30_000)
        finally:
            os.killpg(process.pid, signal.SIGINT)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
    assert any(c.startswith("eskin press") for c in readme_commands(readme))


def _run(command: str, clone: Path, env: dict) -> None:
    done = subprocess.run(_bash(command), cwd=clone, env=env, text=True, capture_output=True,
                          timeout=1800)
    assert done.returncode == 0, f"{command}:\n{done.stdout[-3000:]}{done.stderr[-3000:]}"
