"""Open the built HTML book in headless Chromium and list what a reader would see broken.

Used by ``tests/test_book_browser.py`` (imported as ``from browser import ...``; pytest puts this folder on
``sys.path``).  :func:`chromium_executable` finds Debian's ``chromium`` (installing it with ``apt-get`` when it
is missing and this process may); :func:`check_pages` serves the HTML folder over HTTP on the loopback
interface, drives one Chromium through the DevTools protocol (a websocket, with tornado's client) and
returns, per page, the problems found:

* ``image``: an ``<img>`` that does not decode;
* ``link``: an internal link to a missing file, or to an anchor that the target page does not define;
* ``console``: a JavaScript exception, a ``console.error``, or an error in the browser's log (such as a
  resource that failed to load);
* ``output``: a notebook cell output that is a traceback or went to stderr (warnings, progress bars), or
  whose text shows a traceback or a warning;
* ``glue``: a glued value that did not resolve (the role's source text left on the page);
* ``math``: a math element that MathJax did not typeset.

A screenshot of each page (its top 12,000 px) is saved as PNG.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import functools
import http.server
import json
import os
import re
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Any, Iterator, Sequence
from urllib.parse import unquote, urlparse

#: Debian's package of the browser.
CHROMIUM_PACKAGE = "chromium"
#: Longest wait for one page to load and settle [s].
PAGE_TIMEOUT_S = 90.0
#: Width of the browser window and the screenshots [px]; screenshots keep at most the top MAX_SHOT_PX.
WINDOW_WIDTH_PX = 1280
MAX_SHOT_PX = 12_000
#: Pages open at once (each in a browser context of its own): their load waits and settling sleeps overlap.
PAGES_AT_ONCE = 4


def chromium_executable(install: bool = True) -> str:
    """Path of ``chromium``; when it is not on ``PATH`` and ``install``, install Debian's package with
    ``apt-get`` (as root), running ``apt-get update`` once if the first attempt fails.

    Raises
    ------
    RuntimeError
        Saying why, when there is no browser and it cannot be installed here.
    """
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found:
        return found
    apt = shutil.which("apt-get")
    if not install or apt is None or os.geteuid() != 0:
        raise RuntimeError(
            "headless Chromium is needed to check the book in a browser: `chromium` is not on PATH and cannot "
            f"be installed here (needs apt-get as root); install Debian's `{CHROMIUM_PACKAGE}` package"
        )
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    log = []
    for command in (
        [apt, "install", "-y", CHROMIUM_PACKAGE],
        [apt, "update"],
        [apt, "install", "-y", CHROMIUM_PACKAGE],
    ):
        result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=1200)
        log.append(f"$ {' '.join(command)} -> exit {result.returncode}\n{result.stderr[-2000:]}")
        found = shutil.which("chromium")
        if found:
            return found
    raise RuntimeError(f"`apt-get install -y {CHROMIUM_PACKAGE}` did not provide `chromium`:\n" + "\n".join(log))


# ----------------------------------------------------------------------------- serving the book
@contextlib.contextmanager
def serve(folder: Path) -> Iterator[str]:
    """Serve ``folder`` over HTTP on 127.0.0.1 (a free port) in a thread; yields the base URL."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args: Any) -> None:
            pass

    handler = functools.partial(Quiet, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


@contextlib.contextmanager
def launch_chromium(executable: str) -> Iterator[str]:
    """Start headless Chromium with the DevTools protocol on a free port; yields the browser's websocket URL."""
    profile = tempfile.mkdtemp(prefix="softpend-chromium-")
    process = subprocess.Popen(
        [
            executable,
            "--headless=new",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-background-networking",
            "--disable-component-update",
            "--remote-debugging-port=0",
            "--remote-debugging-address=127.0.0.1",
            f"--user-data-dir={profile}",
            f"--window-size={WINDOW_WIDTH_PX},900",
            "about:blank",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url, seen = None, []
        for line in process.stderr:  # Chromium prints the endpoint on stderr once it listens
            seen.append(line)
            match = re.search(r"DevTools listening on (ws://\S+)", line)
            if match:
                url = match.group(1)
                break
        if url is None:
            raise RuntimeError("chromium exited without a DevTools endpoint:\n" + "".join(seen[-30:]))
        threading.Thread(target=lambda: [None for _ in process.stderr], daemon=True).start()  # keep the pipe drained
        yield url
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        shutil.rmtree(profile, ignore_errors=True)


class DevTools:
    """A minimal client of the Chrome DevTools protocol over one websocket (flat sessions)."""

    def __init__(self, connection) -> None:
        self.connection = connection
        self.next_id = 0
        self.pending: dict[int, asyncio.Future] = {}
        self.events: list[dict[str, Any]] = []
        self.reader = asyncio.ensure_future(self._read())

    @classmethod
    async def connect(cls, url: str) -> "DevTools":
        from tornado.websocket import websocket_connect

        return cls(await websocket_connect(url, max_message_size=512 * 1024 * 1024))

    async def _read(self) -> None:
        while True:
            message = await self.connection.read_message()
            if message is None:
                for future in self.pending.values():
                    if not future.done():
                        future.set_exception(RuntimeError("the DevTools connection closed"))
                return
            data = json.loads(message)
            if "id" in data and data["id"] in self.pending:
                self.pending.pop(data["id"]).set_result(data)
            elif "method" in data:
                self.events.append(data)

    async def send(
        self, method: str, params: dict | None = None, session: str | None = None, timeout_s: float = PAGE_TIMEOUT_S
    ) -> dict[str, Any]:
        self.next_id += 1
        message: dict[str, Any] = {"id": self.next_id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        future = asyncio.get_running_loop().create_future()
        self.pending[self.next_id] = future
        await self.connection.write_message(json.dumps(message))
        data = await asyncio.wait_for(future, timeout_s)
        if "error" in data:
            raise RuntimeError(f"DevTools {method}: {data['error']}")
        return data.get("result", {})

    async def wait_for(self, method: str, session: str, start: int, timeout_s: float = PAGE_TIMEOUT_S) -> None:
        """Wait until an event ``method`` of ``session`` arrives (counting events from index ``start``)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while not any(e["method"] == method and e.get("sessionId") == session for e in self.events[start:]):
            if loop.time() > deadline:
                raise TimeoutError(f"no {method} within {timeout_s:g} s")
            await asyncio.sleep(0.05)

    async def evaluate(self, expression: str, session: str) -> Any:
        result = await self.send(
            "Runtime.evaluate", {"expression": expression, "awaitPromise": True, "returnByValue": True}, session
        )
        if "exceptionDetails" in result:
            raise RuntimeError(f"evaluating the page checks failed: {result['exceptionDetails']}")
        return result["result"].get("value")

    def close(self) -> None:
        self.connection.close()
        self.reader.cancel()


# ----------------------------------------------------------------------------- the checks
#: Runs in the page once it has loaded: waits for MathJax, decodes every image, collects links, ids, outputs.
PAGE_PROBE = r"""
(async () => {
  const deadline = Date.now() + 60000;
  const sleep = ms => new Promise(resolve => setTimeout(resolve, ms));
  await sleep(300);
  while (document.readyState !== "complete" && Date.now() < deadline) await sleep(100);
  if (document.querySelector(".math")) {  // MathJax loads deferred: wait for it, then for its first typesetting
    while (!(window.MathJax && MathJax.startup && MathJax.startup.promise) && Date.now() < deadline) await sleep(100);
    if (window.MathJax && MathJax.startup && MathJax.startup.promise) {
      await Promise.race([MathJax.startup.promise, sleep(Math.max(0, deadline - Date.now()))]);
    }
  }
  const images = await Promise.all([...document.images].map(async img => {
    img.loading = "eager";
    let ok = true;
    try { await img.decode(); } catch (e) { ok = false; }
    return {src: img.getAttribute("src"), ok: ok && img.naturalWidth > 0};
  }));
  const links = [...document.querySelectorAll("a[href]")].map(a => ({href: a.href, raw: a.getAttribute("href")}));
  const ids = [...document.querySelectorAll("[id]")].map(e => e.id)
    .concat([...document.querySelectorAll("a[name]")].map(e => e.getAttribute("name")));
  const outputs = [];
  for (const el of document.querySelectorAll(".cell_output .output.stderr, .cell_output .output.traceback, .cell_output .traceback")) {
    outputs.push(el.className + ": " + el.innerText.slice(0, 300));
  }
  for (const el of document.querySelectorAll(".cell_output")) {
    const text = el.innerText;
    const hit = text.match(/Traceback \(most recent call last\)|\b[A-Z]\w*Warning\b:|\b[A-Z]\w*Error: /);
    if (hit) outputs.push("output text: " + text.slice(Math.max(0, hit.index - 100), hit.index + 200));
  }
  const body = document.body.cloneNode(true);
  body.querySelectorAll("pre, code, script, style, textarea").forEach(e => e.remove());
  const text = body.textContent;
  const glue = [...text.matchAll(/\{glue(:[a-z]+)?\}|glue:(text|figure|math|any)\b|\.ipynb::\w+/g)].map(m => m[0]);
  const math = [...document.querySelectorAll(".math")]
    .filter(e => !e.querySelector("mjx-container") && !e.closest("mjx-container"))
    .map(e => e.textContent.slice(0, 80));
  const height = Math.max(document.documentElement.scrollHeight, document.body.scrollHeight);
  return {images, links, ids, outputs, glue, math, height};
})()
"""


def _page_file(html_dir: Path, url_path: str) -> Path:
    """The file that the server answers ``url_path`` with."""
    target = html_dir / unquote(url_path).lstrip("/")
    return target / "index.html" if url_path.endswith("/") or target.is_dir() else target


@functools.lru_cache(maxsize=None)
def _ids_in_file(path: Path) -> frozenset[str]:
    """The ``id`` and ``name`` attributes in an HTML file."""
    from bs4 import BeautifulSoup

    soup = BeautifulSoup(path.read_text(encoding="utf-8", errors="replace"), "html.parser")
    return frozenset(
        [tag["id"] for tag in soup.find_all(id=True)]
        + [tag["name"] for tag in soup.find_all("a", attrs={"name": True})]
    )


def _link_problems(html_dir: Path, base_url: str, page_path: str, probe: dict[str, Any]) -> list[str]:
    problems = []
    base = urlparse(base_url)
    own_ids = set(probe["ids"])
    for link in probe["links"]:
        url = urlparse(link["href"])
        if url.scheme not in ("http", "https") or url.netloc != base.netloc:
            continue  # external links, mailto: and javascript: are not checked (the book is read offline)
        target = _page_file(html_dir, url.path)
        if not target.is_file():
            problems.append(f"link: {link['raw']!r} points to a missing file {target.relative_to(html_dir)}")
            continue
        fragment = unquote(url.fragment)
        if not fragment:
            continue
        same_page = target == _page_file(html_dir, page_path)
        ids = own_ids if same_page else (_ids_in_file(target) if target.suffix == ".html" else None)
        if ids is not None and fragment not in ids:
            problems.append(f"link: {link['raw']!r}: no anchor #{fragment} in {target.relative_to(html_dir)}")
    return problems


def _console_problems(events: Sequence[dict[str, Any]]) -> list[str]:
    problems = []
    for event in events:
        params = event.get("params", {})
        if event["method"] == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            description = details.get("exception", {}).get("description") or details.get("text", "")
            problems.append(f"console: uncaught exception: {description[:300]}")
        elif event["method"] == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            text = " ".join(str(arg.get("value", arg.get("description", ""))) for arg in params.get("args", []))
            problems.append(f"console: console.{params['type']}: {text[:300]}")
        elif event["method"] == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            entry = params["entry"]
            if urlparse(entry.get("url", "")).path == "/favicon.ico":
                continue  # the browser asks for it by itself; the book declares no icon
            problems.append(f"console: {entry.get('source')}: {entry.get('text', '')[:200]} {entry.get('url', '')}")
    return problems


async def _check_page(tools: DevTools, html_dir: Path, base_url: str, page: str, shot: Path) -> list[str]:
    # a browser context of its own per page: a fresh reader (no storage shared with the other pages)
    context = (await tools.send("Target.createBrowserContext"))["browserContextId"]
    target = await tools.send("Target.createTarget", {"url": "about:blank", "browserContextId": context})
    session = (await tools.send("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True}))[
        "sessionId"
    ]
    try:
        for domain in ("Page", "Runtime", "Log"):
            await tools.send(f"{domain}.enable", session=session)
        await tools.send(
            "Emulation.setDeviceMetricsOverride",
            {"width": WINDOW_WIDTH_PX, "height": 900, "deviceScaleFactor": 1, "mobile": False},
            session,
        )
        start = len(tools.events)
        url = base_url + page
        navigation = await tools.send("Page.navigate", {"url": url}, session)
        if navigation.get("errorText"):
            return [f"load: {navigation['errorText']}"]
        await tools.wait_for("Page.loadEventFired", session, start)
        loaded = len(tools.events)
        await asyncio.sleep(0.5)
        if any(
            e["method"] == "Page.frameStartedLoading" and e.get("sessionId") == session for e in tools.events[loaded:]
        ):  # a redirect (the book's index.html): wait for the target page
            await tools.wait_for("Page.loadEventFired", session, loaded)
        probe = await tools.evaluate(PAGE_PROBE, session)
        height = max(900, min(int(probe["height"]), MAX_SHOT_PX))
        await tools.send(
            "Emulation.setDeviceMetricsOverride",
            {"width": WINDOW_WIDTH_PX, "height": height, "deviceScaleFactor": 1, "mobile": False},
            session,
        )
        # the shot keeps the window, as tall as the page up to MAX_SHOT_PX (a longer page would be "too large"
        # for the browser to capture whole)
        shot_data = await tools.send(
            "Page.captureScreenshot", {"format": "png", "captureBeyondViewport": False}, session
        )
        shot.parent.mkdir(parents=True, exist_ok=True)
        shot.write_bytes(base64.b64decode(shot_data["data"]))
        await asyncio.sleep(0.2)  # late console messages
        events = [e for e in tools.events[start:] if e.get("sessionId") == session]
        problems = [f"image: {image['src']!r} does not decode" for image in probe["images"] if not image["ok"]]
        problems += _link_problems(html_dir, base_url, "/" + page, probe)
        problems += _console_problems(events)
        problems += [f"output: {text}" for text in probe["outputs"]]
        problems += [f"glue: unresolved {text!r}" for text in probe["glue"]]
        problems += [f"math: not typeset: {text!r}" for text in probe["math"]]
        return problems
    finally:
        await tools.send("Target.closeTarget", {"targetId": target["targetId"]})
        await tools.send("Target.disposeBrowserContext", {"browserContextId": context})


def book_pages(html_dir: Path) -> list[str]:
    """Every HTML page of a built book, relative to ``html_dir`` (theme and source folders left out)."""
    return sorted(
        path.relative_to(html_dir).as_posix()
        for path in html_dir.rglob("*.html")
        if not {"_static", "_sources", "_images"} & set(path.relative_to(html_dir).parts)
    )


def check_pages(
    html_dir: Path | str, pages: Sequence[str], screenshot_dir: Path | str, executable: str | None = None
) -> dict[str, list[str]]:
    """Open each page (path relative to ``html_dir``; :data:`PAGES_AT_ONCE` at a time) in headless Chromium;
    returns ``{page: problems}`` (see the module docstring) and saves ``screenshot_dir/<page>.png``."""
    html_dir, screenshot_dir = Path(html_dir).resolve(), Path(screenshot_dir)
    executable = executable or chromium_executable()

    async def run(browser_url: str, base_url: str) -> dict[str, list[str]]:
        tools = await DevTools.connect(browser_url)
        slots = asyncio.Semaphore(PAGES_AT_ONCE)

        async def check(page: str) -> list[str]:
            async with slots:
                return await _check_page(
                    tools, html_dir, base_url, page, screenshot_dir / (page.replace("/", "__") + ".png")
                )

        try:
            return dict(zip(pages, await asyncio.gather(*(check(page) for page in pages))))
        finally:
            tools.close()

    _ids_in_file.cache_clear()
    with serve(html_dir) as base_url, launch_chromium(executable) as browser_url:
        return asyncio.run(run(browser_url, base_url))
