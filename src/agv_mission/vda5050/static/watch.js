// The VDA 5050 fleet view: every vehicle on the broker drawn on its map (the dashboard's
// MapView), with a card of its state. Polls /api/vehicles five times a second.
"use strict";

const esc = (s) => String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);

class FleetView extends MapView {
  constructor(canvas) { super(canvas); this.vehicles = []; }
  draw() {
    super.draw();
    const ctx = this.ctx, P = (x, y) => this.toScreen(x, y);
    ctx.font = "600 12px system-ui, sans-serif";
    ctx.textAlign = "left"; ctx.textBaseline = "middle";
    for (const v of this.vehicles) {
      if (!v.position || v.position.mapId !== this.mapId) continue;
      const color = v.connection === "CONNECTIONBROKEN" ? "#f2555a" : v.color;
      const pts = [[v.position.x, v.position.y], ...v.nodes.map((n) => [n.x, n.y])];
      this.polyline(ctx, P, pts.slice(0, 1 + v.nodes.filter((n) => n.released).length), color, 2, null, 0.9);
      this.polyline(ctx, P, pts.slice(v.nodes.filter((n) => n.released).length), color, 1.5, [5, 4], 0.6);
      this.drawRobot(ctx, P, { x: v.position.x, y: v.position.y, yaw: v.position.theta }, color, true);
      const [x, y] = P(v.position.x, v.position.y);
      const label = `${v.serial}${v.paused ? " ❚❚" : ""}${v.errors.length ? " ⚠" : ""}`;
      ctx.fillStyle = "rgba(15,18,22,0.8)";
      ctx.fillRect(x + 12, y - 20, ctx.measureText(label).width + 8, 16);
      ctx.fillStyle = color; ctx.fillText(label, x + 16, y - 12);
    }
  }
}

const view = new FleetView(document.getElementById("map"));
view.mapId = null;
const maps = {};

async function showMap(mapId) {
  if (view.mapId === mapId) return;
  view.mapId = mapId;
  if (!maps[mapId]) {
    const r = await fetch(`/api/map?id=${encodeURIComponent(mapId)}`);
    maps[mapId] = r.ok ? await r.json() : null;
  }
  const m = maps[mapId];
  view.fitted = false;
  view.scene.rooms = m ? m.rooms : [];
  view.scene.docks = m ? m.docks : [];
  if (m) view.setMap(m);
  else { view.scene.map = null; document.getElementById("hud").textContent = `no map ${mapId}: vehicles on a blank field`; }
  view.touch();
}

function card(v) {
  const pos = v.position ? `(${v.position.x.toFixed(2)}, ${v.position.y.toFixed(2)}, ${v.position.theta.toFixed(2)}) on ${esc(v.position.mapId)}` : "unknown";
  const motion = v.paused ? "paused" : v.driving ? `driving ${v.velocity ? v.velocity.vx.toFixed(2) + " m/s" : ""}` : "standing";
  const battery = v.battery == null ? "–" : `${v.battery.toFixed(1)} %${v.charging ? " ⚡ charging" : ""}${v.voltage ? ` · ${v.voltage} V` : ""}`;
  const order = v.order ? `${esc(v.order)} #${v.orderUpdate} · last node ${esc(v.lastNode)} · ${v.nodes.length} to go` : "none";
  const acts = v.actions.filter((a) => a.actionStatus !== "FINISHED" || a.actionType === "pick" || a.actionType === "drop").slice(-4)
    .map((a) => `${esc(a.actionType)} ${esc(a.actionStatus)}`).join(", ");
  const errs = v.errors.map((e) => `<div class="${e.errorLevel === "FATAL" ? "err" : "warn"}">${esc(e.errorLevel)} ${esc(e.errorType)}: ${esc(e.errorDescription)}</div>`).join("");
  return `<div class="agv" data-serial="${esc(v.serial)}">
    <h2><span class="swatch" style="background:${v.color}"></span>${esc(v.serial)}
      <span class="pill ${esc(v.connection)}">${esc(v.connection || "?")}</span>
      <span class="muted">${esc(v.manufacturer)}</span></h2>
    <div class="kv">position <b>${pos}</b></div>
    <div class="kv">motion <b class="motion">${motion}</b> · battery <b class="battery">${battery}</b></div>
    <div class="kv">order <b class="order">${order}</b></div>
    ${v.loads.length ? `<div class="kv">loads <b>${v.loads.map(esc).join(", ")}</b></div>` : ""}
    ${acts ? `<div class="kv">actions <b>${acts}</b></div>` : ""}
    ${errs}
  </div>`;
}

async function poll() {
  try {
    const r = await fetch("/api/vehicles");
    const doc = await r.json();
    const vs = doc.vehicles;
    for (const v of vs) v.color = v.colour;  // the server's: run.png's and the dashboard's palette
    view.vehicles = vs;
    const ids = [...new Set(vs.filter((v) => v.position).map((v) => v.position.mapId))];
    const sel = document.getElementById("mapsel");
    if (ids.join("|") !== sel.dataset.ids) {
      sel.dataset.ids = ids.join("|");
      sel.innerHTML = ids.map((m) => `<option>${esc(m)}</option>`).join("");
      if (view.mapId && ids.includes(view.mapId)) sel.value = view.mapId;
    }
    if (ids.length && (!view.mapId || !ids.includes(view.mapId))) await showMap(ids[0]);
    document.getElementById("meta").textContent =
      `${doc.broker} · ${doc.connected ? "connected" : "not connected"} · ${vs.length} vehicle${vs.length === 1 ? "" : "s"}`;
    document.getElementById("fleet").innerHTML = vs.length ? vs.map(card).join("") : '<p class="muted">no vehicle seen yet</p>';
    document.getElementById("hud").textContent = view.mapId ? `map ${view.mapId}` : "";
    view.dirty = true;
  } catch (e) {
    document.getElementById("meta").textContent = `the watch server is gone (${e})`;
  }
  setTimeout(poll, 200);
}

document.getElementById("mapsel").addEventListener("change", (e) => showMap(e.target.value));
poll();
