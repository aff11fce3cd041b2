"""The notebook display of laws and verification results: the drawing backend of
:class:`codev_engine.display.Displayable`.

Each displayable type maps to its picture and its HTML summary in
:mod:`codev_engine.view.figures`:

=====================  ==============================  ===========================
type                   picture                         summary
=====================  ==============================  ===========================
``ExplicitLaw``        :func:`~.figures.figure_law`     :func:`~.figures.law_html`
``VerificationResult`` :func:`~.figures.figure_result`  :func:`~.figures.result_html`
=====================  ==============================  ===========================

:func:`mimebundle` renders the picture once for both the HTML and the PNG entries. What the
producer attached to the object (:func:`codev_engine.display.context`: ``verify`` attaches
the spec and the law to its result) is passed to the picture, so a result from ``verify``
shows the state names, the sets and the law's domain.
matplotlib is imported by the figures when they draw, not by this module.
"""

from __future__ import annotations

import base64
from typing import Any

from codev_engine.display import context
from codev_engine.law import ExplicitLaw
from codev_engine.reach.verification import VerificationResult
from codev_engine.view import figures

__all__ = ["html", "mimebundle", "png"]

#: type -> names of its picture and its summary in ``figures`` (looked up when drawing)
_VIEWS: dict[type, tuple[str, str]] = {
    ExplicitLaw: ("figure_law", "law_html"),
    VerificationResult: ("figure_result", "result_html"),
}


def _views(obj: Any) -> tuple[Any, Any]:
    """The picture and summary functions of ``obj``'s type (or of its nearest base)."""
    for cls in type(obj).__mro__:
        names = _VIEWS.get(cls)
        if names is not None:
            return getattr(figures, names[0]), getattr(figures, names[1])
    raise TypeError(f"no notebook display for {type(obj).__name__}")


def _claim_context(obj: Any) -> dict[str, Any]:
    """The spec a result was verified for, so its summary states the claim."""
    problem = context(obj).get("problem")
    return {"problem": problem} if isinstance(obj, VerificationResult) and problem else {}


def png(obj: Any) -> bytes:
    """The picture of a law or a result as PNG bytes.

    Parameters
    ----------
    obj : ExplicitLaw or VerificationResult

    Returns
    -------
    bytes
    """
    figure, _ = _views(obj)
    return figures.png_bytes(figure(obj, **context(obj)))


def html(obj: Any) -> str:
    """The HTML summary of a law or a result, with the picture embedded.

    Parameters
    ----------
    obj : ExplicitLaw or VerificationResult

    Returns
    -------
    str
    """
    figure, summary = _views(obj)
    return summary(obj, figures.png_bytes(figure(obj, **context(obj))), **_claim_context(obj))


def mimebundle(obj: Any) -> dict[str, str]:
    """The notebook display of a law or a result, the picture rendered once.

    Parameters
    ----------
    obj : ExplicitLaw or VerificationResult

    Returns
    -------
    dict
        ``text/plain`` (the object's ``summary()``), ``text/html`` (the summary with the
        picture embedded) and ``image/png`` (base64). Frontends prefer HTML, which shows
        both; the PNG is there for frontends and tools that only take images.
    """
    figure, summary = _views(obj)
    picture = figures.png_bytes(figure(obj, **context(obj)))
    return {
        "text/plain": obj.summary(),
        "text/html": summary(obj, picture, **_claim_context(obj)),
        "image/png": base64.b64encode(picture).decode("ascii"),
    }
