"""The live view in a real browser (issue #19): headless Chromium from the
system's packages, driven by Playwright, against a real `semdepth serve` on
a loopback port. Run by tests/browser.sh (from .ci/run); alone:

    python3 tests/browser/viewer_test.py SEMDEPTH_BIN SCREENSHOT_DIR

What it checks, each with an assertion on what the page shows:
  1. the sessions page loads without console errors, and a session created
     over REST appears in it;
  2. pairs streamed over the WebSocket update the session page: the plot
     holds every pair, the overlay is the last result's contour on the last
     pair's image, the numbers are the last result's;
  3. a box dragged on the left image re-initialises the session with that
     box (the session's hint as stored), and the next pair's result is the
     object in the box: the scene holds two objects side by side, and the
     box names the one the automatic initialisation did not take;
  4. the calibration page shows the samples and R^2, and adds a sample from
     the session's latest disparity;
  5. a session of two named objects lists both with their heights and the
     height of one relative to the other, and draws both contours;
  6. a session deleted while its page is open is reported deleted;
  7. with a token, the page without it shows a prompt, not a broken page;
     a wrong token is refused, the right one opens the sessions, and the
     token never appears in a URL.
Screenshots go to SCREENSHOT_DIR; look at them.
"""

import asyncio
import concurrent.futures
import io
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

from PIL import Image
from playwright.sync_api import expect, sync_playwright

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "examples" / "python"))
from semdepth_client import SemdepthClient, encode_pair, stream_pairs  # noqa: E402

CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
STREAMED = 8               # pairs streamed before the box is drawn
CENTROID_TOL_PX = 3.0      # the re-initialised object's centroid vs the truth
ROI_TOL_PX = 2.0           # the stored box vs the box drawn (screen rounding)
TIMEOUT_MS = 15_000


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, binary, work, token=None):
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.log = open(work / f"server-{self.port}.log", "w")
        args = [binary, "serve", "--listen", f"127.0.0.1:{self.port}", "--db", str(work / f"db-{self.port}.sqlite3")]
        if token:
            args += ["--token", token]
        self.proc = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 20
        while True:
            try:
                urllib.request.urlopen(self.base + "/readyz", timeout=2).read()
                return
            except (urllib.error.URLError, ConnectionError):
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"server did not start; log: {self.log.name}")
                time.sleep(0.1)

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def synth(binary, out, shape, seed, frames):
    subprocess.run([binary, "synth", str(out), "--preset", "clean", "--shape", shape, "--seed", str(seed),
                    "--frames", str(frames)], check=True, stdout=subprocess.DEVNULL)
    return json.loads((out / "truth.json").read_text())


def side_by_side(a, b):
    """Two equal-height images next to each other, as PNG bytes."""
    ia, ib = Image.open(a), Image.open(b)
    both = Image.new(ia.mode, (ia.width + ib.width, ia.height))
    both.paste(ia, (0, 0))
    both.paste(ib, (ia.width, 0))
    buf = io.BytesIO()
    both.save(buf, format="PNG")
    return buf.getvalue()


def stream(base, session_id, messages):
    """Streams over the WebSocket and returns the replies (in a thread of
    its own: Playwright's sync API holds this thread's event loop)."""
    async def run():
        return [r async for r in stream_pairs(base, session_id, messages)]
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, run()).result()


def check(condition, what):
    if not condition:
        raise AssertionError(what)
    print(f"ok: {what}")


def main():
    binary, shots = sys.argv[1], Path(sys.argv[2])
    shots.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="semdepth-browser-"))
    frames = STREAMED + 1
    truth_a = synth(binary, work / "a", "blob", 5, frames)
    truth_b = synth(binary, work / "b", "sphere", 21, frames)
    width_a = truth_a["config"]["width"]
    pairs = [(side_by_side(work / "a" / f"{i:04d}_left.png", work / "b" / f"{i:04d}_left.png"),
              side_by_side(work / "a" / f"{i:04d}_right.png", work / "b" / f"{i:04d}_right.png"))
             for i in range(frames)]
    # The two objects' truth in the composite's coordinates, per frame.
    objects = {
        "a": [f["left"] for f in truth_a["frames"]],
        "b": [{**f["left"],
               "centroid": [f["left"]["centroid"][0] + width_a, f["left"]["centroid"][1]],
               "polygon": [[x + width_a, y] for x, y in f["left"]["polygon"]]} for f in truth_b["frames"]],
    }
    d = truth_a["config"]["disparity"]
    at = lambda z: d["offset_px"] + d["px_per_um"] * z  # noqa: E731

    server = Server(binary, work)
    token_server = Server(binary, work, token="browser-test-token-1f9c")
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            try:
                run_viewer(browser, server, pairs, objects, width_a, at, shots)
                run_token(browser, token_server, shots)
            finally:
                browser.close()
    finally:
        server.stop()
        token_server.stop()
    print("browser tests passed; screenshots in", shots)


def run_viewer(browser, server, pairs, objects, width_a, at, shots):
    api = SemdepthClient(server.base, timeout=30)
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    page.set_default_timeout(TIMEOUT_MS)
    problems = []
    page.on("console", lambda m: m.type == "error" and problems.append(f"console: {m.text}"))
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    page.on("response", lambda r: r.status >= 400 and problems.append(f"HTTP {r.status} for {r.url}"))

    # 1. The sessions page, and a session created over REST appears.
    page.goto(server.base + "/")
    page.wait_for_selector("table#sessions")
    check("No sessions yet" in page.inner_text("main"), "an empty server says there are no sessions")
    cal = api.create_calibration(name="stage steps", model="fit", degree=1,
                                 samples=[{"disparity_px": at(0.0), "z_um": 0.0},
                                          {"disparity_px": at(50.0), "z_um": 50.2},
                                          {"disparity_px": at(100.0), "z_um": 100.0}])
    session = api.create_session(name="two objects", calibration_id=cal["id"])
    sid = session["id"]
    page.wait_for_selector(f'tr[data-session="{sid}"]')
    row = page.inner_text(f'tr[data-session="{sid}"]')
    check(row.startswith("two objects"), "the session created over REST appears in the list")
    # Two sessions of one name tell apart: the row shows when each was
    # created and its id (issue #65).
    check(session["created_at"][:10] in row and sid in row,
          f"the row names the creation time and the id: {row!r}")
    page.screenshot(path=str(shots / "01-sessions.png"))

    # 2. Streaming updates the plot, the overlay and the numbers. The page's
    # event stream is held until two pairs are in, as when a viewer opens
    # just as a stream starts: it hears of pair 1 first, and must fetch
    # pair 0 itself (it once plotted 7 of 8 pairs then, now and again).
    held = []
    page.route("**/events", lambda route: held.append(route))
    page.click(f'tr[data-session="{sid}"] a')
    page.wait_for_selector("#view-left")
    messages = [encode_pair(i, left, right, encoding="png") for i, (left, right) in enumerate(pairs[:STREAMED])]
    replies = stream(server.base, sid, messages[:2])
    page.wait_for_timeout(200)
    check(len(held) == 1, "the page's event stream was held while two pairs went in")
    held[0].continue_()
    page.unroute("**/events")
    replies += stream(server.base, sid, messages[2:])
    last = replies[-1]
    check([r["status"] for r in replies] == ["initialised"] + ["tracked"] * (STREAMED - 1),
          f"the stream's {STREAMED} pairs are tracked")
    page.wait_for_selector(f"#plot-disparity[data-points='{STREAMED}']")
    check(True, f"the disparity plot holds all {STREAMED} pairs")
    page.wait_for_selector(f"#view-left[data-frame='{STREAMED - 1}']")
    page.wait_for_selector(f"#view-right[data-frame='{STREAMED - 1}']")
    check(True, "both images show the last pair")
    check(page.get_attribute("#plot-z", "data-points") == str(STREAMED), "the z plot holds every pair")
    # Axes a reader can use: round ticks on both, named (frame, px), and a
    # standard-error band drawn.
    y_ticks = page.eval_on_selector_all("#plot-disparity text.tick[text-anchor='end']", "ts => ts.map(t => t.textContent)")
    x_ticks = page.eval_on_selector_all("#plot-disparity text.tick[text-anchor='middle']", "ts => ts.map(t => t.textContent)")
    names = page.eval_on_selector_all("#plot-disparity text.axis-name", "ts => ts.map(t => t.textContent)")
    check(len(y_ticks) >= 3 and len(x_ticks) >= 3 and sorted(names) == ["frame", "px"],
          f"the disparity plot's axes are ticked and named (y {y_ticks}, x {x_ticks}, {names})")
    check(page.eval_on_selector("#plot-disparity", "p => p.querySelectorAll('polygon.band').length") >= 1,
          "the disparity plot shades its standard-error band")
    status = page.get_attribute("#numbers .badge", "data-status")
    check(status == "tracked", f"the page's status is the last result's ({status})")
    z_text = page.inner_text("#z-value")
    check(z_text.startswith(f"{last['z_um']:.3f} ± {last['z_std_um']:.3f}"),
          f"the page's z ({z_text}) is the last result's ({last['z_um']:.3f})")
    shown = [[float(v) for v in xy.split(",")]
             for xy in page.get_attribute("#overlay-left polygon", "points").split()]
    contour = last["left"]["contour"]
    check(len(shown) == len(contour) and all(abs(a - b) < 1e-6 for s, c in zip(shown, contour) for a, b in zip(s, c)),
          "the left overlay is the last result's contour")
    page.screenshot(path=str(shots / "02-session-streaming.png"), full_page=True)

    # 3. A box around the other object re-initialises on it.
    found = "a" if last["left"]["centroid"][0] < width_a else "b"
    target = "b" if found == "a" else "a"
    truth = objects[target][STREAMED]
    xs = [x for x, _ in truth["polygon"]]
    ys = [y for _, y in truth["polygon"]]
    box = [min(xs) - 15, min(ys) - 15, max(xs) + 15, max(ys) + 15]
    overlay = page.locator("#overlay-left")
    frame_box = [float(v) for v in overlay.get_attribute("viewBox").split()]
    rect = overlay.bounding_box()

    def to_screen(x, y):
        return (rect["x"] + (x - frame_box[0]) / frame_box[2] * rect["width"],
                rect["y"] + (y - frame_box[1]) / frame_box[3] * rect["height"])

    page.mouse.move(*to_screen(box[0], box[1]))
    page.mouse.down()
    page.mouse.move(*to_screen((box[0] + box[2]) / 2, (box[1] + box[3]) / 2), steps=4)
    page.mouse.move(*to_screen(box[2], box[3]), steps=4)
    page.mouse.up()
    page.wait_for_selector("#message:has-text('The next pair initialises with box')")
    roi = api.get_session(sid)["init"]["roi"]
    drawn = [box[0], box[1], box[2] - box[0], box[3] - box[1]]
    check(roi is not None and all(abs(a - b) <= ROI_TOL_PX for a, b in zip(roi, drawn)),
          f"the session's hint is the box drawn ({roi} vs {[round(v, 1) for v in drawn]})")
    page.screenshot(path=str(shots / "03-box-drawn.png"), full_page=True)
    after = stream(server.base, sid, [encode_pair(0, *pairs[STREAMED], encoding="png")])[0]
    cx, cy = after["left"]["centroid"]
    check(after["status"] == "initialised" and box[0] <= cx <= box[2] and box[1] <= cy <= box[3],
          f"the next pair initialises inside the box ({after['status']}, centroid {cx:.1f}, {cy:.1f})")
    err = ((cx - truth["centroid"][0]) ** 2 + (cy - truth["centroid"][1]) ** 2) ** 0.5
    check(err < CENTROID_TOL_PX, f"on the object in the box ({err:.2f} px from its true centroid)")
    page.wait_for_selector(f"#view-left[data-frame='{STREAMED}']")
    page.wait_for_selector("#numbers .badge[data-status='initialised']")
    first = page.get_attribute("#overlay-left polygon", "points").split()[0].split(",")
    check(abs(float(first[0]) - after["left"]["contour"][0][0]) < 1e-6,
          "the overlay moved to the object in the box")
    page.screenshot(path=str(shots / "04-reinitialised.png"), full_page=True)

    # 3b. A lasso drawn round the first object (10 px outside its outline)
    # names it; "not this" clicked on it then names the other.
    def lasso_round(polygon, k, grow=10.0):
        cx = sum(x for x, _ in polygon) / len(polygon)
        cy = sum(y for _, y in polygon) / len(polygon)
        out = []
        for i in range(0, len(polygon), max(1, len(polygon) // k)):
            x, y = polygon[i]
            r = ((x - cx) ** 2 + (y - cy) ** 2) ** 0.5 or 1.0
            out.append((x + (x - cx) / r * grow, y + (y - cy) / r * grow))
        return out

    def streamed_on(name, what):
        r = stream(server.base, sid, [encode_pair(0, *pairs[STREAMED], encoding="png")])[0]
        cx, cy = r["left"]["centroid"]
        t = objects[name][STREAMED]["centroid"]
        err = ((cx - t[0]) ** 2 + (cy - t[1]) ** 2) ** 0.5
        check(r["status"] == "initialised" and err < CENTROID_TOL_PX,
              f"{what}: the next pair initialises on object {name} ({r['status']}, {err:.2f} px from its true centroid)")

    page.check("#tool-lasso")
    drawn = lasso_round(objects[found][STREAMED]["polygon"], 24)
    page.mouse.move(*to_screen(*drawn[0]))
    page.mouse.down()
    for x, y in drawn[1:]:
        page.mouse.move(*to_screen(x, y), steps=2)
    page.mouse.up()
    page.wait_for_selector("#message:has-text('The next pair initialises with outline')")
    outline = api.get_session(sid)["init"]["outline"]
    check(outline is not None and len(outline) >= 20, f"the session's hint is the lasso drawn ({len(outline or [])} vertices)")
    check(page.get_attribute("#lasso-left", "visibility") == "visible", "the lasso is drawn over the left view")
    page.screenshot(path=str(shots / "04b-lasso.png"), full_page=True)
    streamed_on(found, "a lasso")
    page.check("#tool-exclude")
    t = objects[found][STREAMED]["centroid"]
    page.mouse.click(*to_screen(*t))
    page.wait_for_selector("#message:has-text('1 point not the object')")
    init = api.get_session(sid)["init"]
    clicked = init["exclude"][0] if len(init["exclude"]) == 1 else [float("inf")] * 2
    check(abs(clicked[0] - t[0]) < 1.0 and abs(clicked[1] - t[1]) < 1.0 and init["outline"] is None,
          f"the session's hint is the point that is not the object, the lasso gone ({init['exclude']}, outline {init['outline']})")
    check(page.locator("#overlay-left .not-this").count() == 1, "the point that is not the object is marked")
    page.screenshot(path=str(shots / "04c-not-this.png"), full_page=True)
    streamed_on(target, "\"not this\" on the other")

    # 4. The calibration page: samples, R^2, a sample from the session.
    page.goto(f"{server.base}/#/calibrations/{cal['id']}")
    page.wait_for_selector("table#samples")
    check(page.locator("table#samples tbody tr").count() == 3, "the calibration's three samples are listed")
    check(page.inner_text("#r-squared") == f"{cal['r_squared']:.5f}", "R^2 is shown")
    page.fill("#sample-z", "42.5")
    page.select_option("#sample-session", sid)
    page.click("#add-sample button")
    expect(page.locator("table#samples tbody tr")).to_have_count(4)
    added = api.get_calibration(cal["id"])["samples"][-1]
    latest = api.get_session(sid)["latest_disparity_px"]
    check(added["z_um"] == 42.5 and added.get("session_id") == sid,
          f"a sample from the session was added ({added}, latest disparity {latest})")
    page.screenshot(path=str(shots / "05-calibration.png"), full_page=True)

    check(not problems, f"no console errors or page errors: {problems}")

    # 5. A session of two named objects: both listed with their heights, the
    # height of one relative to the other, both contours drawn.
    def box(poly, margin=12):
        xs, ys = [x for x, _ in poly], [y for _, y in poly]
        return [int(min(xs)) - margin, int(min(ys)) - margin,
                int(max(xs) - min(xs)) + 2 * margin, int(max(ys) - min(ys)) + 2 * margin]
    pair_session = api.create_session(name="needle and lamella", calibration_id=cal["id"], objects=[
        {"name": "a", "roi": box(objects["a"][0]["polygon"])},
        {"name": "b", "roi": box(objects["b"][0]["polygon"])}])["id"]
    page.goto(f"{server.base}/#/sessions/{pair_session}")
    page.wait_for_selector("#view-left")
    replies = stream(server.base, pair_session, messages)
    last = replies[-1]
    check([o["status"] for o in last["objects"]] == ["tracked", "tracked"], "both objects are tracked")
    page.wait_for_selector(f"#view-left[data-frame='{STREAMED - 1}']")
    page.wait_for_selector("table#objects tr[data-object='b']")
    check(page.locator("table#objects tr").count() == 2, "the page lists both objects")
    fits = page.eval_on_selector("table#objects", "t => { const c = t.closest('div'); return [t.scrollWidth, c.clientWidth]; }")
    check(fits[0] <= fits[1], f"the objects table fits inside its card ({fits[0]} px in {fits[1]} px)")
    rel = next(x for x in last["relative"] if x["from"] == "a" and x["to"] == "b")
    shown = page.inner_text("table#relative tr[data-from='a'][data-to='b']")
    expected = f"{rel['dz_um']:.3f} ± {rel['dz_std_um']:.3f}"
    check(expected in shown, f"the relative height a - b ({shown!r}) is the last result's ({expected})")
    drawn = page.get_attribute("#overlay-left polygon[data-object='b']", "points").split()
    check(len(drawn) == len(last["objects"][1]["left"]["contour"]),
          f"the second object's contour is drawn ({len(drawn)} points)")
    page.screenshot(path=str(shots / "06-two-objects.png"), full_page=True)

    # 6. A session deleted while it is watched: the page says so.
    doomed = api.create_session(name="to delete")["id"]
    page.goto(f"{server.base}/#/sessions/{doomed}")
    page.wait_for_selector("#view-left")
    api.delete_session(doomed)
    page.wait_for_selector("#message:has-text('The session was deleted')")
    check(True, "a session deleted while watched is reported deleted")

    # Its last lookup is an expected 404, and nothing else went wrong.
    unexpected = [p for p in problems if "404" not in p or ("HTTP 404" in p and doomed not in p)]
    check(not unexpected, f"no other errors after the deletion: {unexpected}")
    page.close()


def run_token(browser, server, shots):
    token = "browser-test-token-1f9c"
    page = browser.new_page(viewport={"width": 1200, "height": 700})
    page.set_default_timeout(TIMEOUT_MS)
    urls, errors, auth = [], [], []
    page.on("request", lambda r: (urls.append(r.url), auth.append(r.headers.get("authorization"))))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.base + "/")
    page.wait_for_selector("#token-prompt")
    check("needs a token" in page.inner_text("#token-prompt"), "without a token the page asks for one")
    page.screenshot(path=str(shots / "06-token-prompt.png"))
    page.fill("#token", "wrong-token")
    page.press("#token", "Enter")
    page.wait_for_selector("#token-prompt:has-text('was refused')")
    check(True, "a wrong token is refused, with a prompt again")
    page.fill("#token", token)
    page.press("#token", "Enter")
    page.wait_for_selector("table#sessions")
    check(f"Bearer {token}" in auth, "the right token opens the sessions (sent as a bearer header)")
    check(all(token not in u for u in urls), f"the token never appears in a URL ({len(urls)} requests)")
    check(not errors, f"no page errors: {errors}")
    page.close()


if __name__ == "__main__":
    main()
