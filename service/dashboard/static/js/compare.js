/* The compare view's charts: training curves and Pareto panels of several jobs overlaid
   (the pictures are static/js/compare_pictures.js). */
"use strict";

(() => {
  const panels = JSON.parse(document.getElementById("compare-data").textContent);
  MF.fitTicks();
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
        const named = (pt) => pt.candidate + (pt.split ? ` (${pt.split})` : "");  // test/train
        const pts = q.points.map((pt) => ({ x: pt.cost, y: pt.mean, candidate: named(pt) }));
        const front = q.points.filter((pt) => pt.front).sort((a, b) => a.cost - b.cost)
          .map((pt) => ({ x: pt.cost, y: pt.mean, candidate: named(pt) }));
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
