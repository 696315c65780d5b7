/* matforge dashboard: helpers shared by the pages (plain JS, no build step). */
"use strict";

const MF = (() => {
  /** Remove ?token= from the address bar: the server already set the session cookie. */
  function stripToken() {
    const url = new URL(window.location.href);
    if (url.searchParams.has("token")) {
      url.searchParams.delete("token");
      window.history.replaceState(null, "", url.pathname + url.search + url.hash);
    }
  }

  /** GET or POST JSON from the API; throws an Error carrying the server's one-line message. */
  async function api(path, options = {}) {
    const response = await fetch(path, {
      credentials: "same-origin",
      headers: { Accept: "application/json" },
      ...options,
    });
    if (!response.ok) {
      let message = `HTTP ${response.status}`;
      try {
        const body = await response.json();
        if (body && body.error) message = body.error;
      } catch (_) { /* not JSON */ }
      throw new Error(message);
    }
    return response.json();
  }

  /** Create an element: el("td", {class: "num"}, "text", childNode). */
  function el(tag, attrs = {}, ...children) {
    const node = document.createElement(tag);
    for (const [key, value] of Object.entries(attrs)) {
      if (value === null || value === undefined || value === false) continue;
      if (key === "class") node.className = value;
      else if (key === "text") node.textContent = value;
      else node.setAttribute(key, value === true ? "" : value);
    }
    for (const child of children) {
      if (child !== null && child !== undefined) node.append(child);
    }
    return node;
  }

  function seconds(s) {
    if (s === null || s === undefined || !isFinite(s)) return "–";
    // rounded once, then split: 119.6 s is "2 min 00 s" (it was "1 min 60 s"), as the
    // job page (service/routes/dashboard.py fmt_seconds) says
    if (s < 0.9995) return `${Math.round(s * 1000)} ms`;
    if (s < 59.95) return `${s.toFixed(1)} s`;
    const whole = Math.round(s);
    if (whole < 3600) {
      return `${Math.floor(whole / 60)} min ${String(whole % 60).padStart(2, "0")} s`;
    }
    const minutes = Math.round(s / 60);
    return `${Math.floor(minutes / 60)} h ${String(minutes % 60).padStart(2, "0")} min`;
  }

  /** An ISO time as "12 s ago" (recent) or a local date-time. */
  function when(iso) {
    if (!iso) return "–";
    const t = new Date(iso);
    const ago = (Date.now() - t.getTime()) / 1000;
    if (ago < 60) return `${Math.max(0, Math.round(ago))} s ago`;
    if (ago < 3600) return `${Math.round(ago / 60)} min ago`;
    return localTime(iso);
  }

  /** A local date-time that wraps only between its date and its time: the clock time
      and its AM/PM are joined by no-break spaces (a narrow column showed "3:36:38 P" and
      "M" on two lines). */
  function localTime(iso) {
    const t = new Date(iso);
    return `${t.toLocaleDateString()} ${t.toLocaleTimeString().replace(/\s+/g, "\u00a0")}`;
  }

  function badge(state) {
    return el("span", { class: `badge state-${state}`, text: state });
  }

  function progress(job) {
    const pct = Math.round((job.progress || 0) * 100);
    const bar = el("div", { class: "bar" });
    bar.style.width = `${pct}%`;
    return el(
      "div", { class: "progress-cell" },
      el("div", { class: `progress state-${job.state}`, role: "progressbar",
                  "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": String(pct) }, bar),
      el("span", { class: "pct", text: `${pct}%` }),
    );
  }

  function localTimes(root = document) {
    for (const node of root.querySelectorAll("time[datetime]")) {
      const iso = node.getAttribute("datetime");
      if (iso) node.textContent = localTime(iso);
    }
  }

  const isNum = (v) => typeof v === "number" && isFinite(v);

  /** A train.brdf curves.json of before the one schema ({train: {step, ...}, heldout}):
      its phases one after the other, as the kind writes them now. */
  function curvesOfPhases(doc) {
    const out = { step: [], phases: [] };
    let offset = 0;
    for (const name of ["train", "heldout"]) {
      const c = doc[name];
      if (!c || !Array.isArray(c.step) || !c.step.length) continue;
      const before = out.step.length;
      out.step.push(...c.step.map((s) => s + offset));
      for (const [key, values] of Object.entries(c)) {
        if (key === "step" || !Array.isArray(values)) continue;
        if (!out[key]) out[key] = new Array(before).fill(null);
        out[key].push(...values);
      }
      for (const [key, values] of Object.entries(out)) {
        if (key !== "step" && key !== "phases") while (values.length < out.step.length) values.push(null);
      }
      out.phases.push({ name, first_step: offset + 1, last_step: offset + c.step[c.step.length - 1] });
      offset += c.step[c.step.length - 1];
    }
    return out;
  }

  /** The series of a curves.json (docs/artifacts.md, "Chart documents"): {step, series:
      [[name, values]], lr, epoch, phases}, or null when it has nothing to draw. */
  function curveSeries(doc) {
    if (!doc || typeof doc !== "object") return null;
    if (!Array.isArray(doc.step) && doc.train && Array.isArray(doc.train.step)) doc = curvesOfPhases(doc);
    const step = doc.step;
    if (!Array.isArray(step) || !step.length) return null;
    const fits = (v) => Array.isArray(v) && v.length === step.length && v.some(isNum);
    const out = { step, series: [], lr: null, epoch: null, phases: Array.isArray(doc.phases) ? doc.phases : [] };
    for (const [key, value] of Object.entries(doc)) {
      if (key === "step" || key === "phases") continue;
      if (key === "lr" || key === "epoch") { if (fits(value)) out[key] = value; continue; }
      if (fits(value)) out.series.push([key, value]);
      else if (value && typeof value === "object" && !Array.isArray(value)) {
        for (const [sub, list] of Object.entries(value)) if (fits(list)) out.series.push([`${key}.${sub}`, list]);
      }
    }
    return out.series.length || out.lr ? out : null;
  }

  /** The panels of a pareto.json (docs/artifacts.md): each {metric, cost, cost_label,
      dataset, scene, points: [{candidate, mean, std, min, max, cost, front, jobs}]}.
      A report.brdf document of before the one schema (configurations as "points") is read
      as one panel. */
  function paretoPanels(doc) {
    if (!doc || typeof doc !== "object") return [];
    const drawable = (p) => isNum(p.mean) && isNum(p.cost);
    if (Array.isArray(doc.panels)) {
      return doc.panels
        .filter((p) => p && Array.isArray(p.points))
        .map((p) => ({ ...p, points: p.points.filter(drawable) }))
        .filter((p) => p.points.length);
    }
    if (!Array.isArray(doc.points)) return [];
    const x = (doc.axes && doc.axes.x) || "ns_per_eval";
    const points = doc.points.map((p) => ({
      candidate: p.config, mean: p.smape_mean, std: p.smape_std, min: p.smape_min, max: p.smape_max,
      cost: p[x], front: Boolean(p.pareto), jobs: p.runs || [], n: p.n,
    })).filter(drawable);
    return points.length ? [{ metric: "smape", cost: x, cost_label: x, points }] : [];
  }

  /** The unit of a metric or cost column, from its name: "dB" (PSNR), "B" (bytes), "s"
      (seconds; a name in ns is converted by siValue), else "" (a ratio or a count). */
  function unitOf(name) {
    const n = String(name || "").toLowerCase();
    if (/psnr/.test(n)) return "dB";
    if (/bytes?(\b|_|$)/.test(n)) return "B";
    if (/(^|_|\.)ns(_|$)|_ns\b|nanosec/.test(n)) return "ns";
    if (/seconds?(\b|_|$)|(^|_)s$|_sec(_|$)/.test(n)) return "s";
    return "";
  }

  const PREFIXES = [[1e9, "G"], [1e6, "M"], [1e3, "k"], [1, ""], [1e-3, "m"], [1e-6, "µ"],
    [1e-9, "n"], [1e-12, "p"]];

  /** A number with an SI prefix and its unit, three significant digits: 1.53 MB, 12.4 µs,
      31.2 dB (dB and unitless ratios near 1 keep their plain form; "ns" is shown in s). */
  function si(value, unit = "") {
    if (typeof value !== "number" || !isFinite(value)) return String(value);
    let v = value;
    let u = unit;
    if (u === "ns") { v = value * 1e-9; u = "s"; }
    if (u === "dB") return `${+v.toPrecision(3)} dB`;
    if (v === 0) return u ? `0 ${u}` : "0";
    const a = Math.abs(v);
    if (!u && a >= 1e-3 && a < 1e4) return `${+v.toPrecision(3)}`;
    const binary = u === "B";
    const [scale, prefix] = PREFIXES.find(([f]) => a >= f * (binary ? 1 : 0.9999)) ||
      PREFIXES[PREFIXES.length - 1];
    if (binary && scale < 1) return `${+v.toPrecision(3)} B`;
    return `${+(v / scale).toPrecision(3)} ${prefix}${u}`.trim();
  }

  /** Text nodes of ``text`` with a <wbr> after each dot, so a long dotted name can wrap. */
  function breakable(text) {
    const out = [];
    String(text).split(".").forEach((part, i, parts) => {
      out.push(document.createTextNode(i < parts.length - 1 ? `${part}.` : part));
      if (i < parts.length - 1) out.push(document.createElement("wbr"));
    });
    return out;
  }

  /** Chart.js axes whose tick labels never overlap: at most 7 ticks on a numeric axis,
      and a label dropped rather than drawn over its neighbour (14 px apart at least; the
      brdf, pareto and compare pages drew "15.8 ns16 ns16.2 ns" and log axes' every
      tick). Called before a page makes its charts; once is enough. */
  function fitTicks() {
    const Chart = window.Chart;
    if (!Chart || Chart.__mfFitted) return;
    Chart.__mfFitted = true;
    Chart.defaults.scale.ticks.autoSkip = true;
    Chart.defaults.scale.ticks.autoSkipPadding = 14;
    for (const type of ["linear", "logarithmic"]) {
      const scale = Chart.defaults.scales[type];
      if (scale) scale.ticks.maxTicksLimit = 7;
    }
  }

  stripToken();
  return { api, el, seconds, when, badge, progress, localTimes, curveSeries, paretoPanels,
           unitOf, si, breakable, fitTicks };
})();
