// The dashboard's router: #/jobs, #/job/<id>, #/workers, #/submit, #/methods.
// Each page is a module exporting render(view, ...args); leaving a page stops its polling.

import { stats, stopAllPolls, token } from "./api.js";
import { renderJob } from "./job.js";
import { renderJobs } from "./jobs.js";
import { renderMethods } from "./methods.js";
import { renderSubmit } from "./submit.js";
import { renderWorkers } from "./workers.js";

const PAGES = {
  jobs: renderJobs,
  job: renderJob,
  workers: renderWorkers,
  submit: renderSubmit,
  methods: renderMethods,
};

function route() {
  stopAllPolls();
  const [name, ...args] = (location.hash.replace(/^#\/?/, "") || "jobs").split("/");
  const page = PAGES[name] ? name : "jobs";
  for (const a of document.querySelectorAll("nav a")) {
    const current = a.dataset.page === page || (page === "job" && a.dataset.page === "jobs");
    if (current) a.setAttribute("aria-current", "page"); else a.removeAttribute("aria-current");
  }
  const view = document.getElementById("view");
  view.replaceChildren();
  view.dataset.page = page;
  PAGES[page](view, ...args.map(decodeURIComponent));
}

window.addEventListener("hashchange", route);
window.addEventListener("DOMContentLoaded", () => {
  const input = document.getElementById("token");
  input.value = token();
  document.getElementById("token-form").addEventListener("submit", (e) => {
    e.preventDefault();
    localStorage.setItem("lucent-token", input.value.trim());
    input.closest("details").open = false;
    route();
  });
  route();
});

window.lucent = { stats };  // for the end-to-end tests: polls counted
