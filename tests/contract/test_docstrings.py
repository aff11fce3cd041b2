"""Every public function and class of ``codev_engine`` and ``workbench`` has a numpy-style
docstring that names exactly the parameters of its signature.

Every module of both packages is imported (``pkgutil.walk_packages``) and its public objects
are checked with ``numpydoc.validate.validate``. Three of numpydoc's codes fail the test:

- GL08, no docstring;
- PR01, a parameter of the signature is not in ``Parameters`` (or ``Other Parameters``);
- PR02, a documented parameter is not in the signature.

What counts as public:

- a module's objects are the names in its ``__all__`` if it has one, else its names that
  do not start with ``_``; only functions and classes, each checked once, under the module
  that defines it (a re-export is checked where it is defined; a function made by a
  factory is named by the name it is bound to); a compiled (numba) function is checked
  through the Python function it compiles;
- a class's members are the functions, static and class methods, properties and nested
  classes in its own body whose names do not start with ``_``: dunders are not checked,
  the class docstring documents the constructor's parameters;
- a property (or cached property) needs a docstring only: it has no parameters;
- a dataclass documents its fields in ``Attributes`` or ``Parameters``: PR01 is then "a
  public field or constructor parameter documented in neither" (fields starting with
  ``_`` are private), PR02 still applies to ``Parameters``; the docstring ``dataclass``
  makes up from the signature when a class has none is no docstring (GL08);
- a class whose constructor is inherited from a base defined outside these packages (an
  exception without ``__init__``, a Textual pane that keeps ``Widget.__init__``) does not
  document that constructor's parameters: PR01 and PR02 are not checked for it.

Framework hooks are not public API: their contract is the framework's. For a class that
derives from a Textual class (the workbench's app, panes and widgets), the methods Textual
calls by their names are skipped: message handlers ``on_*``, and ``action_*``,
``watch_*``, ``validate_*``, ``compute_*``. In any class, a method that overrides one of a
base class defined outside these packages (``compose``, ``render``, ...) is skipped too. A
plain public method of a widget (``set_text``, ``refresh_law``, ...) is checked.

The failures are reported as one list of ``module.object: CODE message`` lines.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import pkgutil
from collections.abc import Iterator

from numpydoc.docscrape import get_doc_object
from numpydoc.validate import Validator, validate
from textual.widget import Widget

import codev_engine
import workbench

PACKAGES = (codev_engine, workbench)
CHECKED = ("GL08", "PR01", "PR02")
TEXTUAL_HOOKS = ("on_", "action_", "watch_", "validate_", "compute_")
NO_DOCSTRING = ("GL08", "The object does not have a docstring")

# Modules excused from the check: none. Should one ever be excused (say, while its code is
# moved between files), a module here that has no failure any more fails the test, so the
# set cannot keep a module that is done.
NOT_YET: set[str] = set()

Errors = list[tuple[str, str]]


def _ours(obj) -> bool:
    module = getattr(obj, "__module__", None) or ""
    return module.split(".")[0] in {p.__name__ for p in PACKAGES}


def _modules() -> Iterator:
    for package in PACKAGES:
        yield package
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            yield importlib.import_module(info.name)


def _unwrap(obj):
    """The Python function behind a numba dispatcher, or ``obj``."""
    py_func = getattr(obj, "py_func", None)
    return py_func if inspect.isfunction(py_func) else obj


def _public_objects(module) -> Iterator[tuple[str, str, object]]:
    """``(name, defining module, object)`` for each public function and class."""
    listed = "__all__" in vars(module)
    names = module.__all__ if listed else [n for n in vars(module) if not n.startswith("_")]
    for name in names:
        obj = _unwrap(getattr(module, name))
        if not (inspect.isfunction(obj) or inspect.isclass(obj)) or not _ours(obj):
            continue
        if not listed and obj.__module__ != module.__name__:
            continue  # imported, not defined here
        yield name, obj.__module__, obj


def _foreign_bases(cls) -> list[type]:
    return [b for b in cls.__mro__[1:] if b is not object and not _ours(b)]


def _is_hook(cls, name: str) -> bool:
    """Is ``cls.name`` a framework callback (see the module docstring)?"""
    foreign = _foreign_bases(cls)
    if any(name in vars(b) for b in foreign):
        return True
    textual = any(b.__module__.split(".")[0] == "textual" for b in foreign)
    return textual and name.startswith(TEXTUAL_HOOKS)


def _constructor_owner(cls) -> type | None:
    """The class whose ``__init__`` or ``__new__`` makes ``cls``'s signature."""
    for base in cls.__mro__:
        if base is not object and ("__init__" in vars(base) or "__new__" in vars(base)):
            return base
    return None


def _codes(result: dict) -> Errors:
    return [(code, msg) for code, msg in result["errors"] if code in CHECKED]


def _check_function(func) -> Errors:
    return _codes(validate(get_doc_object(func)))


def _check_class(cls) -> Errors:
    if dataclasses.is_dataclass(cls) and (cls.__doc__ or "").startswith(cls.__name__ + "("):
        return [NO_DOCSTRING]  # the signature dataclass wrote in place of a docstring
    # Without the class's members: numpydoc would list them as documented Attributes.
    doc = Validator(get_doc_object(cls, config={"show_class_members": False}))
    errors = _codes(validate(doc.doc))
    if not doc.raw_doc:
        return errors
    if _constructor_owner(cls) in _foreign_bases(cls):
        return [(code, msg) for code, msg in errors if code not in ("PR01", "PR02")]
    if not dataclasses.is_dataclass(cls):
        return errors
    errors = [(code, msg) for code, msg in errors if code != "PR01"]
    documented = set(doc.doc_all_parameters) | {
        n for names, _, _ in doc.doc["Attributes"] for n in names.split(", ")
    }
    wanted = set(doc.signature_parameters) | {f.name for f in dataclasses.fields(cls)}
    missing = sorted(n for n in wanted - documented if not n.startswith("_"))
    if missing:
        errors.append(("PR01", f"Fields {missing} not documented (Attributes or Parameters)"))
    return errors


def _members(cls) -> Iterator[tuple[str, object]]:
    for name, attr in vars(cls).items():
        if name.startswith("_") or _is_hook(cls, name):
            continue
        if isinstance(attr, staticmethod | classmethod):
            attr = attr.__func__
        if isinstance(attr, property | functools.cached_property):
            yield name, attr
        elif inspect.isfunction(attr) or (inspect.isclass(attr) and _ours(attr)):
            yield name, attr


def _check_member(attr) -> Errors:
    if isinstance(attr, property | functools.cached_property):
        getter = attr.fget if isinstance(attr, property) else attr.func
        return [] if getter.__doc__ else [NO_DOCSTRING]
    if inspect.isclass(attr):
        return _check_class(attr)
    return _check_function(attr)


def _failures() -> dict[str, list[str]]:
    """Failures by defining module: ``{module: ["module.object: CODE message", ...]}``."""
    seen: set[int] = set()
    found: dict[str, list[str]] = {}

    def add(module: str, qualname: str, errors: Errors) -> None:
        for code, msg in errors:
            found.setdefault(module, []).append(f"{module}.{qualname}: {code} {msg}")

    def walk_class(module: str, cls, qualname: str) -> None:
        for name, attr in _members(cls):
            add(module, f"{qualname}.{name}", _check_member(attr))
            if inspect.isclass(attr):
                walk_class(module, attr, f"{qualname}.{name}")

    for module in _modules():
        for name, home, obj in _public_objects(module):
            if id(obj) in seen:
                continue
            seen.add(id(obj))
            qualname = name if "<locals>" in obj.__qualname__ else obj.__qualname__
            if inspect.isclass(obj):
                add(home, qualname, _check_class(obj))
                walk_class(home, obj, qualname)
            else:
                add(home, qualname, _check_function(obj))
    return found


def test_public_objects_have_numpy_docstrings():
    found = _failures()
    failing = [
        line
        for module, lines in sorted(found.items())
        if module not in NOT_YET
        for line in lines
    ]
    done = sorted(NOT_YET - set(found))
    report = [f"{len(failing)} docstring failure(s):", *failing] if failing else []
    if done:
        report.append("no failure any more, take out of NOT_YET: " + ", ".join(done))
    assert not report, "\n".join(report)


# --- the checker itself, on objects made here ------------------------------------------


def _documented(x: float, *, scale: int = 1) -> float:
    """Scale a number.

    Parameters
    ----------
    x : float
        The number.
    scale : int
        The factor.

    Returns
    -------
    float
    """
    return x * scale


def _half_documented(x: float, y: float) -> float:
    """Add two numbers.

    Parameters
    ----------
    x : float
        The first.
    z : float
        Not a parameter.

    Returns
    -------
    float
    """
    return x + y


def _undocumented(x):
    return x


@dataclasses.dataclass
class _Fields:
    """A dataclass documented by its fields.

    Attributes
    ----------
    a : int
        A field.
    """

    a: int
    b: int = 0
    _cache: int = 0


@dataclasses.dataclass
class _NoDocstring:
    a: int


class _HookError(Exception):
    """An exception: its constructor, ``Exception.__init__``, is not ours."""

    def with_traceback(self, tb) -> _HookError:  # overrides BaseException.with_traceback
        return self


class _Pane(Widget):
    """A widget: Textual's callbacks are skipped, its own methods are not."""

    def compose(self):
        yield from ()

    def on_mount(self) -> None:
        pass

    def action_save(self) -> None:
        pass

    def refresh_view(self) -> None:
        pass


def test_checker_finds_each_code():
    assert _check_function(_documented) == []
    assert sorted(code for code, _ in _check_function(_half_documented)) == ["PR01", "PR02"]
    assert _check_function(_undocumented) == [NO_DOCSTRING]
    # field `b` is missing; `_cache` is private
    assert _check_class(_Fields) == [
        ("PR01", "Fields ['b'] not documented (Attributes or Parameters)")
    ]
    assert _check_class(_NoDocstring) == [NO_DOCSTRING]
    assert _check_class(_HookError) == []
    assert _is_hook(_HookError, "with_traceback")
    assert [name for name, _ in _members(_Pane)] == ["refresh_view"]
