"""The command line as a new user meets it: ``eskin --help`` and each command's."""

import argparse
import os
import shlex
import subprocess
import sys

import pytest

from eskin.cli import build_parser


def _commands(parser: argparse.ArgumentParser, path=("eskin",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


def test_every_argument_of_every_command_says_what_it_is():
    unexplained = [f"{' '.join(path)} {action.dest}"
                   for path, parser in _commands(build_parser())
                   for action in parser._actions
                   if not action.help and not isinstance(action, argparse._SubParsersAction)]
    assert unexplained == []


def example_commands(text: str) -> list[list[str]]:
    """The commands of a help text's examples: each line under ``examples:`` that starts
    ``  eskin``, up to two spaces (what the command does follows them), as argv."""
    examples = text.split("examples:", 1)[1] if "examples:" in text else ""
    return [shlex.split(line.strip().split("  ")[0])
            for line in examples.splitlines() if line.startswith("  eskin ")]


def test_every_command_says_what_it_does_with_an_example_that_parses():
    """`eskin ports --help` said nothing of what it does. Every command, nested ones too,
    has a one-sentence description and examples of itself under its --help, kept line for
    line; each example's arguments are accepted by the parser (parsed, not run)."""
    parser = build_parser()
    commands = list(_commands(parser))
    assert len(commands) >= 16  # eskin, 13 commands, device's 2
    for path, command in commands[1:]:
        text = command.format_help()
        assert command.description and "\n" not in command.description.strip(), path
        assert command.description.split()[0] in text, (path, text)
        examples = example_commands(text)
        assert any(argv[1:len(path)] == list(path[1:]) for argv in examples), (path, text)
        for argv in examples:
            try:
                parser.parse_args(argv[1:])
            except SystemExit:
                raise AssertionError(f"{' '.join(path)} --help: `{' '.join(argv)}` does not "
                                     "parse") from None
    for argv in example_commands(parser.format_help()):  # eskin --help's own examples
        parser.parse_args(argv[1:])


def test_the_top_help_is_plain_text_with_examples():
    text = build_parser().format_help()
    assert "``" not in text
    assert "examples:" in text
    example_commands = [line.split()[1] for line in text.split("examples:")[1].splitlines()
                        if line.startswith("  eskin ")]
    known = {name for path, _ in _commands(build_parser()) for name in path[1:2]}
    assert example_commands and set(example_commands) <= known


MLFLOW_CHATTER = ("INFO", "Creating initial", "Updating database tables", "Context impl",
                  "Will assume")


@pytest.mark.starts
def test_a_fresh_mlflow_store_says_nothing_of_its_tables(tmp_path):
    """The first command against a new SQLite store makes its tables: MLflow's and
    alembic's INFO lines about it are not the command's output, nor the tracking
    stage's (which connects through the same module)."""
    env = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'cli.db'}"}
    env.pop("MLFLOW_LOGGING_LEVEL", None)
    done = subprocess.run([sys.executable, "-m", "eskin", "compare"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert (tmp_path / "cli.db").exists()  # the store was made, by this command
    assert done.returncode == 1 and done.stdout == "", done
    assert done.stderr.startswith("eskin: error: no MLflow experiment 'eskin'"), done.stderr
    assert done.stderr.count("\n") == 1, done.stderr
    env["MLFLOW_TRACKING_URI"] = f"sqlite:///{tmp_path / 'track.db'}"
    done = subprocess.run([sys.executable, "-c", "from eskin.tracking import connection; "
                           "print(connection.ensure_experiment())"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip().isdigit(), done
    assert not [line for line in done.stderr.splitlines()
                if any(word in line for word in MLFLOW_CHATTER)], done.stderr
