// pfn-view page: sends input as JSON messages over one websocket and draws the frames it receives.
// Frames are binary messages: 4-byte big-endian header length, JSON header, then JPEG or PNG bytes.
"use strict";
const $ = (id) => document.getElementById(id);
const canvas = $("view");
const ctx = canvas.getContext("2d");
let ws = null;
let seq = 0;
let lastFrame = null;           // the last frame header, for the tests and the status line
let framesShown = 0;
let framesArrived = 0;          // frames are numbered as they arrive; decoding may finish out of order,
let framesDrawn = 0;            // and a frame older than the one on screen is never drawn over it
let pendingOrbit = null;        // input is coalesced to one message per animation frame
let pendingPan = null;
let pendingZoom = 1.0;
let pendingTransfer = null;     // the transfer-function editor's newest state, sent once per animation frame
let pendingLabels = {};         // a label scene's panel: label -> what changed, merged, sent once per animation frame
let pendingLabelDensity = null; // a label scene's density scale, sent once per animation frame
let maxLabelEdits = 32;         // labels one message may change (the server's, from its state message)
let lastRetrain = null;         // the last retrain status message
let pvrtG = null;               // the g a PVRT transfer was precomputed for (the only one it renders), or null
const sentAt = new Map();       // seq -> time sent (input-to-image latency)
let lastLatency = null;
const times = [];               // arrival times of the last frames (frame rate)
let shown = null;               // {bitmap, header} of the frame on screen, drawn again when the canvas is resized
let sentView = null;            // [width, height] of the last view message
let viewTimer = null;
// The view's size: the canvas fills the box the panel leaves, and frames are asked for at that box's size in device
// pixels (CSS pixels x devicePixelRatio, the ratio capped: beyond 2 the frames would cost 2.25x and more for detail
// few can see). The server renders at most --size's pixel count and says in each frame's header what it rendered;
// the page scales every frame to the canvas. Resizes are debounced so a window drag sends one message, not sixty.
const MAX_DPR = 2;
const VIEW_DEBOUNCE_MS = 200;
let viewLimits = {min_side: 16, max_side: 2048, max_pixels: 1920 * 1080};  // the server's, from its state message

function send(msg) {
  if (!ws || ws.readyState !== WebSocket.OPEN) return;
  seq += 1;
  msg.seq = seq;
  sentAt.set(seq, performance.now());
  if (sentAt.size > 200) sentAt.delete(sentAt.keys().next().value);
  ws.send(JSON.stringify(msg));
}

function flushInput() {
  if (pendingOrbit) { send({type: "orbit", dx: pendingOrbit[0], dy: pendingOrbit[1]}); pendingOrbit = null; }
  if (pendingPan) { send({type: "pan", dx: pendingPan[0], dy: pendingPan[1]}); pendingPan = null; }
  if (pendingZoom !== 1.0) { send({type: "zoom", factor: Math.min(20, Math.max(0.05, pendingZoom))}); pendingZoom = 1.0; }
  if (pendingTransfer) { send({type: "transfer", ...pendingTransfer}); pendingTransfer = null; }
  const labels = Object.keys(pendingLabels);
  for (let i = 0; i < labels.length; i += maxLabelEdits) {  // "show all" on many labels: several messages
    send({type: "labels", labels: Object.fromEntries(labels.slice(i, i + maxLabelEdits).map((k) => [k, pendingLabels[k]]))});
  }
  pendingLabels = {};
  if (pendingLabelDensity !== null) { send({type: "labels", density_scale: pendingLabelDensity}); pendingLabelDensity = null; }
  requestAnimationFrame(flushInput);
}

function setControl(control, value) { send({type: "set", control: control, value: value}); }

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  ws = new WebSocket(`${proto}//${location.host}/ws`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => {
    $("status").textContent = "connected, waiting for the first frame...";
    sentView = null;
    fitCanvas(); sendView();  // the first view message at once, not after the debounce
  };
  ws.onclose = () => { $("status").textContent = "disconnected (reload the page to reconnect)"; };
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") { onText(JSON.parse(ev.data)); return; }
    const view = new DataView(ev.data);
    const n = view.getUint32(0);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(ev.data, 4, n)));
    const blob = new Blob([new Uint8Array(ev.data, 4 + n)], {type: header.format === "png" ? "image/png" : "image/jpeg"});
    const number = ++framesArrived;
    createImageBitmap(blob).then((bitmap) => {
      if (number < framesDrawn) { bitmap.close(); return; }  // a newer frame is on screen already
      framesDrawn = number;
      if (shown) shown.bitmap.close();
      shown = {bitmap: bitmap, header: header};
      drawShown();
      const now = performance.now();
      if (header.seq !== null && sentAt.has(header.seq)) { lastLatency = now - sentAt.get(header.seq); sentAt.delete(header.seq); }
      times.push(now); while (times.length > 10) times.shift();
      framesShown += 1;
      lastFrame = header;
      showStatus(header);
    });
  };
}

// --- the view's size ---------------------------------------------------------------------------
function measureView() {
  // The canvas's box in device pixels, within the view message's bounds (keeping its aspect ratio); null while the
  // box has no area (a hidden page).
  const r = canvas.getBoundingClientRect();
  const dpr = Math.min(window.devicePixelRatio || 1, MAX_DPR);
  const w = r.width * dpr, h = r.height * dpr;
  if (!(w >= 1 && h >= 1)) return null;
  const L = viewLimits;
  const s = Math.min(1, L.max_side / w, L.max_side / h, Math.sqrt(L.max_pixels / (w * h)));
  let size = [Math.round(w * s), Math.round(h * s)];
  if (Math.max(...size) > L.max_side || size[0] * size[1] > L.max_pixels) size = [Math.floor(w * s), Math.floor(h * s)];
  return [Math.max(L.min_side, size[0]), Math.max(L.min_side, size[1])];
}

function fitCanvas() {
  // The canvas's pixels follow its box at once (the last frame is drawn again: resizing clears a canvas); the server
  // hears of the new size once the box has stopped changing.
  const size = measureView();
  if (size && (canvas.width !== size[0] || canvas.height !== size[1])) {
    canvas.width = size[0]; canvas.height = size[1];
    drawShown();
  }
  clearTimeout(viewTimer);
  viewTimer = setTimeout(sendView, VIEW_DEBOUNCE_MS);
}

function sendView() {
  const size = measureView();
  if (!size || !ws || ws.readyState !== WebSocket.OPEN) return;
  if (sentView && sentView[0] === size[0] && sentView[1] === size[1]) return;  // only a real change restarts
  sentView = size;
  send({type: "view", width: size[0], height: size[1]});
}

function drawShown() {
  // A frame of the canvas's view (full size, capped or a reduced moving frame) is scaled over the whole canvas; a
  // frame for another view (before the first view message, or in flight during a resize) keeps its own aspect ratio,
  // centred, rather than being stretched.
  if (!shown) return;
  const {bitmap, header} = shown;
  const W = canvas.width, H = canvas.height;
  const v = header.view_size;
  ctx.imageSmoothingEnabled = true;
  if (v && v[0] === W && v[1] === H) { ctx.drawImage(bitmap, 0, 0, W, H); return; }
  const k = Math.min(W / bitmap.width, H / bitmap.height);
  const w = bitmap.width * k, h = bitmap.height * k;
  ctx.fillStyle = "#000"; ctx.fillRect(0, 0, W, H);
  ctx.drawImage(bitmap, (W - w) / 2, (H - h) / 2, w, h);
}

function watchPixelRatio() {
  // devicePixelRatio changes (browser zoom, another screen) without the box changing size in every case.
  matchMedia(`(resolution: ${window.devicePixelRatio}dppx)`).addEventListener("change", () => {
    fitCanvas(); watchPixelRatio();
  }, {once: true});
}

function showStatus(h) {
  const fps = times.length > 1 ? (times.length - 1) * 1000 / (times[times.length - 1] - times[0]) : 0;
  $("status").textContent =
    `${h.renderer} ${h.layer} g=${h.g.toFixed(2)}\n` +
    `${h.width}x${h.height}` + (h.view_size && (h.view_size[0] !== h.width || h.view_size[1] !== h.height) ?
      ` of ${h.view_size[0]}x${h.view_size[1]}` : "") + `  spp ${h.spp}${h.denoised ? " (denoised)" : ""}${h.gathered ? ` (${h.gathered} with final gather)` : ""}` +
    (h.level ? `  volume level ${h.level} (coarser while changing)` : "") +
    (h.camera_estimator_used ? `  camera estimator ${h.camera_estimator_used}` +
      (h.camera_estimator === "auto" ? " (auto)" : "") : "") + "\n" +
    `frame ${h.total_ms.toFixed(0)} ms  render ${(h.render_ms || 0).toFixed(0)} ms\n` +
    `${fps.toFixed(1)} frames/s` + (lastLatency !== null ? `  input->image ${lastLatency.toFixed(0)} ms` : "") +
    (h.pvrt ? (h.pvrt.relit ? `\nrelit from ${h.pvrt.kept_samples} kept samples` : "\ncamera rays marched") : "");
  $("message").textContent = h.warnings.length ? h.warnings.join("; ") : $("message").textContent;
  $("stale").style.display = h.stale ? "block" : "none";
  fixG(h.renderer);
}

function fixG(renderer) {
  // A PVRT transfer answers the g its photons scattered with only: the slider shows it and cannot move.
  const fixed = renderer === "pvrt" && pvrtG !== null;
  $("g").disabled = fixed;
  $("g_note").textContent = fixed ? "(fixed by the PVRT transfer)" : "";
  if (fixed) { $("g").value = pvrtG; $("g_value").textContent = Number(pvrtG).toFixed(2); }
}

function onRetrain(m) {
  lastRetrain = m;
  const pct = (100 * (m.fraction || 0)).toFixed(0);
  $("retrain_state").textContent = m.state + (m.state === "running" && m.stage ? ` (${m.stage}, ${pct} %)` : "");
  $("retrain_bar").value = m.fraction || 0;
  $("retrain_line").textContent = m.message || (m.elapsed_s !== null && m.elapsed_s !== undefined ? `${m.elapsed_s.toFixed(0)} s` : "");
  if (m.renderers) setRenderers(m.renderers, m.renderer);
}

function setRenderers(list, current) {
  const names = {neural: "neural (photon field)", pt: "path tracer", preview: "preview (single scattering)",
                 marched: "preview + field (L_i)", photonmap: "photon map", pvrt: "PVRT (relighting)"};
  $("renderer").innerHTML = list.map((r) => `<option value="${r}">${names[r] || r}</option>`).join("");
  $("renderer").value = current;
  fixG(current);
}

function onText(msg) {
  if (msg.type === "state") buildControls(msg);
  else if (msg.type === "error") $("message").textContent = "refused: " + msg.message;
  else if (msg.type === "retrain") onRetrain(msg);
  else if (msg.type === "screenshot") $("message").textContent = "saved " + msg.files.map((f) => f.split("/").pop()).join(", ");
}

function buildControls(s) {
  $("title").textContent = `pfn-view: ${s.scene}`;
  pvrtG = s.pvrt ? s.pvrt.g : null;
  setRenderers(s.renderers, s.renderer);
  // A label scene gets the label panel, a scalar one the control-point editor over its histogram.
  $("tf_box").classList.toggle("hidden", Boolean(s.labels));
  $("labels_box").classList.toggle("hidden", !s.labels);
  if (s.labels) {
    labelPanel.load(s.labels);
    maxLabelEdits = s.labels.max_edits;
    $("label_density").value = 0; $("label_density_value").textContent = s.labels.density_scale.toPrecision(3);
  } else {
    tfEditor.load(s.transfer, s.histogram);
    $("density").value = 0; $("density_value").textContent = s.transfer.density_scale.toPrecision(3);
  }
  $("retrain").disabled = !s.retrain.available;
  if (!s.retrain.available) $("retrain_line").textContent = s.retrain.why;
  if (s.retrain.status) onRetrain(s.retrain.status);
  $("layer").value = s.layer;
  $("g").value = s.g; $("g_value").textContent = Number(s.g).toFixed(2);
  if (s.view_limits) viewLimits = s.view_limits;
  fitCanvas();
  $("drag_scale").value = String(s.drag_scale);
  $("camera_estimator").value = s.camera_estimator;
  $("lights").innerHTML = "";
  s.lights.forEach((lt, i) => {
    const f = document.createElement("fieldset");
    let html = `<legend>light ${i} (${lt.kind})</legend>`;
    if (lt.kind !== "environment") {
      html += `<label>azimuth <span id="az${i}v">${lt.azimuth.toFixed(0)}</span>&deg;</label>` +
        `<input id="az${i}" type="range" min="-180" max="180" step="1" value="${lt.azimuth}">` +
        `<label>elevation <span id="el${i}v">${lt.elevation.toFixed(0)}</span>&deg;</label>` +
        `<input id="el${i}" type="range" min="-90" max="90" step="1" value="${lt.elevation}">`;
    }
    if (lt.yaw !== null && lt.yaw !== undefined) {  // an environment map: it turns about the vertical axis
      html += `<label>rotation <span id="yw${i}v">${lt.yaw.toFixed(0)}</span>&deg;</label>` +
        `<input id="yw${i}" type="range" min="-180" max="180" step="1" value="${lt.yaw}">`;
    }
    const maxPower = Math.max(10, 4 * lt.power);
    html += `<label>power <span id="pw${i}v">${lt.power.toFixed(2)}</span></label>` +
      `<input id="pw${i}" type="range" min="0" max="${maxPower}" step="${maxPower / 200}" value="${lt.power}">`;
    f.innerHTML = html;
    $("lights").appendChild(f);
    const hook = (id, key) => {
      const el = $(id);
      if (!el) return;
      el.addEventListener("input", () => {
        $(id + "v").textContent = Number(el.value).toFixed(key === "power" ? 2 : 0);
        send({type: "light", index: i, [key]: Number(el.value)});
      });
    };
    hook(`az${i}`, "azimuth"); hook(`el${i}`, "elevation"); hook(`pw${i}`, "power"); hook(`yw${i}`, "yaw");
  });
}

// --- input -------------------------------------------------------------------------------------
let drag = null;
canvas.addEventListener("pointerdown", (e) => { drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey}; canvas.setPointerCapture(e.pointerId); });
canvas.addEventListener("pointerup", () => { drag = null; });
canvas.addEventListener("pointermove", (e) => {
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  drag.x = e.clientX; drag.y = e.clientY;
  if (drag.pan || e.shiftKey) {
    const h = canvas.clientHeight || canvas.height;
    const p = pendingPan || [0, 0];
    pendingPan = [Math.max(-10, Math.min(10, p[0] - dx / h)), Math.max(-10, Math.min(10, p[1] + dy / h))];
  } else {
    const o = pendingOrbit || [0, 0];
    pendingOrbit = [Math.max(-360, Math.min(360, o[0] - dx * 0.4)), Math.max(-180, Math.min(180, o[1] + dy * 0.4))];
  }
});
canvas.addEventListener("wheel", (e) => { e.preventDefault(); pendingZoom *= Math.exp(e.deltaY * 0.001); }, {passive: false});

$("renderer").addEventListener("change", (e) => {
  // PVRT renders its transfer's g only: selecting it sets g to that first (else the server refuses the switch)
  if (e.target.value === "pvrt" && pvrtG !== null && Number($("g").value) !== pvrtG) setControl("g", pvrtG);
  fixG(e.target.value);
  setControl("renderer", e.target.value);
});
$("layer").addEventListener("change", (e) => setControl("layer", e.target.value));
$("g").addEventListener("input", (e) => { $("g_value").textContent = Number(e.target.value).toFixed(2); setControl("g", Number(e.target.value)); });
$("exposure").addEventListener("input", (e) => { $("exposure_value").textContent = (e.target.value >= 0 ? "+" : "") + Number(e.target.value).toFixed(1); setControl("exposure", Number(e.target.value)); });
$("auto_exposure").addEventListener("click", () => { $("exposure").value = 0; $("exposure_value").textContent = "+0.0"; setControl("exposure", "auto"); });
$("denoise").addEventListener("change", (e) => setControl("denoise", e.target.checked));
$("camera_estimator").addEventListener("change", (e) => setControl("camera_estimator", e.target.value));
$("drag_scale").addEventListener("change", (e) => {
  const v = e.target.value;
  setControl("drag_scale", v === "auto" ? "auto" : Number(v));
});
$("lossless").addEventListener("change", (e) => setControl("format", e.target.checked ? "png" : "jpeg"));
$("reset_camera").addEventListener("click", () => send({type: "reset_camera"}));
$("screenshot").addEventListener("click", () => send({type: "screenshot"}));

const tfEditor = createTfEditor($("tf"), (fields) => { pendingTransfer = fields; });
$("tf").addEventListener("pointerdown", () => { const c = tfEditor.selectedColour(); if (c) $("tf_color").value = c; });
$("tf_color").addEventListener("input", (e) => tfEditor.setColour(e.target.value));
$("density").addEventListener("input", (e) => {
  $("density_value").textContent = tfEditor.setDensityFactor(Math.pow(10, Number(e.target.value))).toPrecision(3);
});
const labelPanel = createLabelPanel($("label_rows"), (changes) => {
  for (const [label, edit] of Object.entries(changes)) pendingLabels[label] = {...(pendingLabels[label] || {}), ...edit};
}, (density) => { pendingLabelDensity = density; });
$("label_density").addEventListener("input", (e) => {
  $("label_density_value").textContent = labelPanel.setDensityFactor(Math.pow(10, Number(e.target.value))).toPrecision(3);
});
$("labels_show_all").addEventListener("click", () => labelPanel.showAll());
$("labels_hide_all").addEventListener("click", () => labelPanel.hideAll());
$("retrain").addEventListener("click", () => send({type: "retrain", action: "start"}));
$("retrain_cancel").addEventListener("click", () => send({type: "retrain", action: "cancel"}));

// For tests and the curious: frames shown, the last frame's header, the last input's number, the retraining.
window.pfnView = {frames: () => framesShown, header: () => lastFrame, lastSeq: () => seq, send: send,
                  retrain: () => lastRetrain, tf: tfEditor, labels: labelPanel, view: () => sentView};
new ResizeObserver(fitCanvas).observe($("stage"));
window.addEventListener("resize", fitCanvas);
watchPixelRatio();
fitCanvas();
connect();
requestAnimationFrame(flushInput);
