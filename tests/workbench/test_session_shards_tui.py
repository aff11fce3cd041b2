"""The workbench on a session whose law is stored as shards (issue 43, ``codev run
--sharded``): it opens with the session's choice, shows the cached law without merging it
(a ``ShardedLaw``) and exports it as C, merged there on demand."""

from __future__ import annotations

import asyncio

from pilot_tools import EXAMPLES, SIZE, settle, text_of
from textual.widgets import Input

from codev_engine import load_spec
from codev_engine.law_shards import ShardedLaw
from codev_engine.session import RunOptions, Session
from workbench.tui.app import CodevApp
from workbench.tui.state import open_target


def test_the_workbench_opens_a_session_s_shards(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "sessions" / "di"
    problem = load_spec(EXAMPLES / "double_integrator.toml")
    # (no cluster: the sharded stage writes one shard, the same folder artifact)
    Session.create(folder).run(problem, RunOptions(upto="synthesis", sharded=True))
    app = CodevApp(open_target(str(folder)))
    assert app.options.sharded
    dest = tmp_path / "law_c"

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            assert "synthesis cached" in text_of(app, "#pipeline")
            assert isinstance(app.law, ShardedLaw) and app.law.num_regions == 10
            await pilot.press("f3")
            await settle(pilot, app)
            box = app.query_one("#law-export-dir", Input)
            box.value = str(dest)
            box.focus()
            await pilot.press("enter")
            for _ in range(600):  # the tree and its kernel: seconds on a cold cache
                await pilot.pause(0.05)
                out = text_of(app, "#law-export-out")
                if "wrote" in out or "failed" in out:
                    break
            assert "wrote" in text_of(app, "#law-export-out")

    asyncio.run(scenario())
    assert len(list(dest.glob("*.h"))) == 1
