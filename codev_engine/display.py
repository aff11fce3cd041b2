"""Notebook display of the engine's results, drawn by a backend found by module name.

Jupyter shows an object through its ``_repr_png_``, ``_repr_html_`` and
``_repr_mimebundle_`` methods. :class:`Displayable` gives a class all three; each hands the
object to the drawing backend, the module :data:`BACKEND`, imported by name
(``importlib.import_module``) on the first display. That is pandas' plotting-backend
pattern (``pandas.plotting._core._get_plot_backend`` loads the module named by the
``plotting.backend`` option, ``pandas.plotting._matplotlib`` by default, on the first
plot): the classes that display -- the law, the verification result -- import nothing of
the drawing code, so no import arrow runs from them to ``codev_engine.view``, and
``import codev_engine`` loads no matplotlib.

The backend is any module with three functions of one argument, the object:
``png(obj) -> bytes``, ``html(obj) -> str`` and ``mimebundle(obj) -> dict``
(:mod:`codev_engine.view.notebook`, which maps each type to its picture and summary).
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["BACKEND", "Displayable", "backend", "context"]

#: the module that draws (imported on the first display)
BACKEND = "codev_engine.view.notebook"
_loaded: dict[str, ModuleType] = {}


def backend() -> ModuleType:
    """The drawing backend module (:data:`BACKEND`), imported on the first call.

    Returns
    -------
    module
    """
    module = _loaded.get(BACKEND)
    if module is None:
        module = _loaded[BACKEND] = importlib.import_module(BACKEND)
    return module


def context(obj: object) -> dict[str, object]:
    """What the display of ``obj`` may use besides ``obj`` (e.g. the spec of a result).

    Parameters
    ----------
    obj : Displayable

    Returns
    -------
    dict
        ``{"problem": Problem, "law": ExplicitLaw}`` for a result of ``verify``; empty when
        nothing was attached (a result loaded from a file).
    """
    return dict(getattr(obj, "_display_context", None) or {})


class Displayable:
    """Mixin: the notebook display hooks, drawn by :func:`backend`.

    A class that derives from it displays itself in Jupyter; it needs a ``summary()``
    method (the plain-text part of the display) and a picture and summary in the backend.
    The producer of an object may attach what its picture needs (:meth:`attach_display`):
    ``verify`` attaches the spec and the law, so a result shows state names and sets.
    """

    def attach_display(self, **items: object) -> None:
        """Keep ``items`` for the display only (not a field: no effect on equality, saving
        or ``repr``).

        Parameters
        ----------
        **items : object
            E.g. ``problem=..., law=...``.
        """
        object.__setattr__(self, "_display_context", {**context(self), **items})

    def _repr_png_(self) -> bytes:
        """The picture as PNG bytes."""
        return backend().png(self)

    def _repr_html_(self) -> str:
        """The summary table with the picture embedded."""
        return backend().html(self)

    def _repr_mimebundle_(self, include: object = None, exclude: object = None) -> dict[str, str]:
        """HTML summary, PNG and plain text, the picture rendered once (what Jupyter uses)."""
        return backend().mimebundle(self)
