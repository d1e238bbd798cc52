// The Submit page: paste, upload or pick an example scene; the API validates it before anything
// is queued, and each error of its 422 answer is shown next to the field it names.

import { ApiError, api, h, showNotice } from "./api.js";

// ["objects", 0, "edge1"] -> "objects[0].edge1"
function jsonPath(loc) {
  return loc.map((p, i) => (typeof p === "number" ? `[${p}]` : i === 0 ? p : `.${p}`)).join("");
}

// Where a JSON path's last key sits in the text (best effort: keys looked up in order), so that
// clicking an error selects it in the editor.
function locate(text, loc) {
  let at = 0;
  let found = null;
  for (const p of loc) {
    if (typeof p === "number") continue;
    const i = text.indexOf(`"${p}"`, at);
    if (i < 0) break;
    found = [i, i + p.length + 2];
    at = i + 1;
  }
  return found;
}

export function renderSubmit(view) {
  const example = h("select", { id: "example", "aria-label": "example scene" },
    h("option", { value: "" }, "— pick an example —"));
  const file = h("input", { id: "scene-file", type: "file", accept: ".json,application/json" });
  const scene = h("textarea", {
    id: "scene", name: "scene", rows: "18", spellcheck: "false", required: true,
    placeholder: '{"version": 1, "camera": {...}, "materials": {...}, "objects": [...]}',
  });
  const sceneErrors = h("ul", { class: "field-errors", id: "scene-errors", "aria-live": "polite" });
  const field = (name, label, attrs) => {
    const input = h("input", { id: `f-${name}`, name, ...attrs });
    const err = h("span", { class: "field-error", id: `err-${name}`, "aria-live": "polite" });
    return [h("label", { for: `f-${name}` }, label), h("div", {}, input, err)];
  };
  const formError = h("p", { class: "field-error", id: "form-error" });
  const submit = h("button", { type: "submit", id: "submit-job", class: "primary" }, "Submit");
  const form = h("form", { id: "submit-form", novalidate: true },
    h("div", { class: "scene-source" },
      h("label", {}, "Example ", example), h("label", {}, "or upload ", file)),
    h("label", { for: "scene" }, "Scene JSON (", h("a", { href: "/docs" }, "API"), ")"),
    scene, sceneErrors,
    h("div", { class: "fields" },
      ...field("name", "Name", { type: "text", maxlength: "200", placeholder: "optional" }),
      ...field("priority", "Priority (0–9, 9 first)", { type: "number", min: "0", max: "9",
        value: "0" }),
      ...field("tile_size", "Tile size (px)", { type: "number", min: "8", max: "1024",
        placeholder: "64" }),
      ...field("spp_per_pass", "Samples of the first pass", { type: "number", min: "1",
        placeholder: "8" }),
      ...field("max_spp_per_pass", "Largest pass", { type: "number", min: "1",
        placeholder: "64" }),
      // (set in the scene sent, render.target_error: the farm's 422 on it shows here)
      ...field("target_error", "Target relMSE (adaptive; the spp the most a pixel takes)",
        { type: "number", min: "0", step: "any", placeholder: "the scene's" }),
      // (the farm refuses it, 422 on this field, where it cannot denoise: pyoidn missing)
      ...field("denoise", "Denoise when done (Open Image Denoise)", { type: "checkbox" })),
    formError, submit);
  view.append(h("h1", {}, "Submit a scene"), h("section", { class: "panel" }, form));

  function clearErrors() {
    sceneErrors.replaceChildren();
    formError.textContent = "";
    for (const el of form.querySelectorAll(".field-error")) el.textContent = "";
    for (const el of form.querySelectorAll("[aria-invalid]")) el.removeAttribute("aria-invalid");
  }

  function sceneError(path, msg, loc) {
    const li = h("li", { dataset: { path } }, h("code", {}, path || "scene"), " ", msg);
    if (loc) {
      li.tabIndex = 0;
      li.title = "select in the editor";
      li.addEventListener("click", () => {
        const at = locate(scene.value, loc);
        if (at) { scene.focus(); scene.setSelectionRange(...at); }
      });
    }
    sceneErrors.append(li);
    scene.setAttribute("aria-invalid", "true");
  }

  // Whether the scene sent had its render.target_error from the form's field
  let targetFromField = false;

  function showErrors(detail) {
    for (const d of Array.isArray(detail) ? detail : [{ loc: [], msg: String(detail) }]) {
      let loc = (d.loc || []).slice(d.loc?.[0] === "body" ? 1 : 0);
      if (targetFromField && loc.join(".") === "scene.render.target_error") loc = ["target_error"];
      if (loc[0] === "scene") {
        sceneError(jsonPath(loc.slice(1)), d.msg, loc.slice(1));
      } else if (loc.length && document.getElementById(`err-${loc[0]}`)) {
        document.getElementById(`err-${loc[0]}`).textContent = d.msg;
        document.getElementById(`f-${loc[0]}`).setAttribute("aria-invalid", "true");
      } else {
        formError.textContent = `${loc.length ? `${jsonPath(loc)}: ` : ""}${d.msg}`;
      }
    }
  }

  api("/api/examples").then((body) => {
    example.append(...body.data.map((e) =>
      h("option", { value: e.name }, `${e.name} (${e.width}×${e.height}, ${e.spp} spp)`)));
  }).catch((err) => showNotice(`examples: ${err.message}`, "error"));

  example.addEventListener("change", async () => {
    if (!example.value) return;
    const s = await api(`/api/examples/${encodeURIComponent(example.value)}`);
    scene.value = JSON.stringify(s, null, 2);
    const name = document.getElementById("f-name");
    if (!name.value || name.dataset.fromExample) {
      name.value = example.value;
      name.dataset.fromExample = "1";
    }
    clearErrors();
  });
  file.addEventListener("change", async () => {
    const f = file.files[0];
    if (!f) return;
    scene.value = await f.text();
    example.value = "";
    clearErrors();
  });

  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    clearErrors();
    let parsed;
    try {
      parsed = JSON.parse(scene.value);
    } catch (err) {
      sceneError("", `is not valid JSON: ${err.message}`, null);
      return;
    }
    const target = document.getElementById("f-target_error").value;
    targetFromField = target !== "" && parsed !== null && typeof parsed === "object"
      && !Array.isArray(parsed) && (parsed.render == null
        || (typeof parsed.render === "object" && !Array.isArray(parsed.render)));
    if (targetFromField) parsed.render = { ...parsed.render, target_error: Number(target) };
    const body = { scene: parsed, name: document.getElementById("f-name").value.trim() };
    for (const k of ["priority", "tile_size", "spp_per_pass", "max_spp_per_pass"]) {
      const v = document.getElementById(`f-${k}`).value;
      if (v !== "") body[k] = Number(v);
    }
    if (document.getElementById("f-denoise").checked) body.denoise = true;
    submit.disabled = true;
    try {
      const job = await api("/api/jobs", { method: "POST", body });
      showNotice(`Queued ${job.tasks_total} passes`);
      location.hash = `#/job/${job.id}`;
    } catch (err) {
      if (err instanceof ApiError && err.status === 422) showErrors(err.body.detail);
      else formError.textContent = err.message;
    } finally {
      submit.disabled = false;
    }
  });
}
