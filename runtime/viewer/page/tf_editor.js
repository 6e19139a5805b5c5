// pfn-view's transfer-function editor: opacity control points drawn over the volume's histogram (log counts);
// each point carries a colour (the albedo). Drag a point to move it (its scalar stays between its neighbours),
// double-click to add one, right-click to remove one. Every change calls onChange(message fields).
"use strict";
function createTfEditor(canvas, onChange) {
  const ctx = canvas.getContext("2d");
  const pad = 6, gap = 0.001;      // points keep their scalar order with at least `gap` between them
  let points = [], hist = [], density = 1, baseDensity = 1, selected = -1, dragging = -1;
  const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));
  const X = (s) => pad + s * (canvas.width - 2 * pad);
  const Y = (o) => canvas.height - pad - o * (canvas.height - 2 * pad);
  const S = (x) => clamp((x - pad) / (canvas.width - 2 * pad), 0, 1);
  const O = (y) => clamp((canvas.height - pad - y) / (canvas.height - 2 * pad), 0, 1);
  const round4 = (v) => Math.round(v * 1e4) / 1e4;
  const css = (a) => `rgb(${a.map((v) => Math.round(v * 255)).join(",")})`;

  function draw() {
    ctx.fillStyle = "#111"; ctx.fillRect(0, 0, canvas.width, canvas.height);
    ctx.fillStyle = "#3a3d44";
    const w = (canvas.width - 2 * pad) / Math.max(hist.length, 1);
    hist.forEach((h, i) => { ctx.fillRect(pad + i * w, Y(h), Math.max(w - 1, 1), Y(0) - Y(h)); });
    ctx.strokeStyle = "#ddd"; ctx.lineWidth = 1.5; ctx.beginPath();
    ctx.moveTo(X(0), Y(points.length ? points[0].opacity : 0));
    points.forEach((p) => ctx.lineTo(X(p.s), Y(p.opacity)));
    ctx.lineTo(X(1), Y(points.length ? points[points.length - 1].opacity : 0));
    ctx.stroke();
    points.forEach((p, i) => {
      ctx.beginPath(); ctx.arc(X(p.s), Y(p.opacity), i === selected ? 6 : 4.5, 0, 2 * Math.PI);
      ctx.fillStyle = css(p.albedo); ctx.fill();
      ctx.strokeStyle = i === selected ? "#fc3" : "#000"; ctx.lineWidth = 1.5; ctx.stroke();
    });
  }

  function at(e) {
    const r = canvas.getBoundingClientRect();
    return [(e.clientX - r.left) * canvas.width / r.width, (e.clientY - r.top) * canvas.height / r.height];
  }

  function nearest(x, y) {
    let best = -1, dist = 9;
    points.forEach((p, i) => { const d = Math.hypot(X(p.s) - x, Y(p.opacity) - y); if (d < dist) { dist = d; best = i; } });
    return best;
  }

  function message() {
    return {points: points.map((p) => ({s: round4(p.s), opacity: round4(p.opacity), albedo: p.albedo.map(round4)})),
            density_scale: round4(density)};
  }

  function changed() { draw(); onChange(message()); }

  canvas.addEventListener("pointerdown", (e) => {
    if (e.button !== 0) return;
    const [x, y] = at(e);
    selected = dragging = nearest(x, y);
    if (dragging >= 0) canvas.setPointerCapture(e.pointerId);
    draw();
  });
  canvas.addEventListener("pointermove", (e) => {
    if (dragging < 0) return;
    const [x, y] = at(e);
    const lo = dragging > 0 ? points[dragging - 1].s + gap : 0;
    const hi = dragging < points.length - 1 ? points[dragging + 1].s - gap : 1;
    points[dragging].s = clamp(S(x), lo, hi);
    points[dragging].opacity = O(y);
    changed();
  });
  canvas.addEventListener("pointerup", () => { dragging = -1; });
  canvas.addEventListener("dblclick", (e) => {
    const [x, y] = at(e);
    const s = S(x);
    if (points.length >= 32 || points.some((p) => Math.abs(p.s - s) < 2 * gap)) return;
    const i = points.findIndex((p) => p.s > s);
    const k = i < 0 ? points.length : i;
    const a = points[Math.max(k - 1, 0)], b = points[Math.min(k, points.length - 1)];
    const t = b.s > a.s ? clamp((s - a.s) / (b.s - a.s), 0, 1) : 0;
    points.splice(k, 0, {s: s, opacity: O(y), albedo: a.albedo.map((v, c) => v + t * (b.albedo[c] - v))});
    selected = k;
    changed();
  });
  canvas.addEventListener("contextmenu", (e) => {
    e.preventDefault();
    const [x, y] = at(e);
    const i = nearest(x, y);
    if (i < 0 || points.length <= 1) return;
    points.splice(i, 1);
    selected = -1;
    changed();
  });

  return {
    load(transfer, histogram) {
      points = transfer.points.map((p) => ({s: p.s, opacity: p.opacity, albedo: p.albedo.slice()}));
      hist = histogram || [];
      density = baseDensity = transfer.density_scale;
      selected = -1;
      draw();
    },
    // The selected point's colour from an <input type=color> value.
    setColour(hex) {
      if (selected < 0) return;
      points[selected].albedo = [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16) / 255);
      changed();
    },
    selectedColour() {
      if (selected < 0) return null;
      return "#" + points[selected].albedo.map((v) => Math.round(v * 255).toString(16).padStart(2, "0")).join("");
    },
    // The density scale as a factor of the scene's (the page's slider is log10 of it).
    setDensityFactor(f) { density = baseDensity * f; changed(); return density; },
    select(i) { selected = i; draw(); },
    message: message,
    // Where point i is drawn, in page pixels (tests drag it).
    pointOnPage(i) {
      const r = canvas.getBoundingClientRect();
      return [r.left + X(points[i].s) * r.width / canvas.width, r.top + Y(points[i].opacity) * r.height / canvas.height];
    },
  };
}
