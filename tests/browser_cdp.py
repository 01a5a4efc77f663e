"""A minimal headless-Chromium driver over the DevTools protocol (``--remote-debugging-pipe``).

The browser tests used to rely on ``--virtual-time-budget`` with ``--screenshot`` / ``--dump-dom``:
when the budget ran out before the page's first WebGL frame (a loaded two-core machine), Chromium
never wrote the screenshot and never exited, and the test died on its subprocess timeout. Here the
test waits for an explicit condition evaluated in the page, then asks for the screenshot or the
value; every step has its own deadline and fails with a message that names the step.

Protocol: JSON messages terminated by a NUL byte; the browser reads commands on its fd 3 and writes
replies and events on its fd 4 (Chromium's ``--remote-debugging-pipe``). Page commands go to a
flattened session of a target created for the page.
"""

from __future__ import annotations

import base64
import json
import os
import select
import subprocess
import tempfile
import time
from typing import Any

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-default-apps",
    "--no-first-run",
    "--window-size=1400,900",
]


class Browser:
    """One headless Chromium with one page, driven over a pipe.

    Parameters
    ----------
    executable : str
        Path of the Chromium binary.
    timeout : float
        Seconds any single protocol command may take before ``TimeoutError``.
    """

    def __init__(self, executable: str, timeout: float = 300.0) -> None:
        to_browser_r, to_browser_w = os.pipe()
        from_browser_r, from_browser_w = os.pipe()

        def child_fds() -> None:  # runs in the child before exec: the pipe ends become fds 3 / 4
            r, w = os.dup(to_browser_r), os.dup(from_browser_w)
            os.dup2(r, 3)
            os.dup2(w, 4)

        self._stderr = tempfile.TemporaryFile()  # a file, not a pipe: a full pipe would block
        self.proc = subprocess.Popen(
            [executable, *FLAGS, "--remote-debugging-pipe", "about:blank"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=self._stderr,
            pass_fds=(3, 4, to_browser_r, from_browser_w),
            preexec_fn=child_fds,
        )
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._w, self._r = to_browser_w, from_browser_r
        self._buf, self._id, self.timeout = b"", 0, timeout
        self.session: str | None = None
        self.events: list[dict] = []

    def send(self, method: str, page: bool = True, **params: Any) -> dict:
        """Send one command and return its ``result``; events in between go to ``events``."""
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params}
        if page and self.session:
            msg["sessionId"] = self.session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                reply = json.loads(raw)
                if "method" in reply:
                    self.events.append(reply)
                elif reply.get("id") == self._id:
                    if "error" in reply:
                        raise RuntimeError(f"{method}: {reply['error']}")
                    return reply["result"]
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._r], [], [], left)[0]:
                raise TimeoutError(f"Chromium gave no answer to {method} in {self.timeout:.0f} s")
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise RuntimeError(f"Chromium exited during {method}")
            self._buf += chunk

    def open(self, url: str) -> None:
        """Open ``url`` in a fresh page; later commands go to that page."""
        target = self.send("Target.createTarget", page=False, url="about:blank")["targetId"]
        self.session = self.send(
            "Target.attachToTarget", page=False, targetId=target, flatten=True
        )["sessionId"]
        self.send("Page.enable")
        self.send("Runtime.enable")  # console calls and uncaught exceptions arrive as events
        self.send("Page.navigate", url=url)

    def evaluate(self, expression: str) -> Any:
        """Value of a JavaScript expression in the page (a promise is awaited)."""
        out = self.send(
            "Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True
        )
        if "exceptionDetails" in out:
            raise RuntimeError(f"page raised: {out['exceptionDetails']}")
        return out["result"].get("value")

    def screenshot(self) -> bytes:
        """PNG bytes of the page as it is drawn now."""
        return base64.b64decode(self.send("Page.captureScreenshot", format="png")["data"])

    def problems(self) -> list[str]:
        """Console errors / warnings and uncaught exceptions the page reported so far."""
        out = []
        for e in self.events:
            p = e.get("params", {})
            if e["method"] == "Runtime.exceptionThrown":
                out.append("uncaught: " + json.dumps(p.get("exceptionDetails", {}))[:500])
            elif e["method"] == "Runtime.consoleAPICalled" and p.get("type") in (
                "error",
                "warning",
            ):
                args = [str(a.get("value", a.get("description", ""))) for a in p.get("args", [])]
                out.append(f"console.{p['type']}: " + " ".join(args)[:500])
        return out

    def close(self) -> str:
        """Close the browser; return what it wrote on stderr."""
        try:
            self.send("Browser.close", page=False)
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._w)
        os.close(self._r)
        self._stderr.seek(0)
        err = self._stderr.read().decode(errors="replace")
        self._stderr.close()
        return err

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
