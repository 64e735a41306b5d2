"""Every command's options, exactly: each subcommand's argparse actions (flags, dest,
default, type, choices, nargs, required, help, groups, old spellings) against the
snapshot in ``parsers.json``. A parser rebuilt from tables or helpers must parse and
document the same options; a deliberate change of an option regenerates the snapshot
(``python tests/cli/test_parsers.py``) and shows up in its diff."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from masknet.cli import build_parser

SNAPSHOT = Path(__file__).with_name("parsers.json")


def _plain(value: Any) -> Any:
    """``value`` as JSON can hold it: containers kept, anything else by its repr."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    return repr(value)


def _type_name(kind: Any) -> str | None:
    """The name argparse shows for a type (``positive_int``, ``float``), None for none."""
    return None if kind is None else getattr(kind, "__name__", repr(kind))


def _action(action: argparse.Action, group: str | None, exclusive: int | None) -> dict:
    """One option or positional: what decides how it parses and how ``--help`` shows it."""
    row = {
        "action": type(action).__name__,
        "option_strings": list(action.option_strings),
        "dest": action.dest,
        "default": _plain(action.default),
        "type": _type_name(action.type),
        "choices": _plain(None if action.choices is None else list(action.choices)),
        "nargs": _plain(action.nargs),
        "const": _plain(action.const),
        "required": action.required,
        "metavar": _plain(action.metavar),
        "help": action.help,
        "group": group,
        "exclusive": exclusive,
    }
    for extra in ("new", "append"):  # an old spelling's pointer to its new one
        if hasattr(action, extra):
            row[extra] = _plain(getattr(action, extra))
    return row


def dump_parser(parser: argparse.ArgumentParser) -> dict:
    """A subcommand's parser as plain data: its texts, groups and actions in order."""
    groups = {id(a): g.title for g in parser._action_groups for a in g._group_actions}
    exclusive: dict[int, int] = {}
    for number, group in enumerate(parser._mutually_exclusive_groups):
        exclusive |= {id(a): number for a in group._group_actions}
    return {
        "prog": parser.prog,
        "description": parser.description,
        "epilog": parser.epilog,
        "formatter": parser.formatter_class.__name__,
        "exclusive_required": [g.required for g in parser._mutually_exclusive_groups],
        "groups": [[g.title, g.description] for g in parser._action_groups],
        "actions": [_action(a, groups.get(id(a)), exclusive.get(id(a))) for a in parser._actions],
    }


def dump_commands() -> dict:
    """Every subcommand of ``masknet``: its one-line help and its parser."""
    parser = build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    return {
        name: {"help": helps.get(name), **dump_parser(command)}
        for name, command in sub.choices.items()
    }


def test_every_command_parses_and_documents_the_options_of_the_snapshot():
    expected = json.loads(SNAPSHOT.read_text())
    found = json.loads(json.dumps(dump_commands()))  # tuples as lists, as the file has them
    assert list(found) == list(expected)
    for name in expected:
        assert found[name] == expected[name], name


def test_the_dump_sees_a_changed_default():
    """The comparison is not blind: a default changed on a built parser shows."""
    parser = build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    before = dump_parser(sub.choices["register"])
    sub.choices["register"].set_defaults(max_points=2048)
    assert dump_parser(sub.choices["register"]) != before


if __name__ == "__main__":  # regenerate the snapshot after a deliberate change of options
    SNAPSHOT.write_text(json.dumps(dump_commands(), indent=1, sort_keys=False) + "\n")
    print(f"wrote {SNAPSHOT}", file=sys.stderr)
