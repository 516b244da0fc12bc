"""Every module states its public names (``__all__``), and docs/INTERFACES.md lists them."""

from __future__ import annotations

import importlib

import pytest

from tests.public_api import ROOT, current_section, declared_all, listing, module_name, stated_modules, unused_names


def test_every_module_states_its_public_names():
    missing = [str(p.relative_to(ROOT)) for p in stated_modules() if declared_all(p) is None]
    assert not missing, f"add __all__ to: {missing}"


def test_every_stated_name_is_used_by_another_module():
    """``__all__`` is a deliberate surface: a name no other module uses is the module's own detail."""
    assert unused_names() == {}, "drop these from __all__ (or use them): " + str(unused_names())


def test_interfaces_lists_them():
    assert current_section() == listing(), "run: python -m tests.public_api"


LEAN = [module_name(p) for p in stated_modules() if p.parts[len(ROOT.parts)] in ("firmware_io", "runtime")
        and module_name(p) not in ("runtime.ros2_node",)]


@pytest.mark.parametrize("name", LEAN)
def test_every_stated_name_exists(name):
    """Each name of ``__all__`` is defined by its module (imported for real, not read as text)."""
    module = importlib.import_module(name)
    assert [n for n in module.__all__ if not hasattr(module, n)] == []
