"""Open `make report`'s page in a real browser and check that every figure and table shows.

    python benchmarks/tools/report_in_browser.py report.html SCREENSHOTS_DIR [--browser chromium]

Starts the browser headless with its DevTools protocol (Chromium or Chrome; tornado, installed with the
workflow's Jupyter, speaks the protocol's websocket), opens the page, and for each result category
(Figures, Tables, Report) clicks every result's "view" button in turn, as a reader would. For each it
records what the page then shows -- the images with their decoded sizes, the HTML pages in frames with
their tables' rows -- and saves a screenshot. It prints one line per result and exits 1 if any result
shows nothing (an image that does not decode, a page without a table or text), naming it.
"""
from __future__ import annotations

import argparse
import asyncio
import base64
import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

PORT = 9333
#: Every result's row in the page's list, and a click on its "view" (eye) button.
ROWS = "[...document.querySelectorAll('tr')].filter(r => r.querySelector('a[iconname=eye]')).map(r => r.cells[0].textContent.trim())"
VIEW = ("(name) => [...document.querySelectorAll('tr')].find(r => r.cells[0] && r.cells[0].textContent.trim() === name)"
        ".querySelector('a[iconname=eye]').click()")
CLICK = ("(text) => { const found = [...document.querySelectorAll('a, button, li, span, div')].filter("
         "e => e.textContent.trim() === text && e.offsetParent !== null); if (found.length) found.at(-1).click(); "
         "return found.length > 0; }")
#: What the page shows: images (but the 58-pixel logo) with their decoded sizes; frames with their tables' rows.
SHOWN = """(() => ({
  images: [...document.querySelectorAll('img')].filter(i => i.offsetParent !== null && i.naturalWidth !== 58)
            .map(i => [i.naturalWidth, i.naturalHeight]),
  frames: [...document.querySelectorAll('iframe')].filter(f => f.offsetParent !== null && f.clientWidth > 0).map(f => {
            const d = f.contentDocument;  // null for the report's data: URI pages (another origin): read the URI
            const page = d ? d.documentElement.outerHTML : f.src.startsWith('data:') ? (f.src.includes(';base64,')
              ? decodeURIComponent(escape(atob(f.src.split(';base64,')[1]))) : decodeURIComponent(f.src.split(',')[1])) : '';
            return [(page.match(/<tr/g) || []).length, page.replace(/<[^>]*>/g, '').trim().length]; }),
}))()"""


async def check(page: Path, shots: Path, ws_url: str) -> list[str]:
    from tornado.websocket import websocket_connect

    ws = await websocket_connect(ws_url, max_message_size=1 << 30)
    counter = 0

    async def call(method: str, **params):
        nonlocal counter
        counter += 1
        ws.write_message(json.dumps({"id": counter, "method": method, "params": params}))
        while True:
            message = json.loads(await ws.read_message())
            if message.get("id") == counter:
                return message.get("result", {})

    async def js(expression: str):
        reply = await call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        return reply.get("result", {}).get("value")

    async def screenshot(name: str) -> None:
        reply = await call("Page.captureScreenshot", format="png")
        (shots / f"{name.replace('/', '_')}.png").write_bytes(base64.b64decode(reply["data"]))

    await call("Page.enable")
    await call("Page.navigate", url=page.resolve().as_uri())
    await asyncio.sleep(6)
    await screenshot("00_landing")
    failures = []
    for category in ("Figures", "Tables", "Report"):
        if not await js(f"({CLICK})({json.dumps(category)})"):
            failures.append(f"{category}: no such category in the page")
            continue
        await asyncio.sleep(2)
        for name in await js(ROWS) or []:
            await js(f"({VIEW})({json.dumps(name)})")
            await asyncio.sleep(3)
            shown = await js(SHOWN)
            await screenshot(f"{category}_{name}")
            images = [size for size in shown["images"] if size[0] > 0 and size[1] > 0]
            frames = [frame for frame in shown["frames"] if frame and frame[1] > 0]
            ok = bool(images) if name.endswith((".png", ".svg", ".jpg")) else bool(frames)
            print(f"{'shown' if ok else 'NOT SHOWN'}: {name}: images {images}, pages (rows, characters) {frames}")
            if not ok:
                failures.append(name)
        await js(f"({CLICK})('Results')")
        await asyncio.sleep(1.5)
    return failures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("page", type=Path)
    parser.add_argument("shots", type=Path)
    parser.add_argument("--browser", default="chromium")
    args = parser.parse_args(argv)
    args.shots.mkdir(parents=True, exist_ok=True)
    browser = subprocess.Popen([args.browser, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1400,1000",
                                f"--remote-debugging-port={PORT}", "about:blank"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(60):
            try:
                targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{PORT}/json"))
                break
            except OSError:
                time.sleep(0.5)
        else:
            sys.exit(f"{args.browser}: no DevTools endpoint on port {PORT}")
        ws_url = next(target for target in targets if target["type"] == "page")["webSocketDebuggerUrl"]
        failures = asyncio.run(check(args.page, args.shots, ws_url))
    finally:
        browser.terminate()
        browser.wait(timeout=30)
    if failures:
        print("not shown: " + ", ".join(failures))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
