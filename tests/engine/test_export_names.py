"""Generated code is safe by construction: no name, however hostile, becomes code.

A law's names and fingerprint are free text (a law built in Python, or a law file someone
else wrote). The exported C and Python hold them only escaped: the C compiles with
``-std=c99 -Wall -Wextra -Werror -pedantic`` and, comments removed, is the very code of the
same law with plain names; the Python imports in a subprocess without running anything
(no file created), its ``PARAMETER_NAMES`` are the names exactly and, docstring and names
aside, its syntax tree is the plain law's. Both still evaluate the law. A law file with
names that are not identifiers, or a fingerprint that is not a hash, is refused on loading
(one line, exit 2 from the CLI); the export's prefix is checked.
"""

from __future__ import annotations

import ast
import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.deploy.escape import c_prefix, comment, py_names
from codev_engine.errors import SpecError
from tests.engine.test_export import CC, Compiled, assert_agrees, needs_cc
from workbench.cli import main

#: hostile names written out (``{F}``: the path of the canary file an injection creates)
FIXED = [
    "x */\nint FZ_INJECT = 1; /*",
    '"""+__import__("os").system("touch {F}")+"""',
    "'''+__import__('os').system('touch {F}')+'''",
    '"); system("touch {F}"); ("',
    "x\\",  # a trailing backslash: a line splice in a C comment, an escaped quote in Python
    "x\\\nint FZ_SPLICE;",
    "a ??/",  # a trigraph for a backslash (then the line's end: a splice)
    "??= ??( ??) ??' ??< ??! ??> ??-",
    "x\u2028int FZ_LS;\u2029y",  # line and paragraph separators
    "nul\x00inside",
    "\x1b[31mred\x1b[0m",  # a terminal escape
    "\r\nint FZ_CR;",
    "\t\v\f",
    "// int FZ_LINE;",
    "*/ #include <stdio.h> /*",
    "#define evaluate 0",
    "{theta}{0}%s%n",
    "\\N{BULLET}\\x41\\u0041",
    "é ü 中文 \U0001f600",
    "\ud800",  # a lone surrogate (not encodable as UTF-8)
    "int",
    "class",
    "None",
    "__import__",
    "",
    " ",
    "a" * 5000,
    "a/b",  # two names that would collide if '/' were only dropped or replaced...
    "a\\x2fb",  # ...and the text of the escape itself
    "a_b",
    "a-b",
]


def corpus(seed: int = 0, count: int = 40) -> list[str]:
    """``FIXED`` and ``count`` random names made of hostile pieces (distinct)."""
    pieces = ['"', "'", "\\", "\n", "\r", "*/", "/*", "??/", "\u2028", "\x00", '"""', "'''",
              "#", "{", "}", "$", "`", "\x1b", "é", "\U0001f600", "int ", "x", "_", "1", " "]
    rng = np.random.default_rng(seed)
    out = list(FIXED)
    while len(out) < len(FIXED) + count:
        name = "".join(rng.choice(pieces, size=rng.integers(1, 12)))
        if name not in out:
            out.append(name)
    return out


def box_law(names: list[str], outputs: list[str], fingerprint: str) -> ce.ExplicitLaw:
    """Two regions of [-1, 1]^d split at theta_0 = 0, a different affine law in each."""
    d, m = len(names), len(outputs)
    eye = np.eye(d)
    box = np.vstack([eye, -eye])
    A = [np.vstack([eye[:1], box]), np.vstack([-eye[:1], box])]
    b = [np.concatenate([[0.0], np.ones(2 * d)])] * 2
    rng = np.random.default_rng(1)
    F, G = rng.normal(size=(2, m, d)), rng.normal(size=(2, m))
    return ce.ExplicitLaw(A=A, b=b, F=F, G=G, states=tuple(names), inputs=tuple(outputs),
                          fingerprint=fingerprint)


def hostile_law(tmp: Path) -> tuple[ce.ExplicitLaw, ce.ExplicitLaw]:
    """The law with the corpus' names, and the same law with plain names.

    theta has three hostile names (the first injections); the outputs are the whole corpus
    (names go through the same escaping whichever they name, and a long theta would make the
    tree's geometry expensive: u has one row per name instead).
    """
    names = [n.replace("{F}", str(tmp / "F")) for n in corpus()]
    lw = box_law(names[:3], names, fingerprint=names[0])
    plain = dataclasses.replace(
        lw, states=("t0", "t1", "t2"), inputs=tuple(f"u{i}" for i in range(len(names))),
        fingerprint="0123456789abcdef",
    )
    return lw, plain


def _no_comments(c_text: str) -> str:
    return re.sub(r"/\*.*?\*/", "/**/", c_text, flags=re.S)


def test_comment_text_is_inert_and_one_to_one():
    names = corpus(seed=3, count=300)
    shown = [comment(n) for n in names]
    assert len(set(shown)) == len(set(names))  # distinct names stay distinct
    for s in shown:
        assert s.isascii() and s.isprintable()
        for bad in ("*/", "/*", "??", '"', "\n", "\r"):
            assert bad not in s
        assert not s.endswith("\\")
        assert not re.search(r"\\(?![xuU])", s)  # every backslash starts an escape
    assert comment("prev_u") == "prev_u"  # identifiers come out as they are
    # the Python literals evaluate back to the names, exactly
    assert ast.literal_eval(py_names(names)) == tuple(names)
    assert ast.literal_eval(py_names(names[:1])) == tuple(names[:1])
    assert py_names(names).isascii()


@needs_cc
def test_hostile_names_stay_comments_in_the_c(tmp_path):
    lw, plain = hostile_law(tmp_path)
    C = Compiled(lw, tmp_path / "hostile")  # -std=c99 -Wall -Wextra -Werror -pedantic
    P = Compiled(plain, tmp_path / "plain")
    for suffix in (".h", ".c"):
        text = (tmp_path / "hostile" / f"lawc{suffix}").read_text()
        assert text.isascii()
        assert "FZ_" not in _no_comments(text)
        plain_text = (tmp_path / "plain" / f"lawc{suffix}").read_text()
        assert _no_comments(text) == _no_comments(plain_text)
    assert "theta[1] = \\x22\\x22\\x22+__import__(" in C.header
    X = np.random.default_rng(2).uniform(-1.2, 1.2, size=(500, lw.n))
    X[:, 0] = np.where(np.arange(500) % 7 == 0, 0.0, X[:, 0])  # on the split too
    assert_agrees(lw, C, X)
    assert_agrees(plain, P, X)
    # trigraphs are on under -std=c99: the strictest compile of the header alone
    run = subprocess.run([CC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-Wtrigraphs",
                          "-Wcomment", "-pedantic", "-fsyntax-only", "-x", "c",
                          str(tmp_path / "hostile" / "lawc.h")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr


PROBE = """
import json, sys
sys.path.insert(0, sys.argv[1])
import lawpy
X = json.loads(sys.stdin.read())
out = [lawpy.evaluate(x) for x in X]
print(json.dumps({
    "names": list(lawpy.PARAMETER_NAMES), "outputs": list(lawpy.OUTPUT_NAMES),
    "fingerprint": lawpy.FINGERPRINT,
    "r": [r for r, _ in out], "u": [None if u is None else list(u) for _, u in out],
}, ensure_ascii=True))
"""


def _skeleton(text: str) -> str:
    """The module's syntax tree without its docstring and the values of its names."""
    tree = ast.parse(text)
    tree.body = tree.body[1:]  # the docstring
    for s in tree.body:
        if isinstance(s, ast.Assign) and s.targets[0].id in (
            "PARAMETER_NAMES", "OUTPUT_NAMES", "FINGERPRINT"
        ):
            s.value = ast.Constant(None)
    return ast.dump(tree)


def test_hostile_names_stay_literals_in_the_python(tmp_path):
    lw, plain = hostile_law(tmp_path)
    path = ce.export_python(lw, tmp_path / "lawpy.py")
    text = path.read_text(encoding="utf-8")
    assert text.isascii()
    assert _skeleton(text) == _skeleton(ce.export_python(plain, tmp_path / "p" / "lawpy.py")
                                        .read_text())
    X = np.random.default_rng(4).uniform(-1.2, 1.2, size=(200, lw.n))
    run = subprocess.run([sys.executable, "-c", PROBE, str(tmp_path)], input=json.dumps(
        X.tolist()), capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert run.returncode == 0, run.stderr
    assert not (tmp_path / "F").exists(), "a name ran a command"
    got = json.loads(run.stdout)
    assert tuple(got["names"]) == lw.states and tuple(got["outputs"]) == lw.inputs
    assert len(set(lw.inputs)) == len(corpus())
    assert got["fingerprint"] == lw.fingerprint
    ref = lw.locate(X)
    assert got["r"] == ref.tolist()
    U = lw.evaluate(X)
    inside = ref >= 0
    assert np.any(inside) and np.any(~inside)
    assert np.allclose(np.array([u for u in got["u"] if u is not None]), U[inside],
                       rtol=1e-12, atol=1e-12)


def _hand_written(path: Path, base: Path, **arrays) -> Path:
    """The law file ``base`` with some arrays replaced (as another tool might write it)."""
    with np.load(base) as z:
        data = {k: z[k] for k in z.files}
    data.update({k: np.asarray(v) for k, v in arrays.items()})
    np.savez(path, **data)
    return path


def test_law_files_refuse_names_that_are_not_identifiers(tmp_path, capsys):
    base = box_law(["a", "b"], ["u"], "").save(tmp_path / "base.npz")
    for i, name in enumerate(corpus(count=10)):
        name = name.replace("{F}", str(tmp_path / "F"))
        for field in ("states", "inputs"):
            names = np.array([name, "b"] if field == "states" else [name])
            f = _hand_written(tmp_path / f"law{i}.npz", base, **{field: names})
            stored = str(names[0])
            if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", stored):  # "int", "class", "None"...
                assert ce.ExplicitLaw.load(f).parameter_names[:1] in ((stored,), ("a",))
                continue
            with pytest.raises(SpecError) as exc:
                ce.ExplicitLaw.load(f)
            assert exc.value.file == str(f) and exc.value.field == f"{field}[0]"
            assert main(["export", str(f), "--c", str(tmp_path / "c")]) == 2
            err = capsys.readouterr().err.strip()
            assert err.count("\n") == 0 and err.isascii() and "not an identifier" in err, err
            # and a law holding such a name is not saved (it could not be loaded back)
            lw = box_law(["a", "b"], ["u"], "")
            setattr(lw, field, tuple(names))
            with pytest.raises(SpecError, match="not an identifier"):
                lw.save(tmp_path / "never.npz")
    assert not (tmp_path / "c").exists() and not (tmp_path / "F").exists()
    assert not (tmp_path / "never.npz").exists()
    # a fingerprint that is not a hash
    f = _hand_written(tmp_path / "fp.npz", base, fingerprint="ab\n*/ int X; /*")
    assert main(["export", str(f), "--python", str(tmp_path / "x.py")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "fingerprint" in err and not (tmp_path / "x.py").exists()
    # parameters (theta longer than the state) are checked too
    f = _hand_written(tmp_path / "p.npz", base, states=np.array(["a"]),
                      parameters=np.array(["a", "prev_u;"]))
    with pytest.raises(SpecError, match="parameters"):
        ce.ExplicitLaw.load(f)


@pytest.mark.parametrize(
    "name",
    ["", "9lives", "_law", "__law", "a b", "a-b", "a.b", "law\n", "lé", "int", "static",
     "_Bool", "stdint", "Math", "con", "NUL", "lpt1", "x" * 52, "a*/b", "a\x00"],
)
def test_bad_prefixes_are_refused(name, tmp_path):
    with pytest.raises(SpecError) as exc:
        c_prefix(name)
    assert exc.value.field == "name" and "\n" not in str(exc.value)
    lw = box_law(["a", "b"], ["u"], "")
    with pytest.raises(SpecError):
        ce.export_c(lw, tmp_path, name=name)
    assert not any(tmp_path.iterdir())


def test_good_prefixes_pass():
    for name in ("codev_law", "a", "Law2", "x" * 51, "int_", "stdint2"):
        assert c_prefix(name) == name


def test_cli_refuses_a_bad_prefix_in_one_line(tmp_path, capsys):
    f = box_law(["a", "b"], ["u"], "").save(tmp_path / "law.npz")
    for bad in ("int", "stdint", "x*/", "_x"):
        assert main(["export", str(f), "--c", str(tmp_path / "c"), "--name", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and err.startswith("codev: error:"), err
    assert not (tmp_path / "c").exists()


def test_cli_checks_the_prefix_before_planning(tmp_path, capsys, monkeypatch):
    import codev_engine.deploy.plan as plan_module

    def no_plan(*args, **kwargs):
        raise AssertionError("planned before the prefix was checked")

    monkeypatch.setattr(plan_module, "plan", no_plan)
    f = box_law(["a", "b"], ["u"], "").save(tmp_path / "law.npz")
    assert main(["export", str(f), "--c", str(tmp_path / "c"), "--name", "int"]) == 2
    assert "--name: name 'int' is a C keyword" in capsys.readouterr().err


def test_a_prefix_is_made_from_any_design_name():
    from codev_engine.deploy.escape import prefix_for

    assert prefix_for("dc-motor-servo") == "dc_motor_servo"
    assert prefix_for("2d.plant") == "law_2d_plant"
    assert prefix_for("int") == "law_int" and prefix_for("Math") == "law_Math"
    assert prefix_for("") == prefix_for("--") == "codev_law"
    for text in corpus(seed=5, count=200) + ["a" * 64, "a" * 50 + "-b"]:
        assert c_prefix(prefix_for(text)) == prefix_for(text)


@needs_cc
def test_a_hostile_design_name_stays_a_comment_in_the_region_of_operation(tmp_path):
    """The header of a region-of-operation export states the design's name, the verdict
    and its reason (``deploy.operation.operation_note``): free text, escaped like the
    names. The C header compiles under the strictest flags and holds no code of them; the
    Python module imports without running anything, and is the plain export's otherwise."""
    from codev_engine.deploy.operation import operation_law, operation_note
    from codev_engine.law_on_demand import OnDemandLaw
    from tests.conftest import EXAMPLES_DIR

    problem = ce.load_spec(EXAMPLES_DIR / "double_integrator_lqr.toml")
    od = OnDemandLaw(problem)
    law, cert = operation_law(problem, od, ce.verify(problem, od))
    hostile = "\n".join(n.replace("{F}", str(tmp_path / "F")) for n in FIXED[:20])
    bad = dataclasses.replace(problem, name=hostile)
    note = operation_note(bad, dict(cert, reason=FIXED[0] + FIXED[3]))
    plain = operation_note(problem, cert)
    for tag, text in (("hostile", note), ("plain", plain)):
        ce.export_c(law, tmp_path / tag, name="opn", note=text)
        ce.export_python(law, tmp_path / tag / "opn.py", note=text)
    h = (tmp_path / "hostile" / "opn.h").read_text()
    assert h.isascii() and "REGION OF OPERATION of x \\x2a\\x2f" in h
    assert "FZ_" not in _no_comments(h)
    assert _no_comments(h) == _no_comments((tmp_path / "plain" / "opn.h").read_text())
    run = subprocess.run([CC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-Wtrigraphs",
                          "-Wcomment", "-pedantic", "-fsyntax-only", "-x", "c",
                          str(tmp_path / "hostile" / "opn.h")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    text = (tmp_path / "hostile" / "opn.py").read_text()
    assert text.isascii()
    assert _skeleton(text) == _skeleton((tmp_path / "plain" / "opn.py").read_text())
    run = subprocess.run([sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
                          "import opn; print(opn.evaluate([0.1, 0.0])[0])",
                          str(tmp_path / "hostile")], capture_output=True, text=True,
                         cwd=tmp_path, timeout=120)
    assert run.returncode == 0, run.stderr
    assert not (tmp_path / "F").exists(), "the design's name ran a command"
    assert int(run.stdout) == int(law.locate(np.array([[0.1, 0.0]]))[0])
