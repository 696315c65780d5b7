/* The jobs list: polls /api/jobs (one page, filtered and sorted by the server) and
   /api/stats every second. Filters, sort and page live in the address (?name=&state=&kind=
   &sort=&page=, and the parameter and metric columns and filters: ?columns=params.model,
   metric.brdf.smape&filter=params.model=hybrid&filter=metric.brdf.smape<0.1), so a view can
   be bookmarked and shared. */
"use strict";

(() => {
  const POLL_MS = 1000;
  const PAGE_SIZE = 50;
  const SEARCH_DELAY_MS = 250;
  const body = document.getElementById("jobs-body");
  const statusLine = document.getElementById("status-line");
  const nameInput = document.getElementById("f-name");
  const stateSelect = document.getElementById("f-state");
  const kindSelect = document.getElementById("f-kind");
  const chips = document.querySelectorAll("#counts .chip");
  const headers = document.querySelectorAll("#jobs-table th[data-sort]");
  const prev = document.getElementById("page-prev");
  const next = document.getElementById("page-next");
  const pageInfo = document.getElementById("page-info");
  const pager = document.getElementById("pager");
  const groupBox = document.getElementById("f-group");
  const batchFilter = document.getElementById("batch-filter");
  const batchName = document.getElementById("batch-name");
  const compareButton = document.getElementById("compare-btn");
  const compareClear = document.getElementById("compare-clear");
  const columnsForm = document.getElementById("columns-form");
  const columnsInput = document.getElementById("f-columns");
  const filterInput = document.getElementById("f-filter");
  const filterInfo = document.getElementById("filter-info");
  const headRow = document.getElementById("jobs-head");
  const messageHead = headRow.querySelector(".col-message");
  /** The fixed columns of a row (job, kind, state, progress, message, created, time). */
  const FIXED_COLUMNS = 7;
  /** Jobs ticked for the compare view (kept across pages and refreshes). */
  const picked = new Set();
  /** Thumbnail URL of a succeeded job (null: it has no picture), by job id. */
  const thumbs = new Map();
  let timer = null;
  let searchTimer = null;
  let total = 0;

  const initial = new URLSearchParams(window.location.search);
  nameInput.value = initial.get("name") || "";
  stateSelect.value = initial.get("state") || "";
  const urlKind = initial.get("kind") || "";
  if (urlKind && ![...kindSelect.options].some((o) => o.value === urlKind)) {
    // keep an unknown kind from the address as the filter: the API's 422 then names it
    kindSelect.append(MF.el("option", { value: urlKind, text: `${urlKind} (unknown)` }));
  }
  kindSelect.value = urlKind;
  groupBox.checked = initial.get("group") === "1";
  let batch = initial.get("batch") || "";
  let sort = initial.get("sort") || "-created";
  let page = Math.max(1, parseInt(initial.get("page") || "1", 10) || 1);
  /** Chosen column keys (params.X, metric.Y) and filters ("key op value"), as the API
      takes them (service/job_columns.py checks both and names a bad one). */
  let columns = splitColumns(initial.getAll("columns").join(","));
  let filters = initial.getAll("filter").map((f) => f.trim()).filter(Boolean);
  columnsInput.value = columns.join(", ");
  filterInput.value = filters.join(", ");

  function splitColumns(text) {
    const out = [];
    for (const part of text.split(",")) {
      const key = part.trim();
      if (key && !out.includes(key)) out.push(key);
    }
    return out;
  }

  /** Filters from the box: split at the commas that start a new column key, so a value
      may itself hold a comma. */
  function splitFilters(text) {
    return text.split(/,(?=\s*(?:params|metric)\.)/).map((f) => f.trim()).filter(Boolean);
  }

  function colspan() {
    return String(FIXED_COLUMNS + columns.length);
  }

  /** The view's query (what the address bar shows). */
  function viewQuery() {
    const q = new URLSearchParams();
    if (nameInput.value.trim()) q.set("name", nameInput.value.trim());
    if (stateSelect.value) q.set("state", stateSelect.value);
    if (kindSelect.value) q.set("kind", kindSelect.value);
    if (batch) q.set("batch", batch);
    if (columns.length) q.set("columns", columns.join(","));
    for (const f of filters) q.append("filter", f);
    if (groupBox.checked) q.set("group", "1");
    if (sort !== "-created") q.set("sort", sort);
    if (page > 1) q.set("page", String(page));
    return q;
  }

  /** The API's query for the current page. */
  function apiQuery() {
    const q = viewQuery();
    q.delete("page");
    q.delete("group");
    q.set("sort", sort);
    q.set("limit", String(PAGE_SIZE));
    q.set("offset", String((page - 1) * PAGE_SIZE));
    return q;
  }

  /** The picture to show small for a job: its preview.png, else its first image that is
      not a FLIP map (an EXR through its tone-mapped preview). */
  function pickThumb(artifacts) {
    const images = artifacts.filter((a) => !a.name.split("/").pop().startsWith("flip_"));
    const png = images.find((a) => a.name === "preview.png") ||
      images.find((a) => a.media_type === "image/png" || a.media_type === "image/jpeg");
    if (png) return `/api/artifacts/${png.digest}`;
    const exr = images.find((a) => a.media_type === "image/x-exr");
    return exr ? `/api/artifacts/${exr.digest}/preview.png` : null;
  }

  /** Look up the thumbnails of succeeded jobs not seen yet (a finished job's artifacts
      never change, so each is asked for once). */
  function loadThumbs(jobs) {
    for (const job of jobs) {
      if (job.state !== "succeeded" || thumbs.has(job.id)) continue;
      thumbs.set(job.id, null);
      MF.api(`/api/jobs/${job.id}/artifacts`).then((arts) => {
        const src = pickThumb(arts);
        thumbs.set(job.id, src);
        const cell = body.querySelector(`tr[data-id="${job.id}"] .thumb-slot`);
        if (src && cell) cell.replaceChildren(thumb(src));
      }).catch(() => thumbs.delete(job.id));
    }
  }

  function thumb(src) {
    return MF.el("img", { class: "thumb", src, alt: "", loading: "lazy" });
  }

  function renderPicked() {
    compareButton.textContent = `Compare selected (${picked.size})`;
    compareButton.disabled = picked.size < 2;
    compareClear.hidden = picked.size === 0;
  }

  function pickBox(job) {
    const box = MF.el("input", { type: "checkbox", class: "pick", value: job.id,
                                 "aria-label": `select ${job.name || job.kind} to compare`,
                                 checked: picked.has(job.id) });
    box.addEventListener("change", () => {
      if (box.checked) picked.add(job.id); else picked.delete(job.id);
      renderPicked();
    });
    return box;
  }

  /** A column's value as table text: numbers to 4 significant digits, nested values as
      JSON (as `matforge ls --column` prints them). */
  function cellText(value, key) {
    if (value === null || value === undefined) return "";
    const unit = key.startsWith("metric.") ? MF.unitOf(key) : "";
    if (typeof value === "number" && unit) return MF.si(value, unit);
    if (typeof value === "number") {
      return Number.isInteger(value) ? String(value) : String(Number(value.toPrecision(4)));
    }
    if (typeof value === "object") return JSON.stringify(value);
    return String(value);
  }

  function valueCells(job) {
    const values = job.columns || {};
    return columns.map((key) => {
      const value = values[key];
      const text = cellText(value, key);
      return MF.el("td", { class: typeof value === "number" ? "num mono col-value" : "col-value",
                           "data-column": key, title: text || "none", text: text || "–" });
    });
  }

  /** The header cells of the chosen columns (before Message), each with a remove button. */
  function renderHead() {
    for (const th of headRow.querySelectorAll("th.col-value")) th.remove();
    for (const key of columns) {
      const remove = MF.el("button", { type: "button", class: "col-remove", text: "×",
                                       title: `remove the column ${key}`,
                                       "aria-label": `remove the column ${key}` });
      remove.addEventListener("click", () => {
        columns = columns.filter((k) => k !== key);
        columnsInput.value = columns.join(", ");
        refilter();
      });
      const th = MF.el("th", { class: "col-value", "data-column": key, title: key },
        MF.el("span", { class: "col-key" }, ...MF.breakable(key)), remove);
      headRow.insertBefore(th, messageHead);
    }
    document.getElementById("jobs-table").classList.toggle("with-columns", columns.length > 0);
    filterInfo.textContent = filters.length ?
      `${filters.length} filter(s): ${filters.join(" and ")}` : "";
  }

  function row(job) {
    const title = job.name || job.kind;
    const failed = job.state === "failed" && job.error;
    const src = thumbs.get(job.id);
    return MF.el(
      "tr", { "data-id": job.id, "data-state": job.state },
      MF.el("td", {}, MF.el("div", { class: "job-cell" },
        pickBox(job),
        MF.el("span", { class: "thumb-slot" }, src ? thumb(src) : null),
        MF.el("span", {},
          MF.el("a", { class: "job-name", href: `/jobs/${job.id}`, title, text: title }),
          MF.el("span", { class: "job-id", text: job.id.slice(0, 12) })))),
      MF.el("td", { text: job.kind }),
      MF.el("td", {}, MF.badge(job.state)),
      MF.el("td", {}, MF.progress(job)),
      ...valueCells(job),
      MF.el("td", { class: failed ? "message error" : "message",
                    title: failed ? job.error : job.message,
                    text: failed ? job.error : job.message }),
      MF.el("td", { class: "muted when", title: job.created_at, text: MF.when(job.created_at) }),
      MF.el("td", { class: "num", text: MF.seconds(job.timings && job.timings.run_seconds) }),
    );
  }

  function render(jobs) {
    if (!jobs.length) {
      const filtered = nameInput.value.trim() || stateSelect.value || kindSelect.value || batch ||
        filters.length;
      body.replaceChildren(MF.el("tr", { class: "empty" }, MF.el("td", {
        colspan: colspan(),
        text: filtered ? "No jobs match these filters." :
          "No jobs yet. Submit one with `matforge submit SPEC` or POST /api/jobs.",
      })));
      return;
    }
    if (!groupBox.checked) {
      body.replaceChildren(...jobs.map(row));
      return;
    }
    const groups = new Map();  // batch label (or "") -> jobs, in order of first appearance
    for (const job of jobs) {
      const key = job.batch || "";
      if (!groups.has(key)) groups.set(key, []);
      groups.get(key).push(job);
    }
    const rows = [];
    for (const [label, members] of groups) {
      const head = MF.el("td", { colspan: colspan() },
        MF.el("span", { class: "group-label", text: label || "not in a batch" }),
        MF.el("span", { class: "muted small", text: ` · ${members.length} job(s) on this page` }));
      if (label) {
        const only = MF.el("button", { type: "button", class: "btn btn-small", text: "only this batch" });
        only.addEventListener("click", () => { batch = label; refilter(); });
        const compare = MF.el("a", { class: "btn btn-small", text: "compare this batch",
                                     href: `/compare?batch=${encodeURIComponent(label)}` });
        const methods = MF.el("a", { class: "btn btn-small", text: "methods table",
                                     title: "a row per method: mean metrics and costs, the best marked",
                                     href: `/compare?batch=${encodeURIComponent(label)}#c-methods` });
        head.append(" ", only, " ", compare, " ", methods);
      }
      rows.push(MF.el("tr", { class: "group", "data-batch": label }, head), ...members.map(row));
    }
    body.replaceChildren(...rows);
  }

  function renderPager(shown) {
    const first = total ? (page - 1) * PAGE_SIZE + 1 : 0;
    pageInfo.textContent = total ? `${first}–${first + shown - 1} of ${total}` : "";
    prev.disabled = page <= 1;
    next.disabled = page * PAGE_SIZE >= total;
    pager.hidden = !total;  // no pager under a refusal or an empty list
  }

  function renderSort() {
    const key = sort.replace(/^-/, "");
    for (const th of headers) {
      const on = th.getAttribute("data-sort") === key;
      th.setAttribute("aria-sort", on ? (sort.startsWith("-") ? "descending" : "ascending") : "none");
    }
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

  async function listJobs() {
    const response = await fetch(`/api/jobs?${apiQuery()}`, {
      credentials: "same-origin", headers: { Accept: "application/json" },
    });
    const body = await response.json().catch(() => null);
    if (!response.ok) {
      const err = new Error((body && body.error) || `HTTP ${response.status}`);
      err.status = response.status;
      throw err;
    }
    total = parseInt(response.headers.get("X-Total-Count") || String(body.length), 10);
    return body;
  }

  async function refresh() {
    try {
      const [jobs, stats] = await Promise.all([listJobs(), MF.api("/api/stats")]);
      if (!jobs.length && page > 1 && total > 0) {  // the page emptied: go to the last one
        page = Math.ceil(total / PAGE_SIZE);
        changed();
        return;
      }
      render(jobs);
      loadThumbs(jobs);
      renderPager(jobs.length);
      renderCounts(stats);
      statusLine.textContent = `live · updated ${new Date().toLocaleTimeString()}`;
    } catch (err) {
      statusLine.textContent = `cannot refresh: ${err.message}`;
      body.replaceChildren(MF.el("tr", { class: "empty" }, MF.el("td", {
        colspan: colspan(), class: "error", text: err.message,
      })));
      total = 0;  // no pages of a refused query
      renderPager(0);
      if (err.status >= 400 && err.status < 500) {
        // refused as asked (an unknown column or filter): asking again every few seconds
        // would only log the same 422; the next change of the filters asks again
        statusLine.textContent = `refused: ${err.message}`;
        return;
      }
    }
    timer = window.setTimeout(refresh, POLL_MS);
  }

  function changed() {
    const query = viewQuery().toString();
    window.history.replaceState(null, "", window.location.pathname + (query ? `?${query}` : ""));
    renderSort();
    renderHead();
    batchFilter.hidden = !batch;
    batchName.textContent = batch;
    window.clearTimeout(timer);
    refresh();
  }

  function refilter() {
    page = 1;
    changed();
  }

  nameInput.addEventListener("input", () => {
    window.clearTimeout(searchTimer);
    searchTimer = window.setTimeout(refilter, SEARCH_DELAY_MS);
  });
  columnsForm.addEventListener("submit", (event) => {
    event.preventDefault();
    columns = splitColumns(columnsInput.value);
    filters = splitFilters(filterInput.value);
    refilter();
  });
  compareButton.addEventListener("click", () => {
    window.location.href = `/compare?jobs=${[...picked].map((id) => id.slice(0, 12)).join(",")}`;
  });
  compareClear.addEventListener("click", () => {
    picked.clear();
    for (const box of body.querySelectorAll("input.pick")) box.checked = false;
    renderPicked();
  });
  groupBox.addEventListener("change", changed);
  document.getElementById("batch-clear").addEventListener("click", () => { batch = ""; refilter(); });
  stateSelect.addEventListener("change", refilter);
  kindSelect.addEventListener("change", refilter);
  for (const chip of chips) {
    chip.addEventListener("click", () => {
      stateSelect.value = chip.getAttribute("data-state");
      refilter();
    });
  }
  for (const th of headers) {
    th.querySelector("button").addEventListener("click", () => {
      const key = th.getAttribute("data-sort");
      const descFirst = key === "created" || key === "duration" || key === "progress";
      if (sort === key) sort = `-${key}`;
      else if (sort === `-${key}`) sort = key;
      else sort = descFirst ? `-${key}` : key;
      refilter();
    });
  }
  prev.addEventListener("click", () => { page = Math.max(1, page - 1); changed(); });
  next.addEventListener("click", () => { page += 1; changed(); });
  renderSort();
  renderHead();
  batchFilter.hidden = !batch;
  batchName.textContent = batch;
  refresh();
})();
