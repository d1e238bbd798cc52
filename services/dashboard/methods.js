// Speed vs accuracy: the benchmark's charts (bench/accuracy.py) and failure map
// (bench/failure_map.py) when the repository has them, else a note saying they were not measured;
// then the method-comparison grids. No number here is made up.

import { api, h } from "./api.js";

export async function renderMethods(view) {
  view.append(h("h1", {}, "Speed vs accuracy"));
  const { data } = await api("/api/figures");
  const charts = data.filter((f) => f.chart);
  const grid = data.filter((f) => f.grid && !f.chart);
  const rest = data.filter((f) => !f.grid && !f.chart);
  if (charts.length) {
    view.append(h("section", { class: "panel", id: "charts" },
      h("h2", {}, "Error against time, per method (bench/accuracy.py, bench/failure_map.py)"),
      h("p", { class: "muted" }, "Log–log: relative MSE and 1 − SSIM against wall time, one line "
        + "per method, against Mitsuba 3 volpath references; the flat tails are each "
        + "approximation's bias floor. Details in docs/speed-accuracy.md."),
      ...charts.map((f) => h("figure", { class: "figure" },
        h("img", { src: f.url, alt: f.name, loading: "lazy" }),
        h("figcaption", {}, f.name.replace(/^accuracy-/, "").replace(/\.png$/, ""))))));
  } else {
    view.append(h("section", { class: "panel", id: "not-measured" },
      h("h2", {}, "Not measured yet"),
      h("p", {}, "The speed/accuracy benchmark has not been run: there are no charts to show.")));
  }
  if (grid.length) {
    view.append(h("section", { class: "panel" },
      h("h2", {}, "What exists: the methods side by side"),
      ...grid.map((f) => h("figure", { class: "figure" },
        h("img", { src: f.url, alt: f.name, loading: "lazy" }),
        h("figcaption", {}, `${f.name} (docs/images/methods/)`)))));
  }
  if (rest.length) {
    view.append(h("section", { class: "panel" }, h("h2", {}, "Each method"),
      h("div", { class: "thumbs" }, rest.map((f) => h("figure", {},
        h("img", { src: f.url, alt: f.name, loading: "lazy" }),
        h("figcaption", {}, f.name.replace(/\.png$/, "").replace(/_/g, " ")))))));
  }
  if (!data.length) {
    view.append(h("p", { class: "muted" }, "No method figures under docs/images/methods/ either."));
  }
}
