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
  const pictures = document.querySelectorAll("figure img");
  for (const img of pictures) {
    if (img.complete) pixelate(img);
    img.addEventListener("load", () => pixelate(img));
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

  function charts() {
    const node = document.getElementById("metrics-data");
    const box = document.getElementById("metrics-charts");
    if (!node || !box || typeof window.Chart === "undefined") return;
    const metrics = JSON.parse(node.textContent);
    const palette = ["#2f5bd3", "#1f9d55", "#c98a0b", "#d64545", "#7a5af8", "#0e9384"];
    metrics.names.forEach((name, i) => {
      const labels = metrics.labels.filter((l) => typeof metrics.rows[l][name] === "number");
      if (!labels.length) return;
      const canvas = MF.el("canvas", { "aria-label": `${name} per candidate`, role: "img" });
      box.append(MF.el("div", { class: "card" }, MF.el("div", { class: "chart-box" }, canvas)));
      new window.Chart(canvas, {
        type: "bar",
        data: {
          labels,
          datasets: [{
            label: name,
            data: labels.map((l) => metrics.rows[l][name]),
            backgroundColor: palette[i % palette.length],
            borderRadius: 4,
            maxBarThickness: 56,
          }],
        },
        options: {
          responsive: true,
          maintainAspectRatio: false,
          animation: false,
          plugins: { legend: { display: false }, title: { display: true, text: name } },
          scales: { y: { beginAtZero: true } },
        },
      });
    });
  }

  charts();
  if (!FINAL.has(data.state)) window.setTimeout(poll, POLL_MS);
})();
