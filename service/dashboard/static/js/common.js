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
    if (s < 1) return `${Math.round(s * 1000)} ms`;
    if (s < 60) return `${s.toFixed(1)} s`;
    const m = Math.floor(s / 60);
    const r = Math.round(s - 60 * m);
    return m < 60 ? `${m} min ${String(r).padStart(2, "0")} s` : `${Math.floor(m / 60)} h ${m % 60} min`;
  }

  /** An ISO time as "12 s ago" (recent) or a local date-time. */
  function when(iso) {
    if (!iso) return "–";
    const t = new Date(iso);
    const ago = (Date.now() - t.getTime()) / 1000;
    if (ago < 60) return `${Math.max(0, Math.round(ago))} s ago`;
    if (ago < 3600) return `${Math.round(ago / 60)} min ago`;
    return t.toLocaleString();
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
      if (iso) node.textContent = new Date(iso).toLocaleString();
    }
  }

  stripToken();
  return { api, el, seconds, when, badge, progress, localTimes };
})();
