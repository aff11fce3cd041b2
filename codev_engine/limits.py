"""The engine's limits on work that grows while it runs (docs/spec.md, "Limits").

The loader refuses a spec whose size is too large before any work starts
(``pipeline.check_size``). Some work cannot be sized from the fields: how many critical
regions a synthesis finds, how many branches and reachtube boxes a verification explores.
These limits stop it while it runs, with a one-line message that names what to change:

* ``region_bytes``: the memory the critical regions of one synthesis may take (the
  synthesis ends in a ``SolverError``, exit 1);
* ``branches``: branch periods one verification explores (one set through one sample
  period), and ``tube_bytes``: the memory its reachtube's boxes may take; past either, the
  verdict is ``unknown`` with reason ``"limit"`` (a limitation of the verifier, not of the
  design).

The environment variable ``CODEV_LIMITS`` overrides them, e.g.
``CODEV_LIMITS="branches=2e6,tube_bytes=8e9"`` (read when a synthesis or a verification
starts; an unknown name or a value that is not a positive number is an error naming it).
"""

from __future__ import annotations

import os

from codev_engine.errors import SpecError

__all__ = ["DEFAULTS", "LIMITS_ENV", "limits"]

#: the environment variable that overrides :data:`DEFAULTS`
LIMITS_ENV = "CODEV_LIMITS"

#: the limits when ``CODEV_LIMITS`` does not set them
DEFAULTS: dict[str, int] = {
    "region_bytes": 2**32,  # 4 GiB of critical regions in one synthesis
    "branches": 500_000,  # branch periods of one verification
    "tube_bytes": 2**31,  # 2 GiB of reachtube boxes ((2 n + 3) × 8 bytes each)
}


def limits() -> dict[str, int]:
    """The limits in force: :data:`DEFAULTS`, updated from ``CODEV_LIMITS``.

    Returns
    -------
    dict of str to int

    Raises
    ------
    SpecError
        ``CODEV_LIMITS`` names an unknown limit or gives a value that is not a positive
        number (``field="CODEV_LIMITS"``).
    """
    out = dict(DEFAULTS)
    text = os.environ.get(LIMITS_ENV, "").strip()
    for item in filter(None, (p.strip() for p in text.split(","))):
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in DEFAULTS:
            raise SpecError(
                f"unknown limit {name!r} (known: {', '.join(DEFAULTS)})", field=LIMITS_ENV
            )
        try:
            number = float(value)
        except ValueError:
            number = float("nan")
        if not number >= 1 or number == float("inf"):
            raise SpecError(f"{name}: expected a positive number, got {value!r}", field=LIMITS_ENV)
        out[name] = int(number)
    return out
