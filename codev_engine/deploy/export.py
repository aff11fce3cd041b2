"""Export an explicit law (or an ``MpSolution``) as code: C99 or Python.

``export_c(law, dir)`` writes ``dir/PREFIX.h`` and ``dir/PREFIX.c``: a table-driven
binary search tree (``bst.py``) or a sequential search, the affine law of every region and
nothing else (no dynamic allocation, no library call); ``export_python`` a numpy-only
module walking the same tables.
"""

from __future__ import annotations

import os
from pathlib import Path

from codev_engine.deploy.c_code import c_source
from codev_engine.deploy.escape import c_prefix, comment
from codev_engine.deploy.plan import Export, plan
from codev_engine.deploy.python_code import python_source
from codev_engine.io.atomic import remove_stale_beside, write_text

__all__ = ["export_c", "export_python"]


def export_c(
    obj,
    directory: str | os.PathLike,
    *,
    name: str = "codev_law",
    float32: bool = False,
    method: str = "auto",
    merge_equal_laws: bool = False,
    note: str | None = None,
) -> tuple[Path, Path]:
    """Write the law as C99: ``directory/name.h`` and ``directory/name.c``.

    ``int name_evaluate(const double theta[NAME_NTHETA], double u[NAME_NU])`` returns the
    region ``ExplicitLaw.locate`` returns (>= 0) and writes ``u = F_i theta + G_i``, or -1
    outside the law's domain, leaving ``u`` untouched (``float`` with ``float32``).

    Parameters
    ----------
    obj : ExplicitLaw, MpSolution or Export
        The law (or an export already planned by ``plan.plan``: ``method`` and
        ``merge_equal_laws`` are then its own).
    directory : path-like
        Created if missing.
    name : str
        The prefix of the files and of every C name: ASCII letters, digits and '_',
        starting with a letter, at most 51 characters, not a C keyword nor a C standard
        header's name (``escape.c_prefix``).
    float32 : bool
        ``float`` tables and arithmetic instead of ``double``.
    method : {"auto", "bst", "sequential"}
        The search (``auto``: fewer worst-case multiply-adds).
    merge_equal_laws : bool
        Regions with equal laws share tree leaves (``plan.plan``); the code still returns
        ``locate``'s region.
    note : str, optional
        Lines the header states after its first (escaped as comment text): the region of
        operation and its verdict (``deploy.operation.operation_note``).

    Returns
    -------
    header, source : Path

    Raises
    ------
    SpecError
        A bad name or method, or nothing to export.
    """
    c_prefix(name)
    ex = obj if isinstance(obj, Export) else plan(obj, method, merge_equal_laws)
    header, source = c_source(ex, name, float32)
    if note:
        first, rest = header.split("\n", 1)
        header = first + "\n *\n" + "".join(f" * {comment(x)}\n" for x in note.splitlines()) \
            + rest
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    h, c = directory / f"{name}.h", directory / f"{name}.c"
    remove_stale_beside(h, c)  # (what an export killed while writing left)
    write_text(h, header)
    write_text(c, source)
    return h, c


def export_python(
    obj, path: str | os.PathLike, *, method: str = "auto", merge_equal_laws: bool = False,
    note: str | None = None,
) -> Path:
    """Write the law as a Python module (numpy only) with ``evaluate(theta)``.

    Parameters
    ----------
    obj : ExplicitLaw, MpSolution or Export
    path : path-like
        The ``.py`` file to write.
    method : {"auto", "bst", "sequential"}
    merge_equal_laws : bool
    note : str, optional
        Lines the module's docstring states after its first (escaped), as for
        :func:`export_c`.

    Returns
    -------
    Path
    """
    ex = obj if isinstance(obj, Export) else plan(obj, method, merge_equal_laws)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = python_source(ex)
    if note:
        first, rest = text.split("\n", 1)
        text = first + "\n\n" + "".join(f"{comment(x)}\n" for x in note.splitlines()) + rest
    remove_stale_beside(path)  # (what an export killed while writing left)
    write_text(path, text)
    return path
