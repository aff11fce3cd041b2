"""Opening workbench targets and the draft of unsaved edits (workbench/state.py)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

import codev_engine as ce
from codev_engine.session import RunOptions, Session, SessionError, stage_keys
from workbench.tui.form import FIELDS, check_form, form_from_text
from workbench.tui.state import (
    DRAFT,
    EMPTY,
    clear_draft,
    new_design,
    open_target,
    read_draft,
    templates,
    write_draft,
)

ROOT = Path(__file__).resolve().parents[2]
DI = ROOT / "examples" / "double_integrator.toml"
PENDULUM = ROOT / "examples" / "pendulum.toml"


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


# --------------------------------------------------------------------------------------------
# open_target
# --------------------------------------------------------------------------------------------


def test_open_a_spec_file_creates_a_session_named_after_it(cwd):
    opened = open_target(str(DI), sessions_root="sessions")
    folder = cwd / "sessions" / "double-integrator"
    assert opened.session.path == Path("sessions") / "double-integrator"
    assert (folder / "session.json").is_file()
    assert opened.values == form_from_text(DI.read_text(encoding="utf-8"))[0]
    assert opened.has_verify is True
    assert opened.note.startswith("new session") and str(DI) in opened.note
    # the second time, the session exists
    again = open_target(str(DI), sessions_root="sessions")
    assert again.session.path == opened.session.path
    assert again.note.startswith("opened session")
    # nothing else was written to the cwd
    assert sorted(p.name for p in cwd.iterdir()) == ["sessions"]


def test_the_bundled_example_opens_the_bundled_session(cwd):
    """Issue 41: ``make demo`` (which replays ``sessions/double-integrator``), then ``codev
    tui examples/double_integrator.toml``: one session, the bundled one, not a second
    folder beside it (the folder is the spec's name, whatever the file's)."""
    import shutil

    shutil.copytree(ROOT / "sessions" / "double-integrator", cwd / "sessions" /
                    "double-integrator", ignore=shutil.ignore_patterns("artifacts"))
    opened = open_target(str(DI), sessions_root="sessions")
    assert opened.session.path == Path("sessions") / "double-integrator"
    assert opened.note.startswith("opened session"), opened.note
    assert opened.session.journal()  # the demo's runs: its cached stages are reused
    assert sorted(p.name for p in (cwd / "sessions").iterdir()) == ["double-integrator"]


def test_open_a_spec_file_with_session_dir(cwd):
    opened = open_target(str(PENDULUM), session_dir=str(cwd / "mine"), sessions_root="unused")
    assert opened.session.path == cwd / "mine"
    assert (cwd / "mine" / "session.json").is_file()
    assert not (cwd / "unused").exists()


def test_open_a_spec_file_with_an_odd_name_stays_in_the_sessions_root(cwd):
    for name in ("..", ".", "../../escape", "a/b", "ü"):
        text = DI.read_text(encoding="utf-8").replace(
            'name = "double-integrator"', f"name = {json.dumps(name)}"
        )
        spec = cwd / "odd.toml"
        spec.write_text(text, encoding="utf-8")
        opened = open_target(str(spec), sessions_root=cwd / "root")
        path = opened.session.path.resolve()
        assert path.parent == (cwd / "root").resolve(), (name, path)
        assert not path.name.startswith(".")


def test_open_a_missing_or_bad_spec(cwd):
    with pytest.raises(ce.SpecError, match="file not found"):
        open_target(str(cwd / "nope.toml"))
    bad = cwd / "bad.toml"
    bad.write_text("name = [\n", encoding="utf-8")
    with pytest.raises(ce.SpecError) as info:
        open_target(str(bad))
    assert info.value.file == str(bad)
    assert "invalid TOML" in info.value.reason
    assert not (cwd / "sessions").exists()


def test_open_a_session_folder(cwd):
    session = Session.create(cwd / "s")
    problem = ce.load_spec(DI)
    session.save_spec(problem)
    opened = open_target(str(cwd / "s"))
    assert opened.session.path == cwd / "s"
    assert opened.note is None
    chk = check_form(opened.values, with_verify=opened.has_verify)
    assert chk.ok and chk.problem.source != ""
    assert stage_keys(chk.problem, RunOptions()) == stage_keys(problem, RunOptions())


def test_open_a_session_folder_without_a_spec(cwd):
    Session.create(cwd / "empty")
    opened = open_target(str(cwd / "empty"))
    assert all(v == "" for v in opened.values.values())
    assert "no spec" in opened.note


def test_open_a_folder_that_is_not_a_session(cwd):
    (cwd / "notes").mkdir()
    (cwd / "notes" / "x.txt").write_text("hello")
    with pytest.raises(SessionError, match="not a codev session"):
        open_target(str(cwd / "notes"))


def test_open_nothing_gives_a_blank_form(cwd):
    opened = open_target(None, sessions_root=cwd / "sessions")
    assert opened.session.path == cwd / "sessions" / "untitled"
    assert set(opened.values) == {fd.name for fd in FIELDS}
    assert all(v == "" for v in opened.values.values())
    assert opened.has_verify is True
    assert opened.note.startswith("new session") and "fill in" in opened.note
    # a blank form is not a valid spec: every required entry says so
    chk = check_form(opened.values, with_verify=True)
    assert {k for k, v in chk.errors.items() if v == "required"} == {
        fd.name for fd in FIELDS if fd.required
    }


def test_open_nothing_again_reopens_untitled(cwd):
    first = open_target(None, sessions_root=cwd / "sessions")
    first.session.save_spec(ce.load_spec(DI))
    again = open_target(None, sessions_root=cwd / "sessions")
    assert again.session.path == first.session.path
    assert again.values["name"] == "double-integrator"


def test_open_nothing_with_session_dir(cwd):
    opened = open_target(None, session_dir=str(cwd / "here"), sessions_root=cwd / "sessions")
    assert opened.session.path == cwd / "here"
    assert not (cwd / "sessions").exists()


def test_session_folder_and_session_option_together_is_an_error(cwd):
    Session.create(cwd / "s")
    with pytest.raises(SessionError) as info:
        open_target(str(cwd / "s"), session_dir=str(cwd / "t"))
    assert info.value.field == "--session"
    assert not (cwd / "t").exists()


# --------------------------------------------------------------------------------------------
# Drafts
# --------------------------------------------------------------------------------------------


def _values() -> dict[str, str]:
    return form_from_text(DI.read_text(encoding="utf-8"))[0]


def test_draft_round_trip(cwd):
    session = Session.create(cwd / "s")
    assert read_draft(session) is None
    values = _values()
    values["mpc.Q"] = '1 1; 0 x  ünï "quoted" \\ back'
    values["plant.dynamics"] = "x2\n\nu"
    write_draft(session, values, False)
    assert (session.path / DRAFT).is_file()
    assert read_draft(session) == (values, False)
    # the draft wins over spec.toml when the session is opened
    session.save_spec(ce.load_spec(DI))
    opened = open_target(str(session.path))
    assert opened.values == values and opened.has_verify is False
    assert "restored" in opened.note
    clear_draft(session)
    assert not (session.path / DRAFT).exists()
    assert read_draft(session) is None
    clear_draft(session)  # twice is fine
    opened = open_target(str(session.path))
    assert opened.note is None and opened.has_verify is True


def test_draft_fills_missing_entries_and_ignores_unknown_ones(cwd):
    session = Session.create(cwd / "s")
    data = {
        "format": "codev-tui-draft/1",
        "has_verify": True,
        "values": {"mpc.Q": "1", "bogus.field": "x"},
    }
    (session.path / DRAFT).write_text(json.dumps(data), encoding="utf-8")
    values, has_verify = read_draft(session)
    assert values["mpc.Q"] == "1"
    assert "bogus.field" not in values
    assert set(values) == {fd.name for fd in FIELDS}
    assert values["name"] == ""


@pytest.mark.parametrize(
    "content",
    [
        b"{not json",
        b"",
        b"\xff\xfe\x00garbage",
        b"[" * 100_000,
        b"[]",
        b'"a string"',
        b'{"format": "something-else/1", "values": {}}',
        b'{"values": {"name": "x"}}',
        b'{"format": "codev-tui-draft/1", "values": ["name"]}',
        b'{"format": "codev-tui-draft/1", "values": {"name": 1}}',
        b'{"format": "codev-tui-draft/1", "values": {"mpc.Q": ["1"]}}',
        b'{"format": "codev-tui-draft/1", "values": {"mpc.Q": null}}',
        b'{"format": "codev-tui-draft/1", "values": {}, "has_verify": "no"}',
        b'{"format": 1, "values": {}}',
    ],
)
def test_a_corrupted_or_forged_draft_is_ignored(cwd, content):
    session = Session.create(cwd / "s")
    session.save_spec(ce.load_spec(DI))
    (session.path / DRAFT).write_bytes(content)
    assert read_draft(session) is None
    opened = open_target(str(session.path))  # falls back on spec.toml
    assert opened.values == _values()
    assert opened.note is None


def test_a_draft_that_is_a_folder_is_ignored(cwd):
    session = Session.create(cwd / "s")
    (session.path / DRAFT).mkdir()
    assert read_draft(session) is None


# --------------------------------------------------------------------------------------------
# Session.save_spec keeps what it replaces
# --------------------------------------------------------------------------------------------


def _sha16(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def test_save_spec_snapshots_the_spec_it_replaces(cwd):
    session = Session.create(cwd / "s")
    first = ce.load_spec(DI)
    sha1 = session.save_spec(first)
    assert sha1 == hashlib.sha256(first.source.encode()).hexdigest()
    assert session.spec_path().read_text(encoding="utf-8") == first.source
    values = _values()
    values["mpc.R"] = "0.5"
    chk = check_form(values, with_verify=True)
    assert chk.ok
    second = chk.problem
    session.save_spec(second)
    assert session.spec_path().read_text(encoding="utf-8") == second.source
    snaps = {p.name: p.read_text(encoding="utf-8") for p in (session.path / "specs").iterdir()}
    assert snaps == {
        f"{_sha16(first.source)}.toml": first.source,
        f"{_sha16(second.source)}.toml": second.source,
    }
    # saving the same spec again changes nothing
    session.save_spec(second)
    assert len(list((session.path / "specs").iterdir())) == 2


def test_save_spec_keeps_a_hand_edited_spec_toml(cwd):
    session = Session.create(cwd / "s")
    hand = DI.read_text(encoding="utf-8") + "\n# edited by hand\n"
    session.spec_path().write_text(hand, encoding="utf-8")
    session.save_spec(ce.load_spec(DI))
    snaps = {p.read_text(encoding="utf-8") for p in (session.path / "specs").iterdir()}
    assert hand in snaps
    assert session.spec_path().read_text(encoding="utf-8") == DI.read_text(encoding="utf-8")


def test_only_an_opened_spec_file_is_saved_at_once(cwd):
    """A spec file opened into a session is written to spec.toml at once (``save_now``);
    merely opening a session, or nothing, never rewrites its spec."""
    opened = open_target(str(DI), sessions_root="sessions")
    assert opened.save_now is True
    assert open_target(str(opened.session.path)).save_now is False
    assert open_target(None, sessions_root="sessions").save_now is False


# --------------------------------------------------------------------------------------------
# new_design: the templates of New (issue 23)
# --------------------------------------------------------------------------------------------


def test_templates_are_empty_and_every_bundled_example():
    keys = [k for k, _ in templates()]
    assert keys[0] == EMPTY
    assert set(keys[1:]) == {p.stem for p in (ROOT / "examples").glob("*.toml")}
    assert all(about for _, about in templates())  # each says what it is


def test_new_design_copies_an_example_into_a_fresh_folder_named_after_it(cwd):
    first = new_design("double_integrator", sessions_root="sessions")
    assert first.session.path == Path("sessions") / "double-integrator"
    assert first.values == form_from_text(DI.read_text(encoding="utf-8"))[0]
    assert first.save_now and first.follow_name and first.has_verify
    # the folder exists now: the next copy gets a fresh one, nothing of it is reused
    second = new_design("double_integrator", sessions_root="sessions")
    assert second.session.path == Path("sessions") / "double-integrator-2"
    empty = new_design(EMPTY, sessions_root="sessions")
    assert empty.session.path == Path("sessions") / "untitled"
    assert set(empty.values.values()) == {""} and not empty.save_now and empty.follow_name
    assert new_design(EMPTY, sessions_root="sessions").session.path.name == "untitled-2"
    with pytest.raises(ce.SpecError, match="no template 'nope'"):
        new_design("nope", sessions_root="sessions")
