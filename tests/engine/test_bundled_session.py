"""The bundled session replays headless and reproduces its recorded verdicts."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from codev_engine.session import Session
from workbench.cli import main

BUNDLED = Path(__file__).resolve().parents[2] / "sessions" / "double_integrator"


def _copy(tmp_path: Path) -> Path:
    """The committed part of the bundled session (its artifacts are a local cache)."""
    dest = tmp_path / "di"
    shutil.copytree(BUNDLED, dest, ignore=shutil.ignore_patterns("artifacts", ".lock", ".tmp-*"))
    return dest


def test_bundled_session_is_committed_without_artifacts():
    files = {p.name for p in BUNDLED.iterdir()}
    assert {"session.json", "spec.toml", "journal.jsonl", "specs"} <= files
    journal = Session.open(BUNDLED).journal()
    stages = [(r["run"], r["stage"]) for r in journal]
    assert (1, "recording") in stages and (2, "verification") in stages
    assert all(r["status"] != "failed" for r in journal)


def test_bundled_session_replays_and_matches(tmp_path, capsys):
    dest = _copy(tmp_path)
    journal_before = (dest / "journal.jsonl").read_bytes()
    assert main(["replay", str(dest), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["match"] and out["runs"] == 2 and out["checked"] == 8
    # nothing cached in a fresh copy but what run 2 shares with run 1 (model, synthesis)
    assert out["cached"] == 2
    assert (dest / "journal.jsonl").read_bytes() == journal_before
    # the verdicts recorded are the ones reproduced
    verdicts = [
        r["outcome"]["verdict"]
        for r in Session.open(dest).journal()
        if r["stage"] == "verification"
    ]
    assert verdicts == ["robustly_safe", "robustly_safe"]
    # a second replay uses the cache for every stage
    assert main(["replay", str(dest), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["cached"] == again["checked"] == 8
