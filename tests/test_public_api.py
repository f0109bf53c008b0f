"""Every name a package's ``__all__`` lists is importable (a merge once dropped 26 of them)."""

import importlib

import pytest

PACKAGES = [
    "hocnet",
    "hocnet.data",
    "hocnet.dpa",
    "hocnet.hoc",
    "hocnet.tracking",
    "hocnet.metrics",
]


@pytest.mark.parametrize("name", PACKAGES)
def test_all_names_resolve(name):
    module = importlib.import_module(name)
    missing = [n for n in module.__all__ if not hasattr(module, n)]
    assert missing == [], missing
    assert len(set(module.__all__)) == len(module.__all__)
