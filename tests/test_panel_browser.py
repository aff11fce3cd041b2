"""The bundled panel notebook in JupyterLab, in a real browser (slow; issue 42).

JupyterLab serves a copy of ``examples/python_control_panel.ipynb``; headless Chromium
opens it, runs every cell through JupyterLab's own command (``notebook:run-all-cells``,
the app exposed to the page by ``LabApp.expose_app_in_browser``), and the page must then
hold the panel (its ``codev-workbench`` box with the Synthesise button) and the partition
the engine drew (a PNG inside the panel and in the law's output). A screenshot is saved
(``CODEV_SCREENSHOT=FILE`` keeps it) to look at. Chromium is driven through its DevTools
protocol with tornado's websocket client (a dependency of JupyterLab): nothing more to install
than the notebook extra and a Chromium (Debian's ``chromium``); skipped without one.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
pytest.importorskip("jupyterlab", reason="the notebook extra (a dev dependency)")
tornado_ws = pytest.importorskip("tornado.websocket", reason="comes with JupyterLab")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "python_control_panel.ipynb"
CHROMIUM = next(
    (p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None
)
TOKEN = "codev-panel-test"
#: JupyterLab's settings for the test: every cell in the page (no windowing), no news popup
SETTINGS = {
    "@jupyterlab/notebook-extension/tracker.jupyterlab-settings": {"windowingMode": "none"},
    "@jupyterlab/apputils-extension/notification.jupyterlab-settings": {
        "fetchNews": "false", "checkForUpdates": False},
}  # fmt: skip


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_http(url: str, seconds: float) -> bytes:
    end = time.monotonic() + seconds
    while True:
        try:
            with urllib.request.urlopen(url, timeout=5) as r:
                return r.read()
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.5)


class _Page:
    """One Chromium tab over the DevTools protocol (blocking calls on tornado's client)."""

    def __init__(self, ws_url: str):
        from tornado.ioloop import IOLoop

        self.loop = IOLoop()  # a private loop: the test is synchronous
        self.ws = self.loop.run_sync(lambda: tornado_ws.websocket_connect(ws_url,
                                     max_message_size=256 * 2**20))  # fmt: skip
        self.n = 0

    def call(self, method: str, **params) -> dict:
        self.n += 1
        msg_id = self.n
        self.ws.write_message(json.dumps({"id": msg_id, "method": method, "params": params}))

        async def answer() -> dict:
            while True:
                raw = await self.ws.read_message()
                assert raw is not None, "Chromium closed the connection"
                msg = json.loads(raw)
                if msg.get("id") == msg_id:
                    return msg

        msg = self.loop.run_sync(answer, timeout=120)
        assert "error" not in msg, msg
        return msg["result"]

    def js(self, expression: str):
        res = self.call("Runtime.evaluate", expression=expression, returnByValue=True,
                        awaitPromise=True)  # fmt: skip
        return res["result"].get("value")

    def wait_for(self, expression: str, seconds: float, what: str):
        end = time.monotonic() + seconds
        while True:
            value = self.js(expression)
            if value:
                return value
            if time.monotonic() > end:
                raise AssertionError(f"timed out waiting for {what}")
            time.sleep(1.0)

    def close(self) -> None:
        self.ws.close()
        self.loop.close()


@pytest.mark.skipif(CHROMIUM is None, reason="needs a Chromium (Debian: apt-get install chromium)")
def test_jupyterlab_shows_the_panel_and_the_partition(tmp_path):
    work = tmp_path / "lab"
    work.mkdir()
    shutil.copy(NOTEBOOK, work / NOTEBOOK.name)
    settings = tmp_path / "settings"
    for name, values in SETTINGS.items():
        f = settings / name
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps(values))
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "JUPYTERLAB_SETTINGS_DIR": str(settings), "PYTHONPATH": path}
    port, debug = _free_port(), _free_port()
    lab = subprocess.Popen(
        [sys.executable, "-m", "jupyterlab", "--no-browser", f"--port={port}",
         "--ip=127.0.0.1", f"--ServerApp.token={TOKEN}", f"--ServerApp.root_dir={work}",
         "--LabApp.expose_app_in_browser=True",
         *(["--allow-root"] if hasattr(os, "geteuid") and os.geteuid() == 0 else [])],
        cwd=work, env=env, stdout=subprocess.DEVNULL, stderr=(tmp_path / "lab.log").open("w"),
    )  # fmt: skip
    browser = None
    page = None
    try:
        base = f"http://127.0.0.1:{port}"
        _wait_http(f"{base}/api/status?token={TOKEN}", 120)
        browser = subprocess.Popen(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
             f"--remote-debugging-port={debug}", f"--user-data-dir={tmp_path / 'chromium'}",
             "--window-size=1400,2200", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        tabs = json.loads(_wait_http(f"http://127.0.0.1:{debug}/json/list", 60))
        tab = next(t for t in tabs if t.get("type") == "page")
        page = _Page(tab["webSocketDebuggerUrl"])
        page.call("Page.enable")
        page.call("Page.navigate", url=f"{base}/lab/tree/{NOTEBOOK.name}?token={TOKEN}")
        # the notebook open with its kernel idle (JupyterLab may ask which kernel: the
        # notebook's own, accepted)
        page.wait_for(
            """(() => {
                document.querySelector('.jp-Dialog .jp-mod-accept')?.click();
                const app = window.jupyterapp;  // the notebook's panel (headless: no focus)
                const nb = app && [...app.shell.widgets('main')].find(w => w.sessionContext);
                if (nb) app.shell.activateById(nb.id);  // run-all-cells acts on the active one
                return nb?.sessionContext?.session?.kernel?.status === 'idle';
            })()""",
            180, "the notebook and its kernel")
        page.js("void window.jupyterapp.commands.execute('notebook:run-all-cells')")
        # the last cell prints the exported C header's name
        page.wait_for("document.body.innerText.includes('cart_law.h cart_law.c')", 600,
                      "every cell to run")  # fmt: skip
        found = page.wait_for(
            """(() => {
                const panel = document.querySelector('.codev-workbench');
                if (!panel) return null;
                const buttons = [...panel.querySelectorAll('button')].map(b => b.innerText);
                // the partition on the Design tab, drawn and visible (not a hidden tab's)
                const inPanel = [...panel.querySelectorAll('img[src^="data:image/png"]')]
                    .filter(i => i.getBoundingClientRect().width > 100).length;
                const all = document.querySelectorAll(
                    '.jp-OutputArea img[src^="data:image/png"]').length;
                return inPanel > 0 ? {buttons, inPanel, all,
                                       text: panel.innerText.slice(0, 2000)} : null;
            })()""",
            120, "the panel with the partition drawn in it")
        assert "Synthesise" in found["buttons"] and "Cancel" in found["buttons"], found
        assert found["all"] >= 3, found  # the panel's, the law's and the verdict's pictures
        assert "synthesis cached" in found["text"], found["text"]
        page.js("document.querySelector('.codev-workbench').scrollIntoView()")
        shot = base64.b64decode(page.call("Page.captureScreenshot", format="png")["data"])
        (tmp_path / "panel.png").write_bytes(shot)
        if os.environ.get("CODEV_SCREENSHOT"):
            Path(os.environ["CODEV_SCREENSHOT"]).write_bytes(shot)
        assert shot[:8] == b"\x89PNG\r\n\x1a\n" and len(shot) > 20_000
    finally:
        if page is not None:
            if not (tmp_path / "panel.png").exists():  # a failure: what the page showed
                try:
                    shot = page.call("Page.captureScreenshot", format="png")["data"]
                    (tmp_path / "failed.png").write_bytes(base64.b64decode(shot))
                    if os.environ.get("CODEV_SCREENSHOT"):
                        shutil.copy(tmp_path / "failed.png", os.environ["CODEV_SCREENSHOT"])
                except Exception:  # noqa: BLE001 - the test's own failure is the one to see
                    pass
            page.close()
        for proc in (browser, lab):
            if proc is not None:
                proc.terminate()
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
