// Speed vs accuracy: the benchmark's charts and failure table once they exist; until then what
// the repository has (the method-comparison grid), and says so. No number here is made up.

import { api, h } from "./api.js";

export async function renderMethods(view) {
  view.append(h("h1", {}, "Speed vs accuracy"));
  const note = h("section", { class: "panel", id: "not-measured" },
    h("h2", {}, "Not measured yet"),
    h("p", {}, "The speed/accuracy benchmark of the translucent methods (time to a given error "
      + "against a converged reference, per method and scene, and the table of where each "
      + "method fails) has not been run: there are no charts or failure table to show."));
  view.append(note);
  const { data } = await api("/api/figures");
  const grid = data.filter((f) => f.grid);
  const rest = data.filter((f) => !f.grid);
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
