// The viewer page served at / by view_server.cpp: plain HTML, CSS and JavaScript, nothing fetched
// from the internet. The camera is a camera-to-world pose in the scene frame; dragging orbits it
// about the target (left button: around the scene's up axis and the camera's right axis; right
// button or shift: pans), the wheel dollies towards the target, and W/A/S/D/Q/E move it; the
// dataset's cameras are drawn as small frusta (a click jumps to one), and
// "record path" keeps every pose the view takes, saved as path.json for `render --path`. Each change
// asks for a quarter-size image at once; once the camera rests, full size (with half size first
// when the full one would take over a second, as 400x400 does on 2 CPU cores). One
// render is in flight at a time: views asked meanwhile collapse into the newest, sent when it
// returns, so a drag on a slow CPU never queues stale renders on the server. For tests: the current pose is kept in
// <pre id="pose">, body's data-images counts the images drawn and data-drawn lists their sizes (data-first-image-ms and
// data-first-full-ms time the first ones), #drag=DX,DY in the address plays a drag through the
// mouse handlers once the cameras are in, and #size=WxH fixes the image size (data-display gives
// the size shown), #points=on draws the exported points (data-points-drawn counts those in view). The
// view fills the window by default, rendered at a fraction of that size
// ("render": 1/4, 1/2, 1) and drawn scaled up; or it is shown at the camera's size times 1/2, 1, 2.
#include "view/view_server.h"

namespace ablenerf {

const char* viewer_page_html() {
  return R"ABLENERF_PAGE(<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>ablenerf view</title>
<style>
body { margin: 0; font: 14px sans-serif; background: #202124; color: #e8eaed; }
#bar { padding: 6px 10px; display: flex; gap: 12px; align-items: center; flex-wrap: wrap; }
#view { display: block; margin: 0 auto; background: #000; image-rendering: auto; cursor: grab; }
#status { color: #9aa0a6; flex-basis: 100%; }  /* a line of its own: its text never reflows the bar */
select, button { font: inherit; }
</style></head>
<body>
<div id="bar">
  <b>ablenerf view</b>
  <label>camera <select id="cams"></select></label>
  <label>mode <select id="mode"><option>rgb</option><option>depth</option><option>error</option></select></label>
  <label>size <select id="size"><option value="window" selected>window</option><option value="0.5">camera 1/2</option><option value="1">camera</option><option value="2">camera 2x</option></select></label>
  <label>render <select id="fraction"><option value="0.25">1/4</option><option value="0.5" selected>1/2</option><option value="1">1</option></select></label>
  <label id="look-label" hidden>look <select id="look"><option value="mean">mean of the photos</option></select></label>
  <label id="points-label" hidden><input type="checkbox" id="points"> <span id="points-count">points</span></label>
  <button id="rec">record path</button> <button id="save" disabled>save path (0)</button>
  <span id="status">loading cameras...</span>
</div>
<div id="livebar" style="padding: 0 10px 6px; display: none; gap: 12px; align-items: center; flex-wrap: wrap;">
  <b>training</b> <span id="step">step -</span>
  <button id="pause">pause</button> <button id="save-ckpt">save checkpoint</button>
  <label><input type="checkbox" id="follow"> follow training (re-render every 5 s)</label>
  <svg id="curves" width="360" height="90" style="background:#303134"></svg>
</div>
<canvas id="view" width="0" height="0"></canvas>  <!-- sized by the first image: no scroll bar meanwhile -->
<pre id="pose" hidden></pre>
<script>
"use strict";
let info = null, pose = null, target = [0, 0, 0], up = [0, 0, 1];
let seq = 0, restTimer = null, resting = false, recording = false, recorded = [], markers = [];
let inflight = false, queued = null;  // one render at a time; the newest view asked meanwhile waits
let drawnScale = 1, drawnMs = 0;  // the scale of the image on screen and how long it took
let exported = [];  // the run's exported points (scene frame, x y z flat), drawn over the view when asked
const canvas = document.getElementById("view"), ctx = canvas.getContext("2d");
const statusEl = document.getElementById("status");
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const norm = a => Math.sqrt(dot(a, a));
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const col = (p, c) => [p[c], p[4 + c], p[8 + c]];
function setCol(p, c, v) { p[c] = v[0]; p[4 + c] = v[1]; p[8 + c] = v[2]; }
// Rodrigues rotation of v about unit axis k by angle t.
function rot(v, k, t) {
  const c = Math.cos(t), s = Math.sin(t);
  return add(add(mul(v, c), mul(cross(k, v), s)), mul(k, dot(k, v) * (1 - c)));
}
function rotatePose(k, t) {
  const p = pose.slice();
  for (let c = 0; c < 3; ++c) setCol(p, c, rot(col(pose, c), k, t));
  setCol(p, 3, add(target, rot(sub(col(pose, 3), target), k, t)));
  pose = p;
}
// The size the view is shown at: the window's (the largest of the camera's shape that fits under
// the bar), or the camera's times 1/2, 1 or 2 (at most 800 pixels a side).
function display() {
  const choice = document.getElementById("size").value;
  let w, h;
  if (choice === "window") {
    const bar = document.getElementById("view").getBoundingClientRect().top + window.scrollY;
    const aw = Math.max(8, window.innerWidth - 4), ah = Math.max(8, window.innerHeight - bar - 4);
    const s = Math.min(aw / info.width, ah / info.height);
    w = Math.floor(info.width * s); h = Math.floor(info.height * s);
  } else {
    const s = parseFloat(choice);
    w = Math.round(info.width * s); h = Math.round(info.height * s);
    const big = Math.max(w, h);
    if (big > 800) { w = Math.round(w * 800 / big); h = Math.round(h * 800 / big); }
  }
  return [Math.max(8, w), Math.max(8, h)];
}
// The size of the full image rendered for it: the shown size times the "render" fraction (drawn
// scaled up to the shown size). #size=WxH in the address fixes both (benchmarks, tests).
function size() {
  const fixed = /size=([0-9]+)x([0-9]+)/.exec(location.hash);
  if (fixed) return [parseInt(fixed[1]), parseInt(fixed[2])];
  const [dw, dh] = display(), f = parseFloat(document.getElementById("fraction").value);
  return [Math.max(8, Math.round(dw * f)), Math.max(8, Math.round(dh * f))];
}
// A PNG blob as an <img> (loaded through the page's resource loader, like any image).
function loadImage(blob) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => { URL.revokeObjectURL(img.src); resolve(img); };
    img.onerror = () => { URL.revokeObjectURL(img.src); reject("not an image"); };
    img.src = URL.createObjectURL(blob);
  });
}
function request(scale) {
  const my = ++seq;
  if (inflight) { queued = [scale, my]; return; }
  send(scale, my);
}
// The next rung of the ladder while the camera rests: quarter -> full size, with half size between
// when the full image would take over a second (predicted from the render just drawn: the time goes
// with the pixels). #half=always or #half=never in the address overrides the prediction (the
// browser test: headless Chromium's virtual clock does not time renders).
const halfRule = (/half=(always|never)/.exec(location.hash) || [])[1];
function finer(scale, ms) {
  const half = halfRule ? halfRule === "always" : ms / (scale * scale) > 1000;
  return scale < 0.5 && half ? 0.5 : 1;
}
function send(scale, my) {
  inflight = true;
  const [w, h] = size();
  const rw = Math.max(8, Math.round(w * scale)), rh = Math.max(8, Math.round(h * scale));
  const mode = document.getElementById("mode").value;
  const look = document.getElementById("look").value;
  const url = "/api/render?w=" + rw + "&h=" + rh + "&mode=" + mode + "&look=" + look + "&pose=" + pose.map(x => x.toFixed(6)).join(",");
  const t0 = performance.now();
  let nearest = null, took = 0;
  fetch(url).then(r => { nearest = r.headers.get("X-Nearest-Camera"); return r.ok ? r.blob() : r.text().then(t => Promise.reject(t)); })
      .then(b => loadImage(b)).then(img => {
    if (my !== seq) return;  // a newer view is on its way
    canvas.width = w; canvas.height = h;
    const fixed = /size=([0-9]+)x([0-9]+)/.test(location.hash), [dw, dh] = fixed ? [w, h] : display();
    canvas.style.width = dw + "px"; canvas.style.height = dh + "px";
    document.body.dataset.display = dw + "x" + dh;
    ctx.imageSmoothingEnabled = scale < 1;
    ctx.drawImage(img, 0, 0, w, h);
    drawMarkers(w, h);
    took = performance.now() - t0;
    drawnScale = scale; drawnMs = took;
    statusEl.textContent = rw + "x" + rh + " in " + Math.round(took) + " ms" +
      (nearest !== null ? " (error against camera " + nearest + ", from its pose)" : "");
    document.body.dataset.images = (parseInt(document.body.dataset.images || "0") + 1).toString();
    document.body.dataset.drawn = ((document.body.dataset.drawn || "") + " " + rw + "x" + rh).trim();
    // Milliseconds from navigation to the first image and to the first full-size one.
    if (!document.body.dataset.firstImageMs) document.body.dataset.firstImageMs = Math.round(performance.now());
    if (scale === 1 && !document.body.dataset.firstFullMs) document.body.dataset.firstFullMs = Math.round(performance.now());
  }).catch(e => { statusEl.textContent = "render failed: " + e; }).finally(() => {
    inflight = false;
    if (queued) { const [s, m] = queued; queued = null; send(s, m); }
    else if (my === seq && resting && scale < 1) request(finer(scale, took));
  });
}
// The dataset's cameras drawn where they are in the current view (a dot and its frustum); a click
// on one jumps to it.
function drawMarkers(w, h) {
  markers = [];
  const o = col(pose, 3), fx = info.fx * w / info.width, fy = info.fy * w / info.width;
  const project = p => {
    const d = sub(p, o), x = dot(d, col(pose, 0)), y = dot(d, col(pose, 1)), z = dot(d, col(pose, 2));
    return z < -1e-3 ? [w / 2 + fx * x / -z, h / 2 - fy * y / -z] : null;
  };
  if (document.getElementById("points").checked) {
    // The exported points where they fall in this view (no occlusion: an overlay, as the frusta).
    ctx.fillStyle = "rgba(52, 168, 83, 0.75)";
    let drawn = 0;
    for (let i = 0; i + 2 < exported.length; i += 3) {
      const at = project([exported[i], exported[i + 1], exported[i + 2]]);
      if (!at || at[0] < 0 || at[1] < 0 || at[0] > w || at[1] > h) continue;
      ctx.fillRect(at[0] - 0.75, at[1] - 0.75, 1.5, 1.5);
      ++drawn;
    }
    document.body.dataset.pointsDrawn = drawn.toString();
  }
  ctx.lineWidth = 1.5;
  info.cameras.forEach((c, i) => {
    const at = project(col(c, 3));
    if (!at || at[0] < 0 || at[1] < 0 || at[0] > w || at[1] > h) return;
    // The camera's frustum: its image plane's corners at a depth of 8% of its distance from us.
    const s = 0.08 * norm(sub(col(c, 3), o)), hx = 0.5 * info.width / info.fx, hy = 0.5 * info.height / info.fy;
    const corner = (sx, sy) => project(add(col(c, 3), add(add(mul(col(c, 0), sx * hx * s), mul(col(c, 1), sy * hy * s)), mul(col(c, 2), -s))));
    const corners = [corner(-1, -1), corner(1, -1), corner(1, 1), corner(-1, 1)];
    ctx.strokeStyle = ctx.fillStyle = "#fbbc04";
    ctx.beginPath(); ctx.arc(at[0], at[1], 2.5, 0, 2 * Math.PI); ctx.fill();
    if (corners.every(q => q)) {
      ctx.beginPath();
      corners.forEach(q => { ctx.moveTo(at[0], at[1]); ctx.lineTo(q[0], q[1]); });
      ctx.moveTo(corners[3][0], corners[3][1]);
      corners.forEach(q => ctx.lineTo(q[0], q[1]));
      ctx.stroke();
    }
    markers.push([i, at[0] * canvas.clientWidth / w, at[1] * canvas.clientHeight / h]);
  });
}
function changed() {
  document.getElementById("pose").textContent = pose.map(x => x.toFixed(6)).join(",");
  if (recording && (recorded.length === 0 || recorded[recorded.length - 1].join() !== pose.join())) {
    recorded.push(pose.slice());
    document.getElementById("save").textContent = "save path (" + recorded.length + ")";
  }
  resting = false;
  request(0.25);
  clearTimeout(restTimer);
  // At rest: refine now when nothing is in flight, else when the render in flight returns.
  restTimer = setTimeout(() => {
    restTimer = null; resting = true;
    if (!inflight && drawnScale < 1) request(finer(drawnScale, drawnMs));
  }, 250);
}
function jump(i) {
  pose = info.cameras[i].slice();
  // Orbit about the point the camera looks at, at the scene centre's depth.
  const o = col(pose, 3), f = mul(col(pose, 2), -1);
  const d = info.scene === "forward" ? 5.33 : Math.max(0.1, dot(mul(o, -1), f));
  target = add(o, mul(f, d));
  changed();
}
let drag = null;
canvas.addEventListener("contextmenu", e => e.preventDefault());
canvas.addEventListener("mousedown", e => { drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey, moved: false }; });
window.addEventListener("mouseup", e => {
  if (drag && !drag.moved && e.target === canvas) {
    const r = canvas.getBoundingClientRect(), x = e.clientX - r.left, y = e.clientY - r.top;
    const hit = markers.find(m => Math.hypot(m[1] - x, m[2] - y) < 8);
    if (hit) { document.getElementById("cams").value = hit[0]; jump(hit[0]); }
  }
  drag = null;
});
document.getElementById("rec").addEventListener("click", e => {
  recording = !recording;
  e.target.textContent = recording ? "stop recording" : "record path";
  if (recording) { recorded = [pose.slice()]; }
  document.getElementById("save").disabled = recorded.length === 0;
  document.getElementById("save").textContent = "save path (" + recorded.length + ")";
});
// The recorded poses as a file for `ablenerf render --run RUN --path path.json --out video.mp4`.
document.getElementById("save").addEventListener("click", () => {
  const text = JSON.stringify({ ablenerf_path: 1, coordinates: "scene", poses: recorded });
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([text], { type: "application/json" }));
  a.download = "path.json";
  a.click();
});
window.addEventListener("mousemove", e => {
  if (!drag || !pose) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  drag.x = e.clientX; drag.y = e.clientY;
  drag.moved = true;
  if (drag.pan) {
    const dist = norm(sub(col(pose, 3), target)) / 400;
    const move = add(mul(col(pose, 0), -dx * dist), mul(col(pose, 1), dy * dist));
    setCol(pose, 3, add(col(pose, 3), move));
    target = add(target, move);
  } else {
    rotatePose(up, -dx * 0.01);
    rotatePose(col(pose, 0), -dy * 0.01);
  }
  changed();
});
canvas.addEventListener("wheel", e => {
  e.preventDefault();
  if (!pose) return;
  const o = col(pose, 3), k = Math.exp(Math.sign(e.deltaY) * 0.1);
  setCol(pose, 3, add(target, mul(sub(o, target), k)));
  changed();
}, { passive: false });
window.addEventListener("keydown", e => {
  if (!pose) return;
  const step = 0.05 * Math.max(0.1, norm(sub(col(pose, 3), target)));
  const moves = { w: mul(col(pose, 2), -step), s: mul(col(pose, 2), step), a: mul(col(pose, 0), -step),
                  d: mul(col(pose, 0), step), q: mul(col(pose, 1), -step), e: mul(col(pose, 1), step) };
  const m = moves[e.key.toLowerCase()];
  if (!m) return;
  setCol(pose, 3, add(col(pose, 3), m));
  target = add(target, m);
  changed();
});
document.getElementById("mode").addEventListener("change", changed);
document.getElementById("look").addEventListener("change", changed);
document.getElementById("size").addEventListener("change", changed);
document.getElementById("fraction").addEventListener("change", changed);
document.getElementById("points").addEventListener("change", changed);
let resizeTimer = null;  // a window resize re-renders once it settles
window.addEventListener("resize", () => {
  if (!info || document.getElementById("size").value !== "window") return;
  clearTimeout(resizeTimer);
  resizeTimer = setTimeout(changed, 150);
});
document.getElementById("cams").addEventListener("change", e => jump(parseInt(e.target.value)));
// A run being trained (`train --view`): state, buttons and the loss / held-out PSNR curves.
function polyline(points, w, h, colour) {
  if (points.length < 2) return "";
  const xs = points.map(p => p[0]), ys = points.map(p => p[1]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const sx = x => 4 + (w - 8) * (x - x0) / Math.max(1e-9, x1 - x0), sy = y => h - 4 - (h - 8) * (y - y0) / Math.max(1e-9, y1 - y0);
  return '<polyline fill="none" stroke="' + colour + '" points="' + points.map(p => sx(p[0]) + "," + sy(p[1])).join(" ") + '"/>';
}
let lastStep = -1;
function pollLive() {
  fetch("/api/state").then(r => r.json()).then(st => {
    document.getElementById("step").textContent = "step " + st.step + (st.paused ? " (paused)" : "");
    document.getElementById("pause").textContent = st.paused ? "resume" : "pause";
    document.getElementById("pause").dataset.paused = st.paused ? "1" : "";
    if (document.getElementById("follow").checked && st.step !== lastStep && !restTimer) request(1);
    lastStep = st.step;
  });
  fetch("/api/log").then(r => r.json()).then(log => {
    const loss = log.filter(e => e.loss !== undefined && e.step !== undefined).map(e => [e.step, Math.log10(e.loss)]);
    const psnr = log.filter(e => e.type === "eval" && e.psnr !== null).map(e => [e.step, e.psnr]);
    document.getElementById("curves").innerHTML = polyline(loss, 360, 90, "#8ab4f8") + polyline(psnr, 360, 90, "#fbbc04") +
      '<text x="6" y="12" fill="#8ab4f8" font-size="10">log10 loss</text><text x="80" y="12" fill="#fbbc04" font-size="10">held-out PSNR</text>';
  });
}
document.getElementById("pause").addEventListener("click", e => {
  fetch("/api/control?action=" + (e.target.dataset.paused ? "resume" : "pause")).then(pollLive);
});
document.getElementById("save-ckpt").addEventListener("click", () => fetch("/api/control?action=save"));
setInterval(() => { if (info && info.live) pollLive(); }, 5000);
fetch("/api/cameras").then(r => r.json()).then(j => {
  if (j.live) { document.getElementById("livebar").style.display = "flex"; pollLive(); }
  info = j;
  up = j.scene === "forward" ? [0, 1, 0] : [0, 0, 1];
  const sel = document.getElementById("cams");
  j.cameras.forEach((c, i) => { const o = document.createElement("option"); o.value = i; o.textContent = "camera " + i; sel.appendChild(o); });
  statusEl.textContent = j.cameras.length + " cameras, " + j.scene + " scene";
  // A run with per-photo colour: render with one training photo's exposure and white balance.
  if (j.looks && j.looks.length) {
    const ls = document.getElementById("look");
    j.looks.forEach((name, i) => { const o = document.createElement("option"); o.value = i; o.textContent = i + ": " + name; ls.appendChild(o); });
    document.getElementById("look-label").hidden = false;
  }
  // The run's exported points (`ablenerf export --points`), when it has some: a checkbox draws them.
  fetch("/api/points").then(r => r.json()).then(p => {
    if (!p.count) return;
    exported = p.points;
    document.getElementById("points-count").textContent = "points (" + p.count + ")";
    document.getElementById("points-label").hidden = false;
    if (/points=on/.test(location.hash)) { document.getElementById("points").checked = true; changed(); }
  });
  jump(0);
  // #drag=DX,DY: a scripted drag through the real mouse handlers (the headless-browser test).
  const m = /drag=(-?[0-9.]+),(-?[0-9.]+)/.exec(location.hash);
  if (m) {
    const at = (type, x, y) => canvas.dispatchEvent(new MouseEvent(type, { clientX: x, clientY: y, button: 0, bubbles: true }));
    at("mousedown", 100, 100);
    window.dispatchEvent(new MouseEvent("mousemove", { clientX: 100 + parseFloat(m[1]), clientY: 100 + parseFloat(m[2]) }));
    window.dispatchEvent(new MouseEvent("mouseup", {}));
  }
}).catch(e => { statusEl.textContent = "cannot read the cameras: " + e; });
</script>
</body></html>
)ABLENERF_PAGE";
}

}  // namespace ablenerf
