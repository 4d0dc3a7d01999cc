// The top bar shared by every page: navigation and the service's health line.
"use strict";
(function () {
  const here = document.body.dataset.page;
  const bar = document.createElement("header");
  bar.className = "top";
  bar.innerHTML = `
    <a class="brand" href="/"><span class="logo"></span>agv-mission</a>
    <nav>
      <a href="/" class="${here === "runs" ? "active" : ""}">Runs</a>
      <a href="/submit" class="${here === "submit" ? "active" : ""}">Submit</a>
      <a href="/docs">API</a>
    </nav>
    <span class="spacer"></span>
    <span class="health" id="health"></span>`;
  document.body.prepend(bar);
  async function health() {
    const r = await AGV.api("/api/health");
    const el = document.getElementById("health");
    if (r.ok && r.data) {
      const d = r.data;
      el.textContent = `v${d.version ?? "?"} · ${d.running ?? 0} running · ${d.queued ?? 0} queued · ${d.workers ?? "?"} workers`;
    } else {
      el.textContent = r.status === 401 ? "token needed: open /?token=…" : "service unreachable";
    }
  }
  // a page that refreshes its own data (the runs list) refreshes the line with it, so the
  // counts here never disagree with the table below for seconds
  AGV.refreshHealth = health;
  health();
  setInterval(health, 5000);
})();
