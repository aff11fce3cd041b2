"""Every spec field survives ``Problem.to_toml``: a contract on the field list.

``spec/toml_out.problem_data`` writes the spec's fields by hand, one line per field, so a
field added to the parser (``parse.FIELDS``) and forgotten there reads back as its default.
The random designs of tests/engine/test_design_api.py catch that only for the fields their
strategy draws. Here the bundled examples, the test fixtures and the two spec files in
``tests/contract/fields/`` must together set every field of ``parse.FIELDS`` (a new field
fails :func:`test_every_field_is_set_by_some_spec` until a fixture sets it, at a value other
than its default), and each of them must read back equal after ``to_toml``.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

import codev_engine as ce
from codev_engine.spec.parse import FIELDS

ROOT = Path(__file__).resolve().parents[2]
SPECS = sorted(
    [
        *ROOT.glob("examples/*.toml"),
        *ROOT.glob("tests/**/*.toml"),
        *ROOT.glob("sessions/*/spec.toml"),
    ]
)
TABLES = {name for name in FIELDS if name}


def _fields_set(path: Path) -> set[tuple[str, str]]:
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    found = set()
    for table, names in FIELDS.items():
        section = data if table == "" else data.get(table, {})
        for name in names:
            if table == "" and name in TABLES:
                continue  # the tables themselves, checked field by field
            if isinstance(section, dict) and name in section:
                found.add((table, name))
    return found


def test_every_field_is_set_by_some_spec():
    seen = set().union(*(_fields_set(p) for p in SPECS))
    every = {(t, n) for t, names in FIELDS.items() for n in names if not (t == "" and n in TABLES)}
    missing = sorted(f"{t}.{n}" if t else n for t, n in every - seen)
    assert not missing, f"no spec sets {missing}: add it to a file in tests/contract/fields/"


@pytest.mark.parametrize("path", sorted(ROOT.glob("tests/contract/fields/*.toml")),
                         ids=lambda p: p.stem)  # fmt: skip
def test_a_spec_setting_the_rare_fields_reads_back_equal(path):
    problem = ce.load_spec(path, check_mpc=False)
    text = problem.to_toml()
    again = ce.loads_spec(text, check_mpc=False)
    assert again == problem
    for table, name in _fields_set(path):
        # written out, not only equal by luck of a default
        data = tomllib.loads(text)
        assert name in (data if table == "" else data[table]), f"{table}.{name} not written"
