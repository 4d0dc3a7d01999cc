// Runs page: every run with status, name, world, robot, progress and duration, refreshed live.
"use strict";
(function () {
  const params = new URLSearchParams(location.search);
  let filter = params.get("status") || "all";
  let runs = [];
  const tbody = document.querySelector("#runs tbody");
  const empty = document.getElementById("empty");
  const filters = document.getElementById("filters");

  // The run list may not carry world and robot: read them once from each run's mission.yaml.
  const meta = new Map();
  const asked = new Set();
  async function fetchMeta(run) {
    // a run is "running" from its launch, but its mission.yaml is written once loaded: the
    // first simulated step says it is there (asking earlier is a 404 in the console)
    const loading = run.status === "running" && !(run.progress && run.progress.sim_time > 0);
    if (asked.has(run.id) || run.status === "queued" || loading) return;
    asked.add(run.id);
    const text = await AGV.fileText(run.id, "mission.yaml");
    if (!text) { setTimeout(() => asked.delete(run.id), 3000); return; }
    const field = (key) => {
      const m = text.match(new RegExp(`^${key}:\\s*(.+?)\\s*$`, "m"));
      return m ? m[1].replace(/^['"]|['"]$/g, "") : "";
    };
    meta.set(run.id, { world: field("world"), robot: field("robot"), tasks: countTasks(text) });
    render();
  }
  /** the number of items of the top-level `tasks:` list (block style, any indent) */
  function countTasks(text) {
    const lines = text.split("\n");
    const at = lines.findIndex((l) => /^tasks:/.test(l));
    if (at < 0) return null;
    let indent = null, n = 0;
    for (const line of lines.slice(at + 1)) {
      if (/^[A-Za-z_]/.test(line)) break;
      const m = line.match(/^(\s*)- /);
      if (!m) continue;
      if (indent === null) indent = m[1].length;
      if (m[1].length === indent) n++;
    }
    return n || null;
  }
  const worldOf = (run) => AGV.worldName(AGV.runWorld(run)) || meta.get(run.id)?.world || "";
  const robotOf = (run) => AGV.worldName(AGV.runRobot(run)) || meta.get(run.id)?.robot || "";

  function matches(run) {
    if (filter === "all") return true;
    if (filter === "active") return !AGV.FINAL.has(run.status);
    return run.status === filter;
  }

  function renderFilters() {
    const counts = { all: runs.length, active: runs.filter((r) => !AGV.FINAL.has(r.status)).length };
    for (const s of AGV.STATUSES) counts[s] = runs.filter((r) => r.status === s).length;
    const keys = ["all", "active", ...AGV.STATUSES];
    filters.innerHTML = keys
      .filter((k) => k === "all" || k === "active" || counts[k] > 0 || k === filter)
      .map((k) => `<button class="chip ${k === filter ? "on" : ""}" data-status="${k}">${k}<span class="n">${counts[k]}</span></button>`)
      .join("");
  }

  function progressCell(run) {
    const p = run.progress || {};
    const total = run.tasks ?? run.task_count ?? run.mission?.tasks?.length ?? meta.get(run.id)?.tasks ?? null;
    const idx = p.task_index;
    let frac = null;
    if (AGV.FINAL.has(run.status)) frac = run.status === "succeeded" ? 1 : null;
    else if (total && idx != null) frac = Math.min(1, idx / total);
    const task = p.task_type ? `${p.task_type}${idx != null ? ` ${idx + 1}${total ? "/" + total : ""}` : ""}` : "";
    const sim = p.sim_time != null ? `${AGV.fmtNum(p.sim_time, 1)} s sim` : "";
    const detail = AGV.FINAL.has(run.status) ? (run.reason || p.detail || "") : (p.detail || "");
    return `<div class="progress">
      <div>${AGV.esc([task, sim].filter(Boolean).join(" · ") || "–")}</div>
      ${frac != null ? `<div class="bar"><i style="width:${(frac * 100).toFixed(0)}%"></i></div>` : ""}
      <div class="detail" title="${AGV.esc(detail)}">${AGV.esc(detail)}</div></div>`;
  }

  function render() {
    renderFilters();
    const shown = runs.filter(matches);
    empty.hidden = shown.length > 0;
    if (!shown.length && runs.length) empty.innerHTML = `No ${AGV.esc(filter)} runs.`;
    tbody.innerHTML = shown.map((run) => {
      const link = `/runs/${encodeURIComponent(run.id)}`;
      return `<tr data-id="${AGV.esc(run.id)}" data-status="${AGV.esc(run.status)}">
        <td data-label="status">${AGV.badge(run.status)}</td>
        <td class="name" data-label="name"><a href="${link}">${AGV.esc(run.name || "(unnamed)")}</a><div class="id">${AGV.esc(run.id)}</div></td>
        <td data-label="world">${AGV.esc(worldOf(run))}</td>
        <td data-label="robot">${AGV.esc(robotOf(run))}</td>
        <td data-label="progress">${progressCell(run)}</td>
        <td data-label="duration" class="mono">${AGV.fmtDuration(AGV.runDuration(run))}</td>
        <td data-label="created" class="muted">${AGV.fmtClock(run.created)}</td>
      </tr>`;
    }).join("");
  }

  filters.addEventListener("click", (e) => {
    const b = e.target.closest("button[data-status]");
    if (!b) return;
    filter = b.dataset.status;
    const url = new URL(location.href);
    if (filter === "all") url.searchParams.delete("status"); else url.searchParams.set("status", filter);
    history.replaceState(null, "", url);
    render();
  });
  tbody.addEventListener("click", (e) => {
    if (e.target.closest("a")) return;
    const tr = e.target.closest("tr[data-id]");
    if (tr) location.href = `/runs/${encodeURIComponent(tr.dataset.id)}`;
  });

  async function refresh() {
    if (AGV.refreshHealth) AGV.refreshHealth();
    const r = await AGV.api("/api/runs?limit=200");
    if (r.ok && r.data && Array.isArray(r.data.runs)) {
      runs = r.data.runs;
      render();
      for (const run of runs.slice(0, 100)) if (!worldOf(run)) fetchMeta(run);
    }
    const active = runs.some((run) => !AGV.FINAL.has(run.status));
    setTimeout(refresh, active ? 1000 : 3000);
  }
  refresh();
})();
