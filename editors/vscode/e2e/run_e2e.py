#!/usr/bin/env python3
"""End-to-end check of the bondc VS Code extension in a real VS Code workbench.

Starts code-server (VS Code served over HTTP) with the packaged extension, opens
a scratch copy of models/ in headless Chromium driven by Playwright, opens the
flagship model and checks, as a person would see them:

  1. highlighting  - TextMate tokens of the bondgraph grammar get distinct colours
                     (keywords, element kinds, names, units, strings, comments);
  2. diagnostics   - a line with an undefined name, typed into the buffer, gets a
                     red squiggle and a Problems entry from `bondc lsp`; deleting
                     the line clears them;
  3. hover         - mouse over a parameter use shows the server's hover text
                     (declaration and SI value);
  4. definition    - F12 on a parameter use moves the cursor to its declaration.

Prints PASS/FAIL per check, saves screenshots, stops the server, and exits 1
if any check failed. See README.md beside this file for the setup.

Configuration (environment variables; all optional except where noted):
  CODE_SERVER     code-server executable (default /tmp/vscode-e2e/node_modules/.bin/code-server)
  BONDC           bondc executable run as `BONDC lsp` (default <repo>/.venv/bin/bondc)
  VSIX            extension package to install into the extensions dir before the run
                  (default /tmp/vscode-e2e/bondc-0.1.0.vsix if it exists)
  E2E_WORKDIR     scratch dir for user data, extensions, workspace copy (default /tmp/vscode-e2e/run)
  CHROMIUM        browser executable (default /usr/bin/chromium)
  SCREENSHOT_DIR  where PNGs go (default screenshots/ beside this script)
  E2E_TIMEOUT     seconds to wait for each observation (default 60)
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from playwright.sync_api import sync_playwright

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
FLAGSHIP = "electro_pneumatic_hybrid.bg"

CODE_SERVER = os.environ.get("CODE_SERVER", "/tmp/vscode-e2e/node_modules/.bin/code-server")
BONDC = os.environ.get("BONDC", str(REPO / ".venv" / "bin" / "bondc"))
VSIX = os.environ.get("VSIX", "/tmp/vscode-e2e/bondc-0.1.0.vsix")
WORKDIR = Path(os.environ.get("E2E_WORKDIR", "/tmp/vscode-e2e/run"))
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
SHOTS = Path(os.environ.get("SCREENSHOT_DIR", str(HERE / "screenshots")))
TIMEOUT = float(os.environ.get("E2E_TIMEOUT", "60"))
# vscode-languageclient appends `--stdio` to an Executable server's args when the client asks for
# TransportKind.stdio; bondc before 2026-11-24 rejected that argument. With BONDC_STDIO_SHIM=1 the
# setting runs `sh -c 'exec "$0" lsp' BONDC --stdio`, which drops it (for such an older bondc).
STDIO_SHIM = os.environ.get("BONDC_STDIO_SHIM", "") not in ("", "0")
BONDC_COMMAND = ["/bin/sh", "-c", 'exec "$0" lsp', BONDC] if STDIO_SHIM else [BONDC, "lsp"]

EDITOR = ".part.editor .editor-instance .monaco-editor"
results: list[tuple[str, bool, str]] = []


def log(message: str) -> None:
    print(f"[e2e {time.strftime('%H:%M:%S')}] {message}", flush=True)


def record(name: str, ok: bool, evidence: str) -> None:
    results.append((name, ok, evidence))
    print(f"{'PASS' if ok else 'FAIL'}: {name} -- {evidence}", flush=True)


# ------------------------------------------------------------------ server setup

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def prepare() -> tuple[Path, Path, Path, dict]:
    user_data = WORKDIR / "user-data"
    extensions = WORKDIR / "extensions"
    workspace = WORKDIR / "workspace"
    for d in (user_data, workspace):          # fresh editor state and a fresh copy of the models
        shutil.rmtree(d, ignore_errors=True)
    shutil.copytree(REPO / "models", workspace)
    (user_data / "User").mkdir(parents=True)
    settings = {
        "bondc.command": BONDC_COMMAND,
        "security.workspace.trust.enabled": False,
        "telemetry.telemetryLevel": "off",
        "update.mode": "none",
        "extensions.autoCheckUpdates": False,
        "extensions.autoUpdate": False,
        "extensions.ignoreRecommendations": True,
        "workbench.startupEditor": "none",
        "workbench.tips.enabled": False,
        "workbench.enableExperiments": False,
        "workbench.colorTheme": "Default Dark Modern",
        "editor.hover.delay": 200,
        "editor.minimap.enabled": False,
        "files.autoSave": "off",
        "git.enabled": False,
        "chat.disableAIFeatures": True,
    }
    (user_data / "User" / "settings.json").write_text(json.dumps(settings, indent=2))
    env = dict(os.environ)
    env["XDG_CONFIG_HOME"] = str(WORKDIR / "xdg-config")   # keep code-server's own files out of $HOME
    env["XDG_DATA_HOME"] = str(WORKDIR / "xdg-data")
    extensions.mkdir(parents=True, exist_ok=True)
    if VSIX and Path(VSIX).exists():
        log(f"installing {VSIX}")
        out = subprocess.run([CODE_SERVER, "--config", str(WORKDIR / "config.yaml"), "--user-data-dir", str(user_data),
                              "--extensions-dir", str(extensions), "--force", "--install-extension", VSIX],
                             env=env, capture_output=True, text=True, timeout=180)
        log(out.stdout.strip().splitlines()[-1] if out.stdout.strip() else out.stderr.strip())
    if not any(p.name.startswith("bondc.bondc-") for p in extensions.iterdir()):
        raise SystemExit(f"the extension is not installed in {extensions}: set VSIX")
    return user_data, extensions, workspace, env


def start_server(user_data: Path, extensions: Path, workspace: Path, env: dict, port: int) -> subprocess.Popen:
    cmd = [CODE_SERVER, "--config", str(WORKDIR / "config.yaml"), "--auth", "none",
           "--bind-addr", f"127.0.0.1:{port}", "--user-data-dir", str(user_data), "--extensions-dir", str(extensions),
           "--disable-telemetry", "--disable-update-check", "--disable-workspace-trust",
           "--disable-getting-started-override", str(workspace)]
    log("starting " + " ".join(cmd))
    logfile = open(WORKDIR / "code-server.log", "w")
    proc = subprocess.Popen(cmd, env=env, stdout=logfile, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.time() + 120
    while time.time() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"code-server exited with {proc.returncode}; see {WORKDIR / 'code-server.log'}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=2) as r:
                if r.status == 200:
                    return proc
        except OSError:
            time.sleep(0.5)
    raise SystemExit("code-server did not answer /healthz within 120 s")


def stop_server(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    # the extension host's children (bondc lsp) are in the same session/process group
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


# ------------------------------------------------------------------ page helpers

def wait_until(predicate, timeout: float = TIMEOUT, interval: float = 0.25):
    deadline = time.time() + timeout
    last = None
    while time.time() < deadline:
        last = predicate()
        if last:
            return last
        time.sleep(interval)
    return last


def status_text(page, item_id: str) -> str:
    loc = page.locator(f'.statusbar-item[id="{item_id}"]')
    return loc.first.inner_text().strip() if loc.count() else ""


def go_to(page, line: int, column: int) -> None:
    """Ctrl+G LINE:COL in the active editor."""
    page.locator(EDITOR).first.click(position={"x": 300, "y": 10})   # focus the text area
    page.keyboard.press("Control+g")
    box = page.locator(".quick-input-widget input")
    box.wait_for(state="visible")
    box.fill(f":{line}:{column}")
    page.keyboard.press("Enter")
    wait_until(lambda: status_text(page, "status.editor.selection").startswith(f"Ln {line}, Col {column}"), 10)


def cursor_line_col(page) -> tuple[int, int] | None:
    m = re.match(r"Ln (\d+), Col (\d+)", status_text(page, "status.editor.selection"))
    return (int(m.group(1)), int(m.group(2))) if m else None


TOKENS_JS = """
(prefix) => {
  const lines = document.querySelectorAll('%s .view-lines .view-line');
  for (const line of lines) {
    const text = line.textContent.replace(/\\u00a0/g, ' ');
    if (text.trimStart().startsWith(prefix)) {
      return Array.from(line.querySelectorAll('span > span')).map(s => ({
        text: s.textContent.replace(/\\u00a0/g, ' '), cls: s.className, color: getComputedStyle(s).color}));
    }
  }
  return null;
}
""" % EDITOR


def line_tokens(page, prefix: str):
    return page.evaluate(TOKENS_JS, prefix)


def token(tokens, text):
    for t in tokens or []:
        if t["text"].strip() == text:
            return t
    return None


def screenshot(page, name: str) -> None:
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / name))
    try:   # keep the pictures small: a 256-colour palette is plenty for the workbench
        from PIL import Image
        Image.open(SHOTS / name).convert("RGB").quantize(256).save(SHOTS / name, optimize=True)
    except ImportError:
        pass
    log(f"screenshot {SHOTS / name}")


def problems_count(page) -> tuple[int, int] | None:
    """(errors, warnings) from the status bar's problems item (its text is 'E W'; its aria-label
    'No Problems' or e.g. 'Errors: 1, Warnings: 0')."""
    loc = page.locator('.statusbar-item[id="status.problems"]')
    if not loc.count():
        return None
    numbers = re.findall(r"\d+", loc.first.inner_text())
    return (int(numbers[0]), int(numbers[1])) if len(numbers) >= 2 else None


# ------------------------------------------------------------------ checks

def check_highlighting(page, lines: list[str]) -> None:
    model_line = next(i for i, l in enumerate(lines, 1) if l.startswith("model "))
    go_to(page, model_line + 3, 1)
    model = wait_until(lambda: (lambda t: t if token(t, "ElectroPneumaticHybrid") else None)(line_tokens(page, "model ")))
    param = line_tokens(page, "param g ")
    element_line = next(i for i, l in enumerate(lines, 1) if l.strip().startswith("Sf servomotor"))
    go_to(page, element_line, 1)
    element = wait_until(lambda: line_tokens(page, "Sf servomotor"))
    comment = wait_until(lambda: line_tokens(page, "# 'Sf: Servomotor'"))
    screenshot(page, "1_highlighting.png")

    picks = {
        "keyword `model`": token(model, "model"),
        "model name": token(model, "ElectroPneumaticHybrid"),
        "keyword `param`": token(param, "param"),
        "param name `g`": token(param, "g"),
        "number `9.81`": token(param, "9.81"),
        "string": next((t for t in param or [] if t["text"].startswith('"')), None),
        "element kind `Sf`": token(element, "Sf"),
        "element name `servomotor`": token(element, "servomotor"),
        "comment": next((t for t in comment or [] if t["text"].strip()), None),
    }
    missing = [k for k, v in picks.items() if v is None]
    if missing:
        record("1 syntax highlighting", False, f"tokens not found: {missing}; model={model} param={param} element={element}")
        return
    evidence = "; ".join(f"{k}: {v['cls'].split()[0]} {v['color']}" for k, v in picks.items())
    colours = {k: v["color"] for k, v in picks.items()}
    # what a grammar that works must produce: keywords differ from the names they introduce, and
    # numbers, strings and comments each differ from plain names; with no grammar every token of a
    # line would have one class (mtk1).
    distinct = [
        colours["keyword `model`"] != colours["model name"],
        colours["keyword `param`"] != colours["param name `g`"],
        colours["element kind `Sf`"] != colours["element name `servomotor`"],
        colours["number `9.81`"] != colours["param name `g`"],
        colours["string"] != colours["param name `g`"],
        colours["comment"] != colours["param name `g`"],
    ]
    classes = {v["cls"].split()[0] for v in picks.values()}
    # the scopes themselves, with the workbench's own token inspector
    param_g = next(i for i, l in enumerate(lines, 1) if l.strip().startswith("param g "))
    scopes = {
        "model": inspect_scope(page, model_line, 1, "1b_inspect_model.png"),
        "Sf": inspect_scope(page, element_line, 3, None),
        "[m/s^2]": inspect_scope(page, param_g, lines[param_g - 1].index("[m/s^2]") + 3, "1c_inspect_unit.png"),
    }
    ok = (all(distinct) and len(classes) >= 4 and "keyword.other.model.bondgraph" in scopes["model"]
          and "storage.type.element.bondgraph" in scopes["Sf"])
    unit_tokens = [t for t in param if t["text"].strip() in ("[", "m/s^2", "]")]
    record("1 syntax highlighting", ok, evidence + f"; distinct classes: {sorted(classes)}; "
           + "; ".join(f"inspector at `{k}`: {_scope_summary(v)}" for k, v in scopes.items())
           + f"; unit tokens (not a pass criterion): {[(t['text'], t['cls'], t['color']) for t in unit_tokens]}")


def _scope_summary(text: str) -> str:
    m = re.search(r"textmate scopes (.*?)(?: foreground| background| fontStyle|$)", text)
    return m.group(1).strip() if m else text[:160]


def inspect_scope(page, line: int, column: int, shot: str | None) -> str:
    go_to(page, line, column)
    run_command(page, "Developer: Inspect Editor Tokens and Scopes")
    widget = page.locator(".token-inspect-widget")
    try:
        widget.wait_for(state="visible", timeout=10000)
        wait_until(lambda: "bondgraph" in widget.inner_text(), 10)
        text = " ".join(widget.inner_text().split())
        if shot:
            screenshot(page, shot)
    except Exception as error:  # noqa: BLE001 - report what was seen
        text = f"(inspector not shown: {error})"
    page.keyboard.press("Escape")
    return text


def run_command(page, name: str) -> None:
    page.keyboard.press("F1")
    box = page.locator(".quick-input-widget input")
    box.wait_for(state="visible")
    box.fill(">" + name)
    page.locator(".quick-input-list .monaco-list-row").first.wait_for(state="visible")
    time.sleep(0.3)
    page.keyboard.press("Enter")


def check_diagnostics(page, lines: list[str]) -> None:
    baseline = wait_until(lambda: problems_count(page), 10)
    squiggles_before = page.locator(f"{EDITOR} .squiggly-error").count()
    anchor = next(i for i, l in enumerate(lines, 1) if l.strip().startswith("param g "))
    go_to(page, anchor, 1)
    page.keyboard.press("End")
    page.keyboard.press("Enter")
    bad = "param bogus = undefined_thing"
    page.keyboard.type(bad, delay=10)
    inserted = anchor + 1
    squiggle = wait_until(lambda: page.locator(f"{EDITOR} .squiggly-error").count() > squiggles_before)
    counts = wait_until(lambda: (lambda c: c if c and c[0] > 0 else None)(problems_count(page)), 15)
    # the Problems panel: message, code, source
    page.keyboard.press("Control+Shift+m")
    panel_row = page.locator(".markers-panel .monaco-list-row")
    marker_text = ""
    try:
        page.locator(".markers-panel .monaco-list-row .marker-message-details, .markers-panel .monaco-list-row").first \
            .wait_for(state="visible", timeout=int(TIMEOUT * 1000))
        marker_text = wait_until(lambda: (lambda t: t if "undefined" in t else None)(
            " | ".join(" ".join(r.inner_text().split()) for r in panel_row.all())), 20) or ""
    except Exception as error:  # noqa: BLE001
        marker_text = f"(problems panel: {error})"
    screenshot(page, "2_diagnostic.png")
    seen = bool(squiggle) and "undefined_thing" in marker_text and "E301" in marker_text
    record("2a diagnostic appears", seen,
           f"typed `{bad}` at line {inserted}; squiggly-error elements: {page.locator(f'{EDITOR} .squiggly-error').count()} "
           f"(before: {squiggles_before}); status bar (errors, warnings): {counts} (before: {baseline}); "
           f"Problems panel: {marker_text[:300]!r}")

    # remove the line again: go to it and delete it (Ctrl+Shift+K)
    go_to(page, inserted, 1)
    page.keyboard.press("Control+Shift+k")
    removed = wait_until(lambda: not page.evaluate(
        "() => document.querySelector('%s .view-lines').textContent.includes('bogus')" % EDITOR), 10)
    restored = not removed
    cleared = wait_until(lambda: page.locator(f"{EDITOR} .squiggly-error").count() == 0
                         and (problems_count(page) or (1, 0))[0] == 0)
    rows = " | ".join(" ".join(r.inner_text().split()) for r in panel_row.all())
    screenshot(page, "3_diagnostic_cleared.png")
    record("2b diagnostic clears", seen and bool(cleared) and not restored,
           ("" if seen else "nothing to clear (no diagnostic appeared in 2a); ") + f"line deleted (text still contains 'bogus': {restored}); squiggly-error elements: "
           f"{page.locator(f'{EDITOR} .squiggly-error').count()}; status bar (errors, warnings): {problems_count(page)}; "
           f"Problems panel rows: {rows[:200]!r}")
    page.keyboard.press("Control+j")   # hide the panel again
    page.locator(EDITOR).first.click(position={"x": 300, "y": 10})


def check_hover(page, lines: list[str]) -> None:
    line = next(i for i, l in enumerate(lines, 1) if l.strip().startswith("param r_screw"))
    column = lines[line - 1].index("lead/") + 1
    go_to(page, line, column + 1)
    # hover the mouse over the text under the cursor
    cursor = page.locator(f"{EDITOR} .cursors-layer .cursor").first.bounding_box()
    page.mouse.move(cursor["x"] + 3, cursor["y"] + cursor["height"] / 2)
    hover = page.locator(".monaco-hover:not(.hidden) .monaco-hover-content, .monaco-hover:not(.hidden)")
    text = wait_until(lambda: (lambda t: t if "lead" in t and "SI value" in t else None)(
        " ".join(hover.first.inner_text().split()) if hover.count() and hover.first.is_visible() else ""), 30)
    how = "mouse"
    if not text:   # fall back to the keyboard command (Ctrl+K Ctrl+I) to tell a hover from a mouse problem
        page.mouse.move(5, 5)
        go_to(page, line, column + 1)
        page.keyboard.press("Control+k")
        page.keyboard.press("Control+i")
        text = wait_until(lambda: (lambda t: t if "lead" in t and "SI value" in t else None)(
            " ".join(hover.first.inner_text().split()) if hover.count() and hover.first.is_visible() else ""), 30)
        how = "keyboard Ctrl+K Ctrl+I (the mouse hover did not show it)"
    time.sleep(0.6)   # let the hover finish fading in before the picture
    screenshot(page, "4_hover.png")
    ok = bool(text) and "param lead" in text and "0.005" in text
    record("3 hover", ok, f"hovered `lead` at line {line}, col {column + 1} by {how}; hover text: {text!r}")
    page.keyboard.press("Escape")
    page.mouse.move(5, 5)


def check_definition(page, lines: list[str]) -> None:
    use = next(i for i, l in enumerate(lines, 1) if l.strip().startswith("param r_screw"))
    column = lines[use - 1].index("lead/") + 2
    decl = next(i for i, l in enumerate(lines, 1) if l.strip().startswith("param lead"))
    decl_col = lines[decl - 1].index("lead") + 1
    go_to(page, use, column)
    before = cursor_line_col(page)
    page.keyboard.press("F12")
    after = wait_until(lambda: (lambda p: p if p and p[0] != use else None)(cursor_line_col(page)), 30)
    status = status_text(page, "status.editor.selection")
    screenshot(page, "5_definition.png")
    ok = after is not None and after[0] == decl
    record("4 go to definition", ok, f"F12 on `lead` at Ln {before[0] if before else '?'}, Col {before[1] if before else '?'}"
           f" -> status bar '{status}' (declaration `param lead` is line {decl}, name at col {decl_col})")


def main() -> int:
    # a SIGTERM (e.g. from `timeout`) unwinds through the finally below, so code-server is stopped
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    lines = (REPO / "models" / FLAGSHIP).read_text().splitlines()
    user_data, extensions, workspace, env = prepare()
    port = free_port()
    proc = start_server(user_data, extensions, workspace, env, port)
    version = subprocess.run([CODE_SERVER, "--version"], capture_output=True, text=True, env=env).stdout.strip()
    log(f"code-server {version}")
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                        args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.set_default_timeout(TIMEOUT * 1000)
            page.goto(f"http://127.0.0.1:{port}/?folder={workspace}")
            page.locator(".monaco-workbench").wait_for(state="visible")
            page.locator(".explorer-folders-view, .explorer-viewlet").first.wait_for(state="visible")
            time.sleep(2)
            # quick open the flagship
            page.keyboard.press("Control+p")
            box = page.locator(".quick-input-widget input")
            box.wait_for(state="visible")
            box.fill(FLAGSHIP)
            page.locator(".quick-input-list .monaco-list-row").first.wait_for(state="visible")
            time.sleep(0.5)
            page.keyboard.press("Enter")
            page.locator(EDITOR).first.wait_for(state="visible")
            tab = page.locator(".tabs-container .tab.active").first.inner_text()
            mode = wait_until(lambda: (lambda t: t if t else None)(status_text(page, "status.editor.mode")), 30)
            log(f"opened tab {tab!r}, language mode {mode!r}")
            # wait for the language server: the outline/symbols come from it, but the simplest sign is a hover;
            # give it time to start (the first check takes a few seconds) before the checks
            time.sleep(5)
            for check in (check_highlighting, check_diagnostics, check_hover, check_definition):
                try:
                    check(page, lines)
                except Exception as error:  # noqa: BLE001 - a failed step is a failed check
                    record(check.__name__, False, f"exception: {type(error).__name__}: {error}")
                    try:
                        screenshot(page, f"error_{check.__name__}.png")
                    except Exception:  # noqa: BLE001
                        pass
                    page.keyboard.press("Escape")
            browser.close()
    finally:
        stop_server(proc)
    failed = [name for name, ok, _ in results if not ok]
    print(f"\nbondc.command setting: {json.dumps(BONDC_COMMAND)}")
    for log_file in sorted((WORKDIR / "user-data" / "logs").glob("*/exthost*/output_logging_*/*bondc*.log")):
        text = log_file.read_text(errors="replace").strip().splitlines()
        print(f"language client output channel ({log_file.name}, {len(text)} lines; first 6):")
        for line in text[:6]:
            print("    " + line)
        if any("unrecognized arguments: --stdio" in line for line in text):
            print("    -> the client passed --stdio (TransportKind.stdio) and this (older) `bondc lsp` refused "
                  "it; see README.md (BONDC_STDIO_SHIM=1 works around it)")
    print(f"\ncode-server: {version}")
    print(f"{len(results) - len(failed)} passed, {len(failed)} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
