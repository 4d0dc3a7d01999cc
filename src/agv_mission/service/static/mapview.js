// The run page's map: an occupancy grid rendered once to an offscreen canvas, and the live
// layers (rooms, poses, trails, scan, particles, paths, goal) drawn over it at
// requestAnimationFrame, only when something changed. Pan (drag), zoom (wheel, pinch),
// and a "2D Nav Goal" mode (press at the goal, drag for the heading) as in RViz.
// Every robot of a fleet has its own layers (scene.robots) in its own colour: pose, trail,
// plan and goal of all; scan, particles and horizon of the picked one (a click picks).
"use strict";

const MAP_PALETTE = {
  free: [40, 46, 55], occupied: [222, 229, 238], unknown: [21, 25, 31],
};
const LAYER_STYLE = {
  truth: "#4aa3ff", estimate: "#ffb020", scan: "#ff2e63", particles: "#b58cff",
  plan: "#3ecf8e", horizon: "#ffe066", goal: "#ff7ad9", rooms: "#8fa3bf", recorded: "#3ecf8e", dock: "#ffd43b",
  people: "#ff8c1a",
};
const ROOM_HUES = [205, 140, 30, 280, 350, 60, 180, 100, 320, 240];

class MapView {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d", { alpha: false });
    this.scene = this.emptyScene();
    this.layers = { map: true, rooms: true, trails: true, scan: true, particles: true, plan: true,
      horizon: true, goal: true, truth: true, estimate: true, recorded: true, zones: true, people: true };
    this.view = { cx: 0, cy: 0, scale: 40 };
    this.fitted = false;
    this.follow = false;
    this.goalMode = false;
    this.onGoal = null;         // (x, y, yaw) => void, called when a goal is placed
    this.onCursor = null;
    this.onPick = null;         // (name) => void, called when a robot is clicked on the map
    this.robotRadius = 0.11;
    this.alwaysDraw = false;    // benchmarks: redraw every frame
    // Stream updates are drawn at most 20 times a second; interaction (pan, zoom) at the
    // next frame. A frame is requested only when something changed: every drawn frame costs
    // the browser a raster and a composite, taken from the simulation running beside it.
    this.streamFrameMs = 1000 / 20;
    this.urgent = false;
    this.lastDraw = -1e9;
    this.pending = false;
    this._dirty = false;
    this.stats = { frames: 0, rafs: 0, drawMs: 0 };
    this.pointers = new Map();
    this.drag = null;
    this.cursor = null;
    this.W = 0; this.H = 0;
    this.installInput();
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
  }

  get dirty() { return this._dirty; }
  set dirty(value) { this._dirty = value; if (value) this.schedule(); }

  schedule() {
    if (this.pending) return;
    this.pending = true;
    const wait = this.urgent || this.alwaysDraw ? 0 : this.lastDraw + this.streamFrameMs - performance.now();
    if (wait > 4) setTimeout(() => requestAnimationFrame((t) => this.frame(t)), wait);
    else requestAnimationFrame((t) => this.frame(t));
  }

  frame(now) {
    this.pending = false;
    this.stats.rafs++;
    if (!this._dirty && !this.alwaysDraw) return;
    const t0 = performance.now();
    this.draw();
    this.stats.drawMs += performance.now() - t0;
    this.stats.frames++;
    this._dirty = false;
    this.urgent = false;
    this.lastDraw = now;
    if (this.alwaysDraw) this.schedule();
  }

  /** benchmarks: draw every frame (true) or only on change (false) */
  setAlwaysDraw(on) { this.alwaysDraw = on; if (on) this.schedule(); }

  emptyScene() {
    // robots: name -> its layers (insertion order: the run's order); truth, goal, ... read
    // the picked robot's (a one-robot run's only one); people are the world's
    const scene = { map: null, rooms: [], docks: [], recorded: {}, robots: {}, selected: null, fleet: false,
      people: null,
      pendingGoal: null };
    for (const k of ["truth", "estimate", "covariance", "truthTrail", "estTrail", "scan", "particles", "plan", "horizon", "goal"]) {
      Object.defineProperty(scene, k, {
        get() { const r = this.robots[this.selected]; return r ? r[k] : null; },
        set(v) { const r = this.robots[this.selected]; if (r) r[k] = v; },
      });
    }
    return scene;
  }

  /** the layers of robot NAME (made on first use: a stream from before fleets names none) */
  robot(name, info) {
    const s = this.scene;
    let r = s.robots[name];
    if (!r) {
      r = s.robots[name] = { name, colour: null, radius: null, type: null, truth: null, estimate: null, covariance: null,
        truthTrail: [], estTrail: [], scan: null, particles: null, plan: null, horizon: null, goal: null };
      if (s.selected == null) s.selected = name;
    }
    if (info) Object.assign(r, { colour: info.colour || r.colour, radius: info.radius || r.radius, type: info.type || r.type, footprint: info.footprint || r.footprint || null });
    return r;
  }

  reset() {
    const old = this.scene;
    this.scene = this.emptyScene();
    for (const k of ["map", "rooms", "zones", "fleet", "docks"]) this.scene[k] = old[k];
    for (const r of Object.values(old.robots)) this.robot(r.name, r);
    this.scene.selected = old.selected;
    this.dirty = true;
  }

  /** the robot drawn nearest to screen point (sx, sy), within its footprint and a few pixels */
  robotAt(sx, sy) {
    let best = null, bestD = Infinity;
    for (const r of Object.values(this.scene.robots)) {
      if (!r.truth) continue;
      const [x, y] = this.toScreen(r.truth.x, r.truth.y);
      const d = Math.hypot(x - sx, y - sy);
      const reach = Math.max(12, (r.radius || this.robotRadius) * this.view.scale + 6);
      if (d <= reach && d < bestD) { best = r.name; bestD = d; }
    }
    return best;
  }

  resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = this.canvas.clientWidth, h = this.canvas.clientHeight;
    if (!w || !h) return;
    this.W = w; this.H = h;
    this.canvas.width = Math.round(w * dpr);
    this.canvas.height = Math.round(h * dpr);
    this.dpr = dpr;
    if (!this.fitted && this.scene.map) this.fit();
    this.touch();
  }

  /** decode a `map` message (base64 grayscale PNG, row 0 = top) into the offscreen canvas */
  setMap(msg) {
    const img = new Image();
    img.onload = () => {
      const off = document.createElement("canvas");
      off.width = msg.width || img.width;
      off.height = msg.height || img.height;
      const octx = off.getContext("2d");
      octx.drawImage(img, 0, 0, off.width, off.height);
      const data = octx.getImageData(0, 0, off.width, off.height);
      const px = data.data;
      const lut = new Uint8ClampedArray(256 * 3);
      for (let v = 0; v < 256; v++) {
        let c;
        if (v === 205) c = MAP_PALETTE.unknown;
        else {
          const f = Math.min(1, v / 254);
          c = MAP_PALETTE.occupied.map((o, i) => o + (MAP_PALETTE.free[i] - o) * f);
        }
        lut[v * 3] = c[0]; lut[v * 3 + 1] = c[1]; lut[v * 3 + 2] = c[2];
      }
      // the known part of the map (ROS maps often carry a wide unknown border): Fit frames it
      let r0 = off.height, r1 = -1, c0 = off.width, c1 = -1;
      for (let i = 0; i < px.length; i += 4) {
        const v = px[i];
        if (v !== 205) {
          const k = i >> 2, row = (k / off.width) | 0, col = k - row * off.width;
          if (row < r0) r0 = row; if (row > r1) r1 = row;
          if (col < c0) c0 = col; if (col > c1) c1 = col;
        }
        px[i] = lut[v * 3]; px[i + 1] = lut[v * 3 + 1]; px[i + 2] = lut[v * 3 + 2]; px[i + 3] = 255;
      }
      octx.putImageData(data, 0, 0);
      const res = msg.resolution, [ox, oy] = msg.origin;
      const known = r1 < 0 ? null : [ox + c0 * res, oy + (off.height - 1 - r1) * res,
        ox + (c1 + 1) * res, oy + (off.height - r0) * res];
      this.scene.map = { canvas: off, resolution: res, origin: msg.origin,
        width: off.width, height: off.height, known };
      if (!this.fitted) this.fit();
      this.dirty = true;
    };
    img.src = "data:image/png;base64," + msg.png;
  }

  /** decode a `zones` message (base64 RGBA PNG of keepout and speed zones, row 0 = top) */
  setZones(msg) {
    const img = new Image();
    img.onload = () => {
      const off = document.createElement("canvas");
      off.width = msg.width; off.height = msg.height;
      off.getContext("2d").drawImage(img, 0, 0, off.width, off.height);
      this.scene.zones = { canvas: off, resolution: msg.resolution, origin: msg.origin,
        width: msg.width, height: msg.height };
      this.dirty = true;
    };
    img.src = "data:image/png;base64," + msg.png;
  }

  /** the known part of the map in view, as large as it fits */
  fit() {
    const m = this.scene.map;
    const w = this.W, h = this.H;
    if (!m || !w || !h) return;
    let [x0, y0, x1, y1] = m.known || [m.origin[0], m.origin[1],
      m.origin[0] + m.width * m.resolution, m.origin[1] + m.height * m.resolution];
    const grow = (a, b) => { const pad = Math.max(0, 8 - (b - a)) / 2; return [a - pad, b + pad]; };
    [x0, x1] = grow(x0, x1);  // a SLAM map starts as a few metres: frame 8 m at least
    [y0, y1] = grow(y0, y1);
    this.view.cx = (x0 + x1) / 2;
    this.view.cy = (y0 + y1) / 2;
    this.view.scale = Math.min(w / (x1 - x0), h / (y1 - y0)) * 0.95;
    this.fitted = true;
    this.touch();
  }

  /** redraw at the next frame, not at the stream's pace (the user is moving the view) */
  touch() { this.urgent = true; this.dirty = true; }

  zoomBy(factor, sx, sy) {
    const w = this.W, h = this.H;
    if (sx == null) { sx = w / 2; sy = h / 2; }
    const [wx, wy] = this.toWorld(sx, sy);
    this.view.scale = Math.max(2, Math.min(2000, this.view.scale * factor));
    this.view.cx = wx - (sx - w / 2) / this.view.scale;
    this.view.cy = wy + (sy - h / 2) / this.view.scale;
    this.touch();
  }

  toWorld(sx, sy) {
    const w = this.W, h = this.H;
    return [this.view.cx + (sx - w / 2) / this.view.scale, this.view.cy - (sy - h / 2) / this.view.scale];
  }

  toScreen(x, y) {
    const w = this.W, h = this.H;
    return [w / 2 + (x - this.view.cx) * this.view.scale, h / 2 - (y - this.view.cy) * this.view.scale];
  }

  setGoalMode(on) {
    this.goalMode = on;
    this.canvas.classList.toggle("goalmode", on);
  }

  installInput() {
    const c = this.canvas;
    const local = (e) => { const r = c.getBoundingClientRect(); return [e.clientX - r.left, e.clientY - r.top]; };
    c.addEventListener("pointerdown", (e) => {
      try { c.setPointerCapture(e.pointerId); } catch (_) { /* synthetic or already released */ }
      const p = local(e);
      this.pointers.set(e.pointerId, p);
      if (this.goalMode && this.pointers.size === 1) {
        const [x, y] = this.toWorld(...p);
        this.scene.pendingGoal = { x, y, yaw: 0, sx: p[0], sy: p[1] };
        this.drag = { kind: "goal" };
      } else if (this.pointers.size === 1) {
        this.drag = { kind: "pan", last: p, start: p };
      } else if (this.pointers.size === 2) {
        const [a, b] = [...this.pointers.values()];
        this.drag = { kind: "pinch", dist: Math.hypot(a[0] - b[0], a[1] - b[1]) };
        this.scene.pendingGoal = null;
      }
      this.touch();
    });
    c.addEventListener("pointermove", (e) => {
      const p = local(e);
      this.cursor = this.toWorld(...p);
      if (this.onCursor) this.onCursor(this.cursor);
      if (!this.pointers.has(e.pointerId)) return;
      this.pointers.set(e.pointerId, p);
      if (!this.drag) return;
      if (this.drag.kind === "pan") {
        const [lx, ly] = this.drag.last;
        this.view.cx -= (p[0] - lx) / this.view.scale;
        this.view.cy += (p[1] - ly) / this.view.scale;
        this.drag.last = p;
        if (Math.hypot(p[0] - lx, p[1] - ly) > 0) this.follow = false;
      } else if (this.drag.kind === "goal" && this.scene.pendingGoal) {
        const g = this.scene.pendingGoal;
        if (Math.hypot(p[0] - g.sx, p[1] - g.sy) > 4) g.yaw = Math.atan2(-(p[1] - g.sy), p[0] - g.sx);
      } else if (this.drag.kind === "pinch" && this.pointers.size === 2) {
        const [a, b] = [...this.pointers.values()];
        const dist = Math.hypot(a[0] - b[0], a[1] - b[1]);
        if (this.drag.dist > 0) this.zoomBy(dist / this.drag.dist, (a[0] + b[0]) / 2, (a[1] + b[1]) / 2);
        this.drag.dist = dist;
      }
      if (this.drag) this.touch();
    });
    const end = (e) => {
      this.pointers.delete(e.pointerId);
      if (e.type === "pointerup" && this.drag && this.drag.kind === "pan" && this.onPick) {
        const p = local(e), [x0, y0] = this.drag.start;
        const name = Math.hypot(p[0] - x0, p[1] - y0) < 5 ? this.robotAt(p[0], p[1]) : null;
        if (name) this.onPick(name);
      }
      if (this.drag && this.drag.kind === "goal" && this.scene.pendingGoal) {
        const g = this.scene.pendingGoal;
        this.scene.pendingGoal = null;
        if (this.onGoal) this.onGoal(g.x, g.y, g.yaw);
      }
      this.drag = this.pointers.size ? this.drag : null;
      if (this.drag && this.drag.kind === "pinch") this.drag = null;
      this.touch();
    };
    c.addEventListener("pointerup", end);
    c.addEventListener("pointercancel", end);
    c.addEventListener("wheel", (e) => {
      e.preventDefault();
      const p = local(e);
      this.zoomBy(Math.exp(-e.deltaY * 0.0015), p[0], p[1]);
    }, { passive: false });
    c.addEventListener("dblclick", () => this.fit());
  }

  // ---------------------------------------------------------------- drawing
  draw() {
    const ctx = this.ctx, dpr = this.dpr || 1;
    const w = this.W, h = this.H;
    const s = this.scene, L = this.layers, S = this.view.scale;
    if (this.follow && s.truth) { this.view.cx = s.truth.x; this.view.cy = s.truth.y; }  // the picked robot
    const P = (x, y) => this.toScreen(x, y);
    // The map, grid and room outlines change only with the view: rendered once per view into
    // a cached layer, then copied 1:1 each frame (a software raster of the scaled map and the
    // translucent rooms costs several milliseconds a frame).
    const key = [this.canvas.width, this.canvas.height, this.view.cx, this.view.cy, S, L.map, L.rooms, L.zones].join("|");
    if (key !== this.staticKey || s.map !== this.staticMap || s.rooms !== this.staticRooms
        || s.zones !== this.staticZones) {
      if (!this.staticCanvas) this.staticCanvas = document.createElement("canvas");
      const sc = this.staticCanvas;
      if (sc.width !== this.canvas.width || sc.height !== this.canvas.height) {
        sc.width = this.canvas.width; sc.height = this.canvas.height;
      }
      const sctx = sc.getContext("2d");
      sctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      this.drawStatic(sctx, P, w, h);
      this.staticKey = key; this.staticMap = s.map; this.staticRooms = s.rooms; this.staticZones = s.zones;
    }
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(this.staticCanvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    const robots = Object.values(s.robots), picked = s.robots[s.selected];
    // a one-robot run keeps its layer colours; a fleet's robots are each in their own colour
    const tint = (r, layer) => (s.fleet && r.colour ? r.colour : LAYER_STYLE[layer]);
    if (L.particles && picked && picked.particles) {
      ctx.strokeStyle = LAYER_STYLE.particles; ctx.globalAlpha = 0.7; ctx.lineWidth = 1;
      ctx.beginPath();
      const len = Math.max(4, Math.min(12, 0.12 * S));
      for (const q of picked.particles) {
        const [x, y] = P(q[0], q[1]);
        ctx.moveTo(x, y);
        ctx.lineTo(x + Math.cos(q[2]) * len, y - Math.sin(q[2]) * len);
      }
      ctx.stroke();
      ctx.fillStyle = LAYER_STYLE.particles;
      for (const q of picked.particles) { const [x, y] = P(q[0], q[1]); ctx.fillRect(x - 1, y - 1, 2, 2); }
      ctx.globalAlpha = 1;
    }
    if (L.trails) {
      for (const r of robots) {
        this.polyline(ctx, P, r.estTrail, s.fleet ? tint(r, "estimate") : LAYER_STYLE.estimate, 1.5, [4, 3], s.fleet ? 0.45 : 0.8);
        this.polyline(ctx, P, r.truthTrail, tint(r, "truth"), 2, null, 0.8);
      }
    }
    if (L.plan) for (const r of robots) if (r.plan) this.polyline(ctx, P, r.plan, tint(r, "plan"), 2.5, s.fleet ? [8, 4] : null, 0.95);
    if (L.horizon && picked && picked.horizon) {
      this.polyline(ctx, P, picked.horizon, LAYER_STYLE.horizon, 3, null, 0.9);
      ctx.fillStyle = LAYER_STYLE.horizon;
      for (const q of picked.horizon) { const [x, y] = P(q[0], q[1]); ctx.fillRect(x - 1.5, y - 1.5, 3, 3); }
    }
    if (L.people && s.people) {  // [id, x, y, radius] each: a disc the size of the body
      ctx.fillStyle = LAYER_STYLE.people;
      ctx.globalAlpha = 0.85;
      ctx.beginPath();
      for (const q of s.people) {
        const [x, y] = P(q[1], q[2]);
        const r = Math.max(2, q[3] * S);
        ctx.moveTo(x + r, y);
        ctx.arc(x, y, r, 0, 2 * Math.PI);
      }
      ctx.fill();
      ctx.globalAlpha = 1;
    }
    if (L.scan && picked && picked.scan) {
      ctx.fillStyle = LAYER_STYLE.scan;
      const r = Math.max(2.5, Math.min(4, 0.04 * S));
      for (const q of picked.scan) { const [x, y] = P(q[0], q[1]); ctx.fillRect(x - r / 2, y - r / 2, r, r); }
    }
    if (L.goal) for (const r of robots) if (r.goal) this.drawArrow(ctx, P, r.goal, tint(r, "goal"), 0.5, true);
    if (s.pendingGoal) this.drawArrow(ctx, P, s.pendingGoal, "#ffffff", 0.6, true);
    if (L.rooms) this.drawRoomLabels(ctx, P);
    if (L.rooms) this.drawDocks(ctx, P);
    if (L.recorded) this.drawRecorded(ctx, P);
    for (const r of robots) {
      const radius = r.radius || this.robotRadius;
      if (L.estimate && r.estimate) {
        if (r.covariance && r === picked) this.drawCovariance(ctx, P, r.estimate, r.covariance);
        this.drawRobot(ctx, P, r.estimate, LAYER_STYLE.estimate, false, radius, r.footprint);
      }
      if (L.truth && r.truth) this.drawRobot(ctx, P, r.truth, tint(r, "truth"), true, radius, r.footprint);
    }
    if (s.fleet) {
      ctx.font = "600 11px system-ui, sans-serif";
      ctx.textAlign = "left"; ctx.textBaseline = "middle";
      for (const r of robots) {
        if (!r.truth) continue;
        const [x, y] = P(r.truth.x, r.truth.y);
        const rad = Math.max(6, (r.radius || this.robotRadius) * S);
        if (r === picked) {
          ctx.strokeStyle = "#ffffff"; ctx.lineWidth = 2; ctx.setLineDash([3, 3]);
          ctx.beginPath(); ctx.arc(x, y, rad + 5, 0, Math.PI * 2); ctx.stroke(); ctx.setLineDash([]);
        }
        const tw = ctx.measureText(r.name).width;
        ctx.fillStyle = "rgba(11,13,16,0.72)"; ctx.fillRect(x + rad + 4, y - rad - 16, tw + 8, 15);
        ctx.fillStyle = r.colour || "#ffffff"; ctx.fillText(r.name, x + rad + 8, y - rad - 8.5);
      }
    }
    this.drawScaleBar(ctx, w, h);
  }

  drawStatic(ctx, P, w, h) {
    const s = this.scene, L = this.layers, S = this.view.scale;
    ctx.fillStyle = "#0b0d10";
    ctx.fillRect(0, 0, w, h);
    if (s.map && L.map) {
      const m = s.map;
      const [ox, oy] = P(m.origin[0], m.origin[1] + m.height * m.resolution);
      ctx.imageSmoothingEnabled = S * m.resolution < 1.5;
      ctx.drawImage(m.canvas, ox, oy, m.width * m.resolution * S, m.height * m.resolution * S);
      this.drawGrid(ctx, w, h);
    }
    if (s.zones && L.zones) {
      const z = s.zones;
      const [zx, zy] = P(z.origin[0], z.origin[1] + z.height * z.resolution);
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(z.canvas, zx, zy, z.width * z.resolution * S, z.height * z.resolution * S);
    }
    if (L.rooms) this.drawRooms(ctx, P);
  }

  drawGrid(ctx, w, h) {
    // 1 m grid lines once a metre is at least 25 px; otherwise they would be noise
    const S = this.view.scale;
    const step = S >= 25 ? 1 : S >= 5 ? 5 : 0;
    if (!step) return;
    const [x0, y1] = this.toWorld(0, 0), [x1, y0] = this.toWorld(w, h);
    ctx.strokeStyle = "rgba(120,140,170,0.10)"; ctx.lineWidth = 1;
    ctx.beginPath();
    for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) { const sx = Math.round(this.toScreen(x, 0)[0]) + 0.5; ctx.moveTo(sx, 0); ctx.lineTo(sx, h); }
    for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) { const sy = Math.round(this.toScreen(0, y)[1]) + 0.5; ctx.moveTo(0, sy); ctx.lineTo(w, sy); }
    ctx.stroke();
    const [ax, ay] = this.toScreen(0, 0);
    ctx.lineWidth = 2;
    ctx.strokeStyle = "rgba(242,85,90,0.8)"; ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(ax + 0.5 * S, ay); ctx.stroke();
    ctx.strokeStyle = "rgba(62,207,142,0.8)"; ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(ax, ay - 0.5 * S); ctx.stroke();
  }

  polyline(ctx, P, pts, color, width, dash, alpha) {
    if (!pts || pts.length < 2) return;
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.globalAlpha = alpha ?? 1;
    ctx.lineJoin = "round"; ctx.lineCap = "round";
    ctx.setLineDash(dash || []);
    ctx.beginPath();
    let [lx, ly] = P(pts[0][0], pts[0][1]);
    ctx.moveTo(lx, ly);
    const n = pts.length;
    for (let i = 1; i < n; i++) {
      const [x, y] = P(pts[i][0], pts[i][1]);
      if (i < n - 1 && Math.abs(x - lx) + Math.abs(y - ly) < 1.5) continue;  // sub-pixel: skip
      ctx.lineTo(x, y); lx = x; ly = y;
    }
    ctx.stroke();
    ctx.setLineDash([]); ctx.globalAlpha = 1;
  }

  drawRooms(ctx, P) {
    const rooms = this.scene.rooms || [];
    rooms.forEach((room, i) => {
      const poly = room.polygon || [];
      if (poly.length < 3) return;
      const hue = ROOM_HUES[i % ROOM_HUES.length];
      ctx.beginPath();
      poly.forEach((q, k) => { const [x, y] = P(q[0], q[1]); if (k) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
      ctx.closePath();
      ctx.fillStyle = `hsla(${hue}, 70%, 55%, 0.08)`;
      ctx.fill();
      ctx.strokeStyle = `hsla(${hue}, 70%, 65%, 0.55)`; ctx.lineWidth = 1.2; ctx.setLineDash([6, 4]);
      ctx.stroke(); ctx.setLineDash([]);
      if (room.anchor) {
        const [ax, ay] = P(room.anchor.x, room.anchor.y);
        ctx.fillStyle = `hsla(${hue}, 70%, 65%, 0.9)`;
        ctx.beginPath(); ctx.moveTo(ax, ay - 5); ctx.lineTo(ax + 5, ay); ctx.lineTo(ax, ay + 5); ctx.lineTo(ax - 5, ay); ctx.fill();
      }
    });
  }

  drawRoomLabels(ctx, P) {
    ctx.font = "600 12px system-ui, sans-serif";
    ctx.textAlign = "center"; ctx.textBaseline = "middle";
    (this.scene.rooms || []).forEach((room, i) => {
      const poly = room.polygon || [];
      if (poly.length < 3) return;
      let cx = 0, cy = 0;
      for (const q of poly) { cx += q[0]; cy += q[1]; }
      const [lx, ly] = P(cx / poly.length, cy / poly.length);
      const tw = ctx.measureText(room.label).width;
      ctx.fillStyle = "rgba(11,13,16,0.72)";
      ctx.fillRect(lx - tw / 2 - 5, ly - 9, tw + 10, 18);
      ctx.fillStyle = `hsl(${ROOM_HUES[i % ROOM_HUES.length]}, 70%, 72%)`;
      ctx.fillText(room.label, lx, ly);
    });
  }

  // A dock: the charger as a bar across its axis 0.2 m ahead of the docked pose, and its name.
  drawDocks(ctx, P) {
    ctx.font = "600 11px system-ui, sans-serif";
    ctx.textAlign = "center"; ctx.textBaseline = "middle";
    for (const d of this.scene.docks || []) {
      const c = Math.cos(d.yaw || 0), s = Math.sin(d.yaw || 0);
      const fx = d.x + 0.2 * c, fy = d.y + 0.2 * s;
      const [ax, ay] = P(fx - 0.12 * s, fy + 0.12 * c), [bx, by] = P(fx + 0.12 * s, fy - 0.12 * c);
      ctx.strokeStyle = LAYER_STYLE.dock; ctx.lineWidth = 4;
      ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(bx, by); ctx.stroke();
      const [lx, ly] = P(d.x - 0.35 * c, d.y - 0.35 * s);
      ctx.fillStyle = LAYER_STYLE.dock; ctx.fillText("⚡ " + d.name, lx, ly);
    }
  }

  drawRecorded(ctx, P) {
    const entries = this.scene.recorded || {};
    ctx.font = "600 11px system-ui, sans-serif";
    ctx.textAlign = "left"; ctx.textBaseline = "middle";
    for (const [label, pose] of Object.entries(entries)) {
      if (!pose) continue;
      const [x, y] = P(pose.x, pose.y);
      ctx.strokeStyle = LAYER_STYLE.recorded; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.arc(x, y, 7, 0, Math.PI * 2); ctx.stroke();
      ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x + Math.cos(pose.yaw || 0) * 14, y - Math.sin(pose.yaw || 0) * 14); ctx.stroke();
      const text = "✓ " + label;
      const tw = ctx.measureText(text).width;
      ctx.fillStyle = "rgba(11,30,22,0.85)"; ctx.fillRect(x + 10, y - 17, tw + 8, 16);
      ctx.fillStyle = LAYER_STYLE.recorded; ctx.fillText(text, x + 14, y - 9);
    }
  }

  drawArrow(ctx, P, pose, color, length, ring) {
    const S = this.view.scale;
    const [x, y] = P(pose.x, pose.y);
    const len = Math.max(18, length * S);
    const ex = x + Math.cos(pose.yaw) * len, ey = y - Math.sin(pose.yaw) * len;
    ctx.strokeStyle = color; ctx.fillStyle = color; ctx.lineWidth = 2.5;
    ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(ex, ey); ctx.stroke();
    const a = Math.atan2(ey - y, ex - x);
    ctx.beginPath(); ctx.moveTo(ex, ey);
    ctx.lineTo(ex - 9 * Math.cos(a - 0.45), ey - 9 * Math.sin(a - 0.45));
    ctx.lineTo(ex - 9 * Math.cos(a + 0.45), ey - 9 * Math.sin(a + 0.45));
    ctx.closePath(); ctx.fill();
    if (ring) { ctx.beginPath(); ctx.arc(x, y, 5, 0, Math.PI * 2); ctx.stroke(); }
  }

  drawRobot(ctx, P, pose, color, filled, radius, footprint) {
    const S = this.view.scale;
    const [x, y] = P(pose.x, pose.y);
    const r = Math.max(6, (radius || this.robotRadius) * S);
    ctx.beginPath();
    if (footprint && footprint.length >= 3 && r > 6) {  // the polygon, robot frame
      const c = Math.cos(pose.yaw), s = Math.sin(pose.yaw);
      footprint.forEach(([fx, fy], i) => {
        const [px, py] = P(pose.x + c * fx - s * fy, pose.y + s * fx + c * fy);
        if (i) ctx.lineTo(px, py); else ctx.moveTo(px, py);
      });
      ctx.closePath();
    } else ctx.arc(x, y, r, 0, Math.PI * 2);
    if (filled) { ctx.fillStyle = color + "55"; ctx.fill(); }
    ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.stroke();
    ctx.beginPath(); ctx.moveTo(x, y);
    ctx.lineTo(x + Math.cos(pose.yaw) * r * 1.5, y - Math.sin(pose.yaw) * r * 1.5);
    ctx.stroke();
  }

  drawCovariance(ctx, P, pose, cov) {
    // 2-sigma ellipse of the x-y block
    const a = cov[0][0], b = cov[0][1], d = cov[1][1];
    if (!(a >= 0 && d >= 0)) return;
    const tr = a + d, det = a * d - b * b;
    const disc = Math.sqrt(Math.max(0, tr * tr / 4 - det));
    const l1 = tr / 2 + disc, l2 = Math.max(0, tr / 2 - disc);
    const ang = Math.atan2(l1 - a, b || 1e-12);
    const S = this.view.scale;
    const rx = 2 * Math.sqrt(l1) * S, ry = 2 * Math.sqrt(l2) * S;
    if (!(rx > 0.5)) return;
    const [x, y] = P(pose.x, pose.y);
    ctx.beginPath();
    ctx.ellipse(x, y, Math.min(rx, 5000), Math.min(ry, 5000), -ang, 0, Math.PI * 2);
    ctx.fillStyle = "rgba(255,176,32,0.10)"; ctx.fill();
    ctx.strokeStyle = "rgba(255,176,32,0.6)"; ctx.lineWidth = 1; ctx.stroke();
  }

  drawScaleBar(ctx, w, h) {
    const S = this.view.scale;
    const target = 100 / S;
    const pow = Math.pow(10, Math.floor(Math.log10(target)));
    const len = [1, 2, 5, 10].map((k) => k * pow).find((v) => v >= target) || target;
    const px = len * S;
    const x = w / 2 - px / 2, y = h - 14;
    ctx.strokeStyle = "#d7dde5"; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(x, y - 5); ctx.lineTo(x, y); ctx.lineTo(x + px, y); ctx.lineTo(x + px, y - 5); ctx.stroke();
    ctx.fillStyle = "#d7dde5"; ctx.font = "11px ui-monospace, monospace"; ctx.textAlign = "center"; ctx.textBaseline = "bottom";
    ctx.fillText(len >= 1 ? `${len} m` : `${Math.round(len * 100)} cm`, w / 2, y - 3);
  }
}
