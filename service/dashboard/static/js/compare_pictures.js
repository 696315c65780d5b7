/* The compare view's pictures, paired by role (service/compare_pictures.py gives each
   picture its role): every job's main pictures (a score job's reference and candidates each
   a panel), the error maps, the signed difference of each candidate to its reference, or
   one artifact name. Side by side or two under an A/B slider, with one zoom/pan transform
   shared by every view (square pixels when zoomed), an exposure slider for HDR pictures
   (EXRs are tone-mapped by the server's preview route), a readout of every panel's pixel
   value under the cursor (/api/artifacts/{digest}/pixels), and the whole view state in the
   address (picture, mode, zoom, exposure, a, b, split) so that a view can be shared. */
"use strict";

(() => {
  const panels = JSON.parse(document.getElementById("compare-data").textContent);
  const grid = document.getElementById("compare-grid");
  const ab = document.getElementById("compare-ab");
  const pictureSelect = document.getElementById("c-picture");
  const aSelect = document.getElementById("c-a");
  const bSelect = document.getElementById("c-b");
  const split = document.getElementById("c-split");
  const exposure = document.getElementById("c-exposure");
  const exposureValue = document.getElementById("c-exposure-value");
  const exposureBox = document.getElementById("c-exposure-box");
  const readoutLine = document.getElementById("c-readout");
  const view = { scale: 1, x: 0, y: 0 };
  let mode = "grid";
  let tiles = [];
  let diffScale = 0;

  // -- the address: the view state, read once here and written on every change ----------
  const initial = new URLSearchParams(window.location.search);
  // artifact=NAME: links of before the roles (a FLIP map's name: the error maps' view)
  const legacy = initial.get("artifact");
  const wanted = initial.get("picture") || (legacy && /^flip_/.test(legacy) ? "errors" : legacy);
  if (wanted && [...pictureSelect.options].some((o) => o.value === wanted)) pictureSelect.value = wanted;
  if (initial.get("mode") === "ab") mode = "ab";
  for (const radio of document.querySelectorAll('input[name="c-mode"]')) radio.checked = radio.value === mode;
  const zoom = (initial.get("zoom") || "").split(",").map(Number);
  if (zoom.length === 3 && zoom.every(Number.isFinite) && zoom[0] >= 1 && zoom[0] <= 64) {
    [view.scale, view.x, view.y] = zoom;
  }
  const ev = Number(initial.get("exposure"));
  if (initial.has("exposure") && Number.isFinite(ev) && ev >= -6 && ev <= 6) exposure.value = String(ev);
  exposureValue.textContent = `${exposure.value} EV`;
  const sp = Number(initial.get("split"));
  if (initial.has("split") && Number.isFinite(sp) && sp >= 0 && sp <= 100) split.value = String(sp);
  let wantA = initial.get("a");
  let wantB = initial.get("b");

  function saveState() {
    const url = new URL(window.location.href);
    const q = url.searchParams;
    q.delete("artifact");
    const set = (k, v, dflt) => { if (v === dflt || v === null || v === undefined) q.delete(k); else q.set(k, v); };
    set("picture", pictureSelect.value, pictureSelect.options.length ? pictureSelect.options[0].value : null);
    set("mode", mode, "grid");
    const r = (v) => String(+v.toFixed(2));
    set("zoom", view.scale === 1 ? null : `${r(view.scale)},${r(view.x)},${r(view.y)}`, null);
    set("exposure", exposure.value, "0");
    set("a", mode === "ab" ? aSelect.value : null, null);
    set("b", mode === "ab" ? bSelect.value : null, null);
    set("split", mode === "ab" ? split.value : null, "50");
    window.history.replaceState(null, "", url.pathname + url.search + url.hash);
  }

  // -- tiles: what the chosen picture view shows, one per panel ------------------------------
  const byKey = (panel, key) => panel.pictures.find((p) => p.key === key);

  function roleText(pic) {
    if (pic.role === "reference") return "reference";
    if (pic.role === "candidate") return `candidate ${pic.label}`;
    if (pic.role === "error") return `FLIP error of ${pic.label}`;
    return pic.name;
  }

  /** The tiles of view `key`: {id, jobs: [panel], pic} or, for differences,
      {id, jobs, diff: {ref, cand}}; a reference several jobs share is one tile. */
  function tilesOf(key) {
    const out = [];
    const shared = new Map();  // digest of a reference -> its tile
    for (const p of panels) {
      if (key === "main") {
        for (const k of p.main) {
          const pic = byKey(p, k);
          if (pic.role === "reference" && shared.has(pic.digest)) { shared.get(pic.digest).jobs.push(p); continue; }
          const tile = { id: `${p.short}:${pic.key}`, jobs: [p], pic, text: roleText(pic) };
          if (pic.role === "reference") shared.set(pic.digest, tile);
          out.push(tile);
        }
      } else if (key === "errors") {
        for (const pic of p.pictures.filter((q) => q.role === "error")) {
          out.push({ id: `${p.short}:${pic.key}`, jobs: [p], pic, text: roleText(pic) });
        }
      } else if (key === "diff") {
        const ref = p.pictures.find((q) => q.role === "reference");
        if (!ref) continue;
        for (const cand of p.pictures.filter((q) => q.role === "candidate")) {
          out.push({ id: `${p.short}:diff:${cand.label}`, jobs: [p], diff: { ref, cand },
                     text: `${cand.label} − reference` });
        }
      } else {
        const pic = p.pictures.find((q) => q.name === key && (q.role === "lead" || q.role === "image"));
        if (pic) out.push({ id: `${p.short}:${pic.key}`, jobs: [p], pic, text: roleText(pic) });
      }
    }
    return out;
  }

  // -- pixel values: fetched once per object, as float32 RGB ---------------------------------
  const pixelCache = new Map();

  function pixels(pic) {
    if (!pixelCache.has(pic.pixels)) {
      pixelCache.set(pic.pixels, fetch(pic.pixels, { credentials: "same-origin" }).then(async (r) => {
        if (!r.ok) throw new Error(`HTTP ${r.status} for ${pic.name}`);
        const w = Number(r.headers.get("X-Image-Width"));
        const h = Number(r.headers.get("X-Image-Height"));
        return { w, h, values: pic.values, data: new Float32Array(await r.arrayBuffer()) };
      }));
    }
    return pixelCache.get(pic.pixels);
  }

  /** A difference tile's values: the mean over R, G, B of candidate − reference. */
  async function difference(tile) {
    if (!tile.diffData) {
      const [ref, cand] = await Promise.all([pixels(tile.diff.ref), pixels(tile.diff.cand)]);
      if (ref.w !== cand.w || ref.h !== cand.h) {
        throw new Error(`${tile.diff.cand.name} is ${cand.w}x${cand.h}, the reference ${ref.w}x${ref.h}`);
      }
      const d = new Float32Array(ref.w * ref.h);
      for (let i = 0; i < d.length; i++) {
        const j = 3 * i;
        d[i] = (cand.data[j] - ref.data[j] + cand.data[j + 1] - ref.data[j + 1] + cand.data[j + 2] - ref.data[j + 2]) / 3;
      }
      tile.diffData = { w: ref.w, h: ref.h, values: ref.values, data: d, signed: true };
    }
    return tile.diffData;
  }

  /** One scale for every difference map: the 99th percentile of |d| over all of them (a
      few outlying pixels do not wash the others out), at least the largest |d| / 100. */
  function scaleOf(maps) {
    const all = maps.flatMap((m) => Array.from(m.data, Math.abs)).sort((a, b) => a - b);
    if (!all.length) return 0;
    const top = all[all.length - 1];
    return Math.max(all[Math.min(all.length - 1, Math.floor(0.99 * all.length))], top / 100);
  }

  const BLUE = [33, 102, 172];
  const WHITE = [247, 247, 247];
  const RED = [178, 24, 43];

  function paintDiff(canvas, map, scale) {
    canvas.width = map.w;
    canvas.height = map.h;
    const ctx = canvas.getContext("2d");
    const img = ctx.createImageData(map.w, map.h);
    for (let i = 0; i < map.data.length; i++) {
      const t = scale > 0 ? Math.max(-1, Math.min(1, map.data[i] / scale)) : 0;
      const end = t < 0 ? BLUE : RED;
      const a = Math.abs(t);
      for (let c = 0; c < 3; c++) img.data[4 * i + c] = Math.round(WHITE[c] + (end[c] - WHITE[c]) * a);
      img.data[4 * i + 3] = 255;
    }
    ctx.putImageData(img, 0, 0);
  }

  async function drawDiffs() {
    const diffTiles = tiles.filter((t) => t.diff);
    const bar = document.getElementById("c-diffbar");
    bar.hidden = !diffTiles.length || pictureSelect.value !== "diff";
    if (!diffTiles.length) return;
    const maps = [];
    for (const t of diffTiles) {
      try { maps.push(await difference(t)); } catch (err) { t.error = String(err.message || err); }
    }
    diffScale = scaleOf(maps);
    const s = diffScale;
    const ticks = [-s, -s / 2, 0, s / 2, s].map((v) => (v === 0 ? "0" : `${v > 0 ? "+" : "−"}${Math.abs(v).toPrecision(2)}`));
    document.getElementById("c-diffbar-ticks").replaceChildren(...ticks.map((t) => MF.el("span", { text: t })));
    const linear = maps.length && maps[0].values === "linear";
    document.getElementById("c-diffbar-note").textContent =
      `candidate − reference per pixel, the mean of R, G and B (${linear ? "linear values" : "sRGB-encoded values"}), ` +
      "one scale for every map: blue where the candidate is darker, red where it is brighter.";
    for (const canvas of document.querySelectorAll("canvas.pic[data-tile]")) {
      const t = tiles.find((x) => x.id === canvas.dataset.tile);
      if (t && t.diffData) { paintDiff(canvas, t.diffData, s); canvas.dataset.ready = "1"; }
      else if (t && t.error) canvas.replaceWith(MF.el("p", { class: "muted small missing", text: t.error }));
    }
  }

  // -- drawing ------------------------------------------------------------------------------
  function srcOf(pic) {
    const e = parseFloat(exposure.value);
    return pic.hdr && e !== 0 ? `${pic.src}?exposure=${e}` : pic.src;
  }

  function applyView() {
    const t = `translate(${view.x}px, ${view.y}px) scale(${view.scale})`;
    for (const el of document.querySelectorAll(".viewport .pic")) el.style.transform = t;
  }

  function element(tile, extra = {}) {
    if (tile.diff) return MF.el("canvas", { class: `pic ${extra.class || ""}`.trim(), "data-tile": tile.id, role: "img", "aria-label": tile.text });
    const { pic } = tile;
    return MF.el("img", { src: srcOf(pic), alt: `${tile.jobs[0].title}: ${tile.text}`, draggable: "false",
                          class: `pic ${extra.class || ""}`.trim(), "data-hdr": pic.hdr ? "1" : null, "data-tile": tile.id });
  }

  /** Wheel zooms about the pointer, dragging pans; every viewport shares the transform. */
  function attach(viewport) {
    viewport.addEventListener("wheel", (event) => {
      event.preventDefault();
      const box = viewport.getBoundingClientRect();
      const px = event.clientX - box.left;
      const py = event.clientY - box.top;
      const factor = event.deltaY < 0 ? 1.25 : 0.8;
      const next = Math.min(64, Math.max(1, view.scale * factor));
      view.x = px - ((px - view.x) * next) / view.scale;
      view.y = py - ((py - view.y) * next) / view.scale;
      view.scale = next;
      if (next === 1) { view.x = 0; view.y = 0; }
      applyView();
      saveState();
      readout(event);
    }, { passive: false });
    let drag = null;
    viewport.addEventListener("pointerdown", (event) => {
      drag = { x: event.clientX - view.x, y: event.clientY - view.y };
      viewport.setPointerCapture(event.pointerId);
    });
    viewport.addEventListener("pointermove", (event) => {
      if (drag) {
        view.x = event.clientX - drag.x;
        view.y = event.clientY - drag.y;
        applyView();
      }
      readout(event);
    });
    viewport.addEventListener("pointerup", () => { if (drag) saveState(); drag = null; });
    viewport.addEventListener("pointerleave", () => { lastPointer = null; });
  }

  function caption(tile) {
    const p = tile.jobs[0];
    return MF.el("figcaption", {},
      MF.el("span", {}, ...tile.jobs.flatMap((j, i) => [i ? ", " : null, MF.el("a", { href: `/jobs/${j.id}`, text: j.title })])),
      MF.el("span", { class: "job-id", text: `${p.short} · ${p.kind}` }));
  }

  function renderGrid() {
    if (!tiles.length) {
      grid.replaceChildren(MF.el("p", { class: "card muted", id: "c-none", text: "No job here has such a picture." }));
      return;
    }
    grid.replaceChildren(...tiles.map((t) => {
      const viewport = MF.el("div", { class: "viewport" }, element(t));
      attach(viewport);
      return MF.el("figure", { class: "card compare-panel", "data-id": t.jobs[0].id, "data-tile": t.id },
        caption(t), MF.el("p", { class: "pic-role", text: t.text }), viewport,
        MF.el("p", { class: "readout", "data-tile": t.id }));
    }));
  }

  function fillAB() {
    for (const [select, pick, want] of [[aSelect, 0, wantA], [bSelect, 1, wantB]]) {
      const keep = want || select.value;
      select.replaceChildren(...tiles.map((t) => MF.el("option", { value: t.id, text: `${t.jobs[0].title}: ${t.text} (${t.jobs[0].short})` })));
      if (tiles.some((t) => t.id === keep)) select.value = keep;
      else if (tiles[pick]) select.value = tiles[pick].id;
    }
    wantA = null;
    wantB = null;
  }

  function renderAB() {
    const a = tiles.find((t) => t.id === aSelect.value);
    const b = tiles.find((t) => t.id === bSelect.value);
    if (!a || !b || tiles.length < 2) {
      ab.replaceChildren(MF.el("p", { class: "muted", text: "fewer than two pictures in this view" }));
      return;
    }
    // B sits over A in an untransformed clipping box, so that the split stays put on the
    // screen while both pictures zoom and pan together.
    const viewport = MF.el("div", { class: "viewport viewport-ab" },
      element(a, { class: "ab-a" }),
      MF.el("div", { class: "ab-clip" }, element(b, { class: "ab-b" })),
      MF.el("div", { class: "ab-line" }));
    attach(viewport);
    ab.replaceChildren(
      MF.el("div", { class: "ab-labels" },
        MF.el("a", { href: `/jobs/${a.jobs[0].id}`, text: `A: ${a.jobs[0].title} · ${a.text}` }),
        MF.el("a", { href: `/jobs/${b.jobs[0].id}`, text: `B: ${b.jobs[0].title} · ${b.text}` })),
      viewport);
    applySplit();
  }

  function applySplit() {
    const clip = ab.querySelector(".ab-clip");
    const line = ab.querySelector(".ab-line");
    if (!clip) return;
    clip.style.clipPath = `inset(0 0 0 ${split.value}%)`;
    line.style.left = `${split.value}%`;
  }

  function render() {
    tiles = tilesOf(pictureSelect.value);
    grid.hidden = mode !== "grid";
    ab.hidden = mode !== "ab";
    document.body.classList.toggle("mode-ab", mode === "ab");
    exposureBox.hidden = !tiles.some((t) => t.pic && t.pic.hdr);
    document.getElementById("c-colorbar").hidden = !tiles.some((t) => t.pic && t.pic.role === "error");
    fillAB();
    if (mode === "grid") renderGrid(); else renderAB();
    applyView();
    drawDiffs();
    readoutLine.textContent = "";
    saveState();
  }

  // -- the readout: every panel's value at the pixel under the cursor -----------------------
  let lastPointer = null;

  function fmt(v) {
    if (!Number.isFinite(v)) return String(v);
    const a = Math.abs(v);
    return a !== 0 && (a < 1e-3 || a >= 1e4) ? v.toExponential(2) : v.toPrecision(3);
  }

  function valueText(map, u, v) {
    const x = Math.min(map.w - 1, Math.floor(u * map.w));
    const y = Math.min(map.h - 1, Math.floor(v * map.h));
    const i = y * map.w + x;
    if (map.signed) return `${map.data[i] > 0 ? "+" : ""}${fmt(map.data[i])}`;
    if (map.values === "magma") return `FLIP ${fmt(map.data[3 * i])}`;
    return [0, 1, 2].map((c) => fmt(map.data[3 * i + c])).join(" ");
  }

  function readout(event) {
    const viewport = event.currentTarget;
    const pic = viewport.querySelector(".pic");
    if (!pic) return;
    const box = pic.getBoundingClientRect();  // the transformed picture: zoom and pan included
    const u = (event.clientX - box.left) / box.width;
    const v = (event.clientY - box.top) / box.height;
    lastPointer = { u, v, viewport };
    showReadout(u, v);
  }

  async function showReadout(u, v) {
    const shown = mode === "grid" ? tiles : [aSelect.value, bSelect.value].map((id) => tiles.find((t) => t.id === id)).filter(Boolean);
    const inside = u >= 0 && u < 1 && v >= 0 && v < 1;
    const parts = [];
    let where = "";
    for (const t of shown) {
      let text = "";
      if (inside) {
        try {
          const map = t.diff ? await difference(t) : await pixels(t.pic);
          text = valueText(map, u, v);
          if (!where) where = `pixel (${Math.min(map.w - 1, Math.floor(u * map.w))}, ${Math.min(map.h - 1, Math.floor(v * map.h))})`;
        } catch (err) { text = "no values"; }
      }
      for (const node of grid.querySelectorAll(`.readout[data-tile="${CSS.escape(t.id)}"]`)) node.textContent = text;
      if (text) parts.push(`${t.jobs[0].title} · ${t.text}: ${text}`);
    }
    if (lastPointer && (lastPointer.u !== u || lastPointer.v !== v)) return;  // a later move wins
    readoutLine.textContent = inside ? `${where} — ${parts.join("; ")}` : "";
  }

  // -- controls ----------------------------------------------------------------------------
  pictureSelect.addEventListener("change", render);
  for (const radio of document.querySelectorAll('input[name="c-mode"]')) {
    radio.addEventListener("change", () => { mode = radio.value; render(); });
  }
  aSelect.addEventListener("change", () => { renderAB(); applyView(); drawDiffs(); saveState(); });
  bSelect.addEventListener("change", () => { renderAB(); applyView(); drawDiffs(); saveState(); });
  split.addEventListener("input", () => { applySplit(); saveState(); });
  document.getElementById("c-flip").addEventListener("click", () => {
    split.value = split.value === "100" ? "0" : "100";
    applySplit();
    saveState();
  });
  document.addEventListener("keydown", (event) => {
    if (event.key === "f" && mode === "ab") document.getElementById("c-flip").click();
  });
  let exposureTimer = null;
  exposure.addEventListener("input", () => {
    exposureValue.textContent = `${exposure.value} EV`;
    window.clearTimeout(exposureTimer);
    exposureTimer = window.setTimeout(() => {
      for (const img of document.querySelectorAll('.viewport img[data-hdr="1"]')) {
        const base = img.getAttribute("src").split("?")[0];
        img.src = srcOf({ src: base, hdr: true });
      }
      saveState();
    }, 150);
  });
  document.getElementById("c-reset").addEventListener("click", () => {
    view.scale = 1; view.x = 0; view.y = 0; applyView(); saveState();
  });
  render();
})();
