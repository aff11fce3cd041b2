"""The fuzz warm-up (tests/fuzz/conftest.py) keeps the contract, and leaves nothing running.

Its runs are the only ones that import the CLI's modules and load the kernels in this process
(every example's child inherits them): a warning or error on that path is caught here."""

from __future__ import annotations

from tests.fuzz.contract import check


def test_warmup_keeps_the_contract(fuzz_warmup):
    for o in fuzz_warmup["outcomes"]:
        assert check(o, allow_warning_lines=True) == "verdict", o.short()
    assert not fuzz_warmup["threads"], fuzz_warmup["threads"]
