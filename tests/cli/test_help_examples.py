"""Every verb's ``--help`` ends with examples in users' words, and each
example is a command line the parser accepts (a stale example would teach a wrong command).
The help texts name no document users do not have (the repository's own rule,
tests/test_house.py)."""

from __future__ import annotations

import shlex

import pytest
from test_house import outside_references

from servotune.cli.parser import EXAMPLES, build_parser


def _verbs() -> list[str]:
    sub = next(a for a in build_parser()._actions if a.dest == "verb")
    return sorted(sub.choices)


def test_every_verb_has_examples() -> None:
    assert sorted(EXAMPLES) == _verbs()


@pytest.mark.parametrize("verb", _verbs())
def test_each_example_parses_and_the_help_shows_it(verb: str, capsys) -> None:
    for line in EXAMPLES[verb]:
        words = shlex.split(line.split("#")[0].split(">")[0])
        assert words[:2] == ["servotune", verb], line
        build_parser().parse_args(words[1:])  # exits (SystemExit) if an option is wrong
    with pytest.raises(SystemExit):
        build_parser().parse_args([verb, "--help"])
    out = capsys.readouterr().out
    assert "examples:" in out and EXAMPLES[verb][0].split("#")[0].strip() in out
    assert outside_references(out) == [], verb
