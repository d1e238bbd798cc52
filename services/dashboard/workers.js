// The Workers page: each worker process from its heartbeat; silent for 3 intervals = lost.

import { api, fmtRate, h, poll } from "./api.js";

const POLL_MS = 1000;

export function renderWorkers(view) {
  const summary = h("span", { class: "muted", id: "workers-summary" });
  const tbody = h("tbody");
  const table = h("table", { class: "workers cards", id: "workers-table" },
    h("thead", {}, h("tr", {}, h("th", {}, "Worker"), h("th", {}, "Host"), h("th", {}, "Tags"),
      h("th", {}, "Version"), h("th", {}, "Kernel"), h("th", {}, "State"),
      h("th", {}, "Current tile"), h("th", { class: "num" }, "Tiles done"),
      h("th", { class: "num" }, "Paths/s"), h("th", { class: "num" }, "Last heartbeat"))),
    tbody);
  const empty = h("p", { class: "muted", id: "workers-empty", hidden: true },
    "No workers have reported. Start some with ", h("code", {}, "lucent worker --redis URL"),
    " or ", h("code", {}, "lucent up"), ".");
  view.append(h("div", { class: "toolbar" }, h("h1", {}, "Workers"), summary), table, empty);

  function currentTile(task) {
    if (!task) return "–";
    const [job, tile, pass] = task.split("/");
    return h("span", {}, `tile ${tile}, pass ${pass} of `,
      h("a", { href: `#/job/${job}` }, job.slice(0, 8)));
  }

  async function refresh() {
    const body = await api("/api/workers");
    const now = body.server_time ?? Date.now() / 1000;
    const lostAfter = 3 * (body.heartbeat_interval ?? 2);
    const counts = {};
    // A worker whose merge keeps less than another live one's (a farm upgraded worker by
    // worker): target jobs of frames submitted while it is live pool their frames' sums
    const newest = Math.max(1, ...body.data.map((w) => w.protocol ?? 1));
    const rows = body.data.map((w) => {
      const age = w.last_heartbeat ? now - w.last_heartbeat : null;
      // The store says lost once the heartbeat hash expired; the age check catches the rest.
      const state = w.state === "lost" || age === null || age > lostAfter ? "lost" : w.state;
      counts[state] = (counts[state] || 0) + 1;
      return h("tr", { dataset: { id: w.id, state } },
        h("td", { "data-label": "Worker" }, h("code", {}, w.id)),
        h("td", { "data-label": "Host" }, w.host || "–"),
        h("td", { "data-label": "Tags", class: "tags" },
          ...(w.tags && w.tags.length ? w.tags.map((t) => h("span", { class: "tag" }, t))
            : ["–"])),
        h("td", { "data-label": "Version", class: "version" }, w.version || "–",
          ...(w.protocol !== null && w.protocol < newest
            ? [" ", h("span", {
              class: "badge outdated",
              title: "its merge is older than the newest live worker's: a target job of frames "
                + "submitted while it is live pools its frames' error sums (docs/farm.md, "
                + "upgrading a farm)",
            }, "older merge")]
            : [])),
        h("td", { "data-label": "Kernel", class: "kernel" }, w.kernel || "–"),
        h("td", { "data-label": "State", class: "state" },
          h("span", { class: `badge w-${state}` }, state)),
        h("td", { "data-label": "Current tile" }, state === "lost" ? "–" : currentTile(w.current_task)),
        h("td", { "data-label": "Tiles done", class: "num" }, String(w.tiles_done)),
        h("td", { "data-label": "Paths/s", class: "num" }, fmtRate(w.paths_per_second)),
        h("td", { "data-label": "Last heartbeat", class: "num" },
          age === null ? "never" : `${age.toFixed(1)} s ago`));
    });
    tbody.replaceChildren(...rows);
    summary.textContent = Object.entries(counts).map(([s, n]) => `${n} ${s}`).join(", ")
      || "none";
    table.hidden = rows.length === 0;
    empty.hidden = rows.length > 0;
  }

  poll(refresh, POLL_MS);
}
