// Submit page: a YAML editor with the demo missions as templates, checked by the service
// (POST /api/validate) as you type; its line / field errors are drawn beside the lines.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const ta = $("yaml"), gutter = $("gutter"), marks = $("marks");
  const LINE = 20;
  let templates = [];
  let errors = [];
  let checkSeq = 0;
  let timer = null;

  function toast(text, kind) {
    const t = $("toast");
    t.textContent = text; t.className = "toast show " + (kind || "");
    clearTimeout(toast.timer); toast.timer = setTimeout(() => { t.className = "toast"; }, 4000);
  }

  function body() {
    const set = $("overrides").value.split("\n").map((l) => l.trim()).filter((l) => l && !l.startsWith("#"));
    const b = { mission: ta.value };
    if (set.length) b.set = set;
    const seed = $("seed").value.trim();
    if (seed !== "") b.seed = parseInt(seed, 10);
    return b;
  }
  /** a submission: what is checked, and the pace to run it at */
  function submission() {
    const b = body();
    const pace = $("pace").value;
    if (pace !== "") b.pace = parseFloat(pace);
    return b;
  }

  function renderGutter() {
    const n = ta.value.split("\n").length;
    const bad = new Set(errors.map((e) => e.line).filter((l) => l));
    let html = "";
    for (let i = 1; i <= n; i++) html += `<div class="${bad.has(i) ? "err" : ""}">${i}</div>`;
    gutter.innerHTML = html + "<div></div><div></div>";
    marks.innerHTML = errors.filter((e) => e.line).map((e) =>
      `<div style="top:${(e.line - 1) * LINE}px" data-line="${e.line}"><span>${AGV.esc(e.field ? e.field + ": " : "")}${AGV.esc(e.message)}</span></div>`).join("");
    syncScroll();
  }
  function syncScroll() {
    gutter.scrollTop = ta.scrollTop;
    marks.style.transform = `translateY(${-ta.scrollTop}px)`;
  }
  ta.addEventListener("scroll", syncScroll);

  function gotoLine(line) {
    const lines = ta.value.split("\n");
    let pos = 0;
    for (let i = 0; i < line - 1 && i < lines.length; i++) pos += lines[i].length + 1;
    ta.focus();
    ta.setSelectionRange(pos, pos + (lines[line - 1] || "").length);
    ta.scrollTop = Math.max(0, (line - 5) * LINE);
    syncScroll();
  }

  function showErrors(list) {
    errors = list.map((e) => ({ line: e.line ?? null, field: e.field ?? e.loc ?? "", message: e.message ?? e.msg ?? JSON.stringify(e) }));
    $("checkstate").innerHTML = `<span style="color:var(--bad)">${errors.length} problem${errors.length === 1 ? "" : "s"}</span>`;
    $("checks").innerHTML = errors.map((e) =>
      `<div class="err" data-line="${e.line ?? ""}"><span class="where">${e.line ? "line " + e.line : "—"}${e.field ? " · " + AGV.esc(e.field) : ""}</span><div>${AGV.esc(e.message)}</div></div>`).join("");
    renderGutter();
  }

  function showOk(mission) {
    errors = [];
    renderGutter();
    $("checkstate").innerHTML = `<span class="okline">✓ valid</span>`;
    const m = mission || {};
    const tasks = (m.tasks || []).map((t) => t.type).join(", ");
    const world = AGV.worldName(m.world), robot = AGV.worldName(m.robot);
    const summary = [`name   ${m.name ?? ""}`, `world  ${world}`, `robot  ${robot}`, `tasks  ${tasks}`,
      m.stack ? `stack  ${Object.entries(m.stack).map(([k, v]) => `${k}:${v && v.type ? v.type : "…"}`).join(" ")}` : ""].filter(Boolean).join("\n");
    $("checks").innerHTML = `<div class="okline">The service accepts this mission.</div><div class="summary">${AGV.esc(summary)}</div>`;
  }

  async function check() {
    const seq = ++checkSeq;
    if (!ta.value.trim()) { showErrors([{ line: null, field: "", message: "the mission is empty" }]); return false; }
    $("checkstate").textContent = "checking…";
    const r = await AGV.api("/api/validate", { method: "POST", body: body() });
    if (seq !== checkSeq) return null;
    if (r.ok) { showOk(r.data && r.data.mission); return true; }
    if (r.status === 422 && r.data && Array.isArray(r.data.errors)) { showErrors(r.data.errors); return false; }
    showErrors([{ line: null, field: "", message: `the service answered ${r.status}: ${JSON.stringify(r.data?.detail ?? r.data)}` }]);
    return false;
  }

  function changed() {
    localStorage.setItem("agv-draft", ta.value);
    renderGutter();
    clearTimeout(timer);
    timer = setTimeout(check, 500);
  }
  ta.addEventListener("input", changed);
  $("overrides").addEventListener("input", () => { clearTimeout(timer); timer = setTimeout(check, 500); });
  $("seed").addEventListener("input", () => { clearTimeout(timer); timer = setTimeout(check, 500); });
  ta.addEventListener("keydown", (e) => {
    if (e.key === "Tab") {  // two spaces, as YAML wants
      e.preventDefault();
      const s = ta.selectionStart;
      ta.setRangeText("  ", s, ta.selectionEnd, "end");
      changed();
    }
  });
  $("checks").addEventListener("click", (e) => {
    const row = e.target.closest(".err[data-line]");
    if (row && row.dataset.line) gotoLine(parseInt(row.dataset.line, 10));
  });
  $("check").onclick = check;
  $("submit").onclick = async () => {
    $("submit").disabled = true;
    try {
      const r = await AGV.api("/api/runs", { method: "POST", body: submission() });
      if (r.ok && r.data && r.data.id) {
        location.href = `/runs/${encodeURIComponent(r.data.id)}`;
        return;
      }
      if (r.status === 422 && r.data && Array.isArray(r.data.errors)) showErrors(r.data.errors);
      else if (r.status === 429) toast("the queue is full: try again when a run ends", "bad");
      else toast(`submit failed: ${r.status} ${JSON.stringify(r.data?.detail ?? r.data)}`, "bad");
    } finally {
      $("submit").disabled = false;
    }
  };

  function useTemplate(name) {
    const t = templates.find((x) => x.name === name);
    if (!t) return;
    ta.value = t.yaml;
    ta.scrollTop = 0;
    changed();
  }
  $("template").addEventListener("change", (e) => useTemplate(e.target.value));

  (async () => {
    const r = await AGV.api("/api/templates");
    templates = (r.ok && r.data && r.data.templates) || [];
    $("template").innerHTML = `<option value="">(choose)</option>` +
      templates.map((t) => `<option value="${AGV.esc(t.name)}">${AGV.esc(t.name)}</option>`).join("");
    const want = new URLSearchParams(location.search).get("template");
    const draft = localStorage.getItem("agv-draft");
    if (want) { $("template").value = want; useTemplate(want); }
    else if (draft) { ta.value = draft; changed(); }
    else if (templates.length) { $("template").value = templates[0].name; useTemplate(templates[0].name); }
    renderGutter();
  })();
})();
