"""The bundled session replays headless and reproduces its recorded verdicts."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from codev_engine.pipeline import loads_spec
from codev_engine.session import RunOptions, Session, stage_keys
from codev_engine.session.keys import stage_key
from codev_engine.session.stages import TABLE
from workbench.cli import main

BUNDLED = Path(__file__).resolve().parents[2] / "sessions" / "double-integrator"


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


def test_bundled_journal_keys_are_the_keys_computed_now():
    """The keys are a file format: the journal's, hashed by the engine that recorded it, are
    the ones this engine computes from the same spec snapshot and options."""
    journal = Session.open(BUNDLED).journal()
    for rec in journal:
        text = (BUNDLED / "specs" / f"{rec['spec'][:16]}.toml").read_text(encoding="utf-8")
        problem = loads_spec(text, check_mpc=False)
        options = RunOptions.from_json(rec["options"])
        keys = stage_keys(problem, options)
        if rec["stage"] == "recording":
            # the recording's key holds the hash of the code that draws it, which changes
            # with every picture fix (stages.view_code_sha): the journal's details name
            # the one that drew it (none before it was keyed); the rest is the format
            inputs = TABLE["recording"].inputs(problem, options, keys)
            del inputs["view"]
            if "view" in rec["details"]:
                inputs["view"] = rec["details"]["view"]
            keys["recording"] = stage_key("recording", inputs)
        assert keys[rec["stage"]] == rec["key"], (rec["run"], rec["stage"])
        assert rec["artifact"] == f"artifacts/{rec['stage']}-{rec['key'][:16]}." + (
            "rrd" if rec["stage"] == "recording" else "npz"
        )
    assert len(journal) == 8
