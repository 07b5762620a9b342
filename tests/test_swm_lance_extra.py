"""A Lance table read without stable-worldmodel's Lance support says what to install (its releases after 0.1.1 move
Lance reading into a [data] extra) instead of a bare ImportError."""

import types

import pytest

from pokeworld.errors import DataError
from pokeworld.swm import dataset


def test_missing_lance_support_is_one_line_naming_the_extra(tmp_path):
    def get_format(name):
        raise ModuleNotFoundError("No module named 'lancedb'")

    swm = types.SimpleNamespace(data=types.SimpleNamespace(get_format=get_format))
    table = tmp_path / "episodes.lance"
    table.mkdir()
    with pytest.raises(DataError, match=r"stable-worldmodel\[data\]"):
        dataset._read_lance(table, swm, 2**30)
