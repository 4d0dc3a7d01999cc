// Shared helpers for the agv-mission dashboard: API calls (with the optional bearer token),
// formatting, status badges. Plain ES2020, no build step, no external library.
"use strict";

const AGV = (() => {
  const params = new URLSearchParams(location.search);
  if (params.get("token")) localStorage.setItem("agv-token", params.get("token"));
  const token = () => localStorage.getItem("agv-token") || "";

  const FINAL = new Set(["succeeded", "failed", "aborted", "error", "interrupted"]);
  const STATUSES = ["queued", "running", "paused", "succeeded", "failed", "aborted", "error", "interrupted"];

  /** fetch a JSON API route; resolves to {status, ok, data} and never throws on HTTP errors */
  async function api(path, opts = {}) {
    const headers = Object.assign({}, opts.headers || {});
    if (token()) headers["Authorization"] = "Bearer " + token();
    let body = opts.body;
    if (body !== undefined && typeof body !== "string") {
      body = JSON.stringify(body);
      headers["Content-Type"] = "application/json";
    }
    try {
      const res = await fetch(path, { method: opts.method || "GET", headers, body });
      const text = await res.text();
      let data = null;
      try { data = text ? JSON.parse(text) : null; } catch (_) { data = text; }
      return { status: res.status, ok: res.ok, data };
    } catch (err) {
      return { status: 0, ok: false, data: { detail: String(err) } };
    }
  }

  /** a file of a run as text (stream.jsonl, result.json) */
  async function fileText(runId, name) {
    const headers = token() ? { Authorization: "Bearer " + token() } : {};
    const res = await fetch(`/api/runs/${encodeURIComponent(runId)}/files/${encodeURIComponent(name)}`, { headers });
    if (!res.ok) return null;
    return res.text();
  }

  function fileUrl(runId, name) {
    return `/api/runs/${encodeURIComponent(runId)}/files/${encodeURIComponent(name)}`;
  }

  /** with a token, a plain link cannot carry the Authorization header: fetch the file and
   *  hand the browser a blob URL instead (links marked data-file, images data-src) */
  function authoriseFiles(root) {
    if (!token()) return;
    const blob = async (url) => {
      const res = await fetch(url, { headers: { Authorization: "Bearer " + token() } });
      return res.ok ? URL.createObjectURL(await res.blob()) : null;
    };
    for (const img of root.querySelectorAll("img[data-src]")) {
      blob(img.dataset.src).then((u) => { if (u) img.src = u; });
    }
    for (const a of root.querySelectorAll("a[data-file]")) {
      a.addEventListener("click", async (e) => {
        e.preventDefault();
        const u = await blob(a.getAttribute("href"));
        if (!u) return;
        const tmp = document.createElement("a");
        tmp.href = u; tmp.download = a.dataset.file;
        tmp.click();
      });
    }
  }

  function wsUrl(path, params) {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const q = new URLSearchParams(params || {});
    if (token()) q.set("token", token());
    const qs = q.toString();
    return `${proto}//${location.host}${path}${qs ? "?" + qs : ""}`;
  }

  function esc(value) {
    return String(value ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
  }

  function fmtDuration(seconds) {
    if (seconds == null || !isFinite(seconds)) return "–";
    seconds = Math.max(0, seconds);
    if (seconds < 60) return seconds.toFixed(1) + " s";
    const m = Math.floor(seconds / 60), s = Math.floor(seconds % 60);
    if (m < 60) return `${m}m ${String(s).padStart(2, "0")}s`;
    return `${Math.floor(m / 60)}h ${String(m % 60).padStart(2, "0")}m`;
  }

  function parseTime(iso) {
    if (!iso) return null;
    const hasZone = /[zZ]|[+-]\d\d:?\d\d$/.test(iso);
    const ms = Date.parse(hasZone ? iso : iso + "Z");
    return isNaN(ms) ? null : ms;
  }

  function fmtClock(iso) {
    const ms = parseTime(iso);
    if (ms == null) return "–";
    const d = new Date(ms);
    const today = new Date();
    const hm = d.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit", second: "2-digit" });
    return d.toDateString() === today.toDateString() ? hm : d.toLocaleDateString() + " " + hm;
  }

  /** wall duration of a run: started -> ended, or -> now while it goes on */
  function runDuration(run) {
    const start = parseTime(run.started);
    if (start == null) return null;
    const end = parseTime(run.ended) ?? Date.now();
    return (end - start) / 1000;
  }

  function badge(status) {
    return `<span class="badge st-${esc(status)}">${esc(status || "?")}</span>`;
  }

  function fmtNum(v, digits = 2) {
    return typeof v === "number" && isFinite(v) ? v.toFixed(digits) : "–";
  }

  /** world and robot of a run object, wherever the service puts them */
  function runWorld(run) {
    return run.world ?? run.mission?.world ?? run.result?.world ?? run.result?.mission?.world ?? "";
  }
  function runRobot(run) {
    return run.robot ?? run.mission?.robot ?? run.result?.robot ?? run.result?.mission?.robot ?? "";
  }
  function worldName(w) {
    if (w && typeof w === "object") return w.name ?? w.path ?? JSON.stringify(w);
    return String(w ?? "");
  }

  return { api, fileText, fileUrl, authoriseFiles, wsUrl, esc, fmtDuration, fmtClock, parseTime, runDuration, badge, fmtNum, runWorld, runRobot, worldName, FINAL, STATUSES, token };
})();
