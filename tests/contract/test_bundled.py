"""What ships beside the code: ``codev examples`` and ``codev bench`` (workbench/bundled.py).

``codev examples [DIR]`` writes the bundled examples (read through importlib.resources
from the package ``workbench.examples``, the repository's ``examples/``); it refuses to
overwrite a file without ``--force`` (exit 2, one line naming the file, nothing written).
``codev bench NAME`` runs ``benchmarks/NAME.py`` of a checkout; without one (an installed
package) it says so in one line, exit 2. Through ``workbench.cli.main`` and through real
processes; the wheel itself is tested in test_wheel.py.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from workbench.bundled import DEFAULT_EXAMPLES_DIR, benchmarks_dir, example_files
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted(p for p in (ROOT / "examples").iterdir() if p.suffix in (".toml", ".ipynb"))


def codev(*args, cwd: Path, pythonpath: Path | None = None) -> subprocess.CompletedProcess:
    """``python -m workbench.cli ARGS`` in ``cwd`` (``pythonpath`` first on the path)."""
    env = {k: v for k, v in os.environ.items() if k != "CODEV_DEBUG"}
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    return subprocess.run(
        [sys.executable, "-m", "workbench.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=120,
    )


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("codev: error: "), err
    return lines[0]


def test_the_package_holds_every_example_of_the_repository():
    assert len(EXAMPLES) >= 10
    assert [f.name for f in example_files()] == [p.name for p in EXAMPLES]
    for f, p in zip(example_files(), EXAMPLES, strict=True):
        assert f.read_bytes() == p.read_bytes()


def test_examples_writes_every_file_and_the_next_command(tmp_path, capsys):
    dest = tmp_path / "mine"
    assert main(["examples", str(dest)]) == 0
    out = capsys.readouterr().out
    assert sorted(p.name for p in dest.iterdir()) == [p.name for p in EXAMPLES]
    for p in EXAMPLES:
        assert (dest / p.name).read_bytes() == p.read_bytes()
        assert str(dest / p.name) in out
    assert f"codev run {dest / 'double_integrator.toml'}" in out


def test_examples_defaults_to_codev_examples_in_the_working_folder(tmp_path):
    out = codev("examples", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stderr == ""
    written = tmp_path / DEFAULT_EXAMPLES_DIR
    assert sorted(p.name for p in written.iterdir()) == [p.name for p in EXAMPLES]
    assert f"codev run {DEFAULT_EXAMPLES_DIR}/double_integrator.toml" in out.stdout
    # the help says where
    helptext = codev("examples", "--help", cwd=tmp_path).stdout
    assert DEFAULT_EXAMPLES_DIR in helptext.replace("-\n", "-").replace(" ", "")


def test_examples_refuses_to_overwrite_and_writes_nothing(tmp_path):
    dest = tmp_path / "ex"
    dest.mkdir()
    mine = dest / "pendulum.toml"
    mine.write_text("# my edits\n", encoding="utf-8")
    out = codev("examples", dest, cwd=tmp_path)
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert str(mine) in line and "--force" in line
    assert mine.read_text(encoding="utf-8") == "# my edits\n"
    assert [p.name for p in dest.iterdir()] == ["pendulum.toml"]  # nothing else either

    out = codev("examples", dest, "--force", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert mine.read_bytes() == (ROOT / "examples" / "pendulum.toml").read_bytes()


def test_examples_into_a_file_is_bad_input(tmp_path):
    (tmp_path / "taken").write_text("x", encoding="utf-8")
    out = codev("examples", "taken", cwd=tmp_path)
    assert out.returncode == 2
    assert "taken" in one_error_line(out.stderr)


def test_benchmarks_are_found_only_in_a_checkout(tmp_path):
    assert benchmarks_dir() == ROOT / "benchmarks"
    # a package folder as in site-packages: no pyproject.toml or benchmarks/ beside it
    assert benchmarks_dir(tmp_path / "workbench") is None
    (tmp_path / "benchmarks").mkdir()
    assert benchmarks_dir(tmp_path / "workbench") is None  # benchmarks/ alone is not a checkout
    (tmp_path / "pyproject.toml").write_text("", encoding="utf-8")
    assert benchmarks_dir(tmp_path / "workbench") == tmp_path / "benchmarks"


def test_bench_runs_the_checkouts_script(tmp_path):
    out = codev("bench", "synth", "--help", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "usage: synth.py" in out.stdout


def test_bench_offers_every_benchmark_script():
    # a script added to benchmarks/ is offered by codev bench (helpers of a script aside)
    from workbench.cli import BENCHMARKS

    scripts = {p.stem for p in (ROOT / "benchmarks").glob("*.py")} - {"hylaa_peer"}
    assert set(BENCHMARKS) == scripts


def test_bench_without_a_checkout_says_so(tmp_path):
    # the workbench package alone, as an installed wheel lays it out, first on the path
    site = tmp_path / "site-packages"
    shutil.copytree(ROOT / "workbench", site / "workbench")
    out = codev("bench", "synth", "--help", cwd=tmp_path, pythonpath=site)
    assert out.returncode == 2, out.stdout + out.stderr
    assert "needs a checkout of the repository" in one_error_line(out.stderr)
    assert out.stdout == ""
