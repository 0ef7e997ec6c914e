// grassd studio page: inputs -> WebSocket -> views, refined as the server streams them.
"use strict";

const $ = (id) => document.getElementById(id);
const S = {            // what the page knows; tests read it as window.studio
  state: null, ws: null, id: 0, eye: {x: 0, y: -2}, image: null, pinned: null,
  curve: null, table: null, contrast: null, audience: null, pixel: null, light: null,
  curves: 0, pixels: 0, displays: 0, errors: [], sentAt: 0, firstCurveMs: null, failed: false,
};
window.studio = S;
let curvePlot = null, tablePlot = null, dragging = false, lastSend = 0, pendingSend = null;

function showError(text) {
  const box = $("error");
  if (!text) { box.hidden = true; box.textContent = ""; return; }
  box.hidden = false; box.textContent = text; S.errors.push(text);
}
function setStatus(text) { $("status").textContent = text; }

// ------------------------------------------------------------------ inputs
function viewpoint() {
  const d = Math.max(0.1, Math.hypot(S.eye.x, S.eye.y));
  const theta = Math.atan2(S.eye.x, -S.eye.y) * 180 / Math.PI;
  return [Number($("eye-h").value), Math.round(d * 1000) / 1000, Math.round(theta * 10) / 10];
}
function condition() {
  const sunMode = $("sun-mode").value;
  let sun = {mode: sunMode};
  if (sunMode === "site") {
    const m = Number($("sun-time").value);
    const hh = String(Math.floor(m / 60)).padStart(2, "0"), mm = String(m % 60).padStart(2, "0");
    sun = {mode: "site", lux: Number($("sun-lux").value),
           when: `${$("sun-date").value}T${hh}:${mm}`};
  }
  const c = {light: $("light").value, ambient_lux: Number($("lux").value), sun,
             viewpoint: viewpoint(), splay_deg: S.splayMoved ? Number($("splay").value) : null,
             length_mm: Number($("length").value), tables: $("tables").value,
             pixel: $("pixel-choice").value || null};
  if (S.image) c.image = S.image;
  return c;
}
function describe(c) {
  const v = c.viewpoint;
  const sun = c.sun.mode === "site" ? `sun ${c.sun.when.slice(11)}` : `sun ${c.sun.mode}`;
  return `(${v[0]}, ${v[1].toFixed(2)}, ${v[2].toFixed(1)}) · ${c.ambient_lux} lx · ${sun}`;
}
function send() {
  if (!S.ws || S.ws.readyState !== WebSocket.OPEN) return;
  const now = performance.now();
  if (dragging && now - lastSend < 60) {       // pointer moves: at most ~16 requests a second
    clearTimeout(pendingSend); pendingSend = setTimeout(send, 60); return;
  }
  clearTimeout(pendingSend);
  lastSend = now;
  S.id += 1; S.sentAt = now; S.firstCurveMs = null;
  S.condition = condition();
  const msg = {type: "inputs", id: S.id, condition: S.condition};
  if (S.pinned && !S.pinned.final) msg.pinned = S.pinned.condition;  // B's image still refines
  S.ws.send(JSON.stringify(msg));
  setStatus("computing…");
  showError(""); S.failed = false;
  updateReadouts();
}
function updateReadouts() {
  const v = viewpoint();
  $("eye-readout").textContent =
    `h ${v[0]} cm · d ${v[1].toFixed(2)} m · θ ${v[2].toFixed(1)}°`;
  $("eye-h-out").textContent = `${v[0]} cm`;
  $("splay-out").textContent = `${$("splay").value}°`;
  $("length-out").textContent = `${$("length").value} mm`;
  const m = Number($("sun-time").value);
  $("sun-time-out").textContent =
    `${String(Math.floor(m / 60)).padStart(2, "0")}:${String(m % 60).padStart(2, "0")}`;
  $("sun-site").hidden = $("sun-mode").value !== "site";
  drawTop();
}

// ------------------------------------------------------------------ top view
function topFrame() {
  const c = $("topview"), pts = [[0, 0], [S.eye.x, S.eye.y]];
  for (const p of S.state.region) pts.push(p);
  for (const v of S.state.viewpoints) {
    const t = v[2] * Math.PI / 180; pts.push([v[1] * Math.sin(t), -v[1] * Math.cos(t)]);
  }
  let x0 = Math.min(...pts.map(p => p[0])), x1 = Math.max(...pts.map(p => p[0]));
  let y0 = Math.min(...pts.map(p => p[1])), y1 = Math.max(...pts.map(p => p[1]));
  const pad = 0.6; x0 -= pad; x1 += pad; y0 -= pad; y1 += pad;
  const s = Math.min(c.width / (x1 - x0), c.height / (y1 - y0));
  const ox = c.width / 2 - s * (x0 + x1) / 2, oy = c.height / 2 + s * (y0 + y1) / 2;
  return {s, toPx: (x, y) => [ox + s * x, oy - s * y],
          toM: (px, py) => [(px - ox) / s, (oy - py) / s]};
}
function drawTop() {
  if (!S.state) return;
  const c = $("topview"), g = c.getContext("2d"), f = topFrame();
  g.clearRect(0, 0, c.width, c.height);
  if (S.audience) {                        // the audience map: range per place
    const a = S.audience, half = a.step_m * f.s / 2;
    for (const p of a.places) {
      const [px, py] = f.toPx(p.x, p.y), k = Math.max(0, Math.min(1, p.range / a.eye_range));
      g.fillStyle = `hsla(${Math.round(120 * k)}, 60%, 50%, 0.45)`;
      g.fillRect(px - half, py - half, 2 * half, 2 * half);
      if (p.warn) {
        g.strokeStyle = "#b3261e"; g.lineWidth = 2;
        g.strokeRect(px - half + 1, py - half + 1, 2 * half - 2, 2 * half - 2);
      }
    }
  }
  g.setLineDash([4, 3]); g.strokeStyle = "#5b6452"; g.lineWidth = 1; g.beginPath();
  S.state.region.forEach((p, i) => {
    const [px, py] = f.toPx(p[0], p[1]);
    i ? g.lineTo(px, py) : g.moveTo(px, py);
  });
  g.closePath(); g.stroke(); g.setLineDash([]);
  const d = S.state.display, w = d.cols * d.pitch_mm / 1000, h = d.rows * d.pitch_mm / 1000;
  const [dx, dy] = f.toPx(-w / 2, h / 2);
  g.fillStyle = "#3b7a2a"; g.fillRect(dx, dy, Math.max(4, w * f.s), Math.max(3, h * f.s));
  g.fillStyle = "#8a9180";
  for (const v of S.state.viewpoints) {
    const t = v[2] * Math.PI / 180, [px, py] = f.toPx(v[1] * Math.sin(t), -v[1] * Math.cos(t));
    g.beginPath(); g.arc(px, py, 3, 0, 2 * Math.PI); g.fill();
  }
  const [ex, ey] = f.toPx(S.eye.x, S.eye.y), [cx, cy] = f.toPx(0, 0);
  g.strokeStyle = "#22301c"; g.beginPath(); g.moveTo(ex, ey); g.lineTo(cx, cy); g.stroke();
  g.fillStyle = "#22301c"; g.beginPath(); g.arc(ex, ey, 7, 0, 2 * Math.PI); g.fill();
  g.fillStyle = "#5b6452"; g.font = "11px system-ui";
  g.fillText("display", cx + 6, cy - 6);
  g.fillText(S.state.region_is_default ? "region (default)" : "audience region", 6, 14);
}
function pointerEye(ev) {
  const c = $("topview"), r = c.getBoundingClientRect();
  const px = (ev.clientX - r.left) * c.width / r.width;
  const py = (ev.clientY - r.top) * c.height / r.height;
  const [x, y] = topFrame().toM(px, py);
  if (Math.hypot(x, y) < 0.1) return;
  S.eye = {x, y}; send();
}

// ------------------------------------------------------------------ views
function chartWidth(el) { return Math.max(260, el.clientWidth || 600); }
function plotCurve() {
  const c = S.curve; if (!c) return;
  const xs = c.lengths_mm.map((x, i) => [x, i]).sort((a, b) => a[0] - b[0]);
  const x = xs.map(p => p[0]), at = (arr) => xs.map(p => arr[p[1]]);
  const y = at(c.ogcd), se = at(c.ogcd_stderr);
  const data = [x, y, y.map((v, i) => v + 2 * se[i]), y.map((v, i) => v - 2 * se[i])];
  const series = [{label: "length (mm)"},
    {label: "OGCD A", stroke: "#3b7a2a", width: 2, points: {show: true}},
    {label: "+2σ", stroke: "rgba(59,122,42,0.3)"},
    {label: "−2σ", stroke: "rgba(59,122,42,0.3)"}];
  if (S.pinned && S.pinned.curve) {
    const b = S.pinned.curve, m = new Map(b.lengths_mm.map((l, i) => [l, b.ogcd[i]]));
    data.push(x.map(l => (m.has(l) ? m.get(l) : null)));
    series.push({label: "OGCD B", stroke: "#a05a00", width: 2, dash: [6, 4]});
  }
  const el = $("curve-chart");
  if (curvePlot && curvePlot.series.length !== series.length) {
    curvePlot.destroy(); curvePlot = null;
  }
  if (!curvePlot) {
    curvePlot = new uPlot({width: chartWidth(el), height: 240, series,
      bands: [{series: [2, 3], fill: "rgba(59,122,42,0.15)"}],
      scales: {x: {time: false}},
      axes: [{label: "green grass length (mm)"}, {label: "OGCD (ΔE00)"}]}, data, el);
  } else curvePlot.setData(data);
  $("swatches").replaceChildren(...at(c.srgb).map(rgb => {
    const s = document.createElement("span");
    s.style.background = `rgb(${rgb.join(",")})`;
    return s;
  }));
}
function plotTable() {
  const t = S.table; if (!t || t.error) return;
  const levels = t.lengths_mm.map((_, i) => i);
  const data = [levels, t.uncalibrated_ogcd, t.achieved_ogcd];
  const el = $("table-chart");
  if (!tablePlot) {
    tablePlot = new uPlot({width: chartWidth(el), height: 220, scales: {x: {time: false}},
      series: [{label: "level"}, {label: "length linear in level", stroke: "#8a9180", width: 1.5},
               {label: `${t.source} table`, stroke: "#3b7a2a", width: 2}],
      axes: [{label: "8-bit level"}, {label: "OGCD (ΔE00)"}]}, data, el);
  } else tablePlot.setData(data);
}
function showContrast() {
  const c = S.contrast; if (!c) return;
  const rows = [["OGCD range", `${c.ogcd_range.toFixed(2)} ΔE00`],
    ["step per level", `${c.step_de00.toFixed(3)} ΔE00`],
    ["levels a viewer tells apart", `${c.distinct_levels} (JND ${c.jnd_de00} ΔE00)`],
    ["smallest visible step", `${c.min_visible_step_levels} levels`]];
  $("contrast").replaceChildren(...rows.flatMap(([k, v]) => {
    const dt = document.createElement("dt"), dd = document.createElement("dd");
    dt.textContent = k; dd.textContent = v; return [dt, dd];
  }));
}
function showAudience() {
  const a = S.audience, note = $("audience-note"); if (!a) return;
  const worst = Math.min(...a.places.map(p => p.range));
  const kept = Math.round((1 - a.loss) * 100);
  if (a.warned) {
    note.className = "note warn";
    note.textContent = `${a.warned} of ${a.places.length} places in the audience region ` +
      `keep less than ${kept} % of this eye's OGCD range (lowest ${worst.toFixed(1)} ΔE00): ` +
      `content there loses contrast (red squares on the top view).`;
  } else {
    note.className = "note";
    note.textContent = `All ${a.places.length} places keep at least ${kept} % ` +
      `of this eye's range (lowest ${worst.toFixed(1)} ΔE00).`;
  }
}
function showCompare() {
  if (!S.pinned) return;
  $("compare").hidden = false;
  if (S.pinned.pixel) { $("b-img").src = S.pinned.pixel; $("b-img").hidden = false; }
  $("b-cap").textContent = S.pinned.label + (S.pinned.error ? ` · ${S.pinned.error}` :
    S.pinned.range !== null ? ` range ${S.pinned.range.toFixed(2)} ΔE00` : "");
  if (S.pixel) { $("a-img").src = S.pixel; $("a-img").hidden = false; }
  const r = S.contrast ? `range ${S.contrast.ogcd_range.toFixed(2)} ΔE00` : "";
  $("a-cap").textContent = `A: ${describe(S.condition)} ${r}`;
}

function onMessage(ev) {
  const m = JSON.parse(ev.data);
  if (m.id !== S.id) return;                     // a superseded request's late views
  switch (m.type) {
    case "light":
      S.light = m;
      $("sun-readout").textContent = m.sun ? `sun azimuth ${m.sun.azimuth_deg.toFixed(1)}°, ` +
        `elevation ${m.sun.elevation_deg.toFixed(1)}°` : "no sun";
      break;
    case "curve":
      S.curve = m; S.curves += 1;
      if (S.firstCurveMs === null) S.firstCurveMs = performance.now() - S.sentAt;
      $("curve-info").textContent = `${m.replicates} replicates · ` +
        `largest σ ${m.max_stderr.toFixed(3)} ΔE00` + (m.converged ? " · converged" : "");
      setStatus(m.kept ? "converged earlier (kept)" :
        m.converged ? `converged in ${Math.round(m.ms)} ms` : `refining… ${Math.round(m.ms)} ms`);
      plotCurve(); break;
    case "pinned":                                // B's views, after A's
      if (!S.pinned) break;
      if (m.error) { S.pinned.final = true; S.pinned.error = m.error; }  // said under B
      else if (m.curve) {                         // converged (B may have been pinned before)
        S.pinned.curve = m.curve; S.pinned.range = m.ogcd_range ?? null;
        plotCurve();
      } else { S.pinned.pixel = m.image; S.pinned.final = m.final; }
      showCompare();
      break;
    case "pixel":
      S.pixel = m.image; S.pixels += 1; $("pixel-img").src = m.image; $("pixel-img").hidden = false;
      $("pixel-info").textContent = `${$("length").value} mm · ${m.width} px · ${m.spp} paths/px`;
      if (S.pinned) showCompare();
      break;
    case "table":
      S.table = m;
      $("table-info").textContent = m.error ? m.error :
        `R² ${m.r2_before.toFixed(4)} before → ${m.r2_after.toFixed(5)} after · ` +
        `worst level ${m.max_level_error.toFixed(2)} ΔE00`;
      plotTable(); break;
    case "contrast": S.contrast = m; showContrast(); if (S.pinned) showCompare(); break;
    case "display":
      S.displays += 1; $("display-img").src = m.image; $("display-img").hidden = false;
      $("display-note").textContent =
        "Your picture through the table, seen from the eye under this light.";
      break;
    case "audience": S.audience = m; showAudience(); drawTop(); break;
    case "done": setStatus(`done · ${Math.round(m.ms || 0)} ms`); break;
    case "error": S.failed = true; showError(m.message); setStatus("error"); break;
  }
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(`${proto}//${location.host}/ws`);
  S.ws = ws;
  ws.onopen = () => { setStatus("connected"); send(); };
  ws.onmessage = onMessage;
  ws.onclose = () => { setStatus("disconnected: retrying…"); setTimeout(connect, 1000); };
}

async function upload(url, file) {
  const r = await fetch(url, {method: "POST", body: file});
  const body = await r.json().catch(() => ({error: `HTTP ${r.status}`}));
  if (!r.ok) { showError(body.error || `upload failed (HTTP ${r.status})`); return null; }
  return body;
}
function fillLights(lights, chosen) {
  $("light").replaceChildren(...lights.map(l => {
    const o = document.createElement("option"); o.value = l.name; o.textContent = l.label; return o;
  }));
  $("light").value = chosen;
  const src = lights.find(l => l.name === chosen);
  if (src && src.ambient_lux) $("lux").value = src.ambient_lux;
}

async function init() {
  const r = await fetch("api/state");
  if (!r.ok) { showError((await r.json()).error || `HTTP ${r.status}`); return; }
  S.state = await r.json();
  const st = S.state, v = st.viewpoints[0] || [170, 2, 0], t = v[2] * Math.PI / 180;
  S.eye = {x: v[1] * Math.sin(t), y: -v[1] * Math.cos(t)};
  $("eye-h").value = v[0];
  fillLights(st.lights, st.light);
  $("length").max = st.display.green_max_mm; $("length").value = st.display.green_max_mm / 2;
  $("pixel-choice").replaceChildren(...Object.entries(st.pixel.choices).map(([name, m]) => {
    const o = document.createElement("option"); o.value = name; o.textContent = m.source; return o;
  }));
  $("pixel-choice").value = st.pixel.default;
  $("pixel-choice-row").hidden = Object.keys(st.pixel.choices).length < 2;
  const showPixel = () => {
    const m = st.pixel.choices[$("pixel-choice").value];
    $("splay").value = m.splay_deg; S.splayMoved = false;   // the pixel's own splay until moved
    $("pixel-source").textContent = `green sRGB ${m.green_srgb.join(", ")} · yellow ` +
      `${m.yellow_srgb.join(", ")}` + (m.specular ? ` · specular ${m.specular}` : "");
  };
  showPixel();
  $("pixel-choice").addEventListener("change", () => { showPixel(); send(); });
  $("tables").querySelector("option[value=active]").disabled = !st.tables.active;
  $("sun-date").value = new Date().toISOString().slice(0, 10);
  for (const id of ["lux", "sun-mode", "sun-date", "sun-lux", "tables"])
    $(id).addEventListener("change", send);
  $("splay").addEventListener("input", () => { S.splayMoved = true; });  // before its send
  for (const id of ["eye-h", "splay", "length", "sun-time"]) $(id).addEventListener("input", send);
  $("light").addEventListener("change", () => {   // the source's own lux first, then send
    const src = S.state.lights.find(l => l.name === $("light").value);
    if (src && src.ambient_lux) $("lux").value = src.ambient_lux;
    send();
  });
  const c = $("topview");
  c.addEventListener("pointerdown", ev => {
    dragging = true; c.setPointerCapture(ev.pointerId); pointerEye(ev);
  });
  c.addEventListener("pointermove", ev => { if (dragging) pointerEye(ev); });
  c.addEventListener("pointerup", ev => { dragging = false; pointerEye(ev); });
  $("hdri").addEventListener("change", async ev => {
    const f = ev.target.files[0]; if (!f) return;
    setStatus("reading the HDRI…");
    const body = await upload(`api/hdri?name=${encodeURIComponent(f.name)}`, f);
    if (body) { S.state.lights = body.lights; fillLights(body.lights, body.light.name); send(); }
    else setStatus("error");
  });
  $("picture").addEventListener("change", async ev => {
    const f = ev.target.files[0]; if (!f) return;
    const body = await upload("api/picture", f);
    if (body) { S.image = body.image; send(); }
  });
  $("pin").addEventListener("click", () => {
    if (S.failed || !S.curve) return;             // nothing sound to pin
    S.pinned = {curve: S.curve, pixel: S.pixel, condition: S.condition, final: false,
      label: `B: ${describe(S.condition)}`, range: S.contrast ? S.contrast.ogcd_range : null};
    showCompare(); plotCurve();
    send();                                       // B's views now (A's curve and image kept)
  });
  window.addEventListener("resize", () => {
    for (const [p, el] of [[curvePlot, "curve-chart"], [tablePlot, "table-chart"]])
      if (p) p.setSize({width: chartWidth($(el)), height: p.height});
  });
  updateReadouts();
  if (!st.ready) setStatus("warming up (compiling the renderer)…");
  connect();
}
init().catch(err => showError(`the page could not start: ${err}`));
