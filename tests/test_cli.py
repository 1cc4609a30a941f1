"""The command line as a new user meets it: ``eskin --help`` and each command's."""

import argparse

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


def test_the_top_help_is_plain_text_with_examples():
    text = build_parser().format_help()
    assert "``" not in text
    assert "examples:" in text
    example_commands = [line.split()[1] for line in text.split("examples:")[1].splitlines()
                        if line.startswith("  eskin ")]
    known = {name for path, _ in _commands(build_parser()) for name in path[1:2]}
    assert example_commands and set(example_commands) <= known
