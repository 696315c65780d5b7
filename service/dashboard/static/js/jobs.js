/* The jobs list: polls /api/jobs and /api/stats every second. */
"use strict";

(() => {
  const POLL_MS = 1000;
  const body = document.getElementById("jobs-body");
  const statusLine = document.getElementById("status-line");
  const stateSelect = document.getElementById("f-state");
  const kindSelect = document.getElementById("f-kind");
  const chips = document.querySelectorAll("#counts .chip");
  let timer = null;

  const params = new URLSearchParams(window.location.search);
  stateSelect.value = params.get("state") || "";
  kindSelect.value = params.get("kind") || "";

  function filters() {
    const q = new URLSearchParams();
    if (stateSelect.value) q.set("state", stateSelect.value);
    if (kindSelect.value) q.set("kind", kindSelect.value);
    return q;
  }

  function row(job) {
    const title = job.name || job.kind;
    const failed = job.state === "failed" && job.error;
    return MF.el(
      "tr", { "data-id": job.id, "data-state": job.state },
      MF.el("td", {},
        MF.el("a", { class: "job-name", href: `/jobs/${job.id}`, text: title }),
        MF.el("span", { class: "job-id", text: job.id.slice(0, 12) })),
      MF.el("td", { text: job.kind }),
      MF.el("td", {}, MF.badge(job.state)),
      MF.el("td", {}, MF.progress(job)),
      MF.el("td", { class: failed ? "message error" : "message",
                    title: failed ? job.error : job.message,
                    text: failed ? job.error : job.message }),
      MF.el("td", { class: "muted", title: job.created_at, text: MF.when(job.created_at) }),
      MF.el("td", { class: "num", text: MF.seconds(job.timings && job.timings.run_seconds) }),
    );
  }

  function render(jobs) {
    if (!jobs.length) {
      const filtered = stateSelect.value || kindSelect.value;
      body.replaceChildren(MF.el("tr", { class: "empty" }, MF.el("td", {
        colspan: "7",
        text: filtered ? "No jobs match these filters." :
          "No jobs yet. Submit one with `matforge submit SPEC` or POST /api/jobs.",
      })));
      return;
    }
    body.replaceChildren(...jobs.map(row));
  }

  function renderCounts(stats) {
    for (const node of document.querySelectorAll("[data-count]")) {
      const key = node.getAttribute("data-count");
      node.textContent = key === "total" ? stats.total : (stats.counts[key] || 0);
    }
    for (const chip of chips) {
      chip.classList.toggle("active", chip.getAttribute("data-state") === stateSelect.value);
    }
  }

  async function refresh() {
    const q = filters();
    q.set("limit", "200");
    try {
      const [jobs, stats] = await Promise.all([MF.api(`/api/jobs?${q}`), MF.api("/api/stats")]);
      render(jobs);
      renderCounts(stats);
      statusLine.textContent = `live · updated ${new Date().toLocaleTimeString()}`;
    } catch (err) {
      statusLine.textContent = `cannot refresh: ${err.message}`;
    }
    timer = window.setTimeout(refresh, POLL_MS);
  }

  function changed() {
    const q = filters();
    const query = q.toString();
    window.history.replaceState(null, "", window.location.pathname + (query ? `?${query}` : ""));
    window.clearTimeout(timer);
    refresh();
  }

  stateSelect.addEventListener("change", changed);
  kindSelect.addEventListener("change", changed);
  for (const chip of chips) {
    chip.addEventListener("click", () => {
      stateSelect.value = chip.getAttribute("data-state");
      changed();
    });
  }
  refresh();
})();
