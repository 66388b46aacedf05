"""A minimal Chrome DevTools Protocol client (tornado's websocket): load pages offline, record every request.

:func:`load_pages` starts one headless Chromium with the network cut (an unreachable proxy and
``Network.emulateNetworkConditions(offline)``), opens each page in turn and returns, per page, the
URLs it requested, the requests that failed, the uncaught script errors and the values of
JavaScript ``probes`` evaluated once the page has loaded.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tornado.ioloop import IOLoop
from tornado.websocket import websocket_connect

#: Headless Chromium without the background services a closed network lacks.
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
#: ... and with the network cut.
OFFLINE_FLAGS = [
    *FLAGS,
    "--proxy-server=127.0.0.1:9",  # nothing listens there: every http(s) request fails
    "--proxy-bypass-list=<-loopback>",
]


@dataclass
class PageLoad:
    """What one page did while it loaded (see the module docstring)."""

    url: str
    requested: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    probes: dict[str, Any] = field(default_factory=dict)


class _Session:
    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.ids = itertools.count(1)
        self.events: list[dict[str, Any]] = []

    async def call(self, method: str, session: str | None = None, **params: Any) -> dict[str, Any]:
        i = next(self.ids)
        msg: dict[str, Any] = {"id": i, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        await self.ws.write_message(json.dumps(msg))
        while True:
            raw = await self.ws.read_message()
            if raw is None:
                raise RuntimeError("Chromium closed the DevTools connection")
            data = json.loads(raw)
            if data.get("id") == i:
                if "error" in data:
                    raise RuntimeError(f"{method}: {data['error']}")
                return data.get("result", {})
            self.events.append(data)

    async def drain(self, seconds: float) -> None:
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while (left := end - loop.time()) > 0:
            try:
                raw = await asyncio.wait_for(self.ws.read_message(), left)
            except TimeoutError:
                return
            if raw is None:
                return
            self.events.append(json.loads(raw))


async def _load(ws_url: str, pages: list[Path], probes: dict[str, str], settle_s: float) -> list[PageLoad]:
    ws = await websocket_connect(ws_url, max_message_size=256 * 1024 * 1024)
    s = _Session(ws)
    target = (await s.call("Target.createTarget", url="about:blank"))["targetId"]
    sid = (await s.call("Target.attachToTarget", targetId=target, flatten=True))["sessionId"]
    for domain in ("Network.enable", "Page.enable", "Runtime.enable"):
        await s.call(domain, sid)
    await s.call("Network.emulateNetworkConditions", sid, offline=True, latency=0, downloadThroughput=-1, uploadThroughput=-1)
    out = []
    for page in pages:
        s.events.clear()
        load = PageLoad(page.as_uri())
        await s.call("Page.navigate", sid, url=load.url)
        await s.drain(settle_s)
        for name, expr in probes.items():
            res = await s.call("Runtime.evaluate", sid, expression=expr, returnByValue=True)
            load.probes[name] = res.get("result", {}).get("value")
        for ev in s.events:
            method, params = ev.get("method"), ev.get("params", {})
            if method == "Network.requestWillBeSent":
                load.requested.append(params["request"]["url"])
            elif method == "Network.loadingFailed" and not params.get("canceled"):
                load.failed.append(f"{params.get('errorText')} ({params.get('type')}, request {params.get('requestId')})")
            elif method == "Runtime.exceptionThrown":
                load.errors.append(
                    params["exceptionDetails"].get("text", "")
                    + " "
                    + str(params["exceptionDetails"].get("exception", {}).get("description", ""))[:200]
                )
        urls = {
            ev["params"]["requestId"]: ev["params"]["request"]["url"]
            for ev in s.events
            if ev.get("method") == "Network.requestWillBeSent"
        }
        load.failed = [re.sub(r"request (\S+)\)", lambda m, u=urls: u.get(m.group(1), m.group(1)) + ")", f) for f in load.failed]
        out.append(load)
    ws.close()
    return out


def load_pages(
    chromium: str, pages: list[Path], profile: Path, probes: dict[str, str] | None = None, settle_s: float = 2.0
) -> list[PageLoad]:
    """Open ``pages`` (local files) offline in one headless Chromium; see the module docstring."""
    proc = subprocess.Popen(
        [chromium, *OFFLINE_FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0", "about:blank"],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    try:
        ws_url = None
        assert proc.stderr is not None
        for line in proc.stderr:
            m = re.search(r"DevTools listening on (ws://\S+)", line)
            if m:
                ws_url = m.group(1)
                break
        if ws_url is None:
            raise RuntimeError("Chromium did not open its DevTools port")
        return IOLoop.current().run_sync(lambda: _load(ws_url, pages, probes or {}, settle_s), timeout=60 + 10 * len(pages))
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
