"""What ships beside the code: the example specs and notebook, and the benchmark scripts.

The examples live at the repository's ``examples/`` and are installed as the package
``workbench.examples`` (pyproject.toml maps one onto the other), so they are read with
:mod:`importlib.resources` from a checkout, an editable install or a wheel alike;
``codev examples`` writes them out. The benchmarks are not installed: they need the
repository (their peers, data and README), and ``codev bench`` finds them only in a
checkout.
"""

from __future__ import annotations

import importlib.resources
import shlex
from importlib.resources.abc import Traversable
from pathlib import Path

from codev_engine.errors import CodevError

__all__ = [
    "DEFAULT_EXAMPLES_DIR",
    "EXAMPLES_PACKAGE",
    "benchmarks_dir",
    "example_files",
    "next_steps",
    "write_examples",
]

#: the package that holds the bundled examples (the repository's ``examples/``)
EXAMPLES_PACKAGE = "workbench.examples"

#: where ``codev examples`` writes when no folder is given (relative to the working folder)
DEFAULT_EXAMPLES_DIR = "codev-examples"

#: the example files: specs and the notebook (not the package's ``__init__.py``)
_SUFFIXES = (".toml", ".ipynb")


def example_files() -> list[Traversable]:
    """The bundled example files, by name.

    Returns
    -------
    list of Traversable
        Every ``*.toml`` spec and ``*.ipynb`` notebook of :data:`EXAMPLES_PACKAGE`, sorted
        by file name.
    """
    root = importlib.resources.files(EXAMPLES_PACKAGE)
    files = [f for f in root.iterdir() if f.is_file() and f.name.endswith(_SUFFIXES)]
    return sorted(files, key=lambda f: f.name)


def write_examples(folder: str | Path, *, force: bool = False) -> list[Path]:
    """Copy the bundled examples into ``folder`` (created if missing).

    Nothing is written unless every file can be: an existing file stops the copy before
    the first write, unless ``force``.

    Parameters
    ----------
    folder : str or Path
        The destination folder.
    force : bool
        Overwrite the files that exist already.

    Returns
    -------
    list of Path
        The files written, ``folder / name`` for each of :func:`example_files`.

    Raises
    ------
    CodevError
        ``folder`` is not a folder, or (without ``force``) one of the files exists.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise CodevError(f"{folder}: exists and is not a folder")
    files = example_files()
    targets = [folder / f.name for f in files]
    if not force:
        for target in targets:
            if target.exists():
                raise CodevError(f"{target}: exists (codev examples --force overwrites it)")
    folder.mkdir(parents=True, exist_ok=True)
    for source, target in zip(files, targets, strict=True):
        target.write_bytes(source.read_bytes())
    return targets


def next_steps(folder: str | Path) -> list[str]:
    """The commands to try on examples written to ``folder``.

    Parameters
    ----------
    folder : str or Path
        Where :func:`write_examples` wrote them.

    Returns
    -------
    list of str
        Shell commands: verify the double integrator, then open it in the workbench.
    """
    spec = shlex.quote(str(Path(folder) / "double_integrator.toml"))
    return [f"codev run {spec}", f"codev tui {spec}"]


def benchmarks_dir(package_dir: str | Path | None = None) -> Path | None:
    """The checkout's ``benchmarks/`` folder, or None when codev is not run from a checkout.

    A checkout is the folder above the ``workbench`` package holding both ``pyproject.toml``
    and ``benchmarks/``; an installed package sits in ``site-packages``, which has neither.

    Parameters
    ----------
    package_dir : str or Path, optional
        The folder of the ``workbench`` package (default: this module's folder).

    Returns
    -------
    Path or None
        ``<checkout>/benchmarks``, or None.
    """
    package = Path(package_dir) if package_dir is not None else Path(__file__).resolve().parent
    root = package.parent
    if (root / "pyproject.toml").is_file() and (root / "benchmarks").is_dir():
        return root / "benchmarks"
    return None
