// A job: progressive preview (fetched only when its ETag changed), exposure, downloads, the tile
// grid coloured by state or by samples, errors, the methods `auto` chose, cancel, retry, delete;
// a job of frames: a strip of every frame (click one to preview it; Play runs the sequence).

import {
  FINAL, api, authHeaders, digits3, elapsed, fmtDuration, fmtRate, fmtTime, h, poll,
  progressBar, showNotice, statusBadge, token,
} from "./api.js";

const POLL_MS = 1000;         // while the job is queued or running
// A preview costs the service far more than a status poll (every tile's buffer is read and the
// PNG encoded), so a running job's preview is fetched at most every PREVIEW_MIN_MS, and never
// more often than one fetch per PREVIEW_COST_FACTOR times the last fetch took: the service then
// spends at most 1/PREVIEW_COST_FACTOR of a core on one open page, however large the frame.
const PREVIEW_MIN_MS = 2000;
const PREVIEW_COST_FACTOR = 25;
const FINAL_POLL_MS = 5000;   // once it is over (someone may retry it)
const TILE_COLOURS = { queued: "#5b6270", running: "#e0a526", converged: "#3a8fb7", done: "#2f9e61",
                       failed: "#d9453b" };

// Samples per pixel -> colour: dark blue (none) to pale yellow (all planned), viridis-like.
function samplesColour(fraction) {
  const stops = [[38, 33, 92], [33, 120, 142], [63, 188, 115], [240, 230, 110]];
  const x = Math.max(0, Math.min(1, fraction)) * (stops.length - 1);
  const i = Math.min(stops.length - 2, Math.floor(x));
  const t = x - i;
  const c = stops[i].map((a, k) => Math.round(a + (stops[i + 1][k] - a) * t));
  return `rgb(${c.join(",")})`;
}

// A tile's estimated error on the ramp: 1/4 x the middle at its dark end, 4 x at its bright end
// (log scale: the error falls as 1 / samples); the middle is the job's target, or for a job
// without one the frames' estimate (errorCentre)
const ERROR_SPAN = 4;
function errorColour(ratio) {
  return samplesColour((Math.log(ratio) / Math.log(ERROR_SPAN) + 1) / 2);
}

// The ramp's middle: the target; without one the frames' estimate, or before every pixel has
// one the pixel-weighted mean of the tiles' estimates so far; null when no tile has one
function errorCentre(job) {
  if (job.target_error != null) return job.target_error;
  if (job.expected_error != null) return job.expected_error;
  let sum = 0;
  let pixels = 0;
  for (const t of job.tile_states) {
    if (t.expected_error == null) continue;
    sum += t.expected_error * t.width * t.height;
    pixels += t.width * t.height;
  }
  return pixels && sum > 0 ? sum / pixels : null;
}

export function renderJob(view, jobId) {
  let job = null;
  let colourBy = "state";
  let shown = { etag: null, version: -1, key: "" };   // what the preview holds now
  let objectUrl = null;
  let fetching = false;
  let nextPreviewAt = 0;
  let poller = null;
  let frame = 0;                                      // the frame the preview shows
  let strip = { version: -1, at: 0, urls: [] };       // the frame strip's images
  let player = null;

  const title = h("h1", { id: "job-title" }, "Job");
  const badge = h("span", { id: "job-status" });
  const cancelBtn = h("button", { id: "job-cancel", type: "button" }, "Cancel");
  const retryBtn = h("button", { id: "job-retry", type: "button" }, "Retry");
  const deleteBtn = h("button", { id: "job-delete", type: "button" }, "Delete");
  const facts = h("dl", { class: "facts", id: "job-facts" });
  const bar = h("div", { id: "job-progress" });
  const img = h("img", { id: "preview", alt: "the image as merged so far" });
  const previewNote = h("p", { class: "muted small", id: "preview-note" }, "No samples merged yet.");
  const exposure = h("input", {
    id: "exposure", type: "range", min: "-5", max: "5", step: "0.5", value: "0",
    "aria-label": "exposure in stops",
  });
  const exposureOut = h("output", { for: "exposure", id: "exposure-value" }, "0 EV");
  const tonemap = h("select", { id: "tonemap", "aria-label": "tone mapping" },
    ["clamp", "reinhard", "aces"].map((t) => h("option", { value: t }, t)));
  const pngLink = h("a", { id: "download-png", class: "button", download: "" }, "PNG");
  const exrLink = h("a", { id: "download-exr", class: "button", download: "" }, "EXR");
  const grid = h("div", { class: "tile-grid", id: "tile-grid", role: "img" });
  const legend = h("div", { class: "legend", id: "tile-legend" });
  const errorOption = h("option", { value: "error", hidden: true,
    title: "the tile's expected relMSE from its merged samples (grey: none yet)" },
  "estimated error");
  const colourSel = h("select", { id: "colour-by", "aria-label": "colour tiles by" },
    h("option", { value: "state" }, "state"), h("option", { value: "samples" }, "samples"),
    errorOption);
  const errors = h("div", { id: "job-errors" });
  const methods = h("div", { id: "job-methods" });
  const frameStrip = h("div", { class: "frame-strip", id: "frame-strip" });
  const playBtn = h("button", { id: "frames-play", type: "button" }, "Play");
  const framesPanel = h("section", { class: "panel", id: "frames-panel", hidden: true },
    h("div", { class: "toolbar" }, h("h2", {}, "Frames"), h("span", { class: "spacer" }), playBtn),
    frameStrip);

  view.append(
    h("p", { class: "crumbs" }, h("a", { href: "#/jobs" }, "← Jobs")),
    h("div", { class: "toolbar" }, title, badge, h("span", { class: "spacer" }),
      h("span", { class: "group" }, cancelBtn, retryBtn, deleteBtn)),
    bar,
    framesPanel,
    h("div", { class: "job-layout" },
      h("section", { class: "panel preview-panel" },
        h("div", { class: "preview-box" }, img),
        previewNote,
        h("div", { class: "controls" },
          h("label", {}, "Exposure ", exposure, exposureOut),
          h("label", {}, "Tone map ", tonemap),
          h("span", { class: "group" }, h("span", { class: "muted" }, "Download"), pngLink,
            exrLink))),
      h("section", { class: "panel" },
        h("div", { class: "toolbar" }, h("h2", {}, "Tiles"), h("span", { class: "spacer" }),
          h("label", {}, "Colour by ", colourSel)),
        grid, legend,
        facts)),
    h("section", { class: "panel" }, h("h2", {}, "Errors"), errors),
    h("section", { class: "panel" }, h("h2", {}, "Methods chosen by auto"), methods));

  function imageUrl(fmt, withView = true) {
    const q = withView ? `?exposure=${exposure.value}&tonemap=${tonemap.value}` : "";
    return `/api/jobs/${jobId}${frame ? `/frames/${frame}` : ""}/image.${fmt}${q}`;
  }

  function label(version) {
    img.dataset.version = String(version);
    previewNote.textContent =
      `Merge ${version}: ${job.tasks_merged} of ${job.tasks_total} passes.`;
  }

  // Fetch the preview only if the image can have changed: a new merge (image_version) or a new
  // exposure / tone map. The server's ETag is sent back, so an unchanged image costs a 304.
  async function refreshPreview() {
    if (!job || job.samples_merged === 0 || fetching) return;
    const key = `${exposure.value}/${tonemap.value}/${frame}`;
    if (job.image_version === shown.version && key === shown.key) return;
    // A new exposure or the final image is fetched at once; merges of a running job are paced.
    const paced = key === shown.key && !FINAL.includes(job.status);
    if (paced && performance.now() < nextPreviewAt) return;
    fetching = true;
    const started = performance.now();
    try {
      const headers = authHeaders(key === shown.key && shown.etag
        ? { "If-None-Match": shown.etag } : {});
      const version = job.image_version;
      const r = await fetch(imageUrl("png"), { headers, cache: "no-store" });
      if (r.status === 304) {
        // The image shown is still the current one: an image fetched just after the answer
        // that said which merge it was can be of later merges (a job that finished meanwhile),
        // and its ETag then holds for the merge the next answer gives
        shown.version = version;
        label(version);
      } else if (r.ok) {
        const blob = await r.blob();
        if (objectUrl) URL.revokeObjectURL(objectUrl);
        objectUrl = URL.createObjectURL(blob);
        img.src = objectUrl;
        shown = { etag: r.headers.get("ETag"), version, key };
        label(version);
      }
    } finally {
      fetching = false;
      const took = performance.now() - started;
      nextPreviewAt = performance.now() + Math.max(PREVIEW_MIN_MS, PREVIEW_COST_FACTOR * took);
    }
  }

  function renderTiles() {
    grid.style.aspectRatio = `${job.width} / ${job.height}`;
    // a job of frames: the tiles of the frame the preview shows (the legend counts them all)
    const shownTiles = job.tile_states.filter((t) => (t.frame ?? 0) === frame);
    grid.setAttribute("aria-label", `${shownTiles.length} tiles coloured by ${colourBy}`);
    const centre = errorCentre(job);
    const cells = shownTiles.map((t) => {
      const estimate = t.expected_error == null ? ""
        : `, estimated relMSE ${digits3(t.expected_error)}`;
      const fill = colourBy === "state" ? TILE_COLOURS[t.state] || "#888"
        : colourBy === "samples" ? samplesColour(t.samples / job.spp)
          : t.expected_error == null ? "#888" : errorColour(t.expected_error / centre);
      return h("div", {
        class: `tile t-${t.state}${t.error ? " has-error" : ""}`,
        dataset: { index: t.index, state: t.state, samples: t.samples,
          estimate: t.expected_error ?? "" },
        title: `tile ${t.index} (${t.x0}, ${t.y0}) ${t.width}×${t.height}: ${t.state}, `
          + `${t.samples} of ${job.spp} spp${estimate}${t.error ? `\n${t.error}` : ""}`,
        style: `left:${(100 * t.x0) / job.width}%;top:${(100 * t.y0) / job.height}%;`
          + `width:${(100 * t.width) / job.width}%;height:${(100 * t.height) / job.height}%;`
          + `background:${fill}`,
      });
    });
    grid.replaceChildren(...cells);
    if (colourBy === "state") {
      const counts = {};
      for (const t of job.tile_states) counts[t.state] = (counts[t.state] || 0) + 1;
      // "converged": a tile of a job with a target error that has nothing to add for now
      legend.replaceChildren(...Object.entries(TILE_COLOURS)
        .filter(([s]) => s !== "converged" || counts[s]).map(([s, c]) =>
        h("span", {}, h("i", { style: `background:${c}` }), `${s} ${counts[s] || 0}`)));
    } else if (colourBy === "error") {
      const middle = job.target_error != null ? `target ${job.target_error}`
        : job.expected_error != null ? `the frame's estimate ${digits3(centre)}`
          : `the tiles' mean so far ${digits3(centre)}`;
      legend.replaceChildren(h("span", {}, `${digits3(centre / ERROR_SPAN)}`),
        h("i", { class: "ramp", style: `background:linear-gradient(90deg,${
          [0.25, 0.5, 1, 2, 4].map(errorColour).join(",")})` }),
        h("span", {}, `${digits3(centre * ERROR_SPAN)} relMSE (${middle} mid-ramp)`));
    } else {
      legend.replaceChildren(h("span", {}, "0 spp"),
        h("i", { class: "ramp", style: `background:linear-gradient(90deg,${
          [0, 0.33, 0.66, 1].map(samplesColour).join(",")})` }),
        h("span", {}, `${job.spp} spp`));
    }
  }

  function renderErrors() {
    const items = [];
    if (job.error) items.push(h("li", { class: "job-error" }, h("b", {}, "Job failed: "), job.error));
    if (job.waiting_for) items.push(h("li", { class: "job-waiting" }, job.waiting_for));
    for (const [node, n] of Object.entries(job.blocklist || {})) {
      items.push(h("li", { class: "blocklisted", dataset: { node } },
        h("b", {}, "Blocklisted: "), `${node} (${n} failed passes): it gets none of this job's passes`));
    }
    for (const t of job.tile_states.filter((x) => x.error)) {
      items.push(h("li", { class: "tile-error", dataset: { tile: t.index } },
        h("b", {}, `Tile ${t.index} (${t.state}): `), t.error));
    }
    if (job.dropped_samples) {
      items.push(h("li", {}, `${job.dropped_samples} non-finite samples left out.`));
    }
    errors.replaceChildren(items.length ? h("ul", { class: "errors" }, items)
      : h("p", { class: "muted" }, "None."));
  }

  function renderMethods() {
    const entries = Object.entries(job.methods || {});
    methods.replaceChildren(entries.length
      ? h("table", { class: "methods" }, h("thead", {}, h("tr", {}, h("th", {}, "Material"),
        h("th", {}, "Method and why"))),
      h("tbody", {}, entries.map(([m, why]) => h("tr", {}, h("td", {}, m), h("td", {}, why)))))
      : h("p", { class: "muted" },
        "None reported: this job has no translucent material with method \"auto\" "
        + "(or the farm does not report the choice yet)."));
  }

  // A job with render.target_error: the relMSE asked for and the frames' estimate from the
  // samples merged so far (docs/adaptive-sampling.md), none before every pixel has its pilot
  function targetText(j) {
    const asked = `relMSE ${j.target_error}`;
    if (j.expected_error == null) {
      return FINAL.includes(j.status) ? asked : `${asked} · estimated once every pixel has samples`;
    }
    // (where auto's models may add a bias, the estimate is the samples' noise and it together)
    const parts = j.expected_bias
      ? ` (the samples' noise ${digits3(j.expected_error - j.expected_bias)} and auto's bias, `
        + `at most ${digits3(j.expected_bias)})`
      : "";
    const est = digits3(j.expected_error);
    if (j.status !== "done") return `${asked} · now ${est}${parts}`;
    // (the farm stops a frame below its target: a done job above it ran into render.spp)
    return j.expected_error > j.target_error
      ? `${asked} · ${est} (estimated${parts ? `; ${parts.slice(2, -1)}` : ""}): above the `
        + `target, a pixel takes at most ${j.spp} samples`
      : `${asked} · reached ${est} (estimated${parts ? `; ${parts.slice(2, -1)}` : ""})`;
  }

  // A job without a target: the frames' expected relMSE from the samples merged so far
  function estimateText(j) {
    const est = `relMSE ${digits3(j.expected_error)}`;
    return j.status === "done" ? est : `${est} so far`;
  }

  function render() {
    // (tiles coloured by their estimated error: once a merge has given a tile's pixels 2
    // samples; the farm estimates every job's)
    errorOption.hidden = errorCentre(job) == null;
    if (errorOption.hidden && colourBy === "error") {
      colourBy = colourSel.value = "state";
    }
    title.textContent = job.name || `Job ${job.id.slice(0, 8)}`;
    badge.replaceChildren(statusBadge(job.status));
    bar.replaceChildren(progressBar(job.progress, job.status));
    cancelBtn.disabled = FINAL.includes(job.status);
    retryBtn.disabled = !["failed", "cancelled"].includes(job.status);
    deleteBtn.disabled = !FINAL.includes(job.status);
    const rows = [
      ["Size", `${job.width}×${job.height}, ${job.spp} spp`],
      ["Tiles × passes", `${job.tiles} × ${job.passes} (${job.tile_size} px, `
        + (job.largest_pass > job.spp_per_pass
          ? `${job.spp_per_pass}–${job.largest_pass} spp a pass)`
          : `${job.spp_per_pass} spp a pass)`)],
      ["Passes merged", `${job.tasks_merged} / ${job.tasks_total}`],
      ...(job.target_error != null ? [["Target error", targetText(job)]]
        : job.expected_error != null ? [["Estimated error", estimateText(job)]] : []),
      ...(job.denoise ? [["Denoise", "once done, with Open Image Denoise (the noisy image "
        + "kept as image.exr's noisy layer)"]] : []),
      ["Samples/s", fmtRate(job.samples_per_second)],
      ["Elapsed", fmtDuration(elapsed(job))],
      ["ETA", job.status === "done" ? "done" : fmtDuration(job.eta_seconds)],
      ["Submitted", fmtTime(job.created_at)],
      ["Priority", String(job.priority)],
    ];
    facts.replaceChildren(...rows.flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, v)]));
    renderTiles();
    renderErrors();
    renderMethods();
  }

  // The frame strip: every frame's PNG, fetched again when merges landed, at most every
  // PREVIEW_MIN_MS x frames (each is a preview's cost), once more when the job is over.
  async function refreshStrip() {
    if (!job || job.frames <= 1) return;
    framesPanel.hidden = false;
    const over = FINAL.includes(job.status);
    if (job.image_version === strip.version) { renderStrip(); return; }
    if (!over && performance.now() < strip.at) { renderStrip(); return; }
    strip.at = performance.now() + PREVIEW_MIN_MS * job.frames;
    const version = job.image_version;
    const urls = [];
    for (let i = 0; i < job.frames; i++) {
      const r = await fetch(`/api/jobs/${jobId}/frames/${i}/image.png`,
        { headers: authHeaders({}), cache: "no-store" });
      urls.push(r.ok ? URL.createObjectURL(await r.blob()) : null);
    }
    strip.urls.forEach((u) => u && URL.revokeObjectURL(u));
    strip = { ...strip, version, urls };
    renderStrip();
  }

  function renderStrip() {
    const progress = job.frame_progress || [];
    frameStrip.replaceChildren(...Array.from({ length: job.frames }, (_, i) => h("button", {
      type: "button", class: `frame-thumb${i === frame ? " selected" : ""}`,
      dataset: { frame: String(i) },
      // (each frame's estimate: a job with a target samples each frame to it on its own)
      title: `frame ${i}` + (progress[i]?.expected_error == null ? ""
        : `, estimated relMSE ${digits3(progress[i].expected_error)}`),
      onclick: () => { stopPlaying(); showFrame(i); },
    }, strip.urls[i] ? h("img", { src: strip.urls[i], alt: `frame ${i}` }) : h("span", {}, "…"),
    h("span", { class: "frame-caption" },
      `${i} · ${Math.round(100 * (progress[i]?.progress ?? 0))} %`))));
  }

  function showFrame(i) {
    frame = i;
    renderStrip();
    renderTiles();
    updateLinks();
    refreshPreview();
  }

  function stopPlaying() {
    if (player) { clearInterval(player); player = null; playBtn.textContent = "Play"; }
  }

  playBtn.addEventListener("click", () => {
    if (player) { stopPlaying(); return; }
    playBtn.textContent = "Stop";
    // The strip's images, one after the other (no fetch): the sequence as it stands
    player = setInterval(() => {
      if (!img.isConnected) { stopPlaying(); return; }  // the page was left
      frame = (frame + 1) % job.frames;
      if (strip.urls[frame]) img.src = strip.urls[frame];
      renderStrip();
    }, 250);
  });

  async function refresh() {
    job = await api(`/api/jobs/${jobId}`);
    render();
    await refreshPreview();
    await refreshStrip();
    const ms = FINAL.includes(job.status) ? FINAL_POLL_MS : POLL_MS;
    if (poller && poller.ms !== ms) poller.ms = ms;
  }

  async function act(method, path, verb) {
    try {
      job = { ...job, ...(await api(path, { method })) };
      showNotice(`Job ${verb}`);
    } catch (err) {
      showNotice(err.message, "error");
    }
    if (poller) { poller.ms = POLL_MS; poller.run(); }
  }

  cancelBtn.addEventListener("click", () => act("DELETE", `/api/jobs/${jobId}`, "cancelled"));
  retryBtn.addEventListener("click", () => act("POST", `/api/jobs/${jobId}/retry`, "retried"));
  // A finished job: its record, image and scene go; back to the list.
  deleteBtn.addEventListener("click", async () => {
    try {
      await api(`/api/jobs/${jobId}`, { method: "DELETE" });
      showNotice("Job deleted");
      location.hash = "#/jobs";
    } catch (err) {
      showNotice(err.message, "error");
    }
  });
  const onView = () => {
    exposureOut.textContent = `${Number(exposure.value) > 0 ? "+" : ""}${exposure.value} EV`;
    refreshPreview();
  };
  exposure.addEventListener("input", onView);
  tonemap.addEventListener("change", onView);
  colourSel.addEventListener("change", () => { colourBy = colourSel.value; if (job) renderTiles(); });

  // Downloads: plain links (they carry the exposure and tone map for the PNG); with a token the
  // file is fetched with the Authorization header and handed over as a blob.
  const updateLinks = () => {
    pngLink.href = imageUrl("png");
    exrLink.href = imageUrl("exr", false);
    pngLink.download = `${jobId}.png`;
    exrLink.download = `${jobId}.exr`;
  };
  updateLinks();
  exposure.addEventListener("change", updateLinks);
  tonemap.addEventListener("change", updateLinks);
  for (const link of [pngLink, exrLink]) {
    link.addEventListener("click", async (e) => {
      if (!token()) return;
      e.preventDefault();
      const r = await fetch(link.href, { headers: authHeaders() });
      if (!r.ok) { showNotice(`download failed: HTTP ${r.status}`, "error"); return; }
      const a = h("a", { href: URL.createObjectURL(await r.blob()), download: link.download });
      a.click();
      setTimeout(() => URL.revokeObjectURL(a.href), 10000);
    });
  }

  poller = poll(async () => {
    try {
      await refresh();
    } catch (err) {
      if (err.status === 404) {
        view.replaceChildren(h("p", {}, `No job ${jobId}. `, h("a", { href: "#/jobs" }, "Jobs")));
        poller.stop();
        return;
      }
      throw err;
    }
  }, POLL_MS);
}
