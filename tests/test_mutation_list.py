"""The mutation list (tests/mutations.toml, run by ``make mutate``) stays usable as the code
changes: every entry still applies to exactly one line, names its tests, and together the
entries cover every physics module. (Running the mutations takes minutes and is not part of
``make test``; a list that no longer applies would fail it silently otherwise.)"""

from __future__ import annotations

import pytest

from tests.mutate import ROOT, StaleList, check_applies, load

PHYSICS = ["shading", "camera", "geometry", "sampling", "shapes", "lights", "trace", "integrator", "film"]


def test_every_mutation_applies_to_one_line_and_names_existing_tests():
    muts = load()
    assert len(muts) >= 30
    for m in muts:
        try:
            check_applies(m)
        except StaleList as e:
            pytest.fail(str(e))
        for arg in m.tests:
            if arg.startswith("tests/"):
                assert (ROOT / arg.split("::")[0]).is_file(), (m.name, arg)


def test_the_list_covers_every_physics_module():
    files = {m.file for m in load()}
    missing = [name for name in PHYSICS if f"warprt/{name}.py" not in files]
    assert not missing
