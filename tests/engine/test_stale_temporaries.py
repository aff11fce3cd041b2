"""What killed writers leave outside a session: a sweep's folder, and the files codev
writes into a folder of the user's (exports, reports, recordings, ``--out`` files).

- a sweep run into its folder removes the ``.tmp-*`` temporaries a killed writer left
  there, never a live writer's (its ``flock``), never a young unlocked one;
- an export or a report written into a folder removes the stale temporaries a killed
  write of that kind of file left beside it, and only those: a live writer's, another
  program's ``.tmp-*`` and a temporary of another suffix stay.

The writers are real processes holding ``io.atomic``'s temporaries, killed by SIGKILL
(no unwinding: what a power cut or the OOM killer leaves).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import codev_engine as ce
from codev_engine.deploy.export import export_python
from codev_engine.io.atomic import STALE_AFTER
from codev_engine.sweeps.folder import read_sweep
from codev_engine.view.report import write_report
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
DI = ROOT / "examples" / "double_integrator.toml"

#: a writer that holds atomic temporaries for the files named on its command line until
#: killed
_WRITER = """
import sys, time
from contextlib import ExitStack
from codev_engine.io.atomic import atomic_path
with ExitStack() as stack:
    for name in sys.argv[1:]:
        stack.enter_context(atomic_path(name)).write_bytes(b"half")
    print("writing", flush=True)
    time.sleep(120)
"""


def _age(paths, seconds: float = 2 * STALE_AFTER) -> None:
    """Make ``paths`` look ``seconds`` old (what the wait for a stale temporary would do)."""
    past = time.time() - seconds
    for p in paths:
        os.utime(p, (past, past))


def _temporaries(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir() if p.name.startswith(".tmp-")}


class _Writer:
    """A live writer process holding the temporaries of ``targets``."""

    def __init__(self, *targets: Path) -> None:
        folder = targets[0].parent
        folder.mkdir(parents=True, exist_ok=True)
        before = _temporaries(folder)
        self.proc = subprocess.Popen([sys.executable, "-c", _WRITER, *map(str, targets)],
                                     cwd=ROOT, stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout.readline() == "writing\n"
        self.names = _temporaries(folder) - before
        assert len(self.names) == len(targets)
        _age(folder / n for n in self.names)  # (old: only its lock keeps it)

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=30)

    def __enter__(self) -> _Writer:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self.proc.stdout.close()


def test_a_sweep_run_removes_a_killed_writers_temporaries_from_its_folder(tmp_path):
    problem = ce.load_spec(DI)
    grid = {"mpc.horizon": [2]}
    out = tmp_path / "sweep"
    with _Writer(out / "sweep.json", out / "journal.jsonl") as writer:
        ce.sweep(problem, grid, session=out, recording=False)
        assert writer.names <= _temporaries(out)  # (held: a live writer's, however old)
        writer.kill()
    young = out / ".tmp-0123456789ab.json"  # (unlocked, but it may be a writer not yet locked)
    young.write_text("{")
    assert writer.names <= _temporaries(out)  # (nothing removes them between runs)
    ce.sweep(problem, grid, session=out, recording=False)
    assert _temporaries(out) == {young.name}
    assert len(read_sweep(out).journal) == 2  # (the sweep's files intact)


def test_an_export_and_a_report_remove_only_their_own_stale_temporaries(tmp_path):
    problem = ce.load_spec(DI)
    law = ce.synthesize(problem)
    out = tmp_path / "out"
    py, html = out / "law.py", out / "report.html"
    others = [out / ".tmp-notcodevs.py", out / ".tmp-0123456789ab.txt"]
    with _Writer(py, html) as live, _Writer(py, html) as dead:
        for p in others:
            p.write_text("someone else's")
        _age(others)
        dead.kill()
        export_python(law, py)
        write_report(html, problem, law)
        left = _temporaries(out)
        assert live.names <= left and not dead.names & left
        assert {p.name for p in others} <= left
        assert py.read_text().startswith('r"""The explicit law')
        assert html.read_text().startswith("<!DOCTYPE")


def test_codev_synth_out_removes_a_killed_writes_temporary(tmp_path, capsys):
    law = tmp_path / "law.npz"
    with _Writer(law) as dead:
        dead.kill()
    assert main(["synth", str(DI), "--out", str(law)]) == 0
    capsys.readouterr()
    assert _temporaries(tmp_path) == set() and ce.ExplicitLaw.load(law).num_regions > 0
