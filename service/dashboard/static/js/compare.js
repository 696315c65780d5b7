/* The compare view: one picture name across several jobs, side by side or under an A/B
   slider, with one zoom/pan transform shared by every view (square pixels when zoomed) and
   an exposure slider for HDR pictures (EXRs are tone-mapped by the server's preview route). */
"use strict";

(() => {
  const panels = JSON.parse(document.getElementById("compare-data").textContent);
  const grid = document.getElementById("compare-grid");
  const ab = document.getElementById("compare-ab");
  const artifactSelect = document.getElementById("c-artifact");
  const aSelect = document.getElementById("c-a");
  const bSelect = document.getElementById("c-b");
  const split = document.getElementById("c-split");
  const exposure = document.getElementById("c-exposure");
  const exposureValue = document.getElementById("c-exposure-value");
  const exposureBox = document.getElementById("c-exposure-box");
  const view = { scale: 1, x: 0, y: 0 };
  let mode = "grid";

  const initial = new URLSearchParams(window.location.search);
  if (initial.get("artifact")) artifactSelect.value = initial.get("artifact");

  function picture(panel) {
    return panel.images.find((i) => i.name === artifactSelect.value) || null;
  }

  function srcOf(image) {
    const ev = parseFloat(exposure.value);
    return image.hdr && ev !== 0 ? `${image.src}?exposure=${ev}` : image.src;
  }

  function applyView() {
    const t = `translate(${view.x}px, ${view.y}px) scale(${view.scale})`;
    for (const img of document.querySelectorAll(".viewport img")) img.style.transform = t;
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
    }, { passive: false });
    let drag = null;
    viewport.addEventListener("pointerdown", (event) => {
      drag = { x: event.clientX - view.x, y: event.clientY - view.y };
      viewport.setPointerCapture(event.pointerId);
    });
    viewport.addEventListener("pointermove", (event) => {
      if (!drag) return;
      view.x = event.clientX - drag.x;
      view.y = event.clientY - drag.y;
      applyView();
    });
    viewport.addEventListener("pointerup", () => { drag = null; });
  }

  function image(img, extra = {}) {
    return MF.el("img", { src: srcOf(img), alt: img.name, draggable: "false", "data-hdr": img.hdr ? "1" : null, ...extra });
  }

  function renderGrid() {
    grid.replaceChildren(...panels.map((p) => {
      const img = picture(p);
      const viewport = MF.el("div", { class: "viewport" },
        img ? image(img) : MF.el("p", { class: "muted small missing", text: `no ${artifactSelect.value}` }));
      attach(viewport);
      return MF.el("figure", { class: "card compare-panel", "data-id": p.id },
        MF.el("figcaption", {},
          MF.el("a", { href: `/jobs/${p.id}`, text: p.title }),
          MF.el("span", { class: "job-id", text: `${p.short} · ${p.kind}` })),
        viewport);
    }));
  }

  function fillAB() {
    const have = panels.filter((p) => picture(p));
    for (const [select, pick] of [[aSelect, 0], [bSelect, 1]]) {
      const keep = select.value;
      select.replaceChildren(...have.map((p) => MF.el("option", { value: p.id, text: `${p.title} (${p.short})` })));
      if (have.some((p) => p.id === keep)) select.value = keep;
      else if (have[pick]) select.value = have[pick].id;
    }
  }

  function renderAB() {
    const a = panels.find((p) => p.id === aSelect.value);
    const b = panels.find((p) => p.id === bSelect.value);
    if (!a || !b) {
      ab.replaceChildren(MF.el("p", { class: "muted", text: `fewer than two jobs have ${artifactSelect.value}` }));
      return;
    }
    // B sits over A in an untransformed clipping box, so that the split stays put on the
    // screen while both pictures zoom and pan together.
    const viewport = MF.el("div", { class: "viewport viewport-ab" },
      image(picture(a), { class: "ab-a" }),
      MF.el("div", { class: "ab-clip" }, image(picture(b), { class: "ab-b" })),
      MF.el("div", { class: "ab-line" }));
    attach(viewport);
    ab.replaceChildren(
      MF.el("div", { class: "ab-labels" },
        MF.el("a", { href: `/jobs/${a.id}`, text: `A: ${a.title}` }),
        MF.el("a", { href: `/jobs/${b.id}`, text: `B: ${b.title}` })),
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
    grid.hidden = mode !== "grid";
    ab.hidden = mode !== "ab";
    document.body.classList.toggle("mode-ab", mode === "ab");
    exposureBox.hidden = !panels.some((p) => { const i = picture(p); return i && i.hdr; });
    document.getElementById("c-colorbar").hidden = !artifactSelect.value.split("/").pop().startsWith("flip_");
    fillAB();
    if (mode === "grid") renderGrid(); else renderAB();
    applyView();
  }

  artifactSelect.addEventListener("change", render);
  for (const radio of document.querySelectorAll('input[name="c-mode"]')) {
    radio.addEventListener("change", () => { mode = radio.value; render(); });
  }
  aSelect.addEventListener("change", renderAB);
  bSelect.addEventListener("change", renderAB);
  split.addEventListener("input", applySplit);
  document.getElementById("c-flip").addEventListener("click", () => {
    split.value = split.value === "100" ? "0" : "100";
    applySplit();
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
    }, 150);
  });
  document.getElementById("c-reset").addEventListener("click", () => {
    view.scale = 1; view.x = 0; view.y = 0; applyView();
  });
  render();
  overlayCurves();
  overlayPareto();

  /** Reports: one panel (error against cost) of every job's pareto.json in one chart, a
      job's candidates in its colour, its front joined; picked from the panels they have. */
  async function overlayPareto() {
    const box = document.getElementById("c-pareto");
    if (!box || typeof window.Chart === "undefined") return;
    const reports = panels.filter((p) => p.pareto);
    const docs = await Promise.all(reports.map((p) => MF.api(p.pareto).catch(() => null)));
    const byKey = new Map();  // "metric against cost [where]" -> [[panel of the page, pareto panel]]
    reports.forEach((p, i) => {
      for (const q of MF.paretoPanels(docs[i])) {
        const where = [q.dataset, q.scene].filter(Boolean).join(" ");
        const key = `${q.metric} against ${q.cost}${where ? ` [${where}]` : ""}`;
        if (!byKey.has(key)) byKey.set(key, []);
        byKey.get(key).push([p, q]);
      }
    });
    const select = document.getElementById("c-panel");
    const names = [...byKey.keys()].sort((a, b) => byKey.get(b).length - byKey.get(a).length);
    select.replaceChildren(...names.map((n) => MF.el("option", { value: n, text: n })));
    const colours = ["#2f5bd3", "#d64545", "#1f9d55", "#c98a0b", "#7a5af8", "#0e9384"];
    const chart = new window.Chart(document.getElementById("c-pareto-chart"), {
      type: "scatter",
      data: { datasets: [] },
      options: {
        responsive: true, maintainAspectRatio: false, animation: false,
        scales: { x: { type: "linear", title: { display: true, text: "" } },
                  y: { type: "linear", title: { display: true, text: "" } } },
        plugins: {
          title: { display: true, text: "" },
          tooltip: { callbacks: { label: (item) =>
            `${item.raw.candidate}: ${item.raw.y.toPrecision(4)} at ${item.raw.x.toPrecision(4)}` } },
        },
      },
    });
    function draw() {
      const found = byKey.get(select.value) || [];
      chart.data.datasets = found.flatMap(([p, q], i) => {
        const colour = colours[i % colours.length];
        const pts = q.points.map((pt) => ({ x: pt.cost, y: pt.mean, candidate: pt.candidate }));
        const front = q.points.filter((pt) => pt.front).sort((a, b) => a.cost - b.cost)
          .map((pt) => ({ x: pt.cost, y: pt.mean, candidate: pt.candidate }));
        return [
          { type: "scatter", label: `${p.title} (${p.short})`, data: pts, borderColor: colour,
            backgroundColor: colour, pointRadius: 5, pointHoverRadius: 7 },
          { type: "line", label: `${p.title}: front`, data: front, borderColor: colour,
            borderWidth: 1.2, borderDash: [4, 3], pointRadius: 0, fill: false },
        ].filter((d) => d.data.length >= (d.type === "line" ? 2 : 1));  // a line needs two points
      });
      const first = found.length ? found[0][1] : null;
      chart.options.scales.x.title.text = first ? `${first.cost_label || first.cost} (lower is better ←)` : "";
      chart.options.scales.y.title.text = first ? `${first.metric} (lower is better ↓)` : "";
      chart.options.plugins.title.text = `${select.value}: ${found.length} report(s)`;
      chart.update();
    }
    select.addEventListener("change", draw);
    draw();
  }

  /** Training runs: one series of every job's curves.json in one chart (several runs
      overlaid), picked from the series they have. */
  async function overlayCurves() {
    const box = document.getElementById("c-curves");
    if (!box || typeof window.Chart === "undefined") return;
    const runs = panels.filter((p) => p.curves);
    const docs = await Promise.all(runs.map((p) => MF.api(p.curves).catch(() => null)));
    const series = new Map();  // name -> [[panel, steps, values], ...]
    runs.forEach((p, i) => {
      const c = MF.curveSeries(docs[i]);  // the one schema (docs/artifacts.md), older ones too
      if (!c) return;
      for (const [name, values] of c.lr ? [...c.series, ["lr", c.lr]] : c.series) {
        if (!series.has(name)) series.set(name, []);
        series.get(name).push([p, c.step, values]);
      }
    });
    const select = document.getElementById("c-series");
    const names = [...series.keys()].sort((a, b) => series.get(b).length - series.get(a).length);
    select.replaceChildren(...names.map((n) => MF.el("option", { value: n, text: n })));
    if (names.includes("loss")) select.value = "loss";
    const colours = ["#2f5bd3", "#d64545", "#1f9d55", "#c98a0b", "#7a5af8", "#0e9384"];
    const chart = new window.Chart(document.getElementById("c-curves-chart"), {
      type: "line",
      data: { datasets: [] },
      options: {
        responsive: true, maintainAspectRatio: false, animation: false, parsing: false,
        interaction: { mode: "nearest", axis: "x", intersect: false },
        scales: { x: { type: "linear", title: { display: true, text: "step" } }, y: { type: "linear" } },
        plugins: { title: { display: true, text: "" } },
      },
    });
    function draw() {
      const lines = series.get(select.value) || [];
      chart.data.datasets = lines.map(([p, steps, values], i) => ({
        label: `${p.title} (${p.short})`,
        data: steps.map((x, j) => ({ x, y: typeof values[j] === "number" ? values[j] : null })),
        borderColor: colours[i % colours.length], backgroundColor: colours[i % colours.length],
        // short runs' points drawn as dots: a run of one check is still seen
        pointRadius: steps.length <= 30 ? 3 : 0, borderWidth: 1.6, spanGaps: true,
      }));
      const all = lines.flatMap(([, , v]) => v).filter((v) => typeof v === "number");
      const positive = all.length && all.every((v) => v > 0);
      chart.options.scales.y.type = positive && Math.max(...all) / Math.min(...all) >= 30 ? "logarithmic" : "linear";
      chart.options.plugins.title.text = `${select.value}: ${lines.length} run(s)`;
      chart.update();
    }
    select.addEventListener("change", draw);
    draw();
  }
})();
