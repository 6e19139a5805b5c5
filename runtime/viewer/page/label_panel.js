// pfn-view's label panel, shown instead of the transfer-function editor for a label scene: a row per label present
// in the volume (its value and voxel count) with a visibility checkbox, a colour (the albedo) and an opacity
// slider, and "show all" / "hide all". Every change calls onChange({label: {key: value, ...}, ...}) with only what
// changed; the page merges the changes of one animation frame and sends them as `labels` messages. Visibility is
// kept apart from opacity (as on the server): a label shown again comes back at the opacity it had. The density
// scale (the extinction of opacity 1, for every label) is set as a factor of the scene's: onDensity(scale).
"use strict";
function createLabelPanel(container, onChange, onDensity) {
  let rows = [];
  let baseDensity = 1;
  const round4 = (v) => Math.round(v * 1e4) / 1e4;
  const hex = (a) => "#" + a.map((v) => Math.round(v * 255).toString(16).padStart(2, "0")).join("");
  const rgb = (h) => [1, 3, 5].map((i) => round4(parseInt(h.slice(i, i + 2), 16) / 255));

  function input(type, props) {
    const el = document.createElement("input");
    el.type = type;
    Object.assign(el, props);
    return el;
  }

  function span(cls, text) {
    const el = document.createElement("span");
    el.className = cls;
    el.textContent = text;
    return el;
  }

  function build() {
    container.textContent = "";
    rows.forEach((r) => {
      const row = document.createElement("div");
      row.className = "label_row";
      row.dataset.label = String(r.label);
      r.box = input("checkbox", {checked: r.visible, title: `show label ${r.label}`});
      const colour = input("color", {value: hex(r.albedo), title: `colour (albedo) of label ${r.label}`});
      const opacity = input("range", {min: 0, max: 1, step: 0.01, value: r.opacity, title: `opacity of label ${r.label}`});
      r.box.addEventListener("change", () => { r.visible = r.box.checked; onChange({[r.label]: {visible: r.visible}}); });
      colour.addEventListener("input", () => { r.albedo = rgb(colour.value); onChange({[r.label]: {albedo: r.albedo}}); });
      opacity.addEventListener("input", () => {
        r.opacity = round4(Number(opacity.value));
        onChange({[r.label]: {opacity: r.opacity}});
      });
      row.append(r.box, colour, span("label_name", String(r.label)),
                 span("label_count", `${r.voxels.toLocaleString("en")} vox`), opacity);
      container.appendChild(row);
    });
  }

  // Show every label but 0 (by convention the background, which would hide the rest), or hide every label.
  function setAll(visible) {
    const changes = {};
    rows.forEach((r) => {
      const want = visible && r.label !== 0;
      if (r.visible === want || (visible && r.label === 0)) return;
      r.visible = r.box.checked = want;
      changes[r.label] = {visible: want};
    });
    if (Object.keys(changes).length) onChange(changes);
  }

  return {
    load(panel) {
      rows = panel.rows.map((r) => ({label: r.label, voxels: r.voxels, albedo: r.albedo.slice(), opacity: r.opacity,
                                     visible: r.visible}));
      baseDensity = panel.density_scale;
      build();
    },
    // The density scale as a factor of the scene's (the page's slider is log10 of it), within the message's range.
    setDensityFactor(f) {
      const d = Math.min(1e5, Math.max(1e-3, Number((baseDensity * f).toPrecision(6))));
      onDensity(d);
      return d;
    },
    showAll() { setAll(true); },
    hideAll() { setAll(false); },
    // The rows as the page holds them (tests read them).
    rows() { return rows.map((r) => ({label: r.label, voxels: r.voxels, albedo: r.albedo, opacity: r.opacity,
                                      visible: r.visible})); },
  };
}
