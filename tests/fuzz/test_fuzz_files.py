"""Fuzz: corrupted session folders and law files (.npz), and a few real ``codev`` processes.

Same contract as tests/fuzz/test_fuzz_specs.py (tests/fuzz/contract.py). Sessions: the
journal, session.json, spec snapshots, the artifact index and cached artifacts mutated (an
artifact is re-indexed with its new SHA-256 so that its loader is reached), then ``codev
session``, ``codev replay`` and ``codev run --session``; ``codev: warning:`` lines (an
artifact recomputed, docs/sessions.md) may come before the outcome. Law files: arrays of
wrong shapes / dtypes, non-finite, missing or extra, hostile names, pickled object arrays
whose unpickling would create the canary, then ``codev verify --law`` and ``codev export
--python`` (the exported module is then run in a real process: it must not execute names).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.fuzz.contract import GOOD, check, classify, run_forked, run_subprocess
from tests.fuzz.mutations import (
    CANARY,
    EXAMPLES,
    HOSTILE_NAMES,
    ROOT,
    byte_mutation,
    dumps_json,
    mutate_json,
    unicode_text,
)
from tests.fuzz.test_fuzz_specs import DEFAULT, SLOW

# (module-scoped fixtures only, copied per example: the health check does not apply)
DEFAULT_FIXTURES = settings(DEFAULT, suppress_health_check=[
    *DEFAULT.suppress_health_check, HealthCheck.function_scoped_fixture])
SLOW_FIXTURES = settings(SLOW, suppress_health_check=[
    *SLOW.suppress_health_check, HealthCheck.function_scoped_fixture])

SPEC = EXAMPLES / "double_integrator.toml"

#: examples per property in the default suite (see tests/fuzz/test_fuzz_specs.py)
N_SESSION = 15
N_LAW = 15


@pytest.fixture(scope="module")
def base_session(tmp_path_factory) -> Path:
    """The bundled session replayed once (artifacts cached), to copy per example."""
    d = tmp_path_factory.mktemp("session") / "di"
    shutil.copytree(ROOT / "sessions" / "double-integrator", d)
    o = run_forked(["replay", "-q", str(d)], timeout=120)
    assert o.status == 0, o.short()
    return d


@pytest.fixture(scope="module")
def base_law(tmp_path_factory) -> dict:
    """The arrays of the double integrator's law file (``codev synth --out``)."""
    path = tmp_path_factory.mktemp("law") / "di.npz"
    o = run_forked(["synth", "-q", str(SPEC), "--out", str(path)], timeout=120)
    assert o.status == 0, o.short()
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


# ---- session folders -----------------------------------------------------------------------

def _reindex(folder: Path, name: str) -> None:
    """Give ``artifacts/<name>`` its new SHA-256 and size in the index (the loader is then
    reached, not only the hash check)."""
    idx_path = folder / "artifacts" / "index.json"
    idx = json.loads(idx_path.read_text())
    entry = idx.get(name) if isinstance(idx, dict) else None
    target = folder / "artifacts" / name
    if isinstance(entry, dict) and target.is_file():
        raw = target.read_bytes()
        for k in ("sha256", "sha"):
            if k in entry:
                entry[k] = hashlib.sha256(raw).hexdigest()
        if "size" in entry:
            entry["size"] = len(raw)
        idx_path.write_text(json.dumps(idx))


def _mutate_session(folder: Path, data) -> None:
    files = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()
                   and not p.name.startswith(".") and not p.name.endswith(".rrd"))
    for _ in range(data.draw(st.integers(1, 2), label="count")):
        rel = data.draw(st.sampled_from(files), label="file")
        path = folder / rel
        if not path.is_file():  # (deleted, or made a directory, by the first mutation)
            continue
        kind = data.draw(st.sampled_from(["json", "bytes", "delete", "dir", "npz"]),
                         label="kind")
        if kind == "delete":
            path.unlink()
        elif kind == "dir":
            path.unlink()
            path.mkdir()
        elif kind == "bytes":
            path.write_bytes(data.draw(byte_mutation(path.read_bytes()), label="bytes"))
            if rel.startswith("artifacts/") and rel.endswith(".npz"):
                _reindex(folder, path.name)
        elif kind == "npz" and rel.endswith(".npz"):
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            _mutate_arrays(arrays, data)
            _save(path, arrays)
            _reindex(folder, path.name)
        elif rel.endswith(".jsonl"):
            lines = path.read_text().splitlines()
            i = data.draw(st.integers(0, max(0, len(lines) - 1)), label="line")
            if lines:
                lines[i] = dumps_json(mutate_json(json.loads(lines[i]), data))
            path.write_text("\n".join(lines) + "\n")
        elif rel.endswith(".json"):
            path.write_text(dumps_json(mutate_json(json.loads(path.read_text()), data)))
        elif rel.endswith(".toml"):
            text = path.read_text()
            i = data.draw(st.integers(0, len(text)), label="at")
            path.write_text(text[:i] + data.draw(unicode_text, label="insert") + text[i:])


def _prop_session(data, base: Path) -> None:
    with tempfile.TemporaryDirectory(prefix="codev-fuzz-") as tmp:
        folder = Path(tmp) / "s"
        shutil.copytree(base, folder)
        _mutate_session(folder, data)
        command = data.draw(st.sampled_from(["session", "replay", "run"]), label="command")
        if command == "run":
            argv = ["run", "-q", str(folder / "spec.toml"), "--session", str(folder)]
            if not (folder / "spec.toml").is_file():
                argv[2] = str(SPEC)
        elif command == "replay":
            argv = ["replay", "-q", str(folder)]
        else:
            argv = ["session", str(folder)]
        o = run_forked(argv, timeout=30)
        check(o, names=(str(folder),), allow_warning_lines=True)


@settings(DEFAULT_FIXTURES, max_examples=N_SESSION)
@given(data=st.data())
def test_session_corrupted(data, base_session):
    _prop_session(data, base_session)


@pytest.mark.slow
@SLOW_FIXTURES
@given(data=st.data())
def test_session_corrupted_slow(data, base_session):
    _prop_session(data, base_session)


# ---- law files ------------------------------------------------------------------------------

class _Canary:
    """Unpickling runs ``open(path, "w")``: a law file must never be unpickled."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def _bad_array(data, like: np.ndarray) -> np.ndarray:
    kind = data.draw(st.sampled_from(
        ["shape", "dtype", "nonfinite", "huge", "empty", "scalar", "names", "object",
         "bytes", "deep"]), label="bad")
    if kind == "shape":
        shape = data.draw(st.lists(st.integers(0, 5), max_size=4), label="shape")
        return np.ones(tuple(shape))
    if kind == "dtype":
        dt = data.draw(st.sampled_from(["complex128", "bool", "float16", "int8", "uint64",
                                        "datetime64[s]", "U5"]), label="dtype")
        return np.zeros(like.shape, dtype=dt) if like.shape else np.zeros((), dtype=dt)
    if kind == "nonfinite":
        out = np.array(like, dtype=float) if like.dtype.kind in "fiu" else np.zeros(3)
        if out.size:
            out.flat[data.draw(st.integers(0, out.size - 1), label="at")] = data.draw(
                st.sampled_from([np.nan, np.inf, -np.inf]), label="v")
        return out
    if kind == "huge":
        out = np.array(like, dtype=float) if like.dtype.kind in "fiu" else np.zeros(3)
        return out * data.draw(st.sampled_from([1e300, -1e300, 1e-300, 0.0]), label="scale")
    if kind == "empty":
        return np.zeros((0,) * max(1, like.ndim))
    if kind == "scalar":
        return np.array(data.draw(st.sampled_from([0, 1.5, "x", ""]), label="v"))
    if kind == "names":
        n = max(1, like.size) if like.ndim == 1 else 1
        return np.array([data.draw(st.sampled_from(HOSTILE_NAMES + _CODE_NAMES) | unicode_text,
                                   label="name") for _ in range(n)])
    if kind == "object":
        return np.array([_Canary(CANARY)], dtype=object)
    if kind == "bytes":
        return np.array([b"x1", b"x2"])
    return np.array(data.draw(st.sampled_from(
        ['{"a": ' * 5000 + "0" + "}" * 5000, "[" * 100_000, '{"horizon": "x", "norm": 7}',
         '{"regions": 1e999}', "null", '"meta"', "{}", '{"problem": "\\u0000"}']),
        label="meta"))


#: names that would run if pasted into Python or C source unescaped
_CODE_NAMES = [
    f'x"); open("{CANARY}", "w"); ("', f"x'); open('{CANARY}', 'w'); ('",
    f'x\nopen("{CANARY}", "w")\n', f'x"""\nopen("{CANARY}", "w")\n"""',
    f'x */ int canary = system("touch {CANARY}"); /* ', 'x\\', "x\\n", "#include <stdio.h>",
]


def _mutate_arrays(arrays: dict, data) -> None:
    for _ in range(data.draw(st.integers(1, 3), label="count")):
        keys = sorted(arrays)
        op = data.draw(st.sampled_from(["replace", "replace", "delete", "add"]), label="op")
        if op == "add" or not keys:
            name = data.draw(st.sampled_from(["box_lo", "box_hi", "parameters", "domain_A",
                                              "x" * 200, "../evil", "format2"]), label="key")
            arrays[name] = _bad_array(data, np.zeros((3, 2)))
            continue
        key = data.draw(st.sampled_from(keys), label="key")
        if op == "delete":
            del arrays[key]
        else:
            arrays[key] = _bad_array(data, arrays[key])


def _save(path: Path, arrays: dict) -> None:
    buf = io.BytesIO()
    np.savez(buf, **{k.replace("/", "_"): v for k, v in arrays.items()})  # object: pickled
    path.write_bytes(buf.getvalue())


def _fill(arrays: dict, canary: Path) -> dict:
    out = {}
    for k, v in arrays.items():
        if v.dtype.kind == "U":
            v = np.char.replace(v, CANARY, str(canary))
        elif v.dtype.kind == "O":
            v = np.array([_Canary(str(canary))], dtype=object)
        out[k] = v
    return out


def _prop_law(data, base: dict) -> None:
    arrays = dict(base)
    _mutate_arrays(arrays, data)
    with tempfile.TemporaryDirectory(prefix="codev-fuzz-") as tmp:
        tmp = Path(tmp)
        canary = tmp / "CANARY-executed"
        law = tmp / "law.npz"
        _save(law, _fill(arrays, canary))
        command = data.draw(st.sampled_from(["verify", "export"]), label="command")
        if command == "verify":
            argv = ["verify", "-q", str(SPEC), "--law", str(law)]
        else:
            argv = ["export", str(law), "--python", str(tmp / "law_module.py"),
                    "--c", str(tmp / "c")]
        o = run_forked(argv, timeout=30)
        check(o, names=(str(law),), canaries=(canary,))
        module = tmp / "law_module.py"
        if module.is_file():  # the exported code must not run the names it carries
            subprocess.run([sys.executable, "-c", "import runpy, sys; "
                            f"runpy.run_path({str(module)!r})"], cwd=tmp, timeout=60,
                           capture_output=True)
            assert not canary.exists(), f"the exported module ran a name: {o.short()}"


@settings(DEFAULT_FIXTURES, max_examples=N_LAW)
@given(data=st.data())
def test_law_file_corrupted(data, base_law):
    _prop_law(data, base_law)


@pytest.mark.slow
@SLOW_FIXTURES
@given(data=st.data())
def test_law_file_corrupted_slow(data, base_law):
    _prop_law(data, base_law)


# ---- the terminal contract for real (processes) ---------------------------------------------

_REAL = {
    "big-int": ("mpc", "horizon = 2", "horizon = " + "7" * 5001),
    "injection": ("plant", 'dynamics = ["x2", "u"]',
                  f'dynamics = ["x2", "__import__(\\"os\\").system(\\"touch {CANARY}\\")"]'),
    "nan-string": ("mpc", "R = [[0.8]]", 'R = [["nan"]]'),
    "unicode": ("plant", 'states = ["x1", "x2"]', 'states = ["x1", "𝑥₂"]'),
    "caret": ("plant", 'dynamics = ["x2", "u"]', 'dynamics = ["x2", "x1^2 + u"]'),
}


@pytest.mark.parametrize("case", sorted(_REAL))
def test_real_process_spec(case, tmp_path):
    _, old, new = _REAL[case]
    canary = tmp_path / "CANARY-executed"
    text = SPEC.read_text()
    assert old in text
    spec = tmp_path / "spec.toml"
    spec.write_text(text.replace(old, new).replace(CANARY, str(canary)), encoding="utf-8")
    o = run_subprocess(["run", str(spec)], cwd=tmp_path, timeout=60)
    cls = classify(o, names=(str(spec),), canaries=(canary,))
    assert cls in GOOD, o.short()


def test_real_process_pickled_law(tmp_path, base_law):
    canary = tmp_path / "CANARY-executed"
    law = tmp_path / "law.npz"
    _save(law, {**base_law, "F": np.array([_Canary(str(canary))], dtype=object)})
    for argv in (["verify", str(SPEC), "--law", str(law)],
                 ["export", str(law), "--python", str(tmp_path / "m.py")]):
        o = run_subprocess(argv, cwd=tmp_path, timeout=60)
        assert classify(o, names=(str(law),), canaries=(canary,)) == "exit2_one_line", o.short()


def test_real_process_corrupt_journal(tmp_path, base_session):
    folder = tmp_path / "s"
    shutil.copytree(base_session, folder)
    (folder / "journal.jsonl").write_text('{"run": 1, "stage": ' + "[" * 100_000 + "\n")
    for argv in (["replay", str(folder)], ["session", str(folder)]):
        o = run_subprocess(argv, cwd=tmp_path, timeout=60)
        assert classify(o, names=(str(folder),)) == "exit2_one_line", o.short()


assert os.sep == "/"  # (the paths above are POSIX; the suite runs on Linux and macOS)
