// semdepth's live view: sessions, their latest pair with the contours, z
// over frames, pointing at the object (reinit), and calibrations. Plain ES
// module, no build step, no third-party code; it uses only the service's
// public API (the same as any client), with the bearer token, when the
// server wants one, asked for once and kept in sessionStorage (never in a
// URL).

// The objects' colours, in order (the swatches' classes c0..c5 in style.css match).
const PALETTE = ["#00dcff", "#ffaa00", "#78ff50", "#ff50c8", "#ffff5a", "#a082ff"];
const LOST = "#ff3c28";
const TOKEN_KEY = "semdepth-token";
const PLOT_POINTS = 500;
const IMAGE_SIDE = 900;
const SVG = "http://www.w3.org/2000/svg";

const main = document.getElementById("main");
const statusLine = document.getElementById("status-line");

// ---- API ------------------------------------------------------------------

class AuthError extends Error {}

class ApiError extends Error {
  constructor(status, body) {
    super(body?.error?.message ?? `HTTP ${status}`);
    this.status = status;
    this.code = body?.error?.code;
  }
}

function authHeaders(extra = {}) {
  const token = sessionStorage.getItem(TOKEN_KEY);
  return token ? { ...extra, Authorization: `Bearer ${token}` } : extra;
}

async function api(path, { method = "GET", body, signal, raw = false } = {}) {
  const init = { method, signal, headers: authHeaders() };
  if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers["Content-Type"] = "application/json";
  }
  const response = await fetch(path, init);
  if (response.status === 401) throw new AuthError();
  if (!response.ok) {
    let parsed = null;
    try { parsed = await response.json(); } catch { /* not JSON */ }
    throw new ApiError(response.status, parsed);
  }
  return raw ? response : response.json();
}

// Server-sent events over fetch (EventSource cannot send the token header).
async function followEvents(path, onEvent, signal) {
  const response = await fetch(path, { headers: authHeaders({ Accept: "text/event-stream" }), signal });
  if (response.status === 401) throw new AuthError();
  if (!response.ok) throw new ApiError(response.status, await response.json().catch(() => null));
  const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buffer += value;
    let end;
    while ((end = buffer.indexOf("\n\n")) >= 0) {
      const block = buffer.slice(0, end);
      buffer = buffer.slice(end + 2);
      let event = "message";
      const data = [];
      for (const line of block.split("\n")) {
        if (line.startsWith("event:")) event = line.slice(6).trim();
        else if (line.startsWith("data:")) data.push(line.slice(5).replace(/^ /, ""));
      }
      if (data.length) onEvent(event, data.join("\n"));
    }
  }
}

// ---- small helpers --------------------------------------------------------

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v;
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (v !== undefined && v !== null) node.setAttribute(k, v);
  }
  for (const c of children.flat()) {
    if (c !== null && c !== undefined) node.append(c instanceof Node ? c : String(c));
  }
  return node;
}

function svg(tag, attrs = {}) {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  return node;
}

const fmt = (v, digits = 3) => (v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits));
const pm = (v, s, digits) => (v === null || v === undefined ? "–" : `${fmt(v, digits)} ± ${fmt(s, digits)}`);
const badge = (status) => el("span", { class: `badge ${status}`, "data-status": status }, status.replaceAll("_", " "));
const showError = (where, e) => { where.replaceChildren(el("span", { class: "error" }, e.message)); };

// ---- routing --------------------------------------------------------------

let pageAbort = null;

function route() {
  pageAbort?.abort();
  pageAbort = new AbortController();
  const signal = pageAbort.signal;
  const hash = location.hash.replace(/^#/, "") || "/";
  const parts = hash.split("/").filter(Boolean).map(decodeURIComponent);
  document.querySelectorAll("nav a").forEach((a) => {
    a.classList.toggle("active", a.dataset.nav === (parts[0] === "calibrations" ? "calibrations" : "sessions"));
  });
  let page;
  if (parts[0] === "sessions" && parts[1]) page = sessionPage(parts[1], signal);
  else if (parts[0] === "calibrations" && parts[1]) page = calibrationPage(parts[1], signal);
  else if (parts[0] === "calibrations") page = calibrationsPage(signal);
  else page = sessionsPage(signal);
  page.catch((e) => {
    if (signal.aborted || e.name === "AbortError") return;
    if (e instanceof AuthError) tokenPrompt();
    else showError(main, e);
  });
}

function tokenPrompt() {
  pageAbort?.abort();
  const input = el("input", { type: "password", id: "token", autocomplete: "current-password", size: 40, "aria-label": "token" });
  const had = sessionStorage.getItem(TOKEN_KEY);
  main.replaceChildren(el("div", { class: "token-box", id: "token-prompt" },
    el("h1", {}, "This server needs a token"),
    el("p", { class: "help" }, had
      ? "The token given was refused. Enter the token semdepth serve was started with (--token or SEMDEPTH_TOKEN)."
      : "Enter the token semdepth serve was started with (--token or SEMDEPTH_TOKEN). It is kept for this browser tab only."),
    el("form", { class: "inline", onsubmit: (ev) => {
      ev.preventDefault();
      sessionStorage.setItem(TOKEN_KEY, input.value.trim());
      route();
    } }, input, el("button", { type: "submit" }, "Continue"))));
  input.focus();
}

function sleep(ms, signal) {
  return new Promise((resolve, reject) => {
    const t = setTimeout(resolve, ms);
    signal?.addEventListener("abort", () => { clearTimeout(t); reject(new DOMException("aborted", "AbortError")); }, { once: true });
  });
}

// ---- sessions list --------------------------------------------------------

async function sessionsPage(signal) {
  const body = el("tbody");
  const note = el("p", { class: "muted" });
  main.replaceChildren(
    el("h1", {}, "Sessions"),
    el("table", { id: "sessions" },
      el("thead", {}, el("tr", {},
        el("th", {}, "Session"), el("th", {}, "State"), el("th", { class: "num" }, "Frames"),
        el("th", {}, "Calibration"), el("th", { class: "num" }, "Last disparity (px)"), el("th", { class: "num" }, "Last z (µm)"))),
      body),
    note);
  const lastResult = new Map(); // id -> [frames, result]
  for (;;) {
    const { sessions } = await api("/v1/sessions", { signal });
    statusLine.textContent = `${sessions.length} session${sessions.length === 1 ? "" : "s"}`;
    note.textContent = sessions.length ? "" : "No sessions yet: create one over the API (POST /v1/sessions) and it appears here.";
    for (const s of sessions.slice(0, 200)) {
      const known = lastResult.get(s.id);
      if (s.frames > 0 && (!known || known[0] !== s.frames)) {
        try {
          const page = await api(`/v1/sessions/${encodeURIComponent(s.id)}/results?since=${s.frames - 1}&limit=1&contours=false`, { signal });
          lastResult.set(s.id, [s.frames, page.results.at(-1) ?? null]);
        } catch (e) {
          if (e instanceof AuthError || e.name === "AbortError") throw e;
        }
      }
    }
    body.replaceChildren(...sessions.map((s) => {
      const r = lastResult.get(s.id)?.[1];
      return el("tr", { "data-session": s.id },
        el("td", {}, el("a", { href: `#/sessions/${encodeURIComponent(s.id)}` }, s.name ?? s.id), el("div", { class: "muted" }, `created ${created(s)}${s.name ? ` · ${s.id}` : ""}`)),
        el("td", {}, badge(s.state)),
        el("td", { class: "num" }, s.frames),
        el("td", {}, s.calibration_id ? el("a", { href: `#/calibrations/${encodeURIComponent(s.calibration_id)}` }, s.calibration_id) : el("span", { class: "muted" }, "none")),
        el("td", { class: "num" }, r ? pm(r.disparity_axis_px, r.disparity_std_px, 2) : "–"),
        el("td", { class: "num" }, r ? pm(r.z_um, r.z_std_um, 2) : "–"));
    }));
    await sleep(2000, signal);
  }
}

/** When a session was created, to the minute (UTC): two sessions of one name tell apart. */
function created(s) {
  return s.created_at ? `${s.created_at.slice(0, 16).replace("T", " ")} UTC` : "?";
}

// ---- one session ----------------------------------------------------------

async function sessionPage(id, signal) {
  const path = `/v1/sessions/${encodeURIComponent(id)}`;
  let session = await api(path, { signal });
  const title = el("h1", {});
  const meta = el("p", { class: "muted" });
  const message = el("p", { id: "message", class: "help" }, "Drag a box around the object, or click on it, in the left image to point semdepth at it; draw round it with the lasso; click what is not it with \u201cnot this\u201d.");
  const left = imageView("left", true);
  const tools = el("div", { class: "tools", id: "tools", role: "radiogroup" }, ...[["box", "box or point"], ["lasso", "lasso"], ["exclude", "not this"]].map(([tool, label]) =>
    el("label", {}, el("input", { type: "radio", name: "tool", value: tool, id: `tool-${tool}`, ...(tool === "box" ? { checked: "" } : {}) }), ` ${label}`)));
  tools.addEventListener("change", (ev) => { left.tool = ev.target.value; });
  const right = imageView("right", false);
  const numbers = el("div", { class: "numbers", id: "numbers" });
  const zPlot = plotPanel("z (µm), ±1 standard error shaded", "plot-z", "µm");
  const dPlot = plotPanel("disparity across the tilt axis (px), ±1 standard error shaded", "plot-disparity", "px");
  main.replaceChildren(title, meta, message, tools, el("div", { class: "views" }, left.node, right.node), numbers, zPlot.node, dPlot.node);

  const series = []; // {frame, status, d, ds, z, zs}
  let latest = null;
  let pendingHint = null;

  const renderHeader = () => {
    title.replaceChildren(session.name ?? session.id, " ", badge(session.state));
    meta.replaceChildren(`${session.id} · ${session.frames} frames · calibration `,
      session.calibration_id ? el("a", { href: `#/calibrations/${encodeURIComponent(session.calibration_id)}` }, session.calibration_id) : "none",
      hintText(session.init) ? ` · hint ${hintText(session.init)}` : "");
  };
  const point = (r) => {
    const good = r.status === "tracked" || r.status === "initialised";
    return { frame: r.frame, status: r.status, d: good ? r.disparity_axis_px : null, ds: r.disparity_std_px, z: good ? r.z_um : null, zs: r.z_std_um };
  };
  const addToSeries = (r) => {
    if (series.length && r.frame <= series.at(-1).frame) return;
    series.push(point(r));
    if (series.length > PLOT_POINTS) series.shift();
  };
  const renderResult = (r) => {
    latest = r;
    const colour = r.status === "tracked" || r.status === "initialised" ? PALETTE[0] : LOST;
    left.contour(r.left?.contour, colour);
    right.contour(r.right?.contour, colour);
    // The other objects of a session of several, each in its own colour.
    const measured = (o) => o.status === "tracked" || o.status === "initialised";
    const others = (r.objects ?? []).slice(1).map((o, k) => ({ o, colour: measured(o) ? PALETTE[(k + 1) % PALETTE.length] : LOST }));
    left.others(others.map(({ o, colour }) => ({ name: o.name, points: o.left?.contour, colour })));
    right.others(others.map(({ o, colour }) => ({ name: o.name, points: o.right?.contour, colour })));
    const several = (r.objects ?? []).length > 1;
    const objectCells = several ? [
      classed("table", cell("objects", el("table", { class: "objects", id: "objects" }, ...r.objects.map((o, k) =>
        el("tr", { "data-object": o.name },
          el("td", {}, el("span", { class: `swatch ${measured(o) ? `c${k % PALETTE.length}` : "lost"}` }), " ", o.name),
          el("td", {}, badge(o.status)),
          el("td", { class: "num" }, pm(o.disparity_axis_px, o.disparity_std_px, 2), " px"),
          el("td", { class: "num" }, pm(o.z_um, o.z_std_um, 2), " µm")))))),
      classed("table", cell("relative height", el("table", { class: "objects", id: "relative" }, ...(r.relative ?? [])
        .filter((x) => r.objects.findIndex((o) => o.name === x.from) < r.objects.findIndex((o) => o.name === x.to))
        .map((x) => el("tr", { "data-from": x.from, "data-to": x.to },
          el("td", {}, `${x.from} − ${x.to}`),
          el("td", { class: "num" }, pm(x.disparity_axis_px, x.disparity_std_px, 3), " px"),
          el("td", { class: "num" }, pm(x.dz_um, x.dz_std_um, 3), " µm")))))),
    ] : [];
    numbers.replaceChildren(
      classed(r.reason ? "wide" : "", cell("status", badge(r.status), r.reason ? el("div", { class: "muted", id: "reason", title: r.reason }, r.reason) : null)),
      cell("frame", r.frame),
      cell("disparity (x, y) px", r.disparity_px ? `${fmt(r.disparity_px[0], 2)}, ${fmt(r.disparity_px[1], 2)}` : "–"),
      cell("disparity across the axis px", pm(r.disparity_axis_px, r.disparity_std_px, 3)),
      cell("z µm", el("span", { id: "z-value" }, pm(r.z_um, r.z_std_um, 3))),
      cell("occluded (left)", r.left ? `${Math.round(100 * r.left.occluded_fraction)} %` : "–"),
      cell("time ms (track / total)", `${fmt(r.timing_ms?.track, 1)} / ${fmt(r.timing_ms?.total, 1)}`),
      ...objectCells);
    zPlot.draw(series, "z", "zs");
    zPlot.node.hidden = !series.some((p) => p.z !== null && p.z !== undefined);
    dPlot.draw(series, "d", "ds");
  };
  // The first frame the plot holds: the history's first, or 0. Events that
  // came before the event stream was followed are fetched as a gap.
  const floor = Math.max(0, session.frames - PLOT_POINTS);
  // Events are throttled: fill in the pairs between two events from the
  // stored results (one request at a time; the plot stays complete).
  let filling = false;
  // The stored results from frame `from` up to (not including) `until`
  // merged into the plot; how many there were.
  const fill = async (from, until) => {
    const page = await api(`${path}/results?since=${from}&limit=${until - from}&contours=false`, { signal });
    const add = page.results.filter((r) => r.frame < until);
    add.forEach((r) => series.push(point(r)));
    series.sort((a, b) => a.frame - b.frame);
    while (series.length > PLOT_POINTS) series.shift();
    return add.length;
  };
  const backfill = async () => {
    if (filling) return;
    filling = true;
    try {
      if (series.length && series.length < PLOT_POINTS && series[0].frame > floor) {
        await fill(series[0].frame - Math.min(series[0].frame - floor, PLOT_POINTS), series[0].frame);
      }
      for (let i = 1; i < series.length; i++) {
        if (series[i].frame > series[i - 1].frame + 1) {
          const added = await fill(series[i - 1].frame + 1, series[i].frame);
          i = 0;
          if (!added) break;
        }
      }
      if (latest) renderResult(latest);
    } catch (e) {
      if (e instanceof AuthError) tokenPrompt();
    } finally {
      filling = false;
    }
  };

  // The history first (the last PLOT_POINTS pairs), then live events.
  if (session.frames > 0) {
    const page = await api(`${path}/results?since=${floor}&limit=${PLOT_POINTS}&contours=false`, { signal });
    page.results.forEach(addToSeries);
    const last = page.results.at(-1);
    if (last) renderResult(last);
  }
  renderHeader();
  if (session.frames > 0) {
    left.refresh(path, signal);
    right.refresh(path, signal);
  }

  left.onHint = async (hint) => {
    // "Not this" keeps the box and the polarity the session has (hints go
    // as a set) and its other "not this" points; a point or an outline
    // named what is now refused, and goes.
    if (hint.exclude) {
      const keep = Object.fromEntries(["roi", "polarity"].filter((k) => session.init?.[k] != null && session.init[k] !== "any").map((k) => [k, session.init[k]]));
      hint = { ...keep, exclude: [...(session.init?.exclude ?? []), ...hint.exclude] };
    }
    pendingHint = hint;
    left.showHint(hint);
    try {
      session = await api(`${path}/reinit`, { method: "POST", body: { init: hint }, signal });
      message.textContent = `The next pair initialises with ${hintText(hint)}.`;
      message.className = "help";
      renderHeader();
    } catch (e) {
      if (e instanceof AuthError) return tokenPrompt();
      message.textContent = `Not re-initialised: ${e.message}`;
      message.className = "error";
      left.showHint(null);
      pendingHint = null;
    }
  };

  let lastSessionFetch = 0;
  const onEvent = (event, data) => {
    if (event !== "result") return;
    const r = JSON.parse(data);
    if (latest && r.frame < latest.frame) return;
    // A gap: pairs since the last one plotted (or, before any, since the
    // history ended) that no event brought.
    const gap = r.frame > (series.length ? series.at(-1).frame + 1 : floor);
    addToSeries(r);
    renderResult(r);
    if (gap) backfill();
    if (pendingHint && r.status === "initialised") {
      message.textContent = `Initialised with ${hintText(pendingHint)} at frame ${r.frame}.`;
      pendingHint = null;
      left.showHint(null);
    }
    left.refresh(path, signal);
    right.refresh(path, signal);
    session.frames = r.frame + 1;
    session.state = r.status === "lost" ? "lost" : "tracking";
    renderHeader();
    if (performance.now() - lastSessionFetch > 5000) {
      lastSessionFetch = performance.now();
      api(path, { signal }).then((s) => { session = s; renderHeader(); }).catch(() => {});
    }
  };
  // Follow the events; when the stream ends (a server restart, a network
  // glitch), say so and follow again every 2 s until the session is gone.
  for (;;) {
    try {
      await followEvents(`${path}/events`, onEvent, signal);
    } catch (e) {
      if (e instanceof AuthError || e.name === "AbortError") throw e;
      if (e instanceof ApiError && e.status === 404) {
        message.textContent = "The session was deleted.";
        return;
      }
    }
    message.textContent = "Connection to the server lost; reconnecting…";
    await sleep(2000, signal);
    try {
      session = await api(path, { signal });
      renderHeader();
      message.textContent = "Reconnected.";
    } catch (e) {
      if (e instanceof AuthError || e.name === "AbortError") throw e;
      if (e instanceof ApiError && e.status === 404) {
        message.textContent = "The session was deleted.";
        return;
      }
    }
  }
}

function hintText(init) {
  if (!init) return "";
  const not = init.exclude?.length ? `${init.exclude.length} point${init.exclude.length > 1 ? "s" : ""} not the object` : "";
  const named = init.roi ? `box ${init.roi.map((v) => Math.round(v)).join(", ")}`
    : init.point ? `point ${init.point.map((v) => Math.round(v)).join(", ")}`
    : init.outline ? `outline of ${init.outline.length} vertices` : "";
  return [named, not].filter(Boolean).join(", ");
}

function cell(key, ...value) {
  return el("div", {}, el("span", { class: "k" }, key), el("span", { class: "v" }, ...value));
}

// `node` with the class `name` (none when empty): a card that spans columns.
function classed(name, node) {
  if (name) node.className = name;
  return node;
}

// An image with its contour drawn over it as SVG, in the frame's pixel
// coordinates; the left one takes a box or a point.
function imageView(side, pointable) {
  const img = el("img", { alt: `${side} image`, id: `img-${side}`, draggable: "false" });
  const overlay = svg("svg", { id: `overlay-${side}`, preserveAspectRatio: "none" });
  const polygon = svg("polygon", { class: "contour", "data-side": side });
  const hintRect = svg("rect", { class: "hint", visibility: "hidden" });
  const hintPath = svg("polygon", { class: "hint", id: `lasso-${side}`, visibility: "hidden" });
  const excluded = svg("g", { class: "excluded" });
  const othersGroup = svg("g", { class: "others" });
  overlay.append(othersGroup, polygon, hintRect, hintPath, excluded);
  const empty = el("div", { class: "empty" }, "No image yet");
  const node = el("div", { class: `view${pointable ? " pointable" : ""}`, id: `view-${side}` }, img, overlay, empty, el("span", { class: "label" }, side === "left" ? "left view" : "right view"));
  const view = { node, onHint: null, frame: null, tool: "box" };
  let box = null; // [x0, y0, width, height] of the image in frame coordinates
  let busy = false, again = false, url = null;

  view.refresh = async (path, signal) => {
    if (busy) { again = true; return; }
    busy = true;
    try {
      do {
        again = false;
        const response = await api(`${path}/frames/latest/${side}?max_side=${IMAGE_SIDE}`, { signal, raw: true });
        const [w, h, f] = ["x-frame-width", "x-frame-height", "x-frame-scale"].map((k) => Number(response.headers.get(k)));
        const blob = await response.blob();
        if (url) URL.revokeObjectURL(url);
        url = URL.createObjectURL(blob);
        img.src = url;
        view.frame = Number(response.headers.get("x-frame"));
        node.dataset.frame = view.frame;
        box = [-0.5, -0.5, Math.ceil(w / f) * f, Math.ceil(h / f) * f];
        overlay.setAttribute("viewBox", box.join(" "));
        empty.hidden = true;
      } while (again);
    } catch (e) {
      if (e instanceof AuthError) tokenPrompt();
      else if (e.name !== "AbortError") { empty.hidden = false; empty.textContent = e.message; }
    } finally {
      busy = false;
    }
  };
  view.contour = (points, colour) => {
    polygon.setAttribute("points", (points ?? []).map((p) => `${p[0]},${p[1]}`).join(" "));
    polygon.setAttribute("stroke", colour);
  };
  view.others = (list) => {
    othersGroup.replaceChildren(...list.map(({ name, points, colour }) => {
      const p = svg("polygon", { class: "contour", "data-object": name, stroke: colour });
      p.setAttribute("points", (points ?? []).map((q) => `${q[0]},${q[1]}`).join(" "));
      return p;
    }));
  };
  view.showHint = (hint) => {
    hintRect.setAttribute("visibility", "hidden");
    hintPath.setAttribute("visibility", "hidden");
    excluded.replaceChildren(...(hint?.exclude ?? []).map(([x, y]) => svg("path", { class: "not-this", d: `M${x - 6},${y - 6}L${x + 6},${y + 6}M${x - 6},${y + 6}L${x + 6},${y - 6}` })));
    if (hint?.outline) {
      hintPath.setAttribute("points", hint.outline.map((p) => p.join(",")).join(" "));
      hintPath.setAttribute("visibility", "visible");
    } else if (hint?.roi || hint?.point) {
      const [x, y, w, h] = hint.roi ?? [hint.point[0] - 4, hint.point[1] - 4, 8, 8];
      Object.entries({ x, y, width: w, height: h, visibility: "visible" }).forEach(([k, v]) => hintRect.setAttribute(k, v));
    }
  };
  if (pointable) {
    const toFrame = (ev) => {
      const p = overlay.createSVGPoint();
      p.x = ev.clientX; p.y = ev.clientY;
      const q = p.matrixTransform(overlay.getScreenCTM().inverse());
      return [q.x, q.y];
    };
    // The lasso keeps a vertex each time the pointer has moved 3 screen
    // pixels; a closing stretch back to the start is implied.
    let start = null, startScreen = null, lasso = [], lastScreen = null;
    const round = (p) => p.map((v) => Math.round(v * 10) / 10);
    overlay.addEventListener("pointerdown", (ev) => {
      if (!box) return;
      ev.preventDefault();
      overlay.setPointerCapture(ev.pointerId);
      start = toFrame(ev);
      startScreen = lastScreen = [ev.clientX, ev.clientY];
      lasso = [round(start)];
    });
    overlay.addEventListener("pointermove", (ev) => {
      if (!start) return;
      const p = toFrame(ev);
      if (view.tool === "lasso") {
        if (Math.hypot(ev.clientX - lastScreen[0], ev.clientY - lastScreen[1]) >= 3) {
          lasso.push(round(p));
          lastScreen = [ev.clientX, ev.clientY];
          view.showHint({ outline: lasso });
        }
      } else if (view.tool === "box") {
        view.showHint({ roi: [Math.min(start[0], p[0]), Math.min(start[1], p[1]), Math.abs(p[0] - start[0]), Math.abs(p[1] - start[1])] });
      }
    });
    overlay.addEventListener("pointerup", (ev) => {
      if (!start) return;
      const p = toFrame(ev);
      const moved = Math.hypot(ev.clientX - startScreen[0], ev.clientY - startScreen[1]);
      let hint;
      if (view.tool === "exclude") hint = { exclude: [round(p)] };
      else if (view.tool === "lasso") hint = lasso.length >= 3 ? { outline: lasso.length > 4000 ? lasso.filter((_, i) => i % Math.ceil(lasso.length / 4000) === 0) : lasso } : null;
      else hint = moved < 5
        ? { point: [Math.round(p[0]), Math.round(p[1])] }
        : { roi: [Math.round(Math.min(start[0], p[0])), Math.round(Math.min(start[1], p[1])), Math.round(Math.abs(p[0] - start[0])), Math.round(Math.abs(p[1] - start[1]))] };
      start = null;
      if (hint) view.onHint?.(hint);
      else view.showHint(null);
    });
  }
  return view;
}

// Round tick values between lo and hi: the widest step of 1, 2 or 5 times a
// power of ten (at least `least`) that gives n - 1 ticks or more.
function ticks(lo, hi, n, least = 0) {
  const mag = 10 ** Math.floor(Math.log10(Math.max(hi - lo, 1e-12) / n));
  const count = (s) => Math.floor(hi / s + 1e-9) - Math.ceil(lo / s - 1e-9) + 1;
  const steps = [10, 5, 2, 1, 0.5].map((m) => m * mag).filter((s) => s >= least);
  const step = steps.find((s) => count(s) >= n - 1) ?? steps.at(-1) ?? least;
  const values = [];
  for (let k = Math.ceil(lo / step - 1e-9); k * step <= hi + step * 1e-9; k++) values.push(Number((k * step).toPrecision(12)));
  return { values, digits: Math.max(0, -Math.floor(Math.log10(step) + 1e-9)) };
}

// A plot of one series over frames with its +-1 std band; lost pairs are
// red marks on the frame axis. Axes: frames along x, `unit` along y.
function plotPanel(label, id, unit) {
  const plot = svg("svg", { id, viewBox: "0 0 1000 222" });
  const node = el("div", { class: "plot" }, el("div", { class: "title" }, label), plot);
  return {
    node,
    draw(series, key, stdKey) {
      const points = series.filter((p) => p[key] !== null && p[key] !== undefined);
      plot.replaceChildren();
      plot.dataset.points = points.length;
      if (!series.length) return;
      const f0 = series[0].frame, f1 = Math.max(series.at(-1).frame, f0 + 1);
      let lo = Infinity, hi = -Infinity;
      for (const p of points) {
        const s = p[stdKey] ?? 0;
        lo = Math.min(lo, p[key] - s); hi = Math.max(hi, p[key] + s);
      }
      if (!points.length) { lo = 0; hi = 1; }
      if (hi - lo < 1e-6) { lo -= 0.5; hi += 0.5; }
      const pad = (hi - lo) * 0.08;
      lo -= pad; hi += pad;
      const X = (f) => 70 + ((f - f0) / (f1 - f0)) * 915;
      const Y = (v) => 185 - ((v - lo) / (hi - lo)) * 175;
      plot.append(svg("line", { class: "axis", x1: 70, x2: 985, y1: 185, y2: 185 }));
      const yTicks = ticks(lo, hi, 4);
      for (const v of yTicks.values) {
        const t = svg("text", { class: "tick", x: 62, y: Y(v) + 4, "text-anchor": "end" });
        t.textContent = v.toFixed(yTicks.digits);
        plot.append(t, svg("line", { class: "grid", x1: 70, x2: 985, y1: Y(v), y2: Y(v) }));
      }
      const xTicks = ticks(f0, f1, 8, 1);
      for (const f of xTicks.values) {
        const t = svg("text", { class: "tick", x: X(f), y: 201, "text-anchor": "middle" });
        t.textContent = String(f);
        plot.append(t, svg("line", { class: "axis", x1: X(f), x2: X(f), y1: 185, y2: 190 }));
      }
      const xName = svg("text", { class: "axis-name", x: 985, y: 218, "text-anchor": "end" });
      xName.textContent = "frame";
      const yName = svg("text", { class: "axis-name", x: 4, y: 12 });
      yName.textContent = unit;
      plot.append(xName, yName);
      // Runs of consecutive good points: a gap where a pair was lost, and
      // a new run (after a dashed line) where the tracker initialised again.
      const runs = [];
      let run = [];
      for (const p of series) {
        if (p.status === "initialised" && p !== series[0]) {
          if (run.length) runs.push(run);
          run = [];
          plot.append(svg("line", { class: "restart", x1: X(p.frame), x2: X(p.frame), y1: 10, y2: 185, "stroke-dasharray": "4 4" }));
        }
        if (p[key] === null || p[key] === undefined) { if (run.length) runs.push(run); run = []; } else run.push(p);
      }
      if (run.length) runs.push(run);
      for (const r of runs) {
        const upper = r.map((p) => `${X(p.frame)},${Y(p[key] + (p[stdKey] ?? 0))}`);
        const lower = r.slice().reverse().map((p) => `${X(p.frame)},${Y(p[key] - (p[stdKey] ?? 0))}`);
        if (r.length > 1) plot.append(svg("polygon", { class: "band", points: [...upper, ...lower].join(" ") }));
        plot.append(svg("polyline", { class: "line", points: r.map((p) => `${X(p.frame)},${Y(p[key])}`).join(" ") }));
        const end = r.at(-1);
        plot.append(svg("circle", { class: "dot", cx: X(end.frame), cy: Y(end[key]), r: 3 }));
      }
      for (const p of series) {
        if (p.status === "lost") plot.append(svg("rect", { class: "lostmark", x: X(p.frame) - 1.5, y: 186, width: 3, height: 6 }));
      }
    },
  };
}

// ---- calibrations ---------------------------------------------------------

async function calibrationsPage(signal) {
  const { calibrations } = await api("/v1/calibrations", { signal });
  statusLine.textContent = `${calibrations.length} calibration${calibrations.length === 1 ? "" : "s"}`;
  main.replaceChildren(el("h1", {}, "Calibrations"),
    calibrations.length
      ? el("table", { id: "calibrations" },
        el("thead", {}, el("tr", {}, el("th", {}, "Calibration"), el("th", {}, "Model"), el("th", { class: "num" }, "Version"), el("th", { class: "num" }, "Samples"), el("th", { class: "num" }, "R²"))),
        el("tbody", {}, calibrations.map((c) => el("tr", {},
          el("td", {}, el("a", { href: `#/calibrations/${encodeURIComponent(c.id)}` }, c.name ?? c.id)),
          el("td", {}, c.model), el("td", { class: "num" }, c.version),
          el("td", { class: "num" }, c.samples?.length ?? "–"), el("td", { class: "num" }, fmt(c.r_squared, 4))))))
      : el("p", { class: "muted" }, "No calibrations yet: create one over the API (POST /v1/calibrations)."));
}

async function calibrationPage(id, signal) {
  const path = `/v1/calibrations/${encodeURIComponent(id)}`;
  const c = await api(path, { signal });
  const { sessions } = await api("/v1/sessions", { signal });
  const message = el("p", { id: "message", class: "help" });
  const facts = el("div", { class: "numbers" },
    cell("model", c.model + (c.degree ? ` (degree ${c.degree})` : "")),
    cell("version", c.version),
    cell("tilt axis", `${fmt(c.tilt_axis_deg, 1)}°`),
    cell("coefficients", c.coefficients.length ? c.coefficients.map((v) => v.toPrecision(5)).join(", ") : "from each pair"),
    cell("R²", el("span", { id: "r-squared" }, fmt(c.r_squared, 5))),
    cell("residual RMS µm", fmt(c.residual_rms_um, 4)));
  const pending = c.pending ? el("p", { class: "error" }, c.pending) : null;
  const samples = c.samples ?? [];
  const table = el("table", { id: "samples" },
    el("thead", {}, el("tr", {}, el("th", { class: "num" }, "#"), el("th", { class: "num" }, "disparity px"), el("th", { class: "num" }, "z µm"), el("th", { class: "num" }, "residual µm"), el("th", {}, "from"))),
    el("tbody", {}, samples.map((s, i) => el("tr", {},
      el("td", { class: "num" }, i), el("td", { class: "num" }, fmt(s.disparity_px, 3)), el("td", { class: "num" }, fmt(s.z_um, 3)),
      el("td", { class: "num" }, fmt(c.residuals_um?.[i], 4)), el("td", {}, s.session_id ?? "typed in")))));
  const zInput = el("input", { type: "number", step: "any", id: "sample-z", placeholder: "z µm", required: "" });
  const withSession = sessions.filter((s) => s.latest_disparity_px);
  const pick = el("select", { id: "sample-session" }, withSession.map((s) => el("option", { value: s.id }, `${s.name ?? s.id} (created ${created(s)}${s.name ? `, ${s.id}` : ""}; latest ${fmt(s.latest_disparity_px[0], 2)}, ${fmt(s.latest_disparity_px[1], 2)} px)`)));
  const form = c.model === "fit"
    ? el("form", { class: "inline", id: "add-sample", onsubmit: async (ev) => {
      ev.preventDefault();
      try {
        await api(`/v1/sessions/${encodeURIComponent(pick.value)}/calibration-samples`, { method: "POST", body: { calibration_id: id, z_um: Number(zInput.value) }, signal });
        route();
      } catch (e) {
        if (e instanceof AuthError) return tokenPrompt();
        message.textContent = e.message;
        message.className = "error";
      }
    } }, "Add a sample: the latest disparity of", pick, "at", zInput, "µm", el("button", { type: "submit", disabled: withSession.length ? null : "" }, "Add"))
    : el("p", { class: "help" }, "A geometric calibration has no samples.");
  main.replaceChildren(...[el("h1", {}, c.name ?? c.id), facts, pending, curvePlot(c), el("h2", {}, "Samples"), table, form, message].filter(Boolean));
}

// The samples and the fitted curve z(d).
function curvePlot(c) {
  const samples = c.samples ?? [];
  const plot = svg("svg", { id: "plot-calibration", viewBox: "0 0 1000 280" });
  const node = el("div", { class: "plot" }, el("div", { class: "title" }, "z (µm) against disparity (px)"), plot);
  if (!samples.length) return node;
  const ds = samples.map((s) => s.disparity_px), zs = samples.map((s) => s.z_um);
  let d0 = Math.min(...ds), d1 = Math.max(...ds);
  if (d1 - d0 < 1e-6) { d0 -= 1; d1 += 1; }
  const dpad = (d1 - d0) * 0.1;
  d0 -= dpad; d1 += dpad;
  const curve = (d) => c.coefficients.reduce((acc, k, i) => acc + k * d ** i, 0);
  const grid = Array.from({ length: 101 }, (_, i) => d0 + ((d1 - d0) * i) / 100);
  const all = [...zs, ...(c.coefficients.length ? grid.map(curve) : [])];
  let z0 = Math.min(...all), z1 = Math.max(...all);
  if (z1 - z0 < 1e-6) { z0 -= 1; z1 += 1; }
  const X = (d) => 50 + ((d - d0) / (d1 - d0)) * 940;
  const Y = (z) => 245 - ((z - z0) / (z1 - z0)) * 230;
  if (c.coefficients.length) plot.append(svg("polyline", { class: "line", points: grid.map((d) => `${X(d)},${Y(curve(d))}`).join(" ") }));
  for (const s of samples) plot.append(svg("circle", { cx: X(s.disparity_px), cy: Y(s.z_um), r: 5, fill: PALETTE[1], class: "sample" }));
  for (const [v, y] of [[z1, 15], [z0, 245]]) {
    const t = svg("text", { x: 4, y: y + 4 });
    t.textContent = v.toPrecision(4);
    plot.append(t);
  }
  for (const [v, anchor] of [[d0, "start"], [d1, "end"]]) {
    const t = svg("text", { x: X(v), y: 270, "text-anchor": anchor });
    t.textContent = `${v.toPrecision(4)} px`;
    plot.append(t);
  }
  return node;
}

window.addEventListener("hashchange", route);
route();
