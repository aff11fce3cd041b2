"""Free text in generated code: escaped so that it can only ever be text.

A law's names and fingerprint come from a file someone else may have written; the
exported C and Python must stay what codev generated whatever they hold. The writers
never put such text into code directly:

- :func:`comment` makes it a C comment's or a (raw) Python docstring's text: printable
  ASCII with ``\\``, ``/``, ``*``, ``?`` and ``"`` escaped as ``\\xNN`` (so no ``*/``, no
  ``/*``, no trigraph, no backslash-newline, no ``\"\"\"``), every other character as
  ``\\xNN``, ``\\uNNNN`` or ``\\UNNNNNNNN``; one-to-one, so distinct names stay distinct;
- :func:`py_str` and :func:`py_names` make it Python literals (``ascii`` of a plain
  ``str``: every character outside printable ASCII escaped);
- :func:`c_prefix` checks the one name that does become C identifiers and file names, the
  export's prefix (chosen on the command line, not read from the law); :func:`prefix_for`
  makes one from any text (the workbench names the files after the design).
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from codev_engine.errors import SpecError

__all__ = ["C_KEYWORDS", "c_prefix", "comment", "prefix_for", "py_names", "py_str"]

#: the characters a comment keeps as they are (every other one is escaped)
_PLAIN = frozenset(
    "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789"
    " _.,:;=+-()[]<>!#%&^|~@${}'"
)

#: C99 and C11 keywords (a prefix is never one; its names are built from it)
C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto "
    "if inline int long register restrict return short signed sizeof static struct switch "
    "typedef union unsigned void volatile while _Alignas _Alignof _Atomic _Bool _Complex "
    "_Generic _Imaginary _Noreturn _Static_assert _Thread_local".split()
)

#: the C standard headers: ``NAME.h`` next to the source would shadow one under ``-I``
_C_HEADERS = frozenset(
    "assert complex ctype errno fenv float inttypes iso646 limits locale math setjmp signal "
    "stdalign stdarg stdatomic stdbool stddef stdint stdio stdlib stdnoreturn string tgmath "
    "threads time uchar wchar wctype".split()
)

#: names Windows reserves for devices (``nul.h`` cannot be created there)
_DEVICES = frozenset(
    ["con", "prn", "aux", "nul"] + [f"{p}{i}" for p in ("com", "lpt") for i in range(1, 10)]
)

#: the prefix: ASCII letters, digits and '_', starting with a letter (a leading '_' would
#: make the upper-case macros ``_NAME_H`` reserved identifiers)
_PREFIX_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
#: at most this long: the longest name built from it (``NAME_WORST_TESTS``) keeps within
#: the 63 significant characters C99 guarantees
PREFIX_MAX = 51


def comment(text: str) -> str:
    """``text`` as the text of a C comment or of a raw Python docstring.

    Parameters
    ----------
    text : str
        Any text (a name, a fingerprint), possibly hostile.

    Returns
    -------
    str
        Printable ASCII without ``\\``, ``/``, ``*``, ``?`` or ``"``: those and every
        character outside printable ASCII are written ``\\xNN``, ``\\uNNNN`` or
        ``\\UNNNNNNNN`` (so the backslash of an escape is never followed by a newline).
        Identifiers come out unchanged; distinct texts stay distinct.
    """
    out = []
    for ch in str(text):
        if ch in _PLAIN:
            out.append(ch)
        elif ord(ch) < 0x100:
            out.append(f"\\x{ord(ch):02x}")
        elif ord(ch) < 0x10000:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(f"\\U{ord(ch):08x}")
    return "".join(out)


def py_str(text: str) -> str:
    """``text`` as a Python string literal (pure ASCII; evaluates back to ``text``).

    Parameters
    ----------
    text : str

    Returns
    -------
    str
        ``ascii()`` of the plain ``str`` (a ``numpy.str_`` would show as a call).
    """
    return ascii(str(text))


def py_names(names: Iterable[str]) -> str:
    """A tuple of names as a Python literal (pure ASCII).

    Parameters
    ----------
    names : iterable of str

    Returns
    -------
    str
        ``("a", "b")``-like text, ``(n,)`` for one name, ``()`` for none.
    """
    items = [py_str(n) for n in names]
    if len(items) == 1:
        return f"({items[0]},)"
    return "(" + ", ".join(items) + ")"


def c_prefix(name: str) -> str:
    """Check the export's prefix: it names the files and is the start of every C name.

    Parameters
    ----------
    name : str

    Returns
    -------
    str
        ``name`` itself.

    Raises
    ------
    SpecError
        (``field="name"``) unless ``name`` is 1 to ``PREFIX_MAX`` ASCII letters, digits and
        '_', starting with a letter, and neither a C keyword, the name of a C standard
        header nor a device name Windows reserves.
    """
    shown = comment(name)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    if not isinstance(name, str) or not _PREFIX_RE.fullmatch(name):
        raise SpecError(
            f"name '{shown}' is not a C identifier: use ASCII letters, digits and '_', "
            "starting with a letter",
            field="name",
        )
    if len(name) > PREFIX_MAX:
        raise SpecError(
            f"name '{shown}' is too long: at most {PREFIX_MAX} characters (the C names made "
            "from it must stay within C99's 63 significant characters)",
            field="name",
        )
    if name in C_KEYWORDS:
        raise SpecError(f"name '{name}' is a C keyword", field="name")
    if name.lower() in _C_HEADERS:
        raise SpecError(
            f"name '{name}' is a C standard header's: {name}.h would shadow <{name}.h>",
            field="name",
        )
    if name.lower() in _DEVICES:
        raise SpecError(f"name '{name}' is a device name on Windows", field="name")
    return name


def prefix_for(text: str, default: str = "codev_law") -> str:
    """A prefix :func:`c_prefix` accepts, made from any text (a design's name).

    Parameters
    ----------
    text : str
        ``dc-motor-servo``, ``2d.plant``, ``int``...
    default : str
        The prefix when ``text`` has no letter or digit.

    Returns
    -------
    str
        ``text`` with every character but ASCII letters and digits made '_' (runs of them
        one '_', none at the ends), ``law_`` in front of one that does not start with a
        letter or is reserved (a C keyword, a standard header's or a device name), cut to
        ``PREFIX_MAX`` characters: ``dc_motor_servo``, ``law_2d_plant``, ``law_int``.
    """
    stem = re.sub(r"[^A-Za-z0-9]+", "_", str(text)).strip("_")
    if not stem:
        return default
    reserved = stem in C_KEYWORDS or stem.lower() in _C_HEADERS | _DEVICES
    if not stem[0].isalpha() or reserved:
        stem = "law_" + stem
    return stem[:PREFIX_MAX].rstrip("_")
