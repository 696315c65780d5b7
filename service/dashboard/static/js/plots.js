/* Interactive charts of a job's JSON artifacts (the PNGs stay as artifacts for papers), in
   their one schema each (docs/artifacts.md, "Chart documents"; MF.curveSeries and
   MF.paretoPanels read them, and older documents too):
   - curves.json: every series against "step" (lists, or {name: list} groups), the learning
     rate on its own log axis, epoch in the tooltip, a line where each phase begins; log y
     when the values span decades; short runs' points drawn as dots;
   - pareto.json: one chart per panel, error against cost, the front highlighted and joined,
     seed spread (min to max) as error bars, the candidate on hover, its run's job on click. */
"use strict";

(() => {
  const box = document.getElementById("plots");
  if (!box || typeof window.Chart === "undefined") return;
  MF.fitTicks();
  const palette = ["#2f5bd3", "#d64545", "#1f9d55", "#c98a0b", "#7a5af8", "#0e9384", "#e04f9b"];
  const number = (v) => typeof v === "number" && isFinite(v);
  const spansDecades = (values, ratio) => {
    const v = values.filter((x) => number(x) && x > 0);
    return v.length === values.filter(number).length && v.length > 1 &&
      Math.max(...v) / Math.min(...v) >= ratio;
  };

  function card(title, id) {
    const canvas = MF.el("canvas", { id, role: "img", "aria-label": title });
    box.append(MF.el("div", { class: "card plot-card" }, MF.el("div", { class: "plot-box" }, canvas)));
    return canvas;
  }

  /** Few points are drawn as dots as well: one check of a short run is still seen. */
  const FEW_POINTS = 30;

  /** A dashed line and the phase's name where each phase after the first begins. */
  const phaseLines = {
    id: "phaseLines",
    afterDatasetsDraw(chart, args, options) {
      const { ctx, chartArea, scales } = chart;
      for (const phase of (options.phases || []).slice(1)) {
        const x = scales.x.getPixelForValue(phase.first_step - 0.5);
        if (!(x >= chartArea.left && x <= chartArea.right)) continue;
        ctx.save();
        ctx.strokeStyle = "#667085";
        ctx.setLineDash([5, 4]);
        ctx.beginPath(); ctx.moveTo(x, chartArea.top); ctx.lineTo(x, chartArea.bottom); ctx.stroke();
        ctx.fillStyle = "#475467";
        ctx.font = "12px sans-serif";
        ctx.fillText(phase.name, x + 4, chartArea.top + 14);
        ctx.restore();
      }
    },
  };

  function curves(doc, canvas = null, live = false) {
    const c = MF.curveSeries(doc);
    if (!c) return;
    const { step: steps, series: main, lr } = c;
    const radius = steps.length <= FEW_POINTS ? 3 : 0;
    const datasets = main.map(([label, values], i) => ({
      label, data: steps.map((x, j) => ({ x, y: number(values[j]) ? values[j] : null })),
      borderColor: palette[i % palette.length], backgroundColor: palette[i % palette.length],
      pointRadius: radius, borderWidth: 1.6, spanGaps: true, yAxisID: "y",
    }));
    if (lr) {
      datasets.push({
        label: "lr", data: steps.map((x, j) => ({ x, y: lr[j] })), borderColor: "#98a2b3",
        backgroundColor: "#98a2b3", borderDash: [4, 3], pointRadius: radius, borderWidth: 1.2,
        yAxisID: "lr",
      });
    }
    const values = main.flatMap(([, v]) => v);
    const target = canvas || card("training curves", "curves-chart");
    const previous = window.Chart.getChart(target);
    if (previous) previous.destroy();
    const last = steps[steps.length - 1];
    new window.Chart(target, {
      type: "line",
      data: { datasets },
      plugins: [phaseLines],
      options: {
        responsive: true, maintainAspectRatio: false, animation: false, parsing: false,
        interaction: { mode: "nearest", axis: "x", intersect: false },
        plugins: {
          phaseLines: { phases: c.phases },
          title: { display: true, text: live ?
            `Training curves, live: step ${last}` : "Training curves (curves.json)" },
          tooltip: { callbacks: { footer: (items) => (c.epoch && items.length ?
            `epoch ${c.epoch[items[0].dataIndex]}` : "") } },
        },
        scales: {
          // one step alone still gets an x range around it
          x: { type: "linear", title: { display: true, text: "step" },
               ...(steps.length === 1 ? { min: 0, max: 2 * last } : {}) },
          y: { type: spansDecades(values, 30) ? "logarithmic" : "linear",
               ticks: { callback: (v) => MF.si(v) },
               title: { display: true, text: "loss / error (lower is better ↓)" } },
          ...(lr ? { lr: { type: "logarithmic", position: "right", grid: { drawOnChartArea: false },
                           ticks: { callback: (v) => MF.si(v) },
                           title: { display: true, text: "learning rate" } } } : {}),
        },
      },
    });
  }

  /** Vertical error bars from each point's yMin / yMax. */
  const errorBars = {
    id: "errorBars",
    afterDatasetsDraw(chart) {
      const { ctx } = chart;
      chart.data.datasets.forEach((set, i) => {
        const meta = chart.getDatasetMeta(i);
        if (meta.hidden || set.type === "line") return;
        set.data.forEach((p, j) => {
          const x = meta.data[j].x;
          const y = meta.data[j].y;
          ctx.save();
          ctx.strokeStyle = set.borderColor;
          ctx.lineWidth = 1.2;
          ctx.beginPath();
          if (number(p.yMin) && number(p.yMax)) {  // the seed spread
            const top = chart.scales.y.getPixelForValue(p.yMax);
            const bottom = chart.scales.y.getPixelForValue(p.yMin);
            ctx.moveTo(x, top); ctx.lineTo(x, bottom);
            ctx.moveTo(x - 4, top); ctx.lineTo(x + 4, top);
            ctx.moveTo(x - 4, bottom); ctx.lineTo(x + 4, bottom);
          }
          if (number(p.xMin) && number(p.xMax)) {  // the timing pass's spread
            const left = chart.scales.x.getPixelForValue(p.xMin);
            const right = chart.scales.x.getPixelForValue(p.xMax);
            ctx.moveTo(left, y); ctx.lineTo(right, y);
            ctx.moveTo(left, y - 4); ctx.lineTo(left, y + 4);
            ctx.moveTo(right, y - 4); ctx.lineTo(right, y + 4);
          }
          ctx.stroke();
          ctx.restore();
        });
      });
    },
  };

  /** At most this many panels drawn (all are in pareto.json). */
  const MAX_PANELS = 6;

  function pareto(doc) {
    const panels = MF.paretoPanels(doc);
    const several = new Set(panels.map((p) => `${p.dataset || ""} ${p.scene || ""}`)).size > 1;
    panels.slice(0, MAX_PANELS).forEach((panel, k) => paretoPanel(panel, k, several));
    if (panels.length > MAX_PANELS) {
      box.append(MF.el("p", { class: "muted small",
        text: `${MAX_PANELS} of ${panels.length} panels drawn; all are in pareto.json` }));
    }
  }

  function paretoPanel(panel, k, several) {
    const points = panel.points;
    const point = (p) => ({
      x: p.cost, y: p.mean,
      // error bars: min to max over seeds, as pareto.png draws them (else mean ± std)
      yMin: number(p.min) ? p.min : number(p.std) ? p.mean - p.std : null,
      yMax: number(p.max) ? p.max : number(p.std) ? p.mean + p.std : null,
      // the cost's spread over a timing pass's repeats (pareto.json's cost_min..cost_max)
      xMin: number(p.cost_min) ? p.cost_min : null,
      xMax: number(p.cost_max) ? p.cost_max : null,
      point: p,
    });
    const front = points.filter((p) => p.front).sort((a, b) => a.cost - b.cost);
    const rest = points.filter((p) => !p.front);
    const datasets = [
      { type: "line", label: "front", data: front.map(point), borderColor: "#1f9d55",
        borderWidth: 1.5, pointRadius: 0, fill: false, order: 2 },
      { type: "scatter", label: "on the front", data: front.map(point), borderColor: "#1f9d55",
        backgroundColor: "#1f9d55", pointRadius: 6, pointHoverRadius: 8, order: 1 },
      { type: "scatter", label: "beaten", data: rest.map(point), borderColor: "#667085",
        backgroundColor: "#98a2b3", pointRadius: 5, pointHoverRadius: 7, order: 1 },
    ].filter((d) => d.data.length >= (d.type === "line" ? 2 : 1));  // a line needs two points
    const xs = points.map((p) => p.cost);
    const ys = points.map((p) => p.mean);
    const where = several ? ` [${[panel.dataset, panel.scene].filter(Boolean).join(" ")}]` : "";
    const undecided = panel.resolved === false ? " — front not resolved within the spread" : "";
    const title = `${panel.metric} against ${panel.cost}${where}${undecided}`;
    const id = k === 0 ? "pareto-chart" : `pareto-chart-${k}`;
    const canvas = card(title, id);
    canvas.dataset.panel = `${panel.metric} ${panel.cost}`;
    const xUnit = MF.unitOf(panel.cost);
    const yUnit = MF.unitOf(panel.metric);
    const withUnit = (label, unit) => (unit ? `${label} [${unit === "ns" ? "s" : unit}]` : label);
    const chart = new window.Chart(canvas, {
      type: "scatter",
      data: { datasets },
      plugins: [errorBars],
      options: {
        responsive: true, maintainAspectRatio: false, animation: false,
        plugins: {
          title: { display: true, text: `${title} (lower-left is better; click a point: its run)` },
          tooltip: {
            filter: (item) => item.dataset.type !== "line",
            callbacks: {
              // the split says whose error it is: test (held-out data) or train
              title: (items) => items.map((i) => i.raw.point.candidate
                + (i.raw.point.split ? ` (${i.raw.point.split})` : "")),
              label: (item) => {
                const p = item.raw.point;
                const spreadText = number(p.std) ? ` ± ${MF.si(p.std, yUnit)}` : "";
                const seeds = number(p.n) ? `, ${p.n} seed(s)` : "";
                const costSpread = number(p.cost_min) && number(p.cost_max)
                  ? ` (${MF.si(p.cost_min, xUnit)}..${MF.si(p.cost_max, xUnit)})` : "";
                const rel = p.relative && number(p.relative.median)
                  ? `, ${+p.relative.median.toPrecision(3)}x the reference` : "";
                const tie = p.resolved === false && (p.tied_with || []).length
                  ? `; not resolved against ${p.tied_with.join(", ")}` : "";
                return `${panel.metric} ${MF.si(p.mean, yUnit)}${spreadText}, ${panel.cost} ${MF.si(p.cost, xUnit)}${costSpread}${rel}${seeds}${tie}`;
              },
            },
          },
        },
        scales: {
          x: { type: spansDecades(xs, 30) ? "logarithmic" : "linear",
               ticks: { callback: (v) => MF.si(v, xUnit) },
               suggestedMin: Math.min(...points.map(point).map((p) => (number(p.xMin) ? p.xMin : p.x))),
               suggestedMax: Math.max(...points.map(point).map((p) => (number(p.xMax) ? p.xMax : p.x))),
               title: { display: true, text: `${withUnit(panel.cost_label || panel.cost, xUnit)} (lower is better ←)` } },
          y: { type: spansDecades(ys, 30) ? "logarithmic" : "linear",
               ticks: { callback: (v) => MF.si(v, yUnit) },
               title: { display: true, text: `${withUnit(panel.metric, yUnit)} (lower is better ↓)` },
               suggestedMin: Math.min(...points.map(point).map((p) => (number(p.yMin) ? p.yMin : p.y))),
               suggestedMax: Math.max(...points.map(point).map((p) => (number(p.yMax) ? p.yMax : p.y))) },
        },
        onClick: (event, elements) => {
          const hit = elements.find((e) => chart.data.datasets[e.datasetIndex].type !== "line");
          if (!hit) return;
          const p = chart.data.datasets[hit.datasetIndex].data[hit.index].point;
          const run = (p.jobs || [])[0];
          if (run) window.location.href = `/jobs/${run.replace(/^job:/, "").split("/")[0]}`;
        },
      },
    });
  }

  async function load(key, draw) {
    const src = box.dataset[key];
    if (!src) return;
    try {
      draw(await MF.api(src));
    } catch (err) {
      box.append(MF.el("p", { class: "muted", text: `cannot draw ${key}.json: ${err.message}` }));
    }
  }

  /** A running job: poll its published curves until the page reloads with the artifact. */
  function live() {
    const src = box.dataset.liveCurves;
    if (!src) return;
    const canvas = card("training curves (live)", "curves-chart");
    const note = MF.el("p", { class: "muted small", id: "live-note", text: "no curves published yet" });
    box.append(note);
    async function poll() {
      try {
        const response = await fetch(src, { credentials: "same-origin", headers: { Accept: "application/json" } });
        const doc = response.ok ? await response.json() : null;
        if (doc) {
          curves(doc, canvas, true);
          note.textContent = `live · updated ${new Date().toLocaleTimeString()}`;
        }
      } catch (_) { /* the next poll tries again */ }
      window.setTimeout(poll, 2000);
    }
    poll();
  }

  load("pareto", pareto);
  load("curves", curves);
  live();
})();
