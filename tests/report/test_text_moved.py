"""Text formatting lives in servotune.report.text (issue 16); the old names warn and still work."""

from __future__ import annotations

import importlib

import pytest

from servotune.report import text


@pytest.mark.parametrize(
    ("package", "name"),
    [
        ("servotune.verify", "format_table"),
        ("servotune.arch.gantry", "format_comparison"),
        ("servotune.arch.linkage", "format_linkage_summary"),
    ],
)
def test_the_old_name_warns_and_gives_the_same_function(package: str, name: str) -> None:
    mod = importlib.import_module(package)
    assert name not in mod.__all__
    with pytest.warns(DeprecationWarning, match=rf"{package}\.{name} moved to servotune.report"):
        old = getattr(mod, name)
    assert old is getattr(text, name)


def test_an_unknown_name_is_still_an_attribute_error() -> None:
    mod = importlib.import_module("servotune.verify")
    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        mod.nope  # noqa: B018
