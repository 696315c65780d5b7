/* Interactive charts of a job's JSON artifacts (the PNGs stay as artifacts for papers):
   - curves.json: every series against "step" (lists, or {name: list} groups), the learning
     rate on its own log axis; log y when the values span decades;
   - pareto.json: cost against accuracy per configuration, the front highlighted and joined,
     seed spread as error bars, the configuration on hover, its run's job on click. */
"use strict";

(() => {
  const box = document.getElementById("plots");
  if (!box || typeof window.Chart === "undefined") return;
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

  function curves(doc, canvas = null, live = false) {
    const steps = doc.step;
    if (!Array.isArray(steps) || !steps.length) return;
    const series = [];
    for (const [key, value] of Object.entries(doc)) {
      if (key === "step") continue;
      if (Array.isArray(value) && value.length === steps.length && value.some(number)) {
        series.push([key, value]);
      } else if (value && typeof value === "object" && !Array.isArray(value)) {
        for (const [sub, list] of Object.entries(value)) {
          if (Array.isArray(list) && list.length === steps.length && list.some(number)) {
            series.push([`${key}.${sub}`, list]);
          }
        }
      }
    }
    const main = series.filter(([k]) => k !== "lr");
    const lr = series.find(([k]) => k === "lr");
    const datasets = main.map(([label, values], i) => ({
      label, data: steps.map((x, j) => ({ x, y: number(values[j]) ? values[j] : null })),
      borderColor: palette[i % palette.length], backgroundColor: palette[i % palette.length],
      pointRadius: 0, borderWidth: 1.6, spanGaps: true, yAxisID: "y",
    }));
    if (lr) {
      datasets.push({
        label: "lr", data: steps.map((x, j) => ({ x, y: lr[1][j] })), borderColor: "#98a2b3",
        borderDash: [4, 3], pointRadius: 0, borderWidth: 1.2, yAxisID: "lr",
      });
    }
    const values = main.flatMap(([, v]) => v);
    const target = canvas || card("training curves", "curves-chart");
    const previous = window.Chart.getChart(target);
    if (previous) previous.destroy();
    new window.Chart(target, {
      type: "line",
      data: { datasets },
      options: {
        responsive: true, maintainAspectRatio: false, animation: false, parsing: false,
        interaction: { mode: "nearest", axis: "x", intersect: false },
        plugins: { title: { display: true, text: live ?
          `Training curves, live: step ${steps[steps.length - 1]}` : "Training curves (curves.json)" } },
        scales: {
          x: { type: "linear", title: { display: true, text: "step" } },
          y: { type: spansDecades(values, 30) ? "logarithmic" : "linear",
               title: { display: true, text: "loss / error (lower is better ↓)" } },
          ...(lr ? { lr: { type: "logarithmic", position: "right", grid: { drawOnChartArea: false },
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
          if (!number(p.yMin) || !number(p.yMax)) return;
          const x = meta.data[j].x;
          const top = chart.scales.y.getPixelForValue(p.yMax);
          const bottom = chart.scales.y.getPixelForValue(p.yMin);
          ctx.save();
          ctx.strokeStyle = set.borderColor;
          ctx.lineWidth = 1.2;
          ctx.beginPath();
          ctx.moveTo(x, top); ctx.lineTo(x, bottom);
          ctx.moveTo(x - 4, top); ctx.lineTo(x + 4, top);
          ctx.moveTo(x - 4, bottom); ctx.lineTo(x + 4, bottom);
          ctx.stroke();
          ctx.restore();
        });
      });
    },
  };

  function pareto(doc) {
    const xKey = (doc.axes && doc.axes.x) || "ns_per_eval";
    const yKey = (doc.axes && doc.axes.y) || "smape_mean";
    const sKey = (doc.axes && doc.axes.spread) || "smape_std";
    const points = (doc.points || []).filter((p) => number(p[xKey]) && number(p[yKey]));
    if (!points.length) return;
    const point = (p) => ({
      x: p[xKey], y: p[yKey],
      yMin: number(p[sKey]) ? p[yKey] - p[sKey] : null,
      yMax: number(p[sKey]) ? p[yKey] + p[sKey] : null,
      point: p,
    });
    const front = points.filter((p) => p.pareto).sort((a, b) => a[xKey] - b[xKey]);
    const rest = points.filter((p) => !p.pareto);
    const datasets = [
      { type: "line", label: "front", data: front.map(point), borderColor: "#1f9d55",
        borderWidth: 1.5, pointRadius: 0, fill: false, order: 2 },
      { type: "scatter", label: "on the front", data: front.map(point), borderColor: "#1f9d55",
        backgroundColor: "#1f9d55", pointRadius: 6, pointHoverRadius: 8, order: 1 },
      { type: "scatter", label: "beaten", data: rest.map(point), borderColor: "#667085",
        backgroundColor: "#98a2b3", pointRadius: 5, pointHoverRadius: 7, order: 1 },
    ];
    const xs = points.map((p) => p[xKey]);
    const ys = points.map((p) => p[yKey]);
    const chart = new window.Chart(card("speed against accuracy", "pareto-chart"), {
      type: "scatter",
      data: { datasets },
      plugins: [errorBars],
      options: {
        responsive: true, maintainAspectRatio: false, animation: false,
        plugins: {
          title: { display: true, text: `${yKey} against ${xKey} (lower-left is better; click a point: its run)` },
          tooltip: {
            filter: (item) => item.dataset.type !== "line",
            callbacks: {
              title: (items) => items.map((i) => i.raw.point.config),
              label: (item) => {
                const p = item.raw.point;
                const spreadText = number(p[sKey]) ? ` ± ${p[sKey].toPrecision(3)}` : "";
                const detail = ["model", "width", "depth", "latent_dim", "seeds"]
                  .filter((k) => p[k] !== undefined && p[k] !== null)
                  .map((k) => `${k} ${Array.isArray(p[k]) ? p[k].join(",") : p[k]}`).join(", ");
                return [`${yKey} ${p[yKey].toPrecision(4)}${spreadText}, ${xKey} ${p[xKey].toPrecision(4)}`, detail];
              },
            },
          },
        },
        scales: {
          x: { type: spansDecades(xs, 30) ? "logarithmic" : "linear", title: { display: true, text: `${xKey} (lower is better ←)` } },
          y: { type: spansDecades(ys, 30) ? "logarithmic" : "linear", title: { display: true, text: `${yKey} (lower is better ↓)` },
               suggestedMin: Math.min(...points.map(point).map((p) => (number(p.yMin) ? p.yMin : p.y))),
               suggestedMax: Math.max(...points.map(point).map((p) => (number(p.yMax) ? p.yMax : p.y))) },
        },
        onClick: (event, elements) => {
          const hit = elements.find((e) => chart.data.datasets[e.datasetIndex].type !== "line");
          if (!hit) return;
          const p = chart.data.datasets[hit.datasetIndex].data[hit.index].point;
          const run = (p.runs || [])[0];
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
