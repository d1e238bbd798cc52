// The Jobs page: every job with its progress, a status filter, bulk cancel, retry and delete.

import {
  FINAL, api, elapsed, errorSummary, fmtDuration, fmtRate, fmtTime, h, poll, progressBar,
  showNotice, statusBadge,
} from "./api.js";

const STATUSES = ["queued", "running", "done", "failed", "cancelled"];
const POLL_MS = 1000;

export function renderJobs(view) {
  const selected = new Set();
  let jobs = [];
  const filter = h("select", { id: "status-filter", "aria-label": "filter by status" },
    h("option", { value: "" }, "all statuses"),
    STATUSES.map((s) => h("option", { value: s }, s)));
  filter.value = sessionStorage.getItem("lucent-filter") || "";
  const cancelBtn = h("button", { id: "bulk-cancel", type: "button", disabled: true }, "Cancel");
  const retryBtn = h("button", { id: "bulk-retry", type: "button", disabled: true }, "Retry");
  const deleteBtn = h("button", { id: "bulk-delete", type: "button", disabled: true }, "Delete");
  const count = h("span", { class: "muted", id: "jobs-count" });
  const selectAll = h("input", { type: "checkbox", id: "select-all", "aria-label": "select all" });
  const tbody = h("tbody");
  const table = h("table", { class: "jobs cards" },
    h("thead", {}, h("tr", {},
      h("th", { class: "sel" }, selectAll), h("th", {}, "Name"), h("th", {}, "Status"),
      h("th", { class: "wide" }, "Progress"), h("th", { class: "num" }, "Samples/s"),
      h("th", { class: "num" }, "Elapsed"), h("th", { class: "num" }, "ETA"),
      h("th", {}, "Submitted"))),
    tbody);
  // Elements are held, not looked up by id: a poll that was in flight when the user left the page
  // finishes after the page's elements have left the document.
  const selCount = h("span", { class: "muted", id: "sel-count" }, "");
  const empty = h("p", { class: "muted empty", hidden: true, id: "jobs-empty" },
    "No jobs yet. ", h("a", { href: "#/submit" }, "Submit a scene"), ".");
  view.append(
    h("div", { class: "toolbar" },
      h("h1", {}, "Jobs"), count,
      h("span", { class: "spacer" }),
      h("label", {}, "Show ", filter),
      h("span", { class: "group" }, selCount, cancelBtn, retryBtn, deleteBtn)),
    table,
    empty);

  function updateButtons() {
    const n = selected.size;
    selCount.textContent = n ? `${n} selected` : "";
    cancelBtn.disabled = retryBtn.disabled = deleteBtn.disabled = n === 0;
    selectAll.checked = n > 0 && jobs.every((j) => selected.has(j.id));
  }

  // Rows are kept by job id and only their cells are redrawn, so that a checkbox (and a click on
  // it) survives the next poll.
  const rows = new Map();

  function cells(j) {
    const relmse = errorSummary(j);
    return [
      h("td", { "data-label": "Name" }, h("div", {},
        h("a", { href: `#/job/${j.id}`, class: "job-link" }, j.name || j.id.slice(0, 8)),
        h("div", { class: "muted small" }, `${j.width}×${j.height}, ${j.spp} spp`),
        // (the relMSE asked for and the estimate: a finished job's from its record)
        relmse ? h("div", { class: "muted small job-relmse" }, relmse) : null)),
      h("td", { "data-label": "Status", class: "status" }, statusBadge(j.status)),
      h("td", { "data-label": "Progress", class: "wide" }, progressBar(j.progress, j.status)),
      h("td", { "data-label": "Samples/s", class: "num" }, fmtRate(j.samples_per_second)),
      h("td", { "data-label": "Elapsed", class: "num" }, fmtDuration(elapsed(j))),
      h("td", { "data-label": "ETA", class: "num" },
        j.status === "done" ? "done" : fmtDuration(j.eta_seconds)),
      h("td", { "data-label": "Submitted" }, fmtTime(j.created_at)),
    ];
  }

  function row(j) {
    let tr = rows.get(j.id);
    if (!tr) {
      const box = h("input", {
        type: "checkbox", "aria-label": `select ${j.name || j.id}`,
        onchange: (e) => {
          if (e.target.checked) selected.add(j.id); else selected.delete(j.id);
          updateButtons();
        },
      });
      tr = h("tr", { dataset: { id: j.id } }, h("td", { class: "sel" }, box));
      rows.set(j.id, tr);
    }
    tr.querySelector("input").checked = selected.has(j.id);
    tr.dataset.status = j.status;
    tr.replaceChildren(tr.firstChild, ...cells(j));
    return tr;
  }

  async function refresh() {
    const q = filter.value ? `&status=${filter.value}` : "";
    const body = await api(`/api/jobs?limit=200${q}`);
    jobs = body.data;
    const ids = new Set(jobs.map((j) => j.id));
    for (const id of [...selected]) if (!ids.has(id)) selected.delete(id);
    for (const id of [...rows.keys()]) if (!ids.has(id)) { rows.get(id).remove(); rows.delete(id); }
    const trs = jobs.map(row);
    // Re-insert only if the order changed (moving a row would interrupt a click on it).
    if (trs.some((tr, i) => tbody.children[i] !== tr)) tbody.replaceChildren(...trs);
    count.textContent = `${body.count} job${body.count === 1 ? "" : "s"}`;
    empty.hidden = jobs.length > 0;
    table.hidden = jobs.length === 0;
    updateButtons();
  }

  async function bulk(action) {
    // DELETE cancels a queued or running job and deletes a finished one: each button sends it
    // only to the jobs it names.
    const status = new Map(jobs.map((j) => [j.id, j.status]));
    const ids = [...selected].filter((id) => action === "retry"
      || (action === "delete") === FINAL.includes(status.get(id)));
    const results = await Promise.allSettled(ids.map((id) => action === "retry"
      ? api(`/api/jobs/${id}/retry`, { method: "POST" })
      : api(`/api/jobs/${id}`, { method: "DELETE" })));
    const failed = results.filter((r) => r.status === "rejected");
    const verb = { cancel: "cancelled", retry: "retried", delete: "deleted" }[action];
    const ok = ids.length - failed.length;
    if (failed.length) {
      showNotice(`${ok} ${verb}; ${failed.length} not: ${failed[0].reason.message}`, "error");
    } else {
      showNotice(`${ok} job${ok === 1 ? "" : "s"} ${verb}`);
    }
    selected.clear();
    await refresh();
  }

  selectAll.addEventListener("change", () => {
    for (const j of jobs) if (selectAll.checked) selected.add(j.id); else selected.delete(j.id);
    tbody.querySelectorAll("input[type=checkbox]").forEach((b) => { b.checked = selectAll.checked; });
    updateButtons();
  });
  filter.addEventListener("change", () => {
    sessionStorage.setItem("lucent-filter", filter.value);
    selected.clear();
    refresh();
  });
  cancelBtn.addEventListener("click", () => bulk("cancel"));
  retryBtn.addEventListener("click", () => bulk("retry"));
  deleteBtn.addEventListener("click", () => bulk("delete"));
  poll(refresh, POLL_MS);
}
