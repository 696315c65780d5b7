/* One job: live state/progress while it runs (reloads once it finishes), cancel, charts. */
"use strict";

(() => {
  const POLL_MS = 1000;
  const FINAL = new Set(["succeeded", "failed", "cancelled"]);
  const data = JSON.parse(document.getElementById("job-data").textContent);
  const stateBadge = document.getElementById("job-state");
  const progress = document.getElementById("job-progress");
  const progressText = document.getElementById("job-progress-text");
  const message = document.getElementById("job-message");
  const errorBox = document.getElementById("job-error");
  const cancelButton = document.getElementById("cancel-btn");

  MF.localTimes();

  /** Pictures shown larger than they are get square pixels, not a blur (small renders,
      BRDF slices, FLIP maps of tiny images). */
  function pixelate(img) {
    img.classList.toggle("pixelated", img.naturalWidth > 0 && img.naturalWidth < img.clientWidth);
  }
  /** The lead picture is shown at its own size; one smaller than LEAD_MIN_PX wide (a small
      render, a tiny example) at the smallest whole multiple of it that reaches LEAD_MIN_PX,
      so that its pixels stay square and it does not look smaller than the gallery (the
      page's width still caps it). */
  const LEAD_MIN_PX = 320;
  function leadSize(img) {
    const w = img.naturalWidth;
    if (!w || !img.closest(".lead")) return;
    const scale = w >= LEAD_MIN_PX ? 1 : Math.ceil(LEAD_MIN_PX / w);
    img.style.width = `${w * scale}px`;
  }
  const pictures = document.querySelectorAll("figure img");
  for (const img of pictures) {
    if (img.complete) { leadSize(img); pixelate(img); }
    img.addEventListener("load", () => { leadSize(img); pixelate(img); });
  }
  window.addEventListener("resize", () => pictures.forEach(pixelate));

  function show(job) {
    const pct = Math.round((job.progress || 0) * 100);
    stateBadge.className = `badge state-${job.state}`;
    stateBadge.textContent = job.state;
    progress.className = `progress progress-lg state-${job.state}`;
    progress.setAttribute("aria-valuenow", String(pct));
    progress.firstElementChild.style.width = `${pct}%`;
    progressText.textContent = `${pct}%`;
    message.textContent = job.message || "";
    errorBox.hidden = !job.error;
    errorBox.textContent = job.error || "";
    document.getElementById("job-worker").textContent = job.worker || "–";
    document.getElementById("job-attempts").textContent = job.attempts;
    document.getElementById("job-runtime").textContent = MF.seconds(job.timings.run_seconds);
    cancelButton.hidden = FINAL.has(job.state);
  }

  async function poll() {
    try {
      const job = await MF.api(`/api/jobs/${data.id}`);
      if (FINAL.has(job.state)) {
        // Artifacts, manifest and metrics are rendered by the server: show them.
        window.location.reload();
        return;
      }
      show(job);
    } catch (err) {
      message.textContent = `cannot refresh: ${err.message}`;
    }
    window.setTimeout(poll, POLL_MS);
  }

  cancelButton.addEventListener("click", async () => {
    cancelButton.disabled = true;
    try {
      show(await MF.api(`/api/jobs/${data.id}/cancel`, { method: "POST" }));
    } catch (err) {
      message.textContent = `cancel failed: ${err.message}`;
    } finally {
      cancelButton.disabled = false;
    }
  });

  /** One bar chart per metric that varies (none on a report page with Pareto panels): nothing for constant columns (n, queries), a
      metric's baseline ("baseline.<metric>") drawn beside it, the best row highlighted,
      the better direction in the title, and a y axis that fits the values (PSNR does not
      start at 0; values over decades get a log axis). */
  function charts() {
    const node = document.getElementById("metrics-data");
    const box = document.getElementById("metrics-charts");
    if (!node || !box || typeof window.Chart === "undefined") return;
    MF.fitTicks();
    // A report's Pareto panels (plots.js) already chart every row of its table against its
    // own cost axis: per-column bars would put ns and bytes on one axis, one chart per column
    // however few the rows. Other kinds' tables (per-material errors) keep their bars.
    const plots = document.getElementById("plots");
    if (plots && plots.dataset.pareto && plots.dataset.family === "report") return;
    const metrics = JSON.parse(node.textContent);
    const better = metrics.better || {};
    const best = metrics.best || {};
    const names = new Set(metrics.names);
    const palette = ["#2f5bd3", "#1f9d55", "#c98a0b", "#d64545", "#7a5af8", "#0e9384"];
    const number = (v) => typeof v === "number" && isFinite(v);
    metrics.names.forEach((name, i) => {
      if (name.startsWith("baseline.") && names.has(name.slice(9))) return;  // drawn with its metric
      const labels = metrics.labels.filter((l) => number(metrics.rows[l][name]));
      const values = labels.map((l) => metrics.rows[l][name]);
      if (!labels.length || values.every((v) => v === values[0])) return;
      const baseline = names.has(`baseline.${name}`) ? `baseline.${name}` : null;
      const colour = palette[i % palette.length];
      const datasets = [{
        label: baseline ? "model" : name,
        data: values,
        backgroundColor: labels.map((l) => (best[name] === undefined || best[name] === l ? colour : `${colour}66`)),
        borderColor: labels.map((l) => (best[name] === l ? "#101828" : colour)),
        borderWidth: labels.map((l) => (best[name] === l ? 2 : 0)),
        borderRadius: 4,
        maxBarThickness: 56,
      }];
      if (baseline) {
        datasets.push({
          label: "baseline",
          data: labels.map((l) => (number(metrics.rows[l][baseline]) ? metrics.rows[l][baseline] : null)),
          backgroundColor: "#98a2b3",
          borderRadius: 4,
          maxBarThickness: 56,
        });
      }
      const all = datasets.flatMap((d) => d.data).filter(number);
      const positive = all.every((v) => v > 0);
      const log = positive && Math.max(...all) / Math.min(...all) >= 100;
      const sense = better[name];
      const arrow = sense === "lower" ? " (lower is better ↓)" : sense === "higher" ? " (higher is better ↑)" : "";
      const unit = MF.unitOf(name);
      const shown = unit ? `${name} [${unit === "ns" ? "s" : unit}]` : name;
      const canvas = MF.el("canvas", { "aria-label": `${name} per ${metrics.label_header || "row"}`, role: "img",
                                       "data-metric": name });
      box.append(MF.el("div", { class: "card" }, MF.el("div", { class: "chart-box" }, canvas)));
      new window.Chart(canvas, {
        type: "bar",
        data: { labels, datasets },
        options: {
          responsive: true,
          maintainAspectRatio: false,
          animation: false,
          plugins: {
            legend: { display: Boolean(baseline) },
            title: { display: true, text: shown + arrow },
            tooltip: { callbacks: { label: (item) => `${item.dataset.label}: ${MF.si(item.raw, unit)}` } },
            subtitle: { display: best[name] !== undefined, text: `best: ${best[name]}` },
          },
          scales: {
            y: { ...(log ? { type: "logarithmic" } : { beginAtZero: sense !== "higher" || !positive, grace: "5%" }),
                 ticks: { callback: (v) => MF.si(v, unit) } },
          },
        },
      });
    });
  }

  charts();
  if (!FINAL.has(data.state)) window.setTimeout(poll, POLL_MS);
})();
