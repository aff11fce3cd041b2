"""Bad input for ``MpProgram.load``, ``MpSolution.load`` and ``codev mpsolve``; round trips.

Every kind of bad file gives **one** clear error: ``SpecError`` naming the file (``.file``)
and, where one array is at fault, that array (``.field``); the CLI prints one line
``codev: error: FILE: ARRAY: reason`` and exits 2. Object (pickled) arrays are refused
without being unpickled. Problems that are only found by solving (empty or unbounded
parameter set, an LP unbounded for some parameters) are bad input too: ``SpecError`` from
``load`` or from ``mpsolve``, exit 2 from the CLI. A solver breakdown is not bad input: exit 1.

Round trips: ``save`` then ``load`` of a program gives the same arrays; of a solution, the
same regions and identical ``locate`` / ``primal`` / ``value``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_process import run_codev

import codev_engine as ce
from workbench.cli import main

# ---------------------------------------------------------------------------------------
# a valid program: mp-QP, nz = 3, d = 2, 6 bound rows, one equality (10 regions; LP: 6)
# ---------------------------------------------------------------------------------------

REQUIRED = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta")
EQUALITY = ("Aeq", "beq", "Feq")
ALL = REQUIRED + EQUALITY


def valid_arrays(lp: bool = False) -> dict[str, np.ndarray]:
    H = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.2], [0.0, 0.2, 1.5]])
    A = np.vstack([np.eye(3), -np.eye(3)])
    F = np.zeros((6, 2))
    F[0] = [1.0, 0.0]
    F[4] = [0.0, 1.0]
    return {
        "H": np.zeros((3, 3)) if lp else H,
        "c": np.array([1.0, -0.5, 0.2]),
        "C": np.array([[1.0, 0.0], [0.0, 1.0], [0.5, -1.0]]),
        "A": A,
        "b": np.full(6, 0.5),
        "F": F,
        "A_theta": np.vstack([np.eye(2), -np.eye(2)]),
        "b_theta": np.ones(4),
        "Aeq": np.array([[1.0, 1.0, 1.0]]),
        "beq": np.array([0.2]),
        "Feq": np.array([[0.5, 0.0]]),
    }


def write(path: Path, arrays: dict[str, np.ndarray], **extra) -> Path:
    np.savez(path, **arrays, **extra)
    return path


def program_file(tmp_path: Path, name: str = "prog", **changes) -> Path:
    """A program file with some arrays replaced (``None``: removed)."""
    arrays = valid_arrays()
    for k, v in changes.items():
        if v is None:
            arrays.pop(k, None)
        else:
            arrays[k] = v
    return write(tmp_path / f"{name}.npz", arrays, kind=np.array("mpqp"), name=np.array(name))


def cli(capsys, *args) -> tuple[int, str, str]:
    """``codev ARGS`` in-process -> (exit status, stdout, stderr)."""
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, status: int, *words: str) -> str:
    assert code == status, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("codev: error: "), lines[0]
    assert "Traceback" not in err and "internal error" not in err, err
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def assert_spec_error(exc: ce.SpecError, path: Path, field: str | None, *words: str) -> None:
    assert exc.file == str(path), (exc.file, str(exc))
    if field is not None:
        assert exc.field == field, (exc.field, str(exc))
    for w in words:
        assert w in str(exc), (w, str(exc))


def load_and_solve(path: Path):
    """Load, then solve: bad input may be found by either step."""
    prog = ce.MpProgram.load(path)
    return ce.mpsolve(prog)


# ---------------------------------------------------------------------------------------
# MpProgram.load: the valid file first
# ---------------------------------------------------------------------------------------


def test_valid_program_loads_and_solves(tmp_path):
    path = program_file(tmp_path)
    prog = ce.MpProgram.load(path)
    assert (prog.nz, prog.d, prog.kind, prog.name) == (3, 2, "mpqp", "prog")
    assert ce.mpsolve(prog).num_regions > 1


# ---------------------------------------------------------------------------------------
# file-level errors (no array to name)
# ---------------------------------------------------------------------------------------


def _missing(tmp_path: Path) -> Path:
    return tmp_path / "no_such_program.npz"


def _directory(tmp_path: Path) -> Path:
    d = tmp_path / "folder.npz"
    d.mkdir()
    return d


def _text(tmp_path: Path) -> Path:
    p = tmp_path / "text.npz"
    p.write_text("H = [[1]]\nthis is not an npz archive\n")
    return p


def _empty(tmp_path: Path) -> Path:
    p = tmp_path / "empty.npz"
    p.write_bytes(b"")
    return p


def _truncated(tmp_path: Path) -> Path:
    good = program_file(tmp_path, "whole")
    data = good.read_bytes()
    p = tmp_path / "truncated.npz"
    p.write_bytes(data[: len(data) // 2])
    return p


def _truncated_member(tmp_path: Path) -> Path:
    """The zip directory is intact but one member's compressed data is cut short."""
    p = tmp_path / "damaged.npz"
    np.savez_compressed(p, **valid_arrays())
    data = bytearray(p.read_bytes())
    # corrupt bytes inside the first member's compressed data (after its local header)
    start = 30 + len("H.npy") + 20
    for i in range(start, start + 16):
        data[i] ^= 0xFF
    p.write_bytes(bytes(data))
    return p


def _npy(tmp_path: Path) -> Path:
    p = tmp_path / "array.npy"
    np.save(p, np.eye(3))
    return p


def _pickle_file(tmp_path: Path) -> Path:
    import pickle

    marker = tmp_path / "UNPICKLED"
    p = tmp_path / "pickle.npz"
    p.write_bytes(pickle.dumps(_Evil(str(marker))))
    return p


class _Evil:
    """Unpickling this creates the file ``marker``: proof that something was unpickled."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


FILE_CASES = {
    "missing": (_missing, "no such file"),
    "directory": (_directory, "directory"),
    "not_npz": (_text, "not a readable"),
    "empty_file": (_empty, "not a readable"),
    "truncated": (_truncated, "not a readable"),
    "damaged_member": (_truncated_member, ""),
    "npy_not_npz": (_npy, "npz"),
    "pickle_not_npz": (_pickle_file, "not a readable"),
}


@pytest.mark.parametrize("case", list(FILE_CASES))
@pytest.mark.parametrize(
    "load", [ce.MpProgram.load, ce.MpSolution.load], ids=["program", "solution"]
)
def test_load_bad_file(tmp_path, case, load):
    make, words = FILE_CASES[case]
    path = make(tmp_path)
    with pytest.raises(ce.SpecError) as info:
        load(path)
    assert_spec_error(info.value, path, None, words)
    assert not (tmp_path / "UNPICKLED").exists()


@pytest.mark.parametrize("case", list(FILE_CASES))
def test_cli_bad_file(tmp_path, capsys, case):
    make, words = FILE_CASES[case]
    path = make(tmp_path)
    code, out, err = cli(capsys, "mpsolve", path)
    assert_one_line_error(code, err, 2, str(path), words)
    assert out == ""
    assert not (tmp_path / "UNPICKLED").exists()


# ---------------------------------------------------------------------------------------
# array-level errors: each names its array
# ---------------------------------------------------------------------------------------


def _shape_cases() -> dict[str, tuple[str, np.ndarray]]:
    return {
        "H_not_square": ("H", np.ones((3, 2))),
        "H_vector": ("H", np.ones(3)),
        "c_length": ("c", np.zeros(2)),
        "C_columns": ("C", np.zeros((3, 3))),
        "C_rows": ("C", np.zeros((2, 2))),
        "A_columns": ("A", np.zeros((6, 2))),
        "A_vector": ("A", np.zeros(6)),
        "b_length": ("b", np.zeros(5)),
        "b_matrix": ("b", np.zeros((6, 2))),
        "F_rows": ("F", np.zeros((5, 2))),
        "F_columns": ("F", np.zeros((6, 3))),
        "A_theta_vector": ("A_theta", np.ones(4)),
        "A_theta_no_columns": ("A_theta", np.zeros((4, 0))),
        "b_theta_length": ("b_theta", np.ones(3)),
        "Aeq_columns": ("Aeq", np.ones((1, 2))),
        "beq_length": ("beq", np.zeros(2)),
        "Feq_columns": ("Feq", np.zeros((1, 3))),
        "Feq_rows": ("Feq", np.zeros((2, 2))),
    }


SHAPE_CASES = _shape_cases()


def _bad_value_cases() -> dict[str, tuple[str, dict]]:
    """case -> (array that must be named, changes to the valid arrays)."""
    cases: dict[str, tuple[str, dict]] = {}
    for k, (field, val) in SHAPE_CASES.items():
        cases[f"shape_{k}"] = (field, {field: val})
    base = valid_arrays()
    for k in ALL:
        for bad in (np.nan, np.inf, -np.inf):
            arr = base[k].copy()
            arr.flat[arr.size // 2] = bad
            label = {np.nan: "nan"}.get(bad, "inf" if bad > 0 else "-inf")
            cases[f"{label}_{k}"] = (k, {k: arr})
    for k in REQUIRED:
        cases[f"missing_{k}"] = (k, {k: None})
    cases["missing_beq_only"] = ("beq", {"beq": None})
    cases["missing_Aeq_only"] = ("Aeq", {"Aeq": None})
    H = base["H"].copy()
    H[0, 1] += 0.1
    cases["H_not_symmetric"] = ("H", {"H": H})
    cases["H_not_psd"] = ("H", {"H": np.diag([1.0, -1.0, 2.0])})
    cases["H_negative_definite"] = ("H", {"H": -np.eye(3)})
    cases["H_complex"] = ("H", {"H": base["H"] + 1j})
    cases["c_text"] = ("c", {"c": np.array(["1", "2", "3"])})
    cases["A_no_variables"] = (
        "H",
        {
            "H": np.zeros((0, 0)),
            "c": np.zeros(0),
            "C": np.zeros((0, 2)),
            "A": np.zeros((6, 0)),
            "Aeq": np.zeros((1, 0)),
        },
    )
    return cases


BAD_VALUES = _bad_value_cases()


@pytest.mark.parametrize("case", list(BAD_VALUES))
def test_program_load_bad_array(tmp_path, case):
    field, changes = BAD_VALUES[case]
    path = program_file(tmp_path, **changes)
    with pytest.raises(ce.SpecError) as info:
        ce.MpProgram.load(path)
    assert_spec_error(info.value, path, field)
    if case.startswith(("nan_", "inf_", "-inf_")):
        assert "NaN" in info.value.reason or "inf" in info.value.reason, str(info.value)
    if case.startswith("missing_") and field in REQUIRED:
        assert "missing" in info.value.reason, str(info.value)


@pytest.mark.parametrize(
    "case",
    [
        "shape_C_columns",
        "shape_Feq_rows",
        "nan_b",
        "inf_A_theta",
        "missing_F",
        "H_not_symmetric",
        "H_not_psd",
        "c_text",
        "missing_beq_only",
    ],
)
def test_cli_bad_array(tmp_path, capsys, case):
    field, changes = BAD_VALUES[case]
    path = program_file(tmp_path, **changes)
    code, out, err = cli(capsys, "mpsolve", path, "--json")
    line = assert_one_line_error(code, err, 2, str(path), f": {field}: ")
    assert out == "", out
    assert line.index(str(path)) < line.index(f": {field}: ")


@pytest.mark.parametrize("field", ["H", "A", "b_theta", "Feq"])
def test_object_arrays_are_refused_never_unpickled(tmp_path, capsys, field):
    marker = tmp_path / "UNPICKLED"
    arrays = valid_arrays()
    obj = np.empty(arrays[field].shape, dtype=object)
    obj.flat[0] = _Evil(str(marker))
    for i in range(1, obj.size):
        obj.flat[i] = 0.0
    arrays[field] = obj
    path = write(tmp_path / "objects.npz", arrays)  # np.savez pickles object arrays
    with pytest.raises(ce.SpecError) as info:
        ce.MpProgram.load(path)
    assert_spec_error(info.value, path, field)
    assert not marker.exists(), "an object array was unpickled"
    code, _, err = cli(capsys, "mpsolve", path)
    assert_one_line_error(code, err, 2, str(path), f": {field}: ")
    assert not marker.exists(), "an object array was unpickled"


def test_object_array_in_an_ignored_entry_is_refused_too(tmp_path):
    """Even an array the loader does not use is never unpickled (``name`` as an object)."""
    marker = tmp_path / "UNPICKLED"
    arrays = valid_arrays()
    path = write(tmp_path / "objname.npz", arrays, name=np.array([_Evil(str(marker))]))
    with pytest.raises(ce.SpecError):
        ce.MpProgram.load(path)
    assert not marker.exists()


def test_program_constructor_validates_like_load():
    arrays = valid_arrays()
    arrays["F"] = np.zeros((6, 3))
    with pytest.raises(ce.SpecError) as info:
        ce.MpProgram(**arrays)
    assert info.value.field == "F"


def test_one_column_matrix_given_as_vector_is_accepted(tmp_path):
    """d = 1: ``C`` and ``F`` as vectors (a common slip) are read as one-column matrices."""
    arrays = valid_arrays()
    arrays["C"] = arrays["C"][:, 0]
    arrays["F"] = arrays["F"][:, 0]
    arrays["Feq"] = arrays["Feq"][:, 0]
    arrays["A_theta"] = np.array([[1.0], [-1.0]])
    arrays["b_theta"] = np.ones(2)
    prog = ce.MpProgram.load(write(tmp_path / "d1.npz", arrays))
    assert prog.C.shape == (3, 1) and prog.F.shape == (6, 1) and prog.Feq.shape == (1, 1)


# ---------------------------------------------------------------------------------------
# bad input found by solving
# ---------------------------------------------------------------------------------------


def _semantic_cases() -> dict[str, tuple[dict, str | None, tuple[str, ...]]]:
    """case -> (changes, field or None, words that must appear in the message)."""
    box2 = np.vstack([np.eye(2), -np.eye(2)])
    lp_z = {  # LP over z in R^3 with two bounded coordinates and an equality
        "H": np.zeros((3, 3)),
    }
    return {
        # theta1 <= 1 and theta1 >= 2
        "empty_parameter_set": (
            {"b_theta": np.array([1.0, 1.0, -2.0, 1.0])},
            "A_theta",
            ("empty",),
        ),
        # a row 0'theta <= -1
        "empty_parameter_set_zero_row": (
            {"A_theta": np.vstack([box2, [[0.0, 0.0]]]), "b_theta": np.array([1, 1, 1, 1, -1.0])},
            "A_theta",
            ("empty",),
        ),
        # theta1 + theta2 <= -3 inside the unit box
        "empty_parameter_set_corner": (
            {"A_theta": np.vstack([box2, [[1.0, 1.0]]]), "b_theta": np.array([1, 1, 1, 1, -3.0])},
            "A_theta",
            ("empty",),
        ),
        "unbounded_parameter_set": (
            {"A_theta": np.eye(2), "b_theta": np.ones(2)},
            "A_theta",
            ("unbounded",),
        ),
        "unbounded_parameter_set_one_direction": (
            {"A_theta": np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]]), "b_theta": np.ones(3)},
            "A_theta",
            ("unbounded",),
        ),
        "no_parameter_rows": (
            {"A_theta": np.zeros((0, 2)), "b_theta": np.zeros(0)},
            "A_theta",
            ("unbounded",),
        ),
        # min z1 with z1 <= 1.5 only (no lower bound on z1): unbounded everywhere
        "lp_unbounded_everywhere": (
            {
                **lp_z,
                "c": np.array([1.0, 0.0, 0.0]),
                "C": np.zeros((3, 2)),
                "A": np.array([[1.0, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]),
                "b": np.full(5, 1.5),
                "F": np.zeros((5, 2)),
                "Aeq": None,
                "beq": None,
                "Feq": None,
            },
            None,
            ("unbounded",),
        ),
        # min theta1 * z1 with z1 >= -1 only: bounded for theta1 >= 0, unbounded below 0
        "lp_unbounded_for_some_parameters": (
            {
                **lp_z,
                "c": np.zeros(3),
                "C": np.array([[1.0, 0.0], [0, 0], [0, 0]]),
                "A": np.array([[-1.0, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]),
                "b": np.ones(5),
                "F": np.zeros((5, 2)),
                "Aeq": None,
                "beq": None,
                "Feq": None,
            },
            None,
            ("unbounded",),
        ),
    }


SEMANTIC = _semantic_cases()


@pytest.mark.parametrize("case", list(SEMANTIC))
def test_bad_program_found_by_load_or_solve(tmp_path, case):
    changes, field, words = SEMANTIC[case]
    path = program_file(tmp_path, **changes)
    with pytest.raises(ce.SpecError) as info:
        load_and_solve(path)
    exc = info.value
    if exc.file is not None:  # mpsolve does not know the file; load does
        assert exc.file == str(path)
    if field is not None:
        assert exc.field == field, str(exc)
    for w in words:
        assert w in exc.reason, (w, str(exc))


@pytest.mark.parametrize("case", list(SEMANTIC))
def test_cli_bad_program_found_by_load_or_solve(tmp_path, capsys, case):
    changes, field, words = SEMANTIC[case]
    path = program_file(tmp_path, **changes)
    code, out, err = cli(capsys, "mpsolve", path)
    extra = (f": {field}: ",) if field else ()
    assert_one_line_error(code, err, 2, str(path), *extra, *words)
    assert out == ""


def test_infeasible_everywhere_is_a_result_not_an_error(tmp_path, capsys):
    """z1 >= 2 and z1 <= 1.5: no parameter is feasible; zero regions, exit 0."""
    A = np.vstack([valid_arrays()["A"], [[-1.0, 0.0, 0.0]]])
    path = program_file(
        tmp_path, A=A, b=np.concatenate([np.full(6, 1.5), [-2.0]]), F=np.zeros((7, 2))
    )
    sol = load_and_solve(path)
    assert sol.num_regions == 0
    assert np.all(sol.locate(np.zeros((3, 2))) == -1)
    code, out, err = cli(capsys, "mpsolve", path, "--json")
    assert code == 0, err
    assert json.loads(out)["regions"] == 0


# ---------------------------------------------------------------------------------------
# the CLI: happy path, exit 1 on solver failure or timeout, the real process
# ---------------------------------------------------------------------------------------


def test_cli_mpsolve_summary_json_and_out(tmp_path, capsys):
    path = program_file(tmp_path, "qp3")
    code, out, err = cli(capsys, "mpsolve", path)
    assert code == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1, out
    ref = ce.mpsolve(ce.MpProgram.load(path))
    for w in ("qp3", f"{ref.num_regions} critical regions", "mpqp", "nz=3", "d=2", " s"):
        assert w in lines[0], (w, lines[0])

    sol_file = tmp_path / "out" / "qp3.sol.npz"
    code, out, err = cli(capsys, "mpsolve", path, "--json", "--out", sol_file)
    assert code == 0, err
    payload = json.loads(out)
    assert payload["regions"] == ref.num_regions
    assert payload["name"] == "qp3" and payload["kind"] == "mpqp"
    assert (payload["nz"], payload["d"]) == (3, 2)
    assert isinstance(payload["seconds"], float) and payload["seconds"] >= 0
    assert payload["out"] == str(sol_file) and sol_file.is_file()
    loaded = ce.MpSolution.load(sol_file)
    Theta = np.random.default_rng(1).uniform(-1.2, 1.2, (300, 2))
    np.testing.assert_array_equal(loaded.locate(Theta), ref.locate(Theta))
    np.testing.assert_allclose(loaded.value(Theta), ref.value(Theta), rtol=0, atol=1e-12)

    code, out, err = cli(capsys, "mpsolve", path, "--json")
    assert json.loads(out)["out"] is None


def test_cli_mpsolve_lp_kind(tmp_path, capsys):
    arrays = valid_arrays(lp=True)
    path = write(tmp_path / "lp3.npz", arrays)
    code, out, err = cli(capsys, "mpsolve", path, "--json")
    assert code == 0, err
    payload = json.loads(out)
    assert payload["kind"] == "mplp" and payload["regions"] >= 1


def _mpsolve_module():
    return sys.modules["codev_engine.mp.solve"]


def test_cli_solver_error_is_exit_1_not_bad_input(tmp_path, capsys, monkeypatch):
    path = program_file(tmp_path)

    def broken(*_a, **_k):
        raise ce.SolverError("facet coverage did not converge (too many pieces)")

    monkeypatch.setattr(_mpsolve_module(), "mpsolve", broken)
    code, out, err = cli(capsys, "mpsolve", path, "--json")
    assert_one_line_error(code, err, 1, str(path), "facet coverage did not converge")
    assert out == ""


def test_cli_timeout_is_exit_1(tmp_path, capsys, monkeypatch):
    path = program_file(tmp_path)

    def slow(*_a, **_k):
        time.sleep(30)
        raise AssertionError("not interrupted")

    monkeypatch.setattr(_mpsolve_module(), "mpsolve", slow)
    t0 = time.monotonic()
    code, out, err = cli(capsys, "mpsolve", path, "--timeout", "0.3")
    assert time.monotonic() - t0 < 10
    assert_one_line_error(code, err, 1, str(path), "time limit")
    assert out == ""


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_cli_bad_timeout_is_bad_input(tmp_path, capsys, value):
    path = program_file(tmp_path)
    code, _, err = cli(capsys, "mpsolve", path, "--timeout", value)
    assert_one_line_error(code, err, 2, "--timeout")


@pytest.mark.parametrize("value", ["0", "-5"])
def test_cli_bad_max_regions_is_bad_input(tmp_path, capsys, value):
    path = program_file(tmp_path)
    code, _, err = cli(capsys, "mpsolve", path, "--max-regions", value)
    assert_one_line_error(code, err, 2, "--max-regions")


def test_cli_max_regions_stops_the_solve(tmp_path, capsys):
    """Past ``--max-regions`` the solver gives up (exit 1, the count in the message, and how
    to raise the limit); with room enough it solves."""
    path = program_file(tmp_path)
    code, out, _ = cli(capsys, "mpsolve", path, "--json")
    regions = json.loads(out)["regions"]
    assert code == 0 and regions > 1
    code, out, err = cli(capsys, "mpsolve", path, "--max-regions", str(regions - 1))
    assert_one_line_error(code, err, 1, str(path), f"more than {regions - 1} regions")
    assert "--max-regions" in err and "SolveOptions.max_regions" in err, err
    code, out, _ = cli(capsys, "mpsolve", path, "--json", "--max-regions", str(regions))
    assert code == 0 and json.loads(out)["regions"] == regions


def _codev(*args, cwd) -> subprocess.CompletedProcess:
    return run_codev(*args, cwd=cwd, timeout=120)


def test_cli_process_bad_input_and_success(tmp_path):
    """The real process: exit 2 with one line for a bad array, 0 with JSON for a good file."""
    bad = program_file(tmp_path, "bad", F=np.zeros((6, 3)))
    proc = _codev("mpsolve", bad, cwd=tmp_path)
    assert_one_line_error(proc.returncode, proc.stderr, 2, str(bad), ": F: ")
    assert proc.stdout == ""
    good = program_file(tmp_path, "good")
    proc = _codev("mpsolve", good, "--json", "--out", tmp_path / "good.sol.npz", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["regions"] >= 1
    assert proc.stderr == ""


# ---------------------------------------------------------------------------------------
# MpSolution.load: bad arrays
# ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def solution_arrays(tmp_path_factory) -> dict[str, np.ndarray]:
    tmp = tmp_path_factory.mktemp("sol")
    sol = ce.mpsolve(ce.MpProgram(**valid_arrays(), name="qp3"))
    assert sol.num_regions >= 3
    path = sol.save(tmp / "qp3.sol.npz")
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _solution_cases(arrays: dict[str, np.ndarray]) -> dict[str, tuple[str, dict]]:
    R, nz, d = arrays["K"].shape
    rows = arrays["A"].shape[0]
    cases: dict[str, tuple[str, dict]] = {}
    for k in (
        "format",
        "meta",
        "K",
        "k",
        "A",
        "b",
        "offsets",
        "active",
        "active_offsets",
        "domain_A",
        "domain_b",
        "implied",
        "shared_A",
        "shared_b",
    ):
        cases[f"missing_{k}"] = (k, {k: None})
    for k in REQUIRED:
        cases[f"missing_program.{k}"] = (f"program.{k}", {f"program.{k}": None})
    cases["format_unknown"] = ("format", {"format": np.array("codev-mp-solution/99")})
    cases["format_number"] = ("format", {"format": np.array(1.0)})
    cases["meta_not_json"] = ("meta", {"meta": np.array("{seconds: 1")})
    cases["meta_not_object"] = ("meta", {"meta": np.array("[1, 2]")})
    cases["K_shape"] = ("K", {"K": np.zeros((R, nz, d + 1))})
    cases["K_2d"] = ("K", {"K": np.zeros((R, nz))})
    cases["k_count"] = ("k", {"k": np.zeros((R + 1, nz))})
    cases["A_columns"] = ("A", {"A": np.zeros((rows, d + 1))})
    cases["b_length"] = ("b", {"b": np.zeros(rows - 1)})
    cases["offsets_count"] = ("offsets", {"offsets": arrays["offsets"][:-1]})
    cases["offsets_float"] = ("offsets", {"offsets": arrays["offsets"].astype(float)})
    off = arrays["offsets"].copy()
    off[1], off[2] = off[2], off[1]
    cases["offsets_decreasing"] = ("offsets", {"offsets": off})
    off = arrays["offsets"].copy()
    off[-1] += 1
    cases["offsets_past_the_rows"] = ("offsets", {"offsets": off})
    cases["active_float"] = ("active", {"active": arrays["active"].astype(float)})
    cases["active_offsets_count"] = (
        "active_offsets",
        {"active_offsets": arrays["active_offsets"][:-1]},
    )
    cases["implied_not_bool"] = ("implied", {"implied": np.zeros(R, dtype=int)})
    cases["implied_count"] = ("implied", {"implied": np.zeros(R + 1, dtype=bool)})
    cases["shared_A_columns"] = ("shared_A", {"shared_A": np.zeros((2, d + 1))})
    cases["shared_b_length"] = ("shared_b", {"shared_b": np.zeros(1)})
    nan_row = {"shared_A": np.full((1, d), np.nan), "shared_b": np.ones(1)}
    cases["nan_shared_A"] = ("shared_A", nan_row)
    cases["domain_A_columns"] = ("domain_A", {"domain_A": np.zeros((4, d + 1))})
    cases["domain_b_length"] = ("domain_b", {"domain_b": np.zeros(arrays["domain_A"].shape[0] + 1)})
    for k in ("K", "k", "A", "b", "domain_A", "domain_b", "program.c", "program.F"):
        bad = arrays[k].astype(float).copy()
        bad.flat[bad.size // 2] = np.nan
        cases[f"nan_{k}"] = (k, {k: bad})
        bad = bad.copy()
        bad.flat[bad.size // 2] = np.inf
        cases[f"inf_{k}"] = (k, {k: bad})
    H = arrays["program.H"].copy()
    H[0, 1] += 1.0
    cases["program_H_not_symmetric"] = ("program.H", {"program.H": H})
    cases["program_H_not_psd"] = ("program.H", {"program.H": -np.eye(nz)})
    cases["program_F_shape"] = ("program.F", {"program.F": np.zeros((6, d + 1))})
    return cases


SOLUTION_CASE_NAMES = list(
    _solution_cases(
        {
            "K": np.zeros((3, 3, 2)),
            "A": np.zeros((9, 2)),
            "offsets": np.arange(4),
            "active": np.zeros(3, int),
            "active_offsets": np.arange(4),
            "domain_A": np.zeros((4, 2)),
            "k": np.zeros((3, 3)),
            "b": np.zeros(9),
            "domain_b": np.zeros(4),
            "implied": np.zeros(3, dtype=bool),
            "shared_A": np.zeros((0, 2)),
            "shared_b": np.zeros(0),
            "program.c": np.zeros(3),
            "program.F": np.zeros((6, 2)),
            "program.H": np.eye(3),
        }
    )
)


@pytest.mark.parametrize("case", SOLUTION_CASE_NAMES)
def test_solution_load_bad_array(tmp_path, solution_arrays, case):
    field, changes = _solution_cases(solution_arrays)[case]
    arrays = dict(solution_arrays)
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    path = write(tmp_path / "bad.sol.npz", arrays)
    with pytest.raises(ce.SpecError) as info:
        ce.MpSolution.load(path)
    assert_spec_error(info.value, path, field)


@pytest.mark.parametrize("field", ["K", "program.H", "meta"])
def test_solution_object_arrays_are_refused_never_unpickled(tmp_path, solution_arrays, field):
    marker = tmp_path / "UNPICKLED"
    arrays = dict(solution_arrays)
    obj = np.empty(max(arrays[field].size, 1), dtype=object)
    obj[0] = _Evil(str(marker))
    arrays[field] = obj
    path = write(tmp_path / "objects.sol.npz", arrays)
    with pytest.raises(ce.SpecError) as info:
        ce.MpSolution.load(path)
    assert_spec_error(info.value, path, field)
    assert not marker.exists(), "an object array was unpickled"


def test_a_program_file_is_not_a_solution_and_vice_versa(tmp_path, solution_arrays):
    prog = program_file(tmp_path)
    with pytest.raises(ce.SpecError) as info:
        ce.MpSolution.load(prog)
    assert_spec_error(info.value, prog, "format")
    sol = write(tmp_path / "x.sol.npz", solution_arrays)
    with pytest.raises(ce.SpecError) as info:
        ce.MpProgram.load(sol)
    assert info.value.file == str(sol) and info.value.field in REQUIRED


# ---------------------------------------------------------------------------------------
# round trips
# ---------------------------------------------------------------------------------------


def _programs() -> dict[str, ce.MpProgram]:
    qp = valid_arrays()
    lp = valid_arrays(lp=True)
    noeq = {k: v for k, v in valid_arrays().items() if k not in EQUALITY}
    return {
        "qp_equality": ce.MpProgram(**qp, name="qp_equality"),
        "lp_equality": ce.MpProgram(**lp, name="lp_equality"),
        "qp_no_equality": ce.MpProgram(**noeq, name="qp_no_equality"),
    }


def _assert_same_program(a: ce.MpProgram, b: ce.MpProgram) -> None:
    for k in ALL:
        va, vb = getattr(a, k), getattr(b, k)
        if va is None:
            assert vb is None, k
        else:
            assert va.dtype == vb.dtype and va.shape == vb.shape, k
            np.testing.assert_array_equal(va, vb, err_msg=k)
    assert (a.kind, a.nz, a.d) == (b.kind, b.nz, b.d)


def _thetas(prog: ce.MpProgram, n: int = 400) -> np.ndarray:
    """Points in and around the parameter box (some outside it, some outside the domain)."""
    rng = np.random.default_rng(7)
    return rng.uniform(-1.3, 1.3, (n, prog.d))


@pytest.mark.parametrize("name", list(_programs()))
def test_program_round_trip(tmp_path, name):
    prog = _programs()[name]
    path = prog.save(tmp_path / f"{name}.npz")
    back = ce.MpProgram.load(path)
    _assert_same_program(prog, back)
    assert back.name == name
    with np.load(path, allow_pickle=False) as z:
        assert str(z["kind"]) == prog.kind
    # the same program solves to the same partition
    s1, s2 = ce.mpsolve(prog), ce.mpsolve(back)
    Theta = _thetas(prog)
    assert s1.num_regions == s2.num_regions
    np.testing.assert_array_equal(s1.locate(Theta), s2.locate(Theta))
    np.testing.assert_array_equal(s1.primal(Theta), s2.primal(Theta))
    np.testing.assert_array_equal(s1.value(Theta), s2.value(Theta))


@pytest.mark.parametrize("name", list(_programs()))
def test_solution_round_trip(tmp_path, name):
    prog = _programs()[name]
    sol = ce.mpsolve(prog)
    path = sol.save(tmp_path / f"{name}.sol.npz")
    back = ce.MpSolution.load(path)
    _assert_same_program(sol.program, back.program)
    assert back.program.name == name
    assert back.num_regions == sol.num_regions > 0
    for r1, r2 in zip(sol.regions, back.regions, strict=True):
        for k in ("A", "b", "K", "k"):
            np.testing.assert_array_equal(getattr(r1, k), getattr(r2, k), err_msg=k)
        assert r1.active == r2.active
    np.testing.assert_array_equal(sol.domain_A, back.domain_A)
    np.testing.assert_array_equal(sol.domain_b, back.domain_b)
    assert back.seconds == pytest.approx(sol.seconds)
    Theta = _thetas(prog)
    idx = sol.locate(Theta)
    assert (idx >= 0).any() and (idx < 0).any()  # inside and outside the domain
    np.testing.assert_array_equal(back.locate(Theta), idx)
    np.testing.assert_array_equal(back.primal(Theta), sol.primal(Theta))  # NaN == NaN here
    np.testing.assert_array_equal(back.value(Theta), sol.value(Theta))
    # and once more: save of the loaded solution is the same file content
    again = ce.MpSolution.load(back.save(tmp_path / "again.npz"))
    np.testing.assert_array_equal(again.value(Theta), sol.value(Theta))


def test_empty_solution_round_trip(tmp_path):
    arrays = valid_arrays()
    arrays["b"] = np.concatenate([np.full(3, -2.0), np.full(3, 1.5)])  # z <= -2, z >= -1.5
    sol = ce.mpsolve(ce.MpProgram(**arrays, name="infeasible"))
    assert sol.num_regions == 0
    back = ce.MpSolution.load(sol.save(tmp_path / "empty.sol.npz"))
    assert back.num_regions == 0
    assert np.all(back.locate(np.zeros((2, 2))) == -1)
    assert np.all(np.isnan(back.value(np.zeros((2, 2)))))
