// Run page: the run live over the WebSocket while it goes on, and replayed from the run
// directory's stream.jsonl once it is final (time slider). Behaviour tree, event timeline,
// pause / resume / cancel, teleop (arrow keys, pad, record room, nav goal), result and files.
// A fleet run draws every robot in its own colour; picking one (its chip, or a click on it
// on the map) shows its tree, HUD and battery, and points teleop, goals and records at it.
"use strict";
(function () {
  const runId = decodeURIComponent(location.pathname.split("/").filter(Boolean).pop());
  const $ = (id) => document.getElementById(id);
  const view = new MapView($("map"));
  window.agvView = view;  // for tests and the benchmark (frame counters)
  window.agvRunState = () => ({ status, task, state: lastState, replay: replay && { t: replay.t, t0: replay.t0, t1: replay.t1 },
    fleet: view.scene.fleet, selected: view.scene.selected, tree: treeNodes,
    robots: Object.values(view.scene.robots).map((r) => ({ name: r.name, colour: r.colour, type: r.type, pose: r.truth,
      task: states[r.name]?.task ?? null, plan: r.plan ? r.plan.length : 0, trail: r.truthTrail.length })) });

  let run = null;
  let status = null;
  let task = null;
  let lastState = null;
  let ws = null;
  let finalShown = false;
  let replay = null;
  let events = [];
  let treeNodes = null;
  let trees = {};   // robot -> its tree's nodes
  let states = {};  // robot -> its latest state
  let treeDirty = false, eventsDirty = false;
  let cursor = null;
  const LIVE_RATE = 25;

  // ------------------------------------------------------------------ layers panel
  const LAYERS = [["map", "map", "#8a96a6"], ["rooms", "rooms", LAYER_STYLE.rooms], ["truth", "true pose", LAYER_STYLE.truth],
    ["estimate", "estimate", LAYER_STYLE.estimate], ["trails", "trails", "#6b7f99"], ["scan", "scan", LAYER_STYLE.scan],
    ["particles", "particles", LAYER_STYLE.particles], ["plan", "global path", LAYER_STYLE.plan],
    ["horizon", "local horizon", LAYER_STYLE.horizon], ["goal", "goal", LAYER_STYLE.goal], ["recorded", "recorded", LAYER_STYLE.recorded],
    ["zones", "zones", "#d9463c"], ["people", "people", LAYER_STYLE.people]];
  $("layers").innerHTML = LAYERS.map(([k, label, color]) =>
    `<label><input type="checkbox" data-layer="${k}" checked><span class="sw" style="background:${color}"></span>${label}</label>`).join("");
  $("layers").addEventListener("change", (e) => {
    const k = e.target.dataset.layer;
    if (k) { view.layers[k] = e.target.checked; view.dirty = true; }
  });
  $("layers-toggle").onclick = () => $("layers").classList.toggle("open");
  $("fit").onclick = () => view.fit();
  $("zoomin").onclick = () => view.zoomBy(1.4);
  $("zoomout").onclick = () => view.zoomBy(1 / 1.4);
  $("follow").onclick = () => { view.follow = !view.follow; view.dirty = true; };
  view.onCursor = (p) => { cursor = p; };

  function toast(text, kind) {
    const t = $("toast");
    t.textContent = text;
    t.className = "toast show " + (kind || "");
    clearTimeout(toast.timer);
    toast.timer = setTimeout(() => { t.className = "toast"; }, 3500);
  }

  // ------------------------------------------------------------------ status and controls
  function setStatus(s) {
    if (!s || s === status) return;
    status = s;
    $("status").innerHTML = AGV.badge(s);
    $("status").dataset.status = s;
    const final = AGV.FINAL.has(s);
    $("pause").disabled = s !== "running";
    $("resume").disabled = s !== "paused";
    $("cancel").disabled = final;
    $("pace").disabled = final;
    treeDirty = true;  // the progress reads the status too
    updateTeleop();
  }

  // ------------------------------------------------------------------ pace
  /** the run's pace (simulated seconds per wall second, null: as fast as it goes) in the menu */
  function showPace(pace) {
    const sel = $("pace");
    if (document.activeElement === sel) return;  // the user is choosing
    const value = pace == null ? "" : String(+pace);
    if (![...sel.options].some((o) => o.value === value)) {
      const o = document.createElement("option");
      o.value = value; o.textContent = `${value}×`;
      sel.appendChild(o);
    }
    sel.value = value;
  }
  $("pace").addEventListener("change", async () => {
    const value = $("pace").value;
    const pace = value === "" ? null : parseFloat(value);
    const r = await AGV.api(`/api/runs/${encodeURIComponent(runId)}/pace`, { method: "POST", body: { pace } });
    if (r.ok) toast(pace == null ? "pace: as fast as it goes" : `pace: ${pace}× real time`, "good");
    else { toast(`pace: ${r.status} ${r.data?.detail ?? ""}`, "bad"); if (run) showPace(run.pace); }
    $("pace").blur();
  });

  async function control(action) {
    const r = await AGV.api(`/api/runs/${encodeURIComponent(runId)}/${action}`, { method: "POST" });
    if (r.ok) {
      if (action === "pause") setStatus("paused");
      if (action === "resume") setStatus("running");
      toast(`${action}: accepted`, "good");
    } else {
      toast(`${action}: ${r.status} ${r.data?.detail ?? ""}`, "bad");
    }
  }
  $("pause").onclick = () => control("pause");
  $("resume").onclick = () => control("resume");
  $("cancel").onclick = () => {
    const b = $("cancel");
    if (b.dataset.armed) {
      delete b.dataset.armed; b.textContent = "■ Cancel"; control("cancel");
    } else {
      b.dataset.armed = "1"; b.textContent = "■ Confirm cancel";
      setTimeout(() => { delete b.dataset.armed; b.textContent = "■ Cancel"; }, 3000);
    }
  };

  function setMeta() {
    if (!run) return;
    document.title = `${run.name || runId} · agv-mission`;
    $("name").textContent = run.name || runId;
    const world = AGV.worldName(AGV.runWorld(run)), robot = AGV.worldName(AGV.runRobot(run));
    const fleet = view.scene.fleet ? `${Object.keys(view.scene.robots).length} robots` : null;
    const bits = [world && `world ${world}`, fleet || (robot && `robot ${robot}`), `created ${AGV.fmtClock(run.created)}`,
      run.started && `duration ${AGV.fmtDuration(AGV.runDuration(run))}`, `id ${run.id}`];
    const text = bits.filter(Boolean).join(" · ");
    if ($("meta").textContent !== text) $("meta").textContent = text;
    if (robot === "waffle") view.robotRadius = 0.2;
  }

  async function pollRun() {
    const r = await AGV.api(`/api/runs/${encodeURIComponent(runId)}`);
    if (r.status === 404) { $("name").textContent = "no such run"; $("hud").textContent = `run ${runId} not found`; return; }
    if (r.ok && r.data) {
      run = r.data;
      setMeta();
      showPace(run.pace);
      if (!lastState || AGV.FINAL.has(run.status) || run.status === "queued") setStatus(run.status);
      if (AGV.FINAL.has(run.status)) { onFinal(run.status, run.reason, run.result); return; }
      if (!ws) connect();
    }
    setTimeout(pollRun, 2000);
  }

  // ------------------------------------------------------------------ messages
  let lastClampToast = 0;
  function apply(msg, live) {
    const s = view.scene;
    // a robot's own message (a stream from before fleets names none: its one robot)
    const mine = () => view.robot(msg.robot ?? "robot");
    const picked = () => (msg.robot ?? "robot") === s.selected;
    switch (msg.type) {
      case "map": view.setMap(msg); break;
      case "zones": view.setZones(msg); break;
      case "robots": {
        s.fleet = !!msg.fleet;
        for (const r of msg.robots || []) {
          view.robot(r.name, r);
          if (!trees[r.name]) trees[r.name] = r.tree || [];
        }
        if (!s.fleet && msg.robots?.length) view.robotRadius = msg.robots[0].radius || view.robotRadius;
        pick(s.selected ?? msg.robots?.[0]?.name);
        robotsDirty = true;
        break;
      }
      case "rooms": s.rooms = msg.rooms || []; s.docks = msg.docks || []; break;
      case "recorded": s.recorded = Object.assign({}, msg.entries || {}); break;
      case "tree": {
        mine();
        trees[msg.robot ?? "robot"] = msg.nodes || [];
        if (picked()) { treeNodes = msg.nodes || []; treeDirty = true; }
        break;
      }
      case "plan": mine().plan = msg.path; break;
      case "horizon": mine().horizon = msg.path; break;
      case "people": s.people = msg.people; break;  // the world's, every robot's
      case "particles": mine().particles = msg.particles; break;
      case "goal": mine().goal = msg.pose; break;
      case "scan": mine().scan = msg.points; break;
      case "state": {
        const r = mine();
        states[r.name] = msg;
        r.truth = msg.pose; r.estimate = msg.estimate; r.covariance = msg.covariance || null;
        pushTrail(r.truthTrail, msg.pose); pushTrail(r.estTrail, msg.estimate);
        if (live) setStatus(msg.status);
        if (picked()) {
          lastState = msg;
          if (live) { task = msg.task || null; updateTeleop(); }
        }
        robotsDirty = true;
        break;
      }
      case "event": events.push(msg); eventsDirty = true; break;
      case "end": if (live) onFinal(msg.status, msg.reason, msg.result); break;
      case "error": toast(`live stream: ${msg.message}`, "bad"); break;
      case "clamped": {  // the pad may ask for more than the robot can: say so now and then
        const now = Date.now();
        if (now - lastClampToast > 5000) { lastClampToast = now; toast(msg.message, "bad"); }
        break;
      }
      default: break;
    }
    view.dirty = true;
  }

  function pushTrail(trail, p) {
    if (!p) return;
    const last = trail[trail.length - 1];
    if (last && Math.abs(last[0] - p.x) + Math.abs(last[1] - p.y) < 0.01) return;
    trail.push([p.x, p.y]);
    if (trail.length > 50000) trail.splice(0, 10000);
  }

  function connect() {
    // 25 of each frequent message a second: the map draws at most 20 frames a second, and
    // every message parsed is CPU taken from the simulation running beside the browser
    ws = new WebSocket(AGV.wsUrl(`/api/runs/${encodeURIComponent(runId)}/live`, { rate: LIVE_RATE }));
    events = []; eventsDirty = true;  // the stream sends the events so far after its snapshot
    ws.onmessage = (e) => {
      let msg;
      try { msg = JSON.parse(e.data); } catch (_) { return; }
      apply(msg, true);
    };
    ws.onclose = () => {
      ws = null;
      if (!finalShown) setTimeout(() => { if (!finalShown && !ws) connect(); }, 1000);
    };
  }

  function sendCmd(v, w) {
    const robot = view.scene.selected;
    if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({ type: "cmd_vel", v, w, robot }));
  }

  // ------------------------------------------------------------------ robots (a fleet's)
  let robotsDirty = false;
  const robotQuery = () => (view.scene.selected ? `?robot=${encodeURIComponent(view.scene.selected)}` : "");
  function colourOf(name) {
    const r = view.scene.robots[name];
    return view.scene.fleet && r && r.colour ? r.colour : null;
  }
  /** show robot NAME's tree, HUD, battery; teleop, goals and records go to it */
  function pick(name) {
    if (name == null || !view.scene.robots[name]) return;
    const changed = view.scene.selected !== name;
    view.scene.selected = name;
    treeNodes = trees[name] || null;
    lastState = states[name] || null;
    task = lastState?.task || null;
    treeDirty = true; robotsDirty = true; view.dirty = true;
    if (changed) held.clear();  // the robot left behind stops on its own (0.5 s without commands)
    updateTeleop();
  }
  view.onPick = (name) => pick(name);
  $("robots").addEventListener("click", (e) => {
    const chip = e.target.closest("[data-robot]");
    if (chip) pick(chip.dataset.robot);
  });
  function renderRobots() {
    robotsDirty = false;
    const s = view.scene;
    $("robotspanel").hidden = !s.fleet;
    const colour = colourOf(s.selected);
    const head = s.fleet && s.selected ? `<span class="sw" style="background:${colour}"></span>${AGV.esc(s.selected)}` : "";
    if ($("treerobot").innerHTML !== head) $("treerobot").innerHTML = head;
    if ($("teleoprobot").innerHTML !== head) $("teleoprobot").innerHTML = head;
    if (!s.fleet) return;
    const html = Object.values(s.robots).map((r) => {
      const t = states[r.name]?.task;
      const doing = t ? `${t.index + 1} ${t.type}` : (states[r.name] ? "idle" : "");
      return `<button class="robotchip${r.name === s.selected ? " picked" : ""}" data-robot="${AGV.esc(r.name)}" title="${AGV.esc(r.type || "")}">`
        + `<span class="sw" style="background:${r.colour}"></span>${AGV.esc(r.name)}<span class="task">${AGV.esc(doing)}</span></button>`;
    }).join("");
    if ($("robots").innerHTML !== html) $("robots").innerHTML = html;
  }

  // ------------------------------------------------------------------ HUD, tree, events
  const deg = (r) => (r * 180 / Math.PI).toFixed(1).padStart(6) + "°";
  const num = (v, w = 7, d = 3) => (typeof v === "number" ? v.toFixed(d) : "–").padStart(w);
  function updateHud() {
    const st = lastState;
    const lines = [];
    if (st) {
      const tk = st.task ? `task ${st.task.index + 1} ${st.task.type}` : "";
      if (view.scene.fleet) lines.push(`${view.scene.selected} (${view.scene.robots[view.scene.selected]?.type ?? ""})`);
      lines.push(`t ${num(st.t, 8, 1)} s   ${tk}`);
      lines.push(`v ${num(st.v, 6, 2)} m/s   w ${num(st.w, 6, 2)} rad/s`);
      if (st.pose) lines.push(`true x${num(st.pose.x)} y${num(st.pose.y)} θ${deg(st.pose.yaw)}`);
      if (st.estimate) {
        const err = st.pose ? Math.hypot(st.pose.x - st.estimate.x, st.pose.y - st.estimate.y) : null;
        lines.push(`est  x${num(st.estimate.x)} y${num(st.estimate.y)} θ${deg(st.estimate.yaw)}  err ${num(err, 5)} m`);
      }
      if (st.progress?.detail) lines.push(String(st.progress.detail).slice(0, 60));
    } else {
      lines.push(status === "queued" ? "queued: waiting for a worker" : "waiting for the stream…");
    }
    if (cursor) lines.push(`cursor x${num(cursor[0], 7, 2)} y${num(cursor[1], 7, 2)}`);
    const text = lines.join("\n");
    if ($("hud").textContent !== text) $("hud").textContent = text;
    updateBattery(st);
  }

  // The battery's level (0..1, null when the robot has none), charging or not, docked where.
  function updateBattery(st) {
    const box = $("battery");
    const level = st && typeof st.battery === "number" ? st.battery : null;
    box.hidden = level === null;
    if (level === null) return;
    box.dataset.level = String(level);  // the state of charge, 0..1 (tests read it)
    $("batteryfill").style.width = `${Math.max(0, Math.min(1, level)) * 100}%`;
    const text = `${(level * 100).toFixed(1)} %` + (st.docked ? ` · docked at ${st.docked}` : "");
    if ($("batterytext").textContent !== text) $("batterytext").textContent = text;
    box.classList.toggle("charging", !!st.charging);
    box.classList.toggle("low", level <= 0.2);
  }

  /** How far the tree is, from its nodes' statuses: of a task list's tasks ("task 2:
   *  patrol"), those finished; of one task (or a tree without tasks), the steps of its
   *  first node with more than one child (a visit's rooms, a round's waypoints). */
  function treeProgress(nodes) {
    if (!nodes || !nodes.length) return null;
    const st = (j) => String(nodes[j].status || "").toUpperCase();
    const isDone = (j) => st(j) === "SUCCESS" || st(j) === "FAILURE";
    const runningOf = (js) => { const j = js.find((k) => st(k) === "RUNNING"); return j != null ? nodes[j].name : null; };
    const tasks = nodes.map((n, j) => j).filter((j) => /^task \d+: /.test(nodes[j].name || ""));
    if (tasks.length > 1) return { done: tasks.filter(isDone).length, total: tasks.length, current: runningOf(tasks) };
    const childrenOf = (i) => {
      const d = nodes[i].depth || 0, out = [];
      for (let j = i + 1; j < nodes.length && (nodes[j].depth || 0) > d; j++) if ((nodes[j].depth || 0) === d + 1) out.push(j);
      return out;
    };
    let at = tasks.length ? tasks[0] : 0, kids = childrenOf(at);
    while (kids.length === 1) { at = kids[0]; kids = childrenOf(at); }
    if (!kids.length) kids = [at];
    return { done: kids.filter(isDone).length, total: kids.length, current: runningOf(kids) };
  }
  function updateProgress() {
    const p = treeProgress(treeNodes);
    $("progress").hidden = !p;
    if (!p) return;
    const succeeded = status === "succeeded";
    const done = succeeded ? p.total : p.done;
    $("progressbar").value = p.total ? done / p.total : 0;
    const tk = p.current || (lastState?.task ? `task ${lastState.task.index + 1} ${lastState.task.type}` : null);
    const text = `${done}/${p.total}` + (tk && !AGV.FINAL.has(status || "") ? ` · ${tk}` : "");
    if ($("progresstext").textContent !== text) $("progresstext").textContent = text;
  }

  function renderTree() {
    treeDirty = false;
    updateProgress();
    if (!treeNodes) return;
    const el = $("tree");
    const rows = treeNodes.map((n) => {
      const st = String(n.status || "INVALID").toUpperCase();
      const depth = n.depth || 0;
      let guides = "";
      for (let d = 0; d < depth; d++) guides += `<i class="guide" style="left:${d * 16 + 5}px"></i>`;
      return `<div class="node ${st}" style="padding-left:${depth * 16}px" title="${AGV.esc(n.name)}: ${st}">${guides}${depth ? '<span class="elbow"></span>' : ""}<span class="box">${AGV.esc(n.name)}</span></div>`;
    });
    el.innerHTML = `<div class="legend"><span class="l-r">running</span><span class="l-s">success</span><span class="l-f">failure</span><span class="l-i">idle</span></div>` + rows.join("");
    $("treet").textContent = `${treeNodes.length} nodes`;
    // keep the deepest running behaviour in view, unless the user scrolled the tree lately
    const running = el.querySelectorAll(".node.RUNNING");
    if (running.length && performance.now() - treeScrolledAt > 5000) {
      const node = running[running.length - 1];
      const top = node.getBoundingClientRect().top - el.getBoundingClientRect().top + el.scrollTop;
      if (top < el.scrollTop || top > el.scrollTop + el.clientHeight - 30) {
        autoScrolling = true;
        el.scrollTop = Math.max(0, top - el.clientHeight / 2);
      }
    }
  }
  let treeScrolledAt = -1e9, autoScrolling = false;
  $("tree").addEventListener("scroll", () => {
    if (autoScrolling) autoScrolling = false; else treeScrolledAt = performance.now();
  });

  function eventClass(name) {
    if (/fail|collision|abort|error|lost|timeout|deadlock/.test(name)) return "bad";
    if (/recover|fault|skip|kidnap|replan|retry|stuck|clear|wait|yield/.test(name)) return "warn";
    if (/reached|recorded|succeed|saved|done|complete/.test(name)) return "good";
    return "";
  }

  function renderEvents() {
    eventsDirty = false;
    const el = $("events");
    const atBottom = el.scrollTop + el.clientHeight >= el.scrollHeight - 20;
    const shown = events.slice(-500);
    const nowT = replay ? replay.t : Infinity;
    el.innerHTML = shown.map((e) => {
      const name = String(e.event ?? "event");
      const colour = e.robot != null ? colourOf(e.robot) : null;
      const kv = Object.entries(e).filter(([k]) => k !== "t" && k !== "event" && k !== "type" && !(k === "robot" && (colour || !view.scene.fleet)))
        .map(([k, v]) => `${k}=${typeof v === "object" ? JSON.stringify(v) : v}`).join("  ");
      const when = e.t ?? 0;
      const who = colour ? `<span class="robot"><span class="rsw" style="background:${colour}"></span>${AGV.esc(e.robot)}</span>` : "";
      return `<div class="ev ${eventClass(name)} ${when <= nowT ? "past" : "future"}" data-t="${when}"${colour ? ` data-robot="${AGV.esc(e.robot)}" style="border-left:3px solid ${colour};padding-left:4px"` : ""}>
        <span class="t">${AGV.fmtNum(when, 1)}</span><div><div class="name">${who}${AGV.esc(name)}</div><div class="kv">${AGV.esc(kv)}</div></div></div>`;
    }).join("") || `<div class="muted">no events yet</div>`;
    $("evcount").textContent = `${events.length}`;
    if (atBottom && !replay) el.scrollTop = el.scrollHeight;
  }
  $("events").addEventListener("click", (e) => {
    const row = e.target.closest(".ev[data-t]");
    if (row && replay) seek(parseFloat(row.dataset.t));
  });

  // DOM panels refresh at 5 Hz: each refresh is a layout and paint the simulation pays for
  setInterval(() => {
    if (treeDirty) renderTree();
    if (eventsDirty) renderEvents();
    if (robotsDirty) renderRobots();
    updateHud();
  }, 200);
  setInterval(() => { if (run && !AGV.FINAL.has(status || "")) setMeta(); }, 1000);

  // ------------------------------------------------------------------ teleop
  const held = new Set();
  let lastCmd = [0, 0];
  function teleopActive() {
    return (status === "running" || status === "paused") && task && task.type === "teleop";
  }
  function updateTeleop() {
    const on = !!teleopActive();
    $("teleop").classList.toggle("show", on);
    if (!on && view.goalMode) { view.setGoalMode(false); $("navgoal").classList.remove("on"); }
  }
  function command() {
    const k = parseFloat($("speed").value);
    const fwd = (held.has("ArrowUp") ? 1 : 0) - (held.has("ArrowDown") ? 1 : 0);
    const turn = (held.has("ArrowLeft") ? 1 : 0) - (held.has("ArrowRight") ? 1 : 0);
    return [+(0.2 * k * fwd).toFixed(3), +(0.9 * k * turn).toFixed(3)];
  }
  setInterval(() => {
    if (!teleopActive()) return;
    const [v, w] = command();
    if (held.size || lastCmd[0] || lastCmd[1]) {
      sendCmd(v, w);
      lastCmd = [v, w];
      $("cmd").textContent = `v ${v.toFixed(2)}  w ${w.toFixed(2)}`;
    }
  }, 100);
  const KEYS = new Set(["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight"]);
  document.addEventListener("keydown", (e) => {
    if (e.target.closest("input, textarea, select")) return;
    if (!teleopActive()) return;
    if (KEYS.has(e.key)) { held.add(e.key); e.preventDefault(); }
    if (e.key === " ") { held.clear(); sendCmd(0, 0); e.preventDefault(); }
  });
  document.addEventListener("keyup", (e) => { if (KEYS.has(e.key)) held.delete(e.key); });
  window.addEventListener("blur", () => held.clear());
  for (const b of document.querySelectorAll("#pad button")) {
    const key = b.dataset.key;
    b.addEventListener("pointerdown", (e) => {
      e.preventDefault();
      if (key === "stop") { held.clear(); sendCmd(0, 0); return; }
      held.add(key); b.classList.add("held");
      try { b.setPointerCapture(e.pointerId); } catch (_) { /* synthetic or already released */ }
    });
    const up = () => { held.delete(key); b.classList.remove("held"); };
    b.addEventListener("pointerup", up);
    b.addEventListener("pointercancel", up);
  }
  $("navgoal").onclick = () => {
    view.setGoalMode(!view.goalMode);
    $("navgoal").classList.toggle("on", view.goalMode);
  };
  view.onGoal = async (x, y, yaw) => {
    view.setGoalMode(false);
    $("navgoal").classList.remove("on");
    const pose = { x: +x.toFixed(3), y: +y.toFixed(3), yaw: +yaw.toFixed(3) };
    const r = await AGV.api(`/api/runs/${encodeURIComponent(runId)}/goal${robotQuery()}`, { method: "POST", body: pose });
    if (r.ok) { view.scene.goal = pose; view.dirty = true; toast(`goal set: x ${pose.x} y ${pose.y} yaw ${pose.yaw}`, "good"); }
    else toast(`goal refused: ${r.status} ${r.data?.detail ?? ""}`, "bad");
  };
  $("record").onclick = () => {
    const f = $("recform");
    f.classList.toggle("show");
    if (f.classList.contains("show")) $("reclabel").focus();
  };
  $("recform").addEventListener("submit", async (e) => {
    e.preventDefault();
    const label = $("reclabel").value.trim();
    if (!label) return;
    const r = await AGV.api(`/api/runs/${encodeURIComponent(runId)}/rooms/${encodeURIComponent(label)}${robotQuery()}`, { method: "POST" });
    if (r.ok) {
      const pose = r.data?.pose;
      if (pose) { view.scene.recorded[label] = pose; view.dirty = true; }
      toast(`${r.data?.confirmation ?? "saved"}: ${label}`, "good");
      $("reclabel").value = "";
      $("recform").classList.remove("show");
    } else {
      toast(`record ${label}: ${r.status} ${r.data?.detail ?? JSON.stringify(r.data)}`, "bad");
    }
  });

  // ------------------------------------------------------------------ end of run, result, replay
  async function onFinal(finalStatus, reason, result) {
    setStatus(finalStatus);
    if (finalShown) return;
    finalShown = true;
    if (ws) { ws.onclose = null; ws.close(); ws = null; }
    held.clear();
    updateTeleop();
    const r = await AGV.api(`/api/runs/${encodeURIComponent(runId)}`);
    if (r.ok && r.data) { run = r.data; setMeta(); setStatus(run.status); result = result || run.result; reason = reason ?? run.reason; }
    let files = [];
    for (let i = 0; i < 5; i++) {
      const f = await AGV.api(`/api/runs/${encodeURIComponent(runId)}/files`);
      files = (f.ok && f.data && f.data.files) || [];
      if (files.includes("stream.jsonl") && files.includes("result.json")) break;
      await new Promise((res) => setTimeout(res, 700));
    }
    if (!result && files.includes("result.json")) {
      const text = await AGV.fileText(runId, "result.json");
      try { result = JSON.parse(text); } catch (_) { result = null; }
    }
    renderResult(finalStatus, reason, result, files);
    if (files.includes("stream.jsonl")) loadReplay();
  }

  function renderResult(st, reason, result, files) {
    $("resultpanel").hidden = false;
    const m = (result && result.metrics) || {};
    const loc = m.localization || {}, nav = m.navigation || {};
    const rows = [
      ["sim time", result?.sim_time != null ? `${AGV.fmtNum(result.sim_time, 1)} s` : null],
      ["wall time", result?.wall_time != null ? `${AGV.fmtNum(result.wall_time, 1)} s` : null],
      ["real-time factor", m.real_time_factor != null ? `${m.real_time_factor}×` : null],
      ["distance", m.distance_driven != null ? `${AGV.fmtNum(m.distance_driven, 2)} m` : null],
      ["collisions", m.collisions ?? result?.collisions?.count ?? (typeof result?.collisions === "number" ? result.collisions : null)],
      ["min clearance", m.min_clearance != null ? `${AGV.fmtNum(m.min_clearance, 3)} m` : null],
      ["loc. RMSE", loc.position_rmse != null ? `${AGV.fmtNum(loc.position_rmse, 3)} m (max ${AGV.fmtNum(loc.position_max_error, 3)})` : null],
      ["plans / replans", nav.plans != null ? `${nav.plans} / ${nav.replans ?? 0}` : null],
    ];
    const fleet = result?.fleet;
    if (fleet) {
      rows.push(["makespan", fleet.makespan != null ? `${AGV.fmtNum(fleet.makespan, 1)} s` : null],
        ["robot-robot collisions", Array.isArray(fleet.robot_robot_collisions) ? fleet.robot_robot_collisions.length : fleet.robot_robot_collisions],
        ["closest robots", fleet.robot_robot_min_distance != null ? `${AGV.fmtNum(fleet.robot_robot_min_distance, 3)} m` : null],
        ["waits", fleet.waits ? `${fleet.waits.count} (${AGV.fmtNum(fleet.waits.time, 1)} s)` : null],
        ["deadlocks", fleet.deadlocks],
        ["dispatched", Array.isArray(fleet.dispatch) ? fleet.dispatch.length : null]);
    }
    const shownRows = rows.filter(([, v]) => v != null && v !== "");
    // a fleet's result: each robot's status in its colour
    const perRobot = Object.entries(result?.robots || {}).map(([name, r]) => {
      const colour = colourOf(name) || "#8a96a6";
      const done = (r.tasks || []).filter((t) => t.status === "succeeded").length;
      return `<div class="robotresult" data-robot="${AGV.esc(name)}"><span class="robot"><span class="rsw" style="background:${colour}"></span>${AGV.esc(name)}</span> ${AGV.badge(r.status)} <span class="muted">${done}/${(r.tasks || []).length} tasks${r.reason ? " · " + AGV.esc(r.reason) : ""}</span></div>`;
    }).join("");
    const tasks = (result?.tasks || []).map((t) => {
      const wps = t.waypoints ? ` · ${t.waypoints.filter((w) => w.status === "reached").length}/${t.waypoints.length} waypoints` : "";
      const rooms = t.rooms ? ` · ${t.rooms.filter((w) => w.status === "reached").length}/${t.rooms.length} rooms` : "";
      return `<div>${AGV.esc(t.index ?? "")} ${AGV.esc(t.type)} ${AGV.badge(t.status)}${AGV.esc(wps + rooms)}${t.reason ? ` <span class="muted">${AGV.esc(t.reason)}</span>` : ""}</div>`;
    }).join("");
    const links = files.map((f) => `<a href="${AGV.fileUrl(runId, f)}" data-file="${AGV.esc(f)}" target="_blank" rel="noopener">${AGV.esc(f)}</a>`).join("");
    $("result").innerHTML = `
      <p class="reason">${AGV.badge(st)} ${AGV.esc(reason || "")}</p>
      <dl>${shownRows.map(([k, v]) => `<dt>${k}</dt><dd>${AGV.esc(v)}</dd>`).join("")}</dl>
      ${perRobot ? `<div class="robotresults">${perRobot}</div>` : ""}
      ${tasks ? `<div style="margin-top:8px;display:flex;flex-direction:column;gap:3px">${tasks}</div>` : ""}
      <div class="files">${links || '<span class="muted">no files</span>'}</div>
      ${files.includes("run.png") ? `<img ${AGV.token() ? "data-src" : "src"}="${AGV.fileUrl(runId, "run.png")}" alt="run.png">` : ""}`;
    AGV.authoriseFiles($("result"));
    if (result?.events && !events.length) { events = result.events.slice(); eventsDirty = true; }
  }

  async function loadReplay() {
    const text = await AGV.fileText(runId, "stream.jsonl");
    if (!text) return;
    const msgs = [];
    let t = 0;
    for (const line of text.split("\n")) {
      if (!line.trim()) continue;
      let m;
      try { m = JSON.parse(line); } catch (_) { continue; }
      if (typeof m.t === "number") t = m.t;
      m._t = t;
      msgs.push(m);
    }
    if (!msgs.length) return;
    let t0 = Infinity;
    for (const m of msgs) if (m.type === "state") { t0 = m._t; break; }
    if (!isFinite(t0)) t0 = msgs[0]._t;
    const t1 = msgs[msgs.length - 1]._t;
    const evs = msgs.filter((m) => m.type === "event");
    if (evs.length) events = evs.map((m) => { const c = Object.assign({}, m); delete c._t; delete c.type; return c; });
    replay = { msgs, t0, t1, idx: 0, t: -Infinity, mapMsg: null, shownMap: null, playing: false };
    window.agvReplay = replay;
    const scrub = $("scrub");
    scrub.min = t0; scrub.max = t1; scrub.step = 0.1;
    $("replaypanel").hidden = false;
    const span = Math.max(1e-6, t1 - t0);
    $("ticks").innerHTML = events.map((e) => {
      const colour = e.robot != null ? colourOf(e.robot) : null;
      const who = colour ? `${e.robot}: ` : "";
      return `<i class="${eventClass(String(e.event))}" style="left:${(((e.t ?? t0) - t0) / span * 100).toFixed(2)}%${colour ? `;background:${colour}` : ""}" title="${AGV.esc(who + e.event)} @ ${AGV.fmtNum(e.t, 1)} s"></i>`;
    }).join("");
    seek(t1);
  }

  /** show the run as it was at sim time T (incremental when moving forward) */
  function seek(T) {
    if (!replay) return;
    const R = replay;
    T = Math.max(R.t0, Math.min(R.t1, T));
    if (T < R.t) {
      view.reset();
      R.idx = 0; R.mapMsg = null; lastState = null; treeNodes = null; trees = {}; states = {};
    }
    while (R.idx < R.msgs.length && R.msgs[R.idx]._t <= T) {
      const m = R.msgs[R.idx++];
      if (m.type === "map") R.mapMsg = m;
      else if (m.type === "event" || m.type === "end") continue;
      else apply(m, false);
    }
    if (R.mapMsg && R.mapMsg !== R.shownMap) { R.shownMap = R.mapMsg; view.setMap(R.mapMsg); }
    R.t = T;
    $("scrub").value = T;
    $("scrubt").textContent = `${T.toFixed(1)} / ${R.t1.toFixed(1)} s`;
    eventsDirty = true; treeDirty = true; robotsDirty = true;
    view.dirty = true;
  }
  $("scrub").addEventListener("input", (e) => seek(parseFloat(e.target.value)));
  $("play").onclick = () => {
    if (!replay) return;
    replay.playing = !replay.playing;
    $("play").textContent = replay.playing ? "❚❚" : "▶";
    if (replay.playing && replay.t >= replay.t1) seek(replay.t0);
    let last = performance.now();
    const step = (now) => {
      if (!replay.playing) return;
      const dt = (now - last) / 1000; last = now;
      seek(replay.t + dt * parseFloat($("rate").value));
      if (replay.t >= replay.t1) { replay.playing = false; $("play").textContent = "▶"; return; }
      requestAnimationFrame(step);
    };
    requestAnimationFrame(step);
  };

  pollRun();
})();
