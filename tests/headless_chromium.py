"""A headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``):
real mouse clicks, key presses, JavaScript evaluation and screenshots, with the standard library
only (no websocket client, no driver binary).

    with Browser() as b:
        page = b.new_page(1400, 1000)
        page.navigate("file:///tmp/report.html", ready="document.documentElement.dataset.ready")
        page.click("#results th:nth-child(4)")
        page.screenshot("shot.png")
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import tempfile
import time

#: Debian's package names the binary ``chromium``; other systems ``chromium-browser`` or Chrome.
CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome binary, or None (``FACECORR_CHROMIUM`` overrides the search)."""
    if os.environ.get("FACECORR_CHROMIUM"):
        return shutil.which(os.environ["FACECORR_CHROMIUM"])
    for name in CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


class ProtocolError(RuntimeError):
    pass


def _above(fd: int, lowest: int) -> int:
    """A close-on-exec duplicate of ``fd`` numbered ``lowest`` or more (``fd`` is closed)."""
    import fcntl

    new = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, lowest)
    os.close(fd)
    return new


class Browser:
    """One headless browser process; commands and answers are NUL-terminated JSON on fds 3 / 4."""

    def __init__(self, binary: str | None = None, timeout: float = 60.0):
        self.binary = binary or find_chromium()
        if self.binary is None:
            raise FileNotFoundError("no chromium binary on PATH")
        self.timeout = timeout
        self._next_id = 0
        self._buf = b""
        self._events = []

    def __enter__(self):
        self._profile = tempfile.TemporaryDirectory(prefix="facecorr-chromium-")
        cmd_r, self._cmd_w = os.pipe()  # we write commands, the browser reads fd 3
        self._ans_r, ans_w = os.pipe()  # the browser writes answers on fd 4
        # the child's ends above 4, so that moving them to 3 and 4 overwrites neither
        cmd_r, ans_w = (_above(fd, 10) for fd in (cmd_r, ans_w))

        def fds():  # in the child, before exec: the protocol's fixed descriptors (inheritable)
            os.dup2(cmd_r, 3)
            os.dup2(ans_w, 4)

        args = [self.binary, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--remote-debugging-pipe", "--no-first-run", "--no-default-browser-check", "--hide-scrollbars",
                "--mute-audio", "--disable-extensions", "--disable-background-networking",
                f"--user-data-dir={self._profile.name}", "about:blank"]
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, preexec_fn=fds, close_fds=False)
        os.close(cmd_r)
        os.close(ans_w)
        return self

    def __exit__(self, *exc):
        try:
            self.send("Browser.close")
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._cmd_w, self._ans_r):
            try:
                os.close(fd)
            except OSError:
                pass
        self._profile.cleanup()

    def _read_message(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no answer from chromium in time")
            ready, _, _ = select.select([self._ans_r], [], [], left)
            if ready:
                chunk = os.read(self._ans_r, 1 << 20)
                if not chunk:
                    raise ProtocolError(f"chromium closed the pipe (exit code {self.proc.poll()})")
                self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        """Run one protocol command; its result (ProtocolError on an error answer)."""
        self._next_id += 1
        msg = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._cmd_w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            ans = self._read_message(deadline)
            if ans.get("id") == self._next_id:
                if "error" in ans:
                    raise ProtocolError(f"{method}: {ans['error']}")
                return ans.get("result", {})
            if "method" in ans:
                self._events.append(ans)

    def wait_event(self, method: str, session: str | None = None, timeout: float | None = None) -> dict:
        """The next event ``method`` (of ``session``), waiting for it."""
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            for k, ev in enumerate(self._events):
                if ev.get("method") == method and (session is None or ev.get("sessionId") == session):
                    return self._events.pop(k)
            ans = self._read_message(deadline)
            if "method" in ans:
                self._events.append(ans)

    def new_page(self, width: int = 1400, height: int = 1000) -> "Page":
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        page = Page(self, session)
        page.send("Page.enable")
        page.send("Runtime.enable")
        page.resize(width, height)
        return page


class Page:
    """One tab of a :class:`Browser`."""

    def __init__(self, browser: Browser, session: str):
        self.browser, self.session = browser, session

    def send(self, method: str, params: dict | None = None) -> dict:
        return self.browser.send(method, params, session=self.session)

    def resize(self, width: int, height: int) -> None:
        self.send("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})

    def navigate(self, url: str, ready: str | None = None, timeout: float = 30.0) -> float:
        """Open ``url``; wait for the load event and, if given, until the JavaScript expression
        ``ready`` is truthy. Returns the seconds it took."""
        t0 = time.monotonic()
        self.send("Page.navigate", {"url": url})
        self.browser.wait_event("Page.loadEventFired", self.session, timeout=timeout)
        if ready:
            while not self.evaluate(ready):
                if time.monotonic() - t0 > timeout:
                    raise TimeoutError(f"{url}: {ready} not true after {timeout} s")
                time.sleep(0.05)
        return time.monotonic() - t0

    def evaluate(self, expression: str):
        """The value of a JavaScript expression (JSON-serialisable; promises awaited)."""
        r = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True})
        if "exceptionDetails" in r:
            raise ProtocolError(f"{expression}: {r['exceptionDetails'].get('exception', {}).get('description')}")
        return r["result"].get("value")

    def click(self, selector: str) -> None:
        """A real left click (mouse pressed and released) at the centre of the element."""
        box = self.evaluate(f"(() => {{ const e = document.querySelector({json.dumps(selector)}); if (!e) return null;"
                            " e.scrollIntoView({block: 'center'}); const r = e.getBoundingClientRect();"
                            " return [r.left + r.width / 2, r.top + r.height / 2]; })()")
        if box is None:
            raise ProtocolError(f"no element {selector}")
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.send("Input.dispatchMouseEvent", {"type": kind, "x": box[0], "y": box[1], "button": "left",
                                                   "clickCount": 0 if kind == "mouseMoved" else 1})

    def type_text(self, selector: str, text: str) -> None:
        """Focus the element and type ``text`` as keyboard input."""
        self.click(selector)
        self.send("Input.insertText", {"text": text})

    def press(self, key: str, code: str | None = None, key_code: int = 0) -> None:
        for kind in ("keyDown", "keyUp"):
            self.send("Input.dispatchKeyEvent", {"type": kind, "key": key, "code": code or key,
                                                 "windowsVirtualKeyCode": key_code})

    def screenshot(self, path, full_page: bool = False) -> bytes:
        """Write a PNG of the viewport (or the whole page) to ``path``; returns its bytes."""
        params = {"format": "png"}
        if full_page:
            w, h = self.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]")
            params.update(captureBeyondViewport=True, clip={"x": 0, "y": 0, "width": w, "height": h, "scale": 1})
        data = base64.b64decode(self.send("Page.captureScreenshot", params)["data"])
        with open(path, "wb") as f:
            f.write(data)
        return data
