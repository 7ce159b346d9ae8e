// machlink dashboard: one page over the daemon's own API (docs/dashboard.md).
// Everything it shows comes from GET /machines, /jobs, /locks, /whoami, /metrics,
// /jobs/{id}/path and the event stream GET /events; everything it does is an API route the
// CLI uses too. The token lives in this tab's sessionStorage and goes out as the bearer.
"use strict";

const $ = (id) => document.getElementById(id);
const TOKEN_KEY = "machlink.token";
const REFRESH_MS = 5000; // the slow read-back of machines, jobs and locks (events do the rest)
const HEALTH_MS = 10000;
const LOG_MAX = 200;
const FINAL = new Set(["completed", "failed", "cancelled"]);

const S = {
  token: null,
  who: null,
  machines: new Map(), // name -> MachineInfo, plus seenAt (ms since epoch of its last report)
  jobs: new Map(), // id -> JobRecord
  locks: new Map(), // machine -> LockInfo
  overrides: new Map(), // job -> overrides last set from here
  paths: new Map(), // job -> UnitPath (or a pending promise)
  cards: new Map(), // machine -> card elements
  rows: new Map(), // job -> table row elements
  previewJob: null, // chosen by the operator; else the newest running job
  abort: null,
  dirty: false,
  timers: [],
  conn: "off",
};

class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

async function api(method, path, body) {
  const headers = { Authorization: "Bearer " + S.token };
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const r = await fetch(path, {
    method,
    headers,
    cache: "no-store",
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await r.text();
  let v = text;
  try {
    v = text ? JSON.parse(text) : null;
  } catch (_) {
    /* plain text (metrics) */
  }
  if (!r.ok) throw new ApiError(r.status, (v && v.error) || text || r.statusText);
  return v;
}

const sleep = (ms) => new Promise((res) => setTimeout(res, ms));

// ---- words -------------------------------------------------------------------------------

function deviceState(st) {
  const s = (st && st.state) || "unknown";
  switch (s) {
    case "alarm":
      return { key: "alarm", text: "alarm" + (st.code != null ? " " + st.code : "") + (st.text ? ": " + st.text : "") };
    case "needs_operator": {
      const why = st.reason === "other" ? st.text : (st.reason || "").replace(/_/g, " ");
      return { key: "needs_operator", text: "needs operator" + (why ? ": " + why : "") };
    }
    case "not_answering":
      // the link is up, the device says nothing (the daemon pauses the job after the
      // machine's silent_timeout_s)
      return { key: s, text: "not answering for " + (st.silent_s != null ? st.silent_s : "?") + " s" };
    case "unknown":
      // some kinds (CANopen) report only while a job runs
      return { key: s, text: "no report yet" };
    default:
      return { key: s, text: s };
  }
}

function clock(ms) {
  if (ms == null) return "–";
  const s = Math.max(0, ms / 1000);
  if (s >= 3600) return Math.floor(s / 3600) + " h " + String(Math.floor((s % 3600) / 60)).padStart(2, "0") + " min";
  if (s >= 60) return Math.floor(s / 60) + " min " + String(Math.floor(s % 60)).padStart(2, "0") + " s";
  return s.toFixed(s < 10 ? 1 : 0) + " s";
}

const mm = (v) => (Math.round(v * 1000) / 1000).toFixed(3);

function canOperate(machine) {
  const w = S.who;
  if (!w) return false;
  if (w.role === "admin") return true;
  if (w.role !== "operator") return false;
  if (w.machines != null && !w.machines.includes(machine)) return false;
  const l = S.locks.get(machine);
  return !l || l.holder === w.name;
}

function notice(text) {
  $("notice").textContent = text || "";
}

function log(text, at) {
  const li = document.createElement("li");
  const t = new Date(at || Date.now());
  li.textContent = t.toLocaleTimeString([], { hour12: false }) + "  " + text;
  const ol = $("log");
  ol.prepend(li);
  while (ol.childElementCount > LOG_MAX) ol.lastElementChild.remove();
}

// ---- loading -----------------------------------------------------------------------------

async function loadMachines() {
  const list = await api("GET", "/machines");
  const now = Date.now();
  const names = new Set();
  for (const m of list) {
    names.add(m.name);
    m.seenAt = m.age_ms == null ? null : now - m.age_ms;
    S.machines.set(m.name, m);
  }
  for (const n of [...S.machines.keys()]) if (!names.has(n)) S.machines.delete(n);
}

async function loadJobs() {
  const list = await api("GET", "/jobs");
  S.jobs.clear();
  for (const j of list) S.jobs.set(j.id, j);
}

async function loadLocks() {
  const list = await api("GET", "/locks");
  S.locks.clear();
  for (const l of list) S.locks.set(l.machine, l);
}

async function loadHealth() {
  const text = await api("GET", "/metrics");
  const sums = new Map();
  for (const line of String(text).split("\n")) {
    if (!line || line.startsWith("#")) continue;
    const m = line.match(/^([a-z_]+)(\{[^}]*\})?\s+([-0-9.eE+]+|NaN)/);
    if (!m) continue;
    sums.set(m[1], (sums.get(m[1]) || 0) + (Number(m[3]) || 0));
  }
  const rows = [
    ["Link errors", "machlink_link_errors_total"],
    ["Reconnects", "machlink_link_reconnects_total"],
    ["Receive-buffer overflows", "machlink_rx_overflows_total"],
    ["Jobs submitted", "machlink_jobs_submitted_total"],
    ["Jobs finished", "machlink_jobs_finished_total"],
    ["Units acknowledged", "machlink_units_acked_total"],
    ["Jobs queued", "machlink_queue_depth"],
  ];
  const dl = $("health");
  dl.replaceChildren();
  for (const [label, name] of rows) {
    const dt = document.createElement("dt");
    dt.textContent = label;
    const dd = document.createElement("dd");
    dd.textContent = sums.has(name) ? String(sums.get(name)) : "–";
    dd.dataset.metric = name;
    dl.append(dt, dd);
  }
}

async function loadAll() {
  await Promise.all([loadMachines(), loadJobs(), loadLocks()]);
  fillMachineChoice();
  schedule();
  loadHealth().catch(() => {});
}

const pendingJobs = new Set();
function refreshJob(id) {
  if (pendingJobs.has(id)) return;
  pendingJobs.add(id);
  setTimeout(async () => {
    pendingJobs.delete(id);
    try {
      S.jobs.set(id, await api("GET", "/jobs/" + id));
      schedule();
    } catch (_) {
      /* the next refresh tells */
    }
  }, 300);
}

// ---- the event stream --------------------------------------------------------------------

function onEvent(ev) {
  switch (ev.type) {
    case "state": {
      const j = S.jobs.get(ev.job);
      const before = j && j.state;
      if (j) Object.assign(j, { state: ev.state, acked_units: ev.acked, total_units: ev.total, error: ev.error });
      refreshJob(ev.job);
      const m = S.machines.get(ev.machine);
      if (m) {
        if (!FINAL.has(ev.state) && ev.state !== "queued" && ev.state !== "interrupted") m.job = ev.job;
        else if (m.job === ev.job && ev.state !== "paused") m.job = null;
      }
      if (before !== ev.state)
        log("job " + ev.job + " on " + ev.machine + ": " + ev.state + (ev.error ? " — " + ev.error : "") + " (" + ev.acked + "/" + ev.total + ")");
      break;
    }
    case "progress": {
      const j = S.jobs.get(ev.job);
      if (j) {
        j.acked_units = ev.acked;
        j.total_units = ev.total;
      } else refreshJob(ev.job);
      break;
    }
    case "status": {
      const m = S.machines.get(ev.machine);
      if (m) {
        const was = deviceState(m.state).text;
        Object.assign(m, { state: ev.state, detail: ev.detail, position: ev.position, feed: ev.feed, seenAt: Date.now(), age_ms: 0 });
        if (ev.job != null) m.job = ev.job;
        const now = deviceState(ev.state).text;
        if (was !== now) log(ev.machine + ": " + now);
      }
      break;
    }
    case "message":
      log(ev.machine + (ev.job != null ? " (job " + ev.job + ")" : "") + ": " + ev.text);
      break;
  }
  schedule();
}

function setConn(state, text) {
  S.conn = state;
  const c = $("conn");
  c.dataset.conn = state;
  c.textContent = text;
}

async function follow(signal) {
  let delay = 1000;
  let lost = false;
  while (!signal.aborted) {
    try {
      // one controller per stream: a failed read-back ends a stream that went quiet without
      // closing (a daemon gone with its connections half open)
      S.stream = new AbortController();
      signal.addEventListener("abort", () => S.stream.abort(), { once: true });
      const r = await fetch("/events", { headers: { Authorization: "Bearer " + S.token }, cache: "no-store", signal: S.stream.signal });
      if (r.status === 401) return logout("the daemon no longer knows this token");
      if (!r.ok) throw new ApiError(r.status, r.statusText);
      await loadAll(); // after the stream is open: nothing falls between
      setConn("live", "live");
      if (lost) log("reconnected to the daemon");
      lost = false;
      delay = 1000;
      const reader = r.body.getReader();
      const dec = new TextDecoder();
      let buf = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buf += dec.decode(value, { stream: true });
        let i;
        while ((i = buf.indexOf("\n")) >= 0) {
          const line = buf.slice(0, i);
          buf = buf.slice(i + 1);
          if (line.trim()) onEvent(JSON.parse(line));
        }
      }
    } catch (e) {
      if (signal.aborted) return;
    }
    if (!lost) log("lost the daemon's event stream; reconnecting");
    lost = true;
    setConn("retry", "reconnecting…");
    await sleep(delay);
    delay = Math.min(delay * 2, 5000);
  }
}

// ---- drawing -----------------------------------------------------------------------------

function schedule() {
  if (S.dirty) return;
  S.dirty = true;
  requestAnimationFrame(() => {
    S.dirty = false;
    render();
  });
}

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text != null) e.textContent = text;
  return e;
}

function button(label, action, cls) {
  const b = el("button", cls, label);
  b.type = "button";
  b.dataset.action = action;
  return b;
}

function card(name) {
  let c = S.cards.get(name);
  if (c) return c;
  const root = el("article", "machine");
  root.dataset.machine = name;
  const h = el("h3");
  const title = el("span", null, name);
  const link = el("span", "link");
  h.append(title, link);
  const state = el("span", "state");
  const detail = el("div", "detail");
  const dl = el("dl");
  const field = (label) => {
    dl.append(el("dt", null, label));
    const dd = el("dd");
    dl.append(dd);
    return dd;
  };
  const job = field("Job");
  const pos = field("Position");
  const feed = field("Feed");
  const ovr = field("Overrides");
  const seen = field("Last report");
  const prog = el("progress");
  prog.max = 1;
  prog.value = 0;
  const acts = el("div", "actions");
  const b = {
    pause: button("Pause", "pause", "primary"),
    resume: button("Resume", "resume", "primary"),
    cancel: button("Cancel", "cancel", "danger"),
    slower: button("Feed −10%", "feed-down"),
    faster: button("Feed +10%", "feed-up"),
    unlock: button("Unlock", "unlock"),
    home: button("Home", "home"),
    lock: button("Lock", "lock"),
    release: button("Release", "release"),
    brk: button("Break lock", "break", "danger"),
  };
  for (const k in b) {
    b[k].dataset.machine = name;
    acts.append(b[k]);
  }
  b.slower.setAttribute("aria-label", "Feed override down 10 percent on " + name);
  b.faster.setAttribute("aria-label", "Feed override up 10 percent on " + name);
  root.append(h, state, detail, dl, prog, acts);
  c = { root, link, state, detail, job, pos, feed, ovr, seen, prog, b };
  S.cards.set(name, c);
  $("machines").append(root);
  return c;
}

function renderMachines() {
  const now = Date.now();
  for (const [name, m] of S.machines) {
    const c = card(name);
    const ds = deviceState(m.state);
    const j = m.job != null ? S.jobs.get(m.job) : null;
    let key = ds.key;
    let text = ds.text;
    if (key === "offline") text = "offline" + (m.seenAt ? ", last report " + clock(now - m.seenAt) + " ago" : ", never reported");
    if (c.root.dataset.state !== key) c.root.dataset.state = key;
    setText(c.state, text);
    setText(c.link, m.link);
    setText(c.detail, m.detail || "");
    setText(c.job, j ? "#" + j.id + " " + j.file_name + " (" + j.state + ")" : m.job != null ? "#" + m.job : "none" + (m.queued ? ", " + m.queued + " queued" : ""));
    setText(c.pos, m.position ? "X " + mm(m.position[0]) + "  Y " + mm(m.position[1]) + "  Z " + mm(m.position[2]) : "–");
    setText(c.feed, m.feed != null ? Math.round(m.feed) + " mm/min" : "–");
    const o = j && S.overrides.get(j.id);
    setText(c.ovr, o ? "feed " + o.feed + " %, spindle " + o.spindle + " %, rapid " + o.rapid + " %" : "as programmed");
    setText(c.seen, m.seenAt ? clock(now - m.seenAt) + " ago" : "never");
    c.prog.value = j && j.total_units ? j.acked_units / j.total_units : 0;
    c.prog.setAttribute("aria-label", j ? "job " + j.id + ": " + j.acked_units + " of " + j.total_units + " units" : "no job");
    const may = canOperate(name);
    const running = j && j.state === "running";
    const paused = j && j.state === "paused";
    const lock = S.locks.get(name);
    const admin = S.who && S.who.role === "admin";
    const mayGrant = S.who && (admin || (S.who.role === "operator" && (S.who.machines == null || S.who.machines.includes(name))));
    c.b.pause.disabled = !(may && running);
    c.b.pause.dataset.job = j ? j.id : "";
    c.b.resume.disabled = !(may && paused);
    c.b.resume.dataset.job = j ? j.id : "";
    c.b.cancel.disabled = !(may && (running || paused));
    c.b.cancel.dataset.job = j ? j.id : "";
    c.b.slower.disabled = c.b.faster.disabled = !(may && running);
    c.b.slower.dataset.job = c.b.faster.dataset.job = j ? j.id : "";
    c.b.unlock.disabled = c.b.home.disabled = !(may && !j);
    c.b.lock.disabled = !(may && !(lock && lock.explicit && lock.holder === S.who.name));
    c.b.release.disabled = !(mayGrant && lock && (lock.holder === S.who.name || admin));
    c.b.brk.disabled = !(admin && lock && lock.holder !== S.who.name);
    c.b.brk.hidden = !admin;
  }
  for (const [name, c] of S.cards)
    if (!S.machines.has(name)) {
      c.root.remove();
      S.cards.delete(name);
    }
}

function setText(e, t) {
  if (e.textContent !== t) e.textContent = t;
}

function renderJobs() {
  const body = $("jobs").tBodies[0];
  const list = [...S.jobs.values()].sort((a, b) => b.id - a.id).slice(0, 60);
  const keep = new Set(list.map((j) => j.id));
  for (const [id, r] of S.rows)
    if (!keep.has(id)) {
      r.tr.remove();
      S.rows.delete(id);
    }
  let before = null;
  for (let i = list.length - 1; i >= 0; i--) {
    const j = list[i];
    let r = S.rows.get(j.id);
    if (!r) {
      const tr = el("tr");
      tr.dataset.job = j.id;
      const cells = [0, 1, 2, 3, 4, 5, 6, 7].map(() => el("td"));
      tr.append(...cells);
      const prog = el("progress");
      prog.max = 1;
      const ptext = el("span");
      cells[4].append(prog, " ", ptext);
      const acts = el("div", "actions");
      const b = {
        pause: button("Pause", "pause"),
        resume: button("Resume", "resume"),
        cancel: button("Cancel", "cancel", "danger"),
        show: button("Show", "show"),
      };
      for (const k in b) {
        b[k].dataset.job = j.id;
        b[k].setAttribute("aria-label", b[k].textContent + " job " + j.id);
        acts.append(b[k]);
      }
      // choosing what the preview draws is no action on the daemon
      delete b.show.dataset.action;
      b.show.dataset.view = "show";
      cells[7].append(acts);
      r = { tr, cells, prog, ptext, b };
      S.rows.set(j.id, r);
    }
    if (r.tr.nextSibling !== before || r.tr.parentNode !== body) body.insertBefore(r.tr, before);
    before = r.tr;
    r.tr.dataset.jobState = j.state;
    setText(r.cells[0], "#" + j.id);
    setText(r.cells[1], j.machine);
    setText(r.cells[2], j.file_name + " · " + j.op);
    setText(r.cells[3], j.state + (j.error ? ": " + j.error : j.note && j.state !== "completed" ? ": " + j.note : ""));
    r.prog.value = j.total_units ? j.acked_units / j.total_units : 0;
    r.prog.setAttribute("aria-label", "job " + j.id + " progress");
    setText(r.ptext, j.acked_units + " / " + j.total_units);
    setText(r.cells[5], clock(j.elapsed_ms));
    setText(r.cells[6], FINAL.has(j.state) ? "–" : clock(j.eta_ms));
    const may = canOperate(j.machine);
    r.b.pause.disabled = !(may && j.state === "running");
    r.b.resume.disabled = !(may && ["paused", "interrupted", "failed", "cancelled"].includes(j.state));
    r.b.cancel.disabled = !(may && ["queued", "running", "paused", "interrupted"].includes(j.state));
  }
}

function previewTarget() {
  if (S.previewJob != null && S.jobs.has(S.previewJob)) return S.jobs.get(S.previewJob);
  let best = null;
  for (const j of S.jobs.values())
    if ((j.state === "running" || j.state === "paused") && (!best || j.id > best.id)) best = j;
  return best;
}

function renderPreviewChoice() {
  const sel = $("preview-job");
  const open = [...S.jobs.values()].filter((j) => !FINAL.has(j.state) || j.id === S.previewJob).sort((a, b) => b.id - a.id);
  const want = ["", ...open.map((j) => String(j.id))];
  const have = [...sel.options].map((o) => o.value);
  if (want.join() !== have.join()) {
    sel.replaceChildren();
    sel.append(new Option("the running job", ""));
    for (const j of open) sel.append(new Option("#" + j.id + " " + j.file_name + " on " + j.machine, String(j.id)));
  }
  sel.value = S.previewJob == null ? "" : String(S.previewJob);
}

const SVGNS = "http://www.w3.org/2000/svg";
function svgPath(cls) {
  const p = document.createElementNS(SVGNS, "path");
  p.setAttribute("class", cls);
  p.setAttribute("vector-effect", "non-scaling-stroke");
  p.setAttribute("stroke-width", cls === "done" ? "3" : "1.5");
  return p;
}

function pathData(path, upto, cutOnly) {
  let d = "";
  const pts = path.points;
  for (let k = 1; k < upto && k < pts.length; k++) {
    if (path.cut[k] === cutOnly) d += "M" + pts[k - 1][0] + " " + pts[k - 1][1] + "L" + pts[k][0] + " " + pts[k][1];
  }
  return d;
}

function drawPath(svg, path, acked) {
  if (!svg.firstChild || svg.dataset.drawn !== String(path.total) + ":" + path.points.length) {
    const [x0, y0, x1, y1] = path.bounds;
    const w = Math.max(x1 - x0, 1),
      h = Math.max(y1 - y0, 1),
      pad = Math.max(w, h) * 0.04;
    svg.setAttribute("viewBox", x0 - pad + " " + (-y1 - pad) + " " + (w + 2 * pad) + " " + (h + 2 * pad));
    const g = document.createElementNS(SVGNS, "g");
    g.setAttribute("transform", "scale(1,-1)");
    const travel = svgPath("travel"),
      plan = svgPath("plan"),
      done = svgPath("done");
    travel.setAttribute("d", pathData(path, path.points.length, false));
    plan.setAttribute("d", pathData(path, path.points.length, true));
    const tool = document.createElementNS(SVGNS, "circle");
    tool.setAttribute("class", "tool");
    tool.setAttribute("r", String(Math.max(w, h) * 0.012));
    g.append(travel, plan, done, tool);
    svg.replaceChildren(g);
    svg.dataset.drawn = String(path.total) + ":" + path.points.length;
    svg.dataset.acked = "";
  }
  if (acked == null || svg.dataset.acked === String(acked)) return;
  svg.dataset.acked = String(acked);
  const upto = acked > 0 ? path.ends[Math.min(acked, path.ends.length) - 1] : 1;
  const g = svg.firstChild;
  g.children[2].setAttribute("d", pathData(path, upto, true));
  const at = path.points[Math.max(0, upto - 1)];
  g.children[3].setAttribute("cx", String(at[0]));
  g.children[3].setAttribute("cy", String(at[1]));
}

let lastPreview = 0;
function renderPreview() {
  renderPreviewChoice();
  const j = previewTarget();
  const svg = $("preview");
  const cap = $("preview-caption");
  if (!j) {
    setText(cap, "No job is running.");
    svg.replaceChildren();
    svg.dataset.drawn = "";
    return;
  }
  const p = S.paths.get(j.id);
  if (!p) {
    S.paths.set(j.id, "loading");
    api("GET", "/jobs/" + j.id + "/path")
      .then((path) => S.paths.set(j.id, path))
      .catch((e) => S.paths.set(j.id, { error: e.message }))
      .finally(schedule);
  }
  const sewing = j.op === "stitch" || /\.(dst|jef)$/i.test(j.file_name);
  const unit = sewing ? "stitch records sewn" : "units done";
  setText(cap, "Job #" + j.id + " " + j.file_name + " on " + j.machine + ": " + j.state + ", " + j.acked_units + " of " + j.total_units + " " + unit + ".");
  cap.dataset.job = j.id;
  cap.dataset.acked = j.acked_units;
  if (!p || p === "loading") return;
  if (p.error) {
    setText(cap, cap.textContent + " (" + p.error + ")");
    return;
  }
  // the executed part follows at most 4 times a second
  const now = performance.now();
  if (svg.dataset.drawn && now - lastPreview < 250) {
    setTimeout(schedule, 260);
    drawPath(svg, p, null);
    return;
  }
  lastPreview = now;
  drawPath(svg, p, j.acked_units);
}

function render() {
  renderMachines();
  renderJobs();
  renderPreview();
  const viewer = !S.who || S.who.role === "viewer";
  $("sub-preview").disabled = viewer;
  $("sub-queue").disabled = viewer;
}

// ---- actions (each one API route, as the CLI's) ------------------------------------------

async function act(action, data) {
  const job = data.job ? Number(data.job) : null;
  const machine = data.machine;
  notice("");
  try {
    switch (action) {
      case "pause":
        S.jobs.set(job, await api("POST", "/jobs/" + job + "/pause"));
        break;
      case "resume": {
        const plan = await api("GET", "/jobs/" + job + "/resume");
        const ok = await confirmSteps("Resume job " + job + " from line " + plan.from_line + " of " + plan.total + "?", plan.steps.concat(plan.note ? ["note: " + plan.note] : []), plan.moves ? "The machine moves: resume" : "Resume");
        if (!ok) return;
        S.jobs.set(job, await api("POST", "/jobs/" + job + "/resume"));
        break;
      }
      case "cancel": {
        const ok = await confirmSteps("Cancel job " + job + "?", ["The machine stops as soon as it is safe; what it did stays done, and the job can be resumed later."], "Cancel the job");
        if (!ok) return;
        S.jobs.set(job, await api("POST", "/jobs/" + job + "/cancel"));
        break;
      }
      case "feed-up":
      case "feed-down": {
        const o = S.overrides.get(job) || { feed: 100, spindle: 100, rapid: 100 };
        const feed = Math.max(50, Math.min(200, o.feed + (action === "feed-up" ? 10 : -10)));
        const a = await api("POST", "/jobs/" + job + "/override", { feed });
        S.overrides.set(job, a.overrides);
        S.jobs.set(job, a.job);
        break;
      }
      case "unlock":
      case "home": {
        const a = await api("POST", "/machines/" + encodeURIComponent(machine) + "/" + action);
        log(machine + ": " + a.said);
        break;
      }
      case "lock":
        await api("POST", "/machines/" + encodeURIComponent(machine) + "/lock");
        await loadLocks();
        break;
      case "break": {
        const ok = await confirmSteps("Break the lock on " + machine + "?", ["Its holder loses control of the machine; the audit log names you."], "Break the lock");
        if (!ok) return;
        await api("POST", "/machines/" + encodeURIComponent(machine) + "/lock", { break: true });
        await loadLocks();
        break;
      }
      case "release":
        await api("POST", "/machines/" + encodeURIComponent(machine) + "/release");
        await loadLocks();
        break;
    }
  } catch (e) {
    notice(e.message);
    log("refused: " + e.message);
  }
  schedule();
}

function confirmSteps(title, steps, yes) {
  const d = $("confirm");
  $("confirm-title").textContent = title;
  const ol = $("confirm-steps");
  ol.replaceChildren(...steps.map((s) => el("li", null, s)));
  $("confirm-yes").textContent = yes;
  return new Promise((res) => {
    const done = (v) => {
      $("confirm-yes").onclick = $("confirm-no").onclick = null;
      d.onclose = null;
      if (d.open) d.close();
      res(v);
    };
    $("confirm-yes").onclick = () => done(true);
    $("confirm-no").onclick = () => done(false);
    d.onclose = () => done(false);
    d.showModal();
    $("confirm-yes").focus();
  });
}

// ---- submit ------------------------------------------------------------------------------

function fillMachineChoice() {
  const sel = $("sub-machine");
  const names = [...S.machines.keys()];
  if ([...sel.options].map((o) => o.value).join() === names.join()) return;
  const was = sel.value;
  sel.replaceChildren(...names.map((n) => new Option(n + " (" + S.machines.get(n).link + ")", n)));
  if (names.includes(was)) sel.value = was;
}

async function readFile(file) {
  const bytes = new Uint8Array(await file.arrayBuffer());
  try {
    return { file_name: file.name, file_text: new TextDecoder("utf-8", { fatal: true }).decode(bytes) };
  } catch (_) {
    let s = "";
    for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
    return { file_name: file.name, file_base64: btoa(s) };
  }
}

async function jobSpec() {
  const file = $("sub-file").files[0];
  if (!file) throw new Error("choose a file first");
  const op = $("sub-op").value;
  const num = (id) => Number($(id).value);
  let operation = null;
  const cut = { tool: { diameter: num("sub-tool") }, depth: num("sub-depth"), feed: num("sub-feed") };
  if (op === "profile") operation = { op, side: "outside", cut };
  if (op === "pocket") operation = { op, cut };
  if (op === "stitch") operation = { op, stitch_length: num("sub-stitch") };
  return { machine: $("sub-machine").value, input: await readFile(file), operation };
}

function figures(p) {
  const s = p.stats;
  const lines = [p.units + " units for " + p.machine + " (" + p.post + " post, " + p.operation + ")"];
  if (s.stitches + s.jumps > 0) lines.push(s.stitches + " stitches over " + s.cutting_length.toFixed(1) + " mm, " + s.jumps + " jumps over " + s.rapid_length.toFixed(1) + " mm");
  else {
    lines.push("cutting " + s.cutting_length.toFixed(1) + " mm in " + s.lines + " lines and " + s.arcs + " arcs; rapids " + s.rapid_length.toFixed(1) + " mm in " + s.rapids + " moves");
    lines.push("estimated time " + clock(1000 * (s.cutting_time + s.rapid_time + s.dwell_time)));
  }
  if (p.estimate_s != null) lines.push("the machine's own estimate: " + clock(1000 * p.estimate_s));
  for (const w of p.warnings) lines.push("warning: " + w);
  return lines.join("\n");
}

async function previewSubmit() {
  $("sub-error").textContent = "";
  $("sub-stats").textContent = "planning…";
  try {
    const p = await api("POST", "/plan", await jobSpec());
    $("sub-stats").textContent = figures(p);
    const svg = $("sub-preview-svg");
    svg.dataset.drawn = "";
    drawPath(svg, p.path, 0);
  } catch (e) {
    $("sub-stats").textContent = "";
    $("sub-error").textContent = e.message;
  }
}

async function queueSubmit(ev) {
  if (ev) ev.preventDefault();
  $("sub-error").textContent = "";
  try {
    const j = await api("POST", "/jobs", await jobSpec());
    S.jobs.set(j.id, j);
    $("sub-stats").textContent = "queued job #" + j.id + " on " + j.machine + " (" + j.total_units + " units)";
    log("queued job " + j.id + " on " + j.machine);
    schedule();
  } catch (e) {
    $("sub-error").textContent = e.message;
  }
}

// ---- session -----------------------------------------------------------------------------

async function start(token) {
  S.token = token;
  S.who = await api("GET", "/whoami");
  sessionStorage.setItem(TOKEN_KEY, token);
  $("login").hidden = true;
  $("board").hidden = false;
  $("logout").hidden = false;
  $("who").textContent = S.who.name + " · " + S.who.role + (S.who.role === "operator" && S.who.machines ? " on " + S.who.machines.join(", ") : "");
  document.body.dataset.role = S.who.role;
  S.abort = new AbortController();
  follow(S.abort.signal);
  S.timers.push(
    setInterval(() => {
      if (S.conn === "live")
        Promise.all([loadMachines(), loadJobs(), loadLocks()]).then(schedule, (e) => {
          if (!(e instanceof ApiError) && S.stream) S.stream.abort();
        });
    }, REFRESH_MS),
    setInterval(() => {
      if (S.conn === "live") loadHealth().catch(() => {});
    }, HEALTH_MS),
    setInterval(schedule, 1000), // ages and clocks, no request
  );
}

function logout(why) {
  if (S.abort) S.abort.abort();
  S.timers.forEach(clearInterval);
  S.timers = [];
  sessionStorage.removeItem(TOKEN_KEY);
  S.token = S.who = null;
  for (const m of [S.machines, S.jobs, S.locks, S.cards, S.rows, S.paths, S.overrides]) m.clear();
  $("machines").replaceChildren();
  $("jobs").tBodies[0].replaceChildren();
  $("board").hidden = true;
  $("login").hidden = false;
  $("logout").hidden = true;
  $("who").textContent = "";
  $("login-error").textContent = why || "";
  setConn("off", "not connected");
  $("token").focus();
}

document.addEventListener("DOMContentLoaded", () => {
  $("login-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    $("login-error").textContent = "";
    const t = $("token").value.trim();
    try {
      await start(t);
      $("token").value = "";
    } catch (e) {
      S.token = null;
      $("login-error").textContent = e.status === 401 ? "The daemon does not know this token." : e.message;
    }
  });
  $("logout").addEventListener("click", () => logout());
  document.addEventListener("click", (ev) => {
    const v = ev.target.closest("button[data-view]");
    if (v) {
      S.previewJob = Number(v.dataset.job);
      schedule();
      return;
    }
    const b = ev.target.closest("button[data-action]");
    if (!b || b.disabled || b.closest("form")) return;
    act(b.dataset.action, b.dataset);
  });
  $("preview-job").addEventListener("change", (ev) => {
    S.previewJob = ev.target.value ? Number(ev.target.value) : null;
    schedule();
  });
  $("sub-preview").addEventListener("click", previewSubmit);
  $("sub-queue").addEventListener("click", () => queueSubmit());
  $("submit-form").addEventListener("submit", queueSubmit);
  // `machlink dashboard` hands the page its key in the URL's fragment (never sent anywhere)
  const given = new URLSearchParams(location.hash.slice(1)).get("token");
  if (given) {
    sessionStorage.setItem(TOKEN_KEY, given);
    history.replaceState(null, "", location.pathname);
  }
  const saved = sessionStorage.getItem(TOKEN_KEY);
  if (saved)
    start(saved).catch((e) => logout(e.status === 401 ? "The daemon does not know this token any more." : ""));
  else $("token").focus();
});
