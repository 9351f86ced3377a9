"""The flagship report in a real browser: headless Chromium driven over the DevTools protocol.

Chromium is started with ``--remote-debugging-pipe`` (the protocol as
NUL-terminated JSON on file descriptors 3 and 4), so the test needs nothing
but the standard library and the ``chromium`` binary (Debian package
``chromium``). It opens the report as a ``file://`` URL and checks that

- nothing is logged to the console and no script error happens,
- the page fetches nothing but itself (every network request is the file),
- the bond graph, the SVG plots and the MathML equations are laid out with a
  non-zero size, and the equations are laid out as MathML (not as text),

and keeps a full-page screenshot in ``tests/artifacts/`` for a human to look at. On a 1280 x 800
screen the report leads with the answer: the verdict, the chosen motor's margins and the two plots
of the answer are all above the fold (their boxes from ``DOM.getBoxModel``); that first screen is
kept as a screenshot too.
The report of a 2 kHz PWM drive is zoomed and panned with the mouse (real input
events) and reset with a double-click; screenshots of its first plot before and
after the zoom are kept there too.

Without Chromium the test is skipped, except in CI (``CI`` set to anything but
empty, 0, false or no), where it fails: the CI image must install it
(``apt-get install -y chromium``). ``BONDC_CHROMIUM`` names another binary.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from test_report_build import flagship_report, pwm_report

ARTIFACTS = Path(__file__).parent / "artifacts"
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
TIMEOUT = 60.0
WIDTH, HEIGHT = 1100, 900


def chromium_binary() -> str | None:
    explicit = os.environ.get("BONDC_CHROMIUM")
    if explicit:
        return explicit
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


class DevTools:
    """A headless Chromium and one page of it, spoken to over ``--remote-debugging-pipe``."""

    def __init__(self, binary: str):
        self.profile = tempfile.mkdtemp(prefix="bondc-chromium-")
        # fds 3 and 4 of the browser: it reads commands from 3 and writes replies and events to 4
        to_browser_read, self._to_browser = os.pipe()
        self._from_browser, from_browser_write = os.pipe()
        flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-extensions", "--disable-default-apps", "--mute-audio", "--hide-scrollbars",
                 f"--user-data-dir={self.profile}", "--remote-debugging-pipe", f"--window-size={WIDTH},{HEIGHT}",
                 "about:blank"]
        # A tiny trampoline puts the pipe ends on fds 3 and 4 and becomes the browser.
        trampoline = ("import os, sys\n"
                      "read, write = os.dup(int(sys.argv[1])), os.dup(int(sys.argv[2]))\n"
                      "os.dup2(read, 3)\nos.dup2(write, 4)\n"
                      "os.set_inheritable(3, True)\nos.set_inheritable(4, True)\n"
                      "for fd in {read, write, int(sys.argv[1]), int(sys.argv[2])} - {3, 4}:\n"
                      "    os.close(fd)\n"
                      "os.execv(sys.argv[3], sys.argv[3:])\n")
        self.process = subprocess.Popen([sys.executable, "-c", trampoline, str(to_browser_read),
                                         str(from_browser_write), binary, *flags],
                                        pass_fds=(to_browser_read, from_browser_write),
                                        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.PIPE)
        os.close(to_browser_read)
        os.close(from_browser_write)
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict] = []
        self.session: str | None = None

    # -- protocol

    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> int:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        return self._next_id

    def _receive(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError("Chromium did not answer in time")
            ready, _, _ = select.select([self._from_browser], [], [], remaining)
            if ready:
                chunk = os.read(self._from_browser, 1 << 20)
                if not chunk:
                    raise ConnectionError("Chromium closed the DevTools pipe: " + self._stderr())
                self._buffer += chunk
        message, _, self._buffer = self._buffer.partition(b"\0")
        return json.loads(message)

    def call(self, method: str, params: dict | None = None, *, page: bool = True) -> dict:
        """Send a command (to the page's session unless ``page`` is False); return its result."""
        number = self._send(method, params, self.session if page else None)
        deadline = time.monotonic() + TIMEOUT
        while True:
            message = self._receive(deadline)
            if message.get("id") == number:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})
            if "method" in message:
                self.events.append(message)

    def wait_for(self, method: str) -> dict:
        """The first event ``method`` of the page (already received or still to come)."""
        for event in self.events:
            if event["method"] == method:
                return event
        deadline = time.monotonic() + TIMEOUT
        while True:
            message = self._receive(deadline)
            if "method" in message:
                self.events.append(message)
                if message["method"] == method:
                    return message

    def _stderr(self) -> str:
        """What the browser wrote to stderr (once it has exited), for the failure message."""
        try:
            self.process.wait(timeout=5)
            return self.process.stderr.read().decode(errors="replace")[-3000:] if self.process.stderr else ""
        except (OSError, ValueError, subprocess.TimeoutExpired):
            return ""

    # -- the page

    def open(self, url: str, width: int = WIDTH, height: int = HEIGHT) -> None:
        """Open ``url`` in a new page of ``width`` x ``height`` CSS pixels; the events of pages opened
        before are forgotten."""
        self.events = []
        target = self.call("Target.createTarget", {"url": "about:blank"}, page=False)["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True},
                                 page=False)["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable")
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})
        self.call("Page.navigate", {"url": url})
        self.wait_for("Page.loadEventFired")

    def evaluate(self, expression: str):
        reply = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True})
        if "exceptionDetails" in reply:
            raise RuntimeError(f"evaluation failed: {reply['exceptionDetails']}")
        return reply["result"]["value"]

    def box(self, selector: str) -> tuple[float, float, float, float]:
        """(left, top, right, bottom) of the border box of the first element matching ``selector``, in
        CSS pixels of the page (not scrolled), from the DevTools protocol's DOM.getBoxModel."""
        root = self.call("DOM.getDocument", {"depth": 0})["root"]["nodeId"]
        node = self.call("DOM.querySelector", {"nodeId": root, "selector": selector})["nodeId"]
        assert node, f"no element matches {selector!r}"
        quad = self.call("DOM.getBoxModel", {"nodeId": node})["model"]["border"]
        xs, ys = quad[0::2], quad[1::2]
        return min(xs), min(ys), max(xs), max(ys)

    def screenshot(self, path: Path) -> None:
        size = self.call("Page.getLayoutMetrics")["cssContentSize"]
        shot = self.call("Page.captureScreenshot", {
            "format": "png", "captureBeyondViewport": True,
            "clip": {"x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1}})
        path.write_bytes(base64.b64decode(shot["data"]))

    def close(self) -> None:
        try:
            self._send("Browser.close")
            self.process.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.process.kill()
            self.process.wait()
        finally:
            for descriptor in (self._to_browser, self._from_browser):
                try:
                    os.close(descriptor)
                except OSError:
                    pass
            if self.process.stderr:
                self.process.stderr.close()
            shutil.rmtree(self.profile, ignore_errors=True)


MEASURE = """JSON.stringify((() => {
  const box = (element) => { const r = element.getBoundingClientRect(); return [r.width, r.height]; };
  const all = (selector) => Array.from(document.querySelectorAll(selector));
  return {
    title: document.title,
    diagram: all("svg.bond-graph").map(box),
    plots: all("svg.plot").map(box),
    maths: all("math").map(box),
    mathml: all("math").every((m) => m instanceof MathMLElement),
    mathDisplay: all("math[display=block]").map((m) => getComputedStyle(m).display),
    fractions: all("mfrac").map(box),
    scripts: all("script").length,
    page: [document.documentElement.scrollWidth, document.documentElement.scrollHeight],
  };
})())"""


@pytest.fixture(scope="module")
def browser():
    binary = chromium_binary()
    if binary is None:
        message = ("headless Chromium is needed for the browser test: install the Debian package 'chromium' "
                   "(apt-get install -y chromium) or set BONDC_CHROMIUM to the binary")
        if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
            pytest.fail(message)
        pytest.skip(message)
    devtools = DevTools(binary)
    try:
        yield devtools
    finally:
        devtools.close()


@pytest.mark.slow
def test_flagship_report_in_chromium(browser):
    report = flagship_report()
    url = report.resolve().as_uri()
    browser.open(url)
    measured = json.loads(browser.evaluate(MEASURE))
    ARTIFACTS.mkdir(exist_ok=True)
    browser.screenshot(ARTIFACTS / "flagship_report.png")
    assert (ARTIFACTS / "flagship_report.png").stat().st_size > 10_000

    problems = []
    for event in browser.events:
        method, params = event["method"], event.get("params", {})
        if method == "Runtime.consoleAPICalled":
            problems.append(f"console.{params.get('type')}: {params.get('args')}")
        elif method == "Runtime.exceptionThrown":
            problems.append(f"exception: {params.get('exceptionDetails')}")
        elif method == "Log.entryAdded" and params["entry"]["level"] in ("error", "warning"):
            problems.append(f"log {params['entry']['level']}: {params['entry'].get('text')} "
                            f"({params['entry'].get('url', '')})")
    assert problems == []

    requests = [e["params"]["request"]["url"] for e in browser.events if e["method"] == "Network.requestWillBeSent"]
    assert requests and set(requests) == {url}, requests          # the page loads nothing but itself

    assert measured["title"].startswith("ElectroPneumaticHybrid")
    assert measured["scripts"] == 1                              # zoom.js, bondc's own
    [diagram] = measured["diagram"]
    assert diagram[0] > 300 and diagram[1] > 300
    assert len(measured["plots"]) >= 8                           # outputs, power, validation-free flagship
    assert all(width > 300 and height > 100 for width, height in measured["plots"])
    assert len(measured["maths"]) >= 6                           # one per state at least
    assert all(width > 20 and height > 10 for width, height in measured["maths"])
    assert measured["mathml"] is True
    assert set(measured["mathDisplay"]) == {"block math"}        # laid out by the MathML engine
    # stacked fractions (d/dt of each state first), not text in a line
    assert len(measured["fractions"]) >= 6 and all(height > 25 for _, height in measured["fractions"][:6])
    assert all(width > 0 and height > 0 for width, height in measured["fractions"])
    assert measured["page"][0] <= WIDTH                          # nothing forces a horizontal scroll


FOLD_WIDTH, FOLD_HEIGHT = 1280, 800


@pytest.mark.slow
def test_flagship_report_leads_with_the_answer_above_the_fold(browser):
    """At 1280 x 800 the first screen holds the answer: the verdict, the chosen motor's rule margins,
    the torque over time against its limits and the torque-speed points on its envelope; the model's
    sections (bond graph, parameters, ...) come after it."""
    report = flagship_report()
    browser.open(report.resolve().as_uri(), FOLD_WIDTH, FOLD_HEIGHT)
    assert browser.evaluate("window.scrollY") == 0
    ARTIFACTS.mkdir(exist_ok=True)
    shot = browser.call("Page.captureScreenshot", {"format": "png", "clip": {
        "x": 0, "y": 0, "width": FOLD_WIDTH, "height": FOLD_HEIGHT, "scale": 1}})
    (ARTIFACTS / "flagship_report_top.png").write_bytes(base64.b64decode(shot["data"]))

    left, top, right, bottom = browser.box("#answer p.verdict-text")
    assert 0 <= top < bottom <= FOLD_HEIGHT and right - left > 400
    assert browser.evaluate('document.querySelector("#answer p.verdict-text").textContent').startswith(
        "SV-200 is the smallest motor that qualifies")
    for selector in ("#answer table.margins", "#answer .answer-figures figure:nth-child(1) svg.plot",
                     "#answer .answer-figures figure:nth-child(2) svg.plot"):
        left, top, right, bottom = browser.box(selector)
        assert bottom <= FOLD_HEIGHT and right <= FOLD_WIDTH and right - left > 300, selector
    plots = [browser.box(f"#answer .answer-figures figure:nth-child({n}) svg.plot") for n in (1, 2)]
    assert plots[0][2] <= plots[1][0]                               # side by side
    for section in ("#bond-graph", "#parameters", "#equations"):
        assert browser.box(section)[1] > FOLD_HEIGHT, section       # the model comes after the answer
    assert _problems(browser.events) == []


def _problems(events) -> list[str]:
    problems = []
    for event in events:
        method, params = event["method"], event.get("params", {})
        if method == "Runtime.consoleAPICalled":
            problems.append(f"console.{params.get('type')}: {params.get('args')}")
        elif method == "Runtime.exceptionThrown":
            problems.append(f"exception: {params.get('exceptionDetails')}")
        elif method == "Log.entryAdded" and params["entry"]["level"] in ("error", "warning"):
            problems.append(f"log {params['entry']['level']}: {params['entry'].get('text')}")
    return problems


PLOT_STATE = """JSON.stringify((() => {
  const svg = document.querySelectorAll("svg.plot[data-zoom]")[%d];
  const visible = (g) => getComputedStyle(g).display !== "none";
  return {
    view: svg.getAttribute("data-view").split(" ").map(Number),
    d: svg.querySelector('[id$="-zoomline0"] path').getAttribute("d").length,
    ticks: Array.from(svg.querySelectorAll('g[id*="-xtick_"]')).filter(visible)
      .map((g) => g.querySelector("text").textContent)
      .concat(Array.from(svg.querySelectorAll("g.zoom-ticks text")).map((t) => t.textContent)),
  };
})())"""


def test_plots_zoom_pan_and_reset_in_chromium(browser):
    """Drag across the PWM report's first plot: its time range narrows, the line is redrawn from the
    finer samples and the x ticks follow; Shift+drag pans; a double-click shows the whole run again."""
    report = pwm_report()
    url = report.resolve().as_uri()
    browser.open(url)
    deadline = time.monotonic() + TIMEOUT                      # the zoom data are inflated once loaded
    while browser.evaluate('document.querySelectorAll("svg.plot[data-zoom]:not([data-zoom-ready])").length'):
        assert time.monotonic() < deadline, "the plots' zoom data were never ready"
        time.sleep(0.05)
    geometry = json.loads(browser.evaluate("""JSON.stringify((() => {
      const svg = document.querySelector("svg.plot[data-zoom]");
      svg.scrollIntoView();
      const r = svg.getBoundingClientRect(), box = JSON.parse(svg.getAttribute("data-zoom")).box;
      const k = r.width / svg.viewBox.baseVal.width;
      return {rect: [r.left, r.top + window.scrollY, r.width, r.height], left: r.left + box[0] * k,
              top: r.top + box[1] * k, width: box[2] * k, height: box[3] * k};
    })())"""))
    x, y, width, height = geometry["rect"]
    clip = {"x": x, "y": y, "width": width, "height": height, "scale": 1}

    def shot(name: str) -> None:
        data = browser.call("Page.captureScreenshot", {"format": "png", "clip": clip})["data"]
        (ARTIFACTS / name).write_bytes(base64.b64decode(data))

    def state() -> dict:
        return json.loads(browser.evaluate(PLOT_STATE % 0))

    def drag(start: float, end: float, modifiers: int = 0) -> None:
        middle = geometry["top"] + geometry["height"] / 2
        at = [geometry["left"] + f * geometry["width"] for f in (start, (start + end) / 2, end)]
        for kind, where, buttons in (("mouseMoved", at[0], 0), ("mousePressed", at[0], 1), ("mouseMoved", at[1], 1),
                                     ("mouseMoved", at[2], 1), ("mouseReleased", at[2], 0)):
            browser.call("Input.dispatchMouseEvent", {"type": kind, "x": where, "y": middle, "button": "left",
                                                      "buttons": buttons, "clickCount": 1, "modifiers": modifiers})

    ARTIFACTS.mkdir(exist_ok=True)
    whole = state()
    t_end = whole["view"][1]
    assert whole["view"] == [0.0, t_end] and t_end > 0
    shot("pwm_plot_whole.png")

    drag(0.40, 0.42)                                            # 2 % of the run: some 40 PWM periods
    zoomed = state()
    shot("pwm_plot_zoomed.png")
    assert zoomed["view"][0] == pytest.approx(0.40 * t_end, abs=0.003 * t_end)
    assert zoomed["view"][1] == pytest.approx(0.42 * t_end, abs=0.003 * t_end)
    assert zoomed["d"] != whole["d"] and zoomed["ticks"] != whole["ticks"]
    assert len(zoomed["ticks"]) >= 3
    assert all(zoomed["view"][0] <= float(t) <= zoomed["view"][1] for t in zoomed["ticks"])

    drag(0.6, 0.4, modifiers=8)                                 # Shift+drag to the left: later times
    panned = state()
    span = zoomed["view"][1] - zoomed["view"][0]
    assert panned["view"][0] == pytest.approx(zoomed["view"][0] + 0.2 * span, rel=0.05)
    assert panned["view"][1] - panned["view"][0] == pytest.approx(span, rel=1e-6)

    middle = (geometry["left"] + geometry["width"] / 2, geometry["top"] + geometry["height"] / 2)
    for count in (1, 2):                                        # a double-click: two clicks, then dblclick
        for kind in ("mousePressed", "mouseReleased"):
            browser.call("Input.dispatchMouseEvent", {"type": kind, "x": middle[0], "y": middle[1], "button": "left",
                                                      "buttons": 1 if kind == "mousePressed" else 0,
                                                      "clickCount": count})
    assert state() == whole

    other = json.loads(browser.evaluate(PLOT_STATE % 1))          # the other plots were left as they were
    assert other["view"] == [0.0, t_end]
    assert _problems(browser.events) == []                      # no script error, no CSP violation
    requests = [e["params"]["request"]["url"] for e in browser.events if e["method"] == "Network.requestWillBeSent"]
    assert set(requests) == {url}


EQUATION_BOXES = """JSON.stringify(Array.from(document.querySelectorAll('.equation')).map((equation) => {
  const box = equation.getBoundingClientRect();
  let top = Infinity, bottom = -Infinity;
  const walker = document.createTreeWalker(equation, NodeFilter.SHOW_TEXT);
  for (let text = walker.nextNode(); text; text = walker.nextNode()) {
    const range = document.createRange();
    range.selectNodeContents(text);
    for (const rect of range.getClientRects()) {
      if (rect.height) { top = Math.min(top, rect.top); bottom = Math.max(bottom, rect.bottom); }
    }
  }
  return {text: equation.textContent.slice(0, 40), scroll: equation.scrollHeight, client: equation.clientHeight,
          above: box.top - top, below: bottom - (box.top + equation.clientTop + equation.clientHeight)};
}))"""


@pytest.mark.slow
@pytest.mark.parametrize("zoom", [1, 2])
def test_no_equation_is_clipped_at_the_top_of_its_fractions(browser, zoom):
    """The equations scroll sideways when wide; that makes their box clip vertically too, and the top of
    a tall fraction's numerator (``p_mass`` over ``M``) was cut off, reading like rho. At 100 % and at
    200 % zoom (half as many CSS pixels across, two device pixels each) every equation's content,
    each glyph's line box included, lies inside its box."""
    report = flagship_report()
    browser.open(report.resolve().as_uri(), width=WIDTH // zoom)
    browser.call("Emulation.setDeviceMetricsOverride",
                 {"width": WIDTH // zoom, "height": HEIGHT // zoom, "deviceScaleFactor": zoom, "mobile": False})
    equations = json.loads(browser.evaluate(EQUATION_BOXES))
    assert len(equations) >= 6
    clipped = [e for e in equations if e["scroll"] > e["client"] or e["above"] > 0.5 or e["below"] > 0.5]
    assert clipped == []
