// The JSON API, polling that stops while the page is hidden, and small formatting helpers.

export class ApiError extends Error {
  constructor(status, body) {
    super(typeof body?.detail === "string" ? body.detail : `HTTP ${status}`);
    this.status = status;
    this.body = body;
  }
}

export function token() {
  return localStorage.getItem("lucent-token") || "";
}

export function authHeaders(extra = {}) {
  const t = token();
  return t ? { ...extra, Authorization: `Bearer ${t}` } : extra;
}

// fetch + JSON; throws ApiError (with the parsed body: a 422 names its fields) on non-2xx.
export async function api(path, { method = "GET", body } = {}) {
  const headers = authHeaders(body === undefined ? {} : { "Content-Type": "application/json" });
  const r = await fetch(path, {
    method, headers, body: body === undefined ? undefined : JSON.stringify(body),
  });
  let data = null;
  const text = await r.text();
  try { data = text ? JSON.parse(text) : null; } catch { data = { detail: text }; }
  if (!r.ok) throw new ApiError(r.status, data);
  return data;
}

// --- polling ----------------------------------------------------------------------------------
// Every poller of the current page runs `fn` every `ms` milliseconds while the page is visible,
// never two at once, and not at all while it is hidden (visibilitychange restarts it at once).
const pollers = new Set();
export const stats = { polls: 0 };   // read by the tests: no polls while hidden

export function poll(fn, ms) {
  const p = { fn, ms, timer: null, running: false, stopped: false };
  p.run = async () => {
    clearTimeout(p.timer);
    p.timer = null;
    if (p.stopped || document.hidden || p.running) return;
    p.running = true;
    stats.polls += 1;
    try { await p.fn(); } catch (err) { showNotice(err.message, "error"); }
    p.running = false;
    if (!p.stopped && !document.hidden) p.timer = setTimeout(p.run, p.ms);
  };
  p.stop = () => { p.stopped = true; clearTimeout(p.timer); pollers.delete(p); };
  pollers.add(p);
  p.run();
  return p;
}

export function stopAllPolls() {
  for (const p of [...pollers]) p.stop();
}

document.addEventListener("visibilitychange", () => {
  for (const p of pollers) {
    if (document.hidden) { clearTimeout(p.timer); p.timer = null; } else p.run();
  }
});

// --- notices and formatting ------------------------------------------------------------------
let noticeTimer = null;
export function showNotice(text, kind = "info") {
  const el = document.getElementById("notice");
  el.textContent = text;
  el.className = kind;
  el.hidden = false;
  clearTimeout(noticeTimer);
  noticeTimer = setTimeout(() => { el.hidden = true; }, kind === "error" ? 8000 : 4000);
}

export function h(tag, attrs = {}, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === null || v === undefined || v === false) continue;
    if (k.startsWith("on")) el.addEventListener(k.slice(2), v);
    else if (k === "class") el.className = v;
    else if (k === "dataset") Object.assign(el.dataset, v);
    else el.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return el;
}

export function fmtDuration(s) {
  if (s === null || s === undefined || !isFinite(s)) return "–";
  s = Math.max(0, s);
  if (s < 10) return `${s.toFixed(1)} s`;
  if (s < 60) return `${Math.round(s)} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
  return `${Math.floor(s / 3600)} h ${Math.round((s % 3600) / 60)} min`;
}

export function fmtRate(x) {
  if (x === null || x === undefined || !isFinite(x)) return "–";
  if (x >= 1e6) return `${(x / 1e6).toFixed(2)} M`;
  if (x >= 1e3) return `${(x / 1e3).toFixed(1)} k`;
  return x.toFixed(0);
}

// A relMSE to 3 significant digits, as the job pages give it
export const digits3 = (x) => String(Number(Number(x).toPrecision(3)));

// A job's error in a few words: the relMSE it asks for (render.target_error) and its frames'
// estimate from the samples merged so far (the API's expected_error, which a job out of Redis
// keeps in its record; "so far" while it runs), "" where it has neither
export function errorSummary(j) {
  const est = j.expected_error == null ? null
    : digits3(j.expected_error) + (FINAL.includes(j.status) ? "" : " so far");
  if (j.target_error != null) {
    return `target relMSE ${j.target_error}` + (est == null ? "" : ` · ${est}`);
  }
  return est == null ? "" : `relMSE ${est}`;
}

export function fmtTime(t) {
  if (!t) return "–";
  const d = new Date(t * 1000);
  const today = new Date().toDateString() === d.toDateString();
  return today ? d.toLocaleTimeString() : d.toLocaleString();
}

export function statusBadge(status) {
  return h("span", { class: `badge s-${status}` }, status);
}

export function progressBar(fraction, status) {
  const pct = Math.round(Math.max(0, Math.min(1, fraction)) * 1000) / 10;
  return h("div", {
    class: `progress s-${status}`, role: "progressbar", "aria-valuemin": "0",
    "aria-valuemax": "100", "aria-valuenow": String(pct),
  }, h("div", { class: "bar", style: `width:${pct}%` }), h("span", {}, `${pct} %`));
}

export const FINAL = ["done", "failed", "cancelled"];

export function elapsed(job) {
  if (!job.started_at) return null;
  return (job.finished_at || Date.now() / 1000) - job.started_at;
}
