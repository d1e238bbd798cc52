"""The dashboard end to end: headless Chromium on the pages, a real farm behind them.

Each test saves a screenshot of what it checked into the ``artifacts`` folder."""

from __future__ import annotations

import io
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.conftest import wait_until

ROOT = Path(__file__).resolve().parents[2]

ROOT_EXAMPLE = "cornell_box"
# The example at half its size (edited in the page), cut into 20 tiles x 3 passes (16, 16 and 32
# samples): a few seconds on 2 worker processes.
FAST = {"tile_size": "32", "spp_per_pass": "16"}

# Mean of a canvas copy of the <img>: the preview as the browser decoded it; -1 while a new
# preview is still loading (naturalWidth is 0 then, and reading the canvas would throw).
IMG_MEAN = """(img) => {
  if (!img.complete || !img.naturalWidth) return -1;
  const c = document.createElement('canvas');
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext('2d'); g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let s = 0; for (let i = 0; i < d.length; i += 4) s += d[i] + d[i + 1] + d[i + 2];
  return s / (3 * c.width * c.height);
}"""


def shot(page, artifacts, name):
    page.screenshot(path=str(artifacts / f"{name}.png"), full_page=True)


def no_page_errors(page):
    assert not page.console_errors, page.console_errors


@pytest.fixture
def api(dashboard):
    with dashboard.api() as c:
        yield c


def test_submit_an_example_and_watch_it_reach_100_percent(dashboard, page, artifacts, api):
    page.goto(f"{dashboard.url}/#/submit")
    page.select_option("#example", ROOT_EXAMPLE)
    page.wait_for_function("document.querySelector('#scene').value.includes('\"camera\"')")
    assert json.loads(page.input_value("#scene"))["film"] == {"width": 320, "height": 240}
    assert page.input_value("#f-name") == ROOT_EXAMPLE
    scene = json.loads(page.input_value("#scene"))
    scene["film"] = {"width": 160, "height": 120}
    page.fill("#scene", json.dumps(scene, indent=2))
    for name, value in FAST.items():
        page.fill(f"#f-{name}", value)
    shot(page, artifacts, "submit")
    page.click("#submit-job")

    # The job page: progress to 100 %, every tile done, a preview that is not black.
    page.wait_for_url("**/#/job/*")
    job_id = page.url.rsplit("/", 1)[1]
    page.wait_for_selector("#job-status .badge.s-done", timeout=120_000)
    assert page.get_attribute("#job-progress [role=progressbar]", "aria-valuenow") == "100"
    assert page.inner_text("#job-progress") == "100 %"
    states = page.eval_on_selector_all("#tile-grid .tile", "ts => ts.map(t => t.dataset.state)")
    assert states == ["done"] * 20
    job = api.get(f"/api/jobs/{job_id}").json()
    page.wait_for_function(
        f"document.querySelector('#preview').dataset.version === '{job['image_version']}'")
    page.wait_for_function("document.querySelector('#preview').complete")
    mean = page.eval_on_selector("#preview", IMG_MEAN)
    assert mean > 20, f"the preview is black (mean {mean:.1f} of 255)"

    # The download link gives the same image as a PNG file.
    png = api.get(page.get_attribute("#download-png", "href"))
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    pixels = np.asarray(Image.open(io.BytesIO(png.content)).convert("RGB"))
    assert pixels.shape == (120, 160, 3) and pixels.mean() > 20
    exr = api.get(page.get_attribute("#download-exr", "href"))
    assert exr.status_code == 200 and exr.content[:4] == b"\x76\x2f\x31\x01"  # OpenEXR magic

    # Exposure: +2 EV fetches a brighter image (a new ETag), and the tiles coloured by samples.
    page.fill("#exposure", "2")
    page.dispatch_event("#exposure", "input")
    page.wait_for_function(f"(m) => ({IMG_MEAN})(document.querySelector('#preview')) > m + 10",
                           arg=mean)
    page.select_option("#colour-by", "samples")
    assert page.inner_text("#tile-legend").endswith("64 spp")
    assert page.inner_text("#job-methods").startswith("None reported")
    # FAST's first pass of 16 samples, then 16 and 32: the passes as they are, not the cap.
    assert "20 × 3 (32 px, 16–32 spp a pass)" in page.inner_text("#job-facts")
    shot(page, artifacts, "job")
    no_page_errors(page)


def test_preview_is_fetched_only_when_its_etag_changes(dashboard, page, api):
    scene = json.loads((ROOT / "examples" / f"{ROOT_EXAMPLE}.json").read_text())
    scene["film"] = {"width": 64, "height": 48}
    scene["render"]["spp"] = 8
    job = api.post("/api/jobs", json={"scene": scene, "name": "etag"}).json()
    api_wait(api, job["id"], "done")
    images = []
    page.on("request", lambda r: images.append(r.url) if "/image.png" in r.url else None)
    page.goto(f"{dashboard.url}/#/job/{job['id']}")
    page.wait_for_selector("#preview[data-version]")
    page.wait_for_timeout(2000)  # three polls of the job at least: the image did not change
    assert len(images) == 1, images


def test_cancel_a_second_job_from_the_jobs_page(dashboard, page, artifacts, api):
    scene = json.loads((ROOT / "examples" / f"{ROOT_EXAMPLE}.json").read_text())
    scene["render"]["spp"] = 64
    job = api.post("/api/jobs", json={"scene": scene, "name": "to cancel",
                                      "spp_per_pass": 4}).json()
    page.goto(f"{dashboard.url}/#/jobs")
    row = page.locator(f"tr[data-id='{job['id']}']")
    row.locator("input[type=checkbox]").check()
    assert page.inner_text("#sel-count") == "1 selected"
    page.click("#bulk-cancel")
    page.wait_for_selector(f"tr[data-id='{job['id']}'][data-status='cancelled']")
    assert api.get(f"/api/jobs/{job['id']}").json()["status"] == "cancelled"

    # The filter shows it among the cancelled jobs; its page offers retry, not cancel.
    page.select_option("#status-filter", "cancelled")
    page.wait_for_function("[...document.querySelectorAll('tbody tr')]"
                           ".every(r => r.dataset.status === 'cancelled')")
    shot(page, artifacts, "jobs")
    page.select_option("#status-filter", "")
    page.click(f"tr[data-id='{job['id']}'] a.job-link")
    page.wait_for_selector("#job-status .badge.s-cancelled")
    assert page.is_disabled("#job-cancel") and page.is_enabled("#job-retry")

    # A finished job can be deleted from its page: record, image and scene go, and the list
    # shows it no more.
    assert page.is_enabled("#job-delete")
    page.click("#job-delete")
    page.wait_for_selector("#jobs-count")
    page.wait_for_selector(f"tr[data-id='{job['id']}']", state="detached")
    assert api.get(f"/api/jobs/{job['id']}").status_code == 404
    no_page_errors(page)


def test_a_bad_scene_shows_its_error_next_to_the_field(dashboard, page, artifacts, api):
    before = api.get("/api/jobs").json()["count"]
    scene = json.loads((ROOT / "examples" / f"{ROOT_EXAMPLE}.json").read_text())
    scene["render"]["spp"] = 0
    scene["objects"][0]["edge1"] = [2, 0]
    page.goto(f"{dashboard.url}/#/submit")
    page.fill("#scene", json.dumps(scene, indent=2))
    page.fill("#f-tile_size", "4")
    page.click("#submit-job")
    # Pydantic checks the body's own fields first: tile_size is named, next to its input.
    page.wait_for_selector("#err-tile_size:not(:empty)")
    assert "8" in page.inner_text("#err-tile_size")
    assert page.get_attribute("#f-tile_size", "aria-invalid") == "true"
    page.fill("#f-tile_size", "")
    page.click("#submit-job")
    spp = page.wait_for_selector("#scene-errors li[data-path='render.spp']")
    assert "spp" in spp.inner_text()
    assert page.locator("#scene-errors li[data-path='objects[0].edge1']").count() == 1
    assert page.get_attribute("#scene", "aria-invalid") == "true"
    page.wait_for_timeout(300)
    assert page.inner_text("#err-tile_size") == ""
    shot(page, artifacts, "submit-errors")
    # Clicking the error selects the key in the editor.
    spp.click()
    selected = page.evaluate("(() => { const t = document.querySelector('#scene');"
                             " return t.value.slice(t.selectionStart, t.selectionEnd); })()")
    assert selected == '"spp"'
    # Not JSON at all: said before anything is sent.
    page.fill("#scene", "{not json")
    page.click("#submit-job")
    page.wait_for_selector("#scene-errors li:has-text('not valid JSON')")
    assert api.get("/api/jobs").json()["count"] == before  # nothing queued
    no_page_errors(page)


def test_workers_page_lists_the_workers_and_shows_a_lost_one(dashboard, page, artifacts):
    store = dashboard.store()
    page.goto(f"{dashboard.url}/#/workers")
    page.wait_for_function("document.querySelectorAll('#workers-table tbody tr').length >= 2")
    live = page.locator("#workers-table tbody tr:not([data-state='lost'])")
    assert live.count() >= 2
    first = live.first.inner_text()
    assert "s ago" in first
    # each its release, none marked older than another
    from renderer import __version__
    from services.farm.store import MERGE_PROTOCOL

    assert live.first.locator("td.version").inner_text() == __version__
    assert live.first.locator("td.kernel").inner_text() == \
        os.environ.get("LUCENT_WORKER_KERNEL", "packet")
    assert page.locator("#workers-table .outdated").count() == 0
    # (each worker process's heartbeat: what its merge keeps, the kernel it renders with)
    assert {(w.get("protocol"), w.get("kernel")) for w in store.workers()
            if w.get("state") != "lost"} == \
        {(str(MERGE_PROTOCOL), os.environ.get("LUCENT_WORKER_KERNEL", "packet"))}
    # A worker that beats once and falls silent is shown as lost within 3 intervals.
    store.heartbeat("ghost@nowhere", {"host": "nowhere", "pid": 1, "state": "busy",
                                      "current_task": "", "tiles_done": 7,
                                      "paths_per_second": 1.0, "tags": "bigmem,gpu"},
                    ttl=3 * 0.5)
    ghost = page.locator("tr[data-id='ghost@nowhere']")
    ghost.wait_for()
    # its node's pool tags, one badge each
    assert ghost.locator("td.tags .tag").all_inner_texts() == ["bigmem", "gpu"]
    # a heartbeat without a release or protocol: a worker from before, its merge older than
    # the farm's others
    assert ghost.locator("td.version").inner_text() == "– older merge"
    assert ghost.locator("td.kernel").inner_text() == "–"
    t0 = time.monotonic()
    page.wait_for_selector("tr[data-id='ghost@nowhere'][data-state='lost']", timeout=10_000)
    assert time.monotonic() - t0 < 5.0
    assert "lost" in page.inner_text("#workers-summary")
    shot(page, artifacts, "workers")
    store.remove_worker("ghost@nowhere")
    store.r.close()
    no_page_errors(page)


def test_a_hidden_page_stops_polling(dashboard, page):
    page.goto(f"{dashboard.url}/#/jobs")
    page.wait_for_selector("#jobs-count:not(:empty)")
    requests: list[str] = []
    page.on("request", lambda r: requests.append(r.url) if "/api/" in r.url else None)
    page.evaluate("""() => {
      Object.defineProperty(document, 'hidden', {configurable: true, get: () => true});
      document.dispatchEvent(new Event('visibilitychange'));
    }""")
    page.wait_for_timeout(300)  # a poll already in flight may finish
    requests.clear()
    page.wait_for_timeout(3000)
    assert requests == [], requests
    page.evaluate("""() => {
      Object.defineProperty(document, 'hidden', {configurable: true, get: () => false});
      document.dispatchEvent(new Event('visibilitychange'));
    }""")
    page.wait_for_timeout(500)
    assert any("/api/jobs" in u for u in requests), "polling did not resume"


def test_a_refresh_that_lands_after_the_user_left_the_page_is_harmless(dashboard, page):
    # A change of the jobs filter starts a refresh; it is held in flight while the user goes to
    # the workers page, then answered. The jobs page must not reach for its elements in the
    # document any more: it did, by id, and threw "Cannot set properties of null" (seen in about
    # one run in ten of the test above, which clicks a job link right after changing the filter).
    page.goto(f"{dashboard.url}/#/jobs")
    page.wait_for_selector("#jobs-count:not(:empty)")
    held = []
    page.route("**/api/jobs?*", lambda route: held.append(route))
    page.select_option("#status-filter", "cancelled")
    deadline = time.monotonic() + 10
    while not held and time.monotonic() < deadline:
        page.wait_for_timeout(50)
    assert held, "changing the filter sent no request"
    page.evaluate("location.hash = '#/workers'")
    page.wait_for_selector("#workers-summary", state="attached")
    for route in held:
        route.continue_()
    page.wait_for_timeout(500)
    page.unroute("**/api/jobs?*")
    no_page_errors(page)


def test_speed_vs_accuracy_page_shows_what_exists(dashboard, page, artifacts):
    page.goto(f"{dashboard.url}/#/methods")
    if list((ROOT / "docs" / "images" / "accuracy").glob("*.png")):
        chart = page.wait_for_selector("#charts figure img")
        page.wait_for_function("(i) => i.complete && i.naturalWidth > 0", arg=chart)
    else:
        assert "Not measured yet" in page.inner_text("#not-measured")
    grid = ROOT / "docs" / "images" / "methods"
    if list(grid.glob("*_grid.png")):
        img = page.wait_for_selector("figure.figure img")
        page.wait_for_function("(i) => i.complete && i.naturalWidth > 0", arg=img)
    shot(page, artifacts, "methods")
    no_page_errors(page)


def test_a_phone_gets_one_column_and_no_sideways_scroll(dashboard, browser, artifacts):
    context = browser.new_context(viewport={"width": 390, "height": 844}, device_scale_factor=2,
                                  is_mobile=True, has_touch=True)
    page = context.new_page()
    try:
        for name in ("jobs", "workers", "submit", "methods"):
            page.goto(f"{dashboard.url}/#/{name}")
            page.wait_for_timeout(700)
            width = page.evaluate("document.documentElement.scrollWidth")
            assert width <= 390, f"{name}: {width} px wide on a 390 px screen"
            shot(page, artifacts, f"phone-{name}")
        page.goto(f"{dashboard.url}/#/jobs")
        page.click("a.job-link >> nth=0")
        page.wait_for_selector("#tile-grid .tile")
        page.wait_for_timeout(500)
        assert page.evaluate("document.documentElement.scrollWidth") <= 390
        shot(page, artifacts, "phone-job")
    finally:
        context.close()


def test_a_job_with_a_target_error_shows_the_target_and_its_estimate(dashboard, page, api,
                                                                      artifacts):
    """A job with render.target_error: its page gives the relMSE asked for and, once done, the
    frame's estimate the farm stopped on (the API's expected_error, to 3 digits). The Submit
    form's denoise box asks for the job option, and the job page says the image is denoised (or
    the farm's 422 on the field shows next to it where it cannot denoise)."""
    from renderer.film.denoise import oidn_available

    scene = json.loads((ROOT / "examples" / f"{ROOT_EXAMPLE}.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["render"]["spp"] = 256
    scene["render"]["target_error"] = 0.05
    page.goto(f"{dashboard.url}/#/submit")
    page.fill("#scene", json.dumps(scene))
    page.fill("#f-tile_size", "16")
    page.check("#f-denoise")
    page.click("#submit-job")
    if not oidn_available():
        error = page.wait_for_selector("#err-denoise:not(:empty)")
        assert "cannot denoise" in error.inner_text()
        page.uncheck("#f-denoise")
        page.click("#submit-job")
    page.wait_for_url("**/#/job/*")
    job_id = page.url.rsplit("/", 1)[1]
    page.wait_for_selector("#job-status .badge.s-done", timeout=120_000)
    job = api.get(f"/api/jobs/{job_id}").json()
    assert job["target_error"] == 0.05 and job["expected_error"] is not None
    assert job["denoise"] is oidn_available()
    facts = dict(zip(page.locator("#job-facts dt").all_inner_texts(),
                     page.locator("#job-facts dd").all_inner_texts(), strict=True))
    reached = repr(float(f"{job['expected_error']:.3g}"))  # (3 digits, as the page gives it)
    assert facts["Target error"] == f"relMSE 0.05 · reached {reached} (estimated)", facts
    assert ("Denoise" in facts) is oidn_available()
    # Each tile's estimate; over the frame's pixels they make the job's (Σ e_p / P both)
    tiles = job["tile_states"]
    assert all(t["expected_error"] is not None for t in tiles), tiles
    pixels = sum(t["width"] * t["height"] for t in tiles)
    assert sum(t["expected_error"] * t["width"] * t["height"] for t in tiles) / pixels == \
        pytest.approx(job["expected_error"], rel=1e-9)
    page.select_option("#colour-by", "error")
    assert page.inner_text("#tile-legend").endswith("0.2 relMSE (target 0.05 mid-ramp)")
    shown = page.eval_on_selector_all(
        "#tile-grid .tile", "ts => ts.map(t => [Number(t.dataset.estimate), t.title])")
    assert [e for e, _ in shown] == pytest.approx([t["expected_error"] for t in tiles])
    assert all("estimated relMSE" in title for _, title in shown)
    page.wait_for_function(
        f"document.querySelector('#preview').dataset.version === '{job['image_version']}'")
    page.wait_for_function("document.querySelector('#preview').complete")
    assert page.eval_on_selector("#preview", IMG_MEAN) > 20
    shot(page, artifacts, "target")
    # The Jobs page gives the target and the estimate under the job's name, once it is out of
    # Redis too (the sweeper archives it within a second or so: the listing reads its record)
    wait_until(lambda: dashboard.store().get_job(job_id) is None, 30, "the job archived")
    page.goto(f"{dashboard.url}/#/jobs")
    summary = page.wait_for_selector(f"tr[data-id='{job_id}'] .job-relmse")
    assert summary.inner_text() == f"target relMSE 0.05 · {reached}"
    shot(page, artifacts, "jobs-target")
    no_page_errors(page)


def test_the_submit_forms_target_sets_the_scenes_and_its_error_shows_next_to_it(
        dashboard, page, api, artifacts):
    """The Submit form's target relMSE is set in the scene sent (render.target_error, over the
    scene's own); a value the farm refuses (422 on scene.render.target_error) is said next to
    the field, not in the scene's errors, and nothing is queued."""
    before = api.get("/api/jobs").json()["count"]
    scene = json.loads((ROOT / "examples" / f"{ROOT_EXAMPLE}.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["render"].update(spp=64, target_error=0.5)
    page.goto(f"{dashboard.url}/#/submit")
    page.fill("#scene", json.dumps(scene))
    page.fill("#f-target_error", "-0.02")
    page.click("#submit-job")
    error = page.wait_for_selector("#err-target_error:not(:empty)")
    assert "> 0" in error.inner_text()
    assert page.get_attribute("#f-target_error", "aria-invalid") == "true"
    assert page.locator("#scene-errors li").count() == 0
    shot(page, artifacts, "submit-target-error")
    assert api.get("/api/jobs").json()["count"] == before
    page.fill("#f-target_error", "0.02")
    page.click("#submit-job")
    page.wait_for_url("**/#/job/*")
    job = api.get(f"/api/jobs/{page.url.rsplit('/', 1)[1]}").json()
    assert job["target_error"] == 0.02
    page.wait_for_selector("#job-status .badge.s-done", timeout=120_000)
    no_page_errors(page)


def test_a_running_job_with_a_target_error_shows_its_estimate_so_far(dashboard, page):
    """While a job with a target runs, its page gives the estimate from the samples merged so
    far, and says when there is none yet (a pixel without its pilot); done above its target, it
    names the cap a pixel takes. The job is made in the store, not queued; its answer is given
    the target, the estimates and the status by the page's route."""
    import uuid

    from services.farm.planner import Plan

    store = dashboard.store()
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "target", 0, Plan(16, 16, 4, 8, 4), b"{}")
    estimate = {"expected_error": None, "status": "running"}

    def answer(route):
        body = route.fetch().json()
        body.update(target_error=0.01, spp=64, **estimate)
        route.fulfill(json=body)

    page.route(f"**/api/jobs/{job_id}", answer)
    page.goto(f"{dashboard.url}/#/job/{job_id}")
    row = "() => [...document.querySelectorAll('#job-facts dd')].some(d => d.innerText === {!r})"
    page.wait_for_function(row.format("relMSE 0.01 · estimated once every pixel has samples"))
    estimate["expected_error"] = 0.031234
    page.wait_for_function(row.format("relMSE 0.01 · now 0.0312"), timeout=15_000)
    # Done above its target (the farm stops a frame below it): the cap is named
    estimate["status"] = "done"
    page.wait_for_function(row.format(
        "relMSE 0.01 · 0.0312 (estimated): above the target, a pixel takes at most 64 samples"),
        timeout=15_000)
    # Where auto's models may add a bias (expected_bias), the noise and the bias are named
    # (the page again: a done job's is not polled)
    estimate.update(expected_error=0.0091, expected_bias=0.0061, status="running")
    page.reload()
    page.wait_for_function(row.format(
        "relMSE 0.01 · now 0.0091 (the samples' noise 0.003 and auto's bias, at most 0.0061)"),
        timeout=15_000)
    estimate["status"] = "done"
    page.wait_for_function(row.format(
        "relMSE 0.01 · reached 0.0091 (estimated; the samples' noise 0.003 and auto's bias, "
        "at most 0.0061)"), timeout=15_000)
    page.unroute(f"**/api/jobs/{job_id}")
    store.cancel_job(job_id)
    no_page_errors(page)


def test_a_preview_fetched_after_its_answer_is_labelled_by_the_next(dashboard, page, api):
    """The preview is fetched after the job's answer that gave its merge; a job that merged
    again (or finished) between the two serves the later image, whose ETag the next answer's
    merge then matches (304): the page labels the image with that merge, not the first. Made
    here by giving the page's first answer of a done job an earlier merge."""
    job_id = small_done_job(api)
    version = api.get(f"/api/jobs/{job_id}").json()["image_version"]
    assert version > 1
    answers = []

    def answer(route):
        body = route.fetch().json()
        if not answers:  # (the first: a merge the preview will be newer than)
            body.update(status="running", image_version=1, tasks_merged=1)
        answers.append(body["image_version"])
        route.fulfill(json=body)

    page.route(f"**/api/jobs/{job_id}", answer)
    page.goto(f"{dashboard.url}/#/job/{job_id}")
    page.wait_for_function(
        f"document.querySelector('#preview').dataset.version === '{version}'", timeout=15_000)
    assert answers[0] == 1
    assert page.inner_text("#preview-note").startswith(f"Merge {version}: ")
    page.unroute(f"**/api/jobs/{job_id}")
    no_page_errors(page)


def test_a_job_without_a_target_shows_its_estimated_error(dashboard, page, api):
    """Every job's merges estimate its error: a job without a target gives the frames' expected
    relMSE as a fact, and its tiles can be coloured by their estimates on a ramp whose middle
    is the frame's. A job nothing was merged into has no estimate to colour by."""
    import uuid

    from services.farm.planner import Plan

    job_id = small_done_job(api)
    job = api.get(f"/api/jobs/{job_id}").json()
    assert job["target_error"] is None and job["expected_error"] > 0
    page.goto(f"{dashboard.url}/#/job/{job_id}")
    page.wait_for_selector("#job-status .badge.s-done")
    facts = dict(zip(page.locator("#job-facts dt").all_inner_texts(),
                     page.locator("#job-facts dd").all_inner_texts(), strict=True))
    estimate = repr(float(f"{job['expected_error']:.3g}"))
    assert facts["Estimated error"] == f"relMSE {estimate}" and "Target error" not in facts
    assert not page.eval_on_selector("#colour-by option[value=error]", "o => o.hidden")
    page.select_option("#colour-by", "error")
    assert page.inner_text("#tile-legend").endswith(
        f"relMSE (the frame's estimate {estimate} mid-ramp)")
    shown = page.eval_on_selector_all(
        "#tile-grid .tile", "ts => ts.map(t => [Number(t.dataset.estimate), t.style.background])")
    assert [e for e, _ in shown] == pytest.approx([t["expected_error"] for t in job["tile_states"]])
    # (the tiles' estimates differ, and so do their colours)
    assert len({e for e, _ in shown}) == len(shown) == len({c for _, c in shown}) > 1
    # ... and the Jobs page under its name
    page.goto(f"{dashboard.url}/#/jobs")
    summary = page.wait_for_selector(f"tr[data-id='{job_id}'] .job-relmse")
    assert summary.inner_text() == f"relMSE {estimate}"

    store = dashboard.store()
    empty = uuid.uuid4().hex
    store.create_job(empty, "nothing merged", 0, Plan(16, 16, 4, 8, 4), b"{}")
    page.goto(f"{dashboard.url}/#/job/{empty}")
    page.wait_for_selector("#job-facts dt")
    assert page.eval_on_selector("#colour-by option[value=error]", "o => o.hidden")
    facts = page.locator("#job-facts dt").all_inner_texts()
    assert "Estimated error" not in facts and "Target error" not in facts
    # Running, one tile estimated (the answer given by the page's route): the ramp's middle is
    # the estimated tiles' mean, the frame having none yet
    def answer(route):
        body = route.fetch().json()
        body["status"] = "running"
        body["tile_states"][0]["expected_error"] = 0.0234
        route.fulfill(json=body)

    page.route(f"**/api/jobs/{empty}", answer)
    page.reload()
    page.wait_for_function(
        "!document.querySelector('#colour-by option[value=error]').hidden")
    page.select_option("#colour-by", "error")
    assert page.inner_text("#tile-legend").endswith(
        "relMSE (the tiles' mean so far 0.0234 mid-ramp)")
    page.unroute(f"**/api/jobs/{empty}")
    store.cancel_job(empty)
    no_page_errors(page)



def test_the_api_process_survives(dashboard):
    # Last in the module: nothing above crashed the service or the workers.
    assert dashboard.server.poll() is None and dashboard.worker.poll() is None


# --- helpers --------------------------------------------------------------------------------------


def small_done_job(api) -> str:
    """The example scene at 32×24, 16 spp in 2 passes of 8 and 16-px tiles, submitted and
    rendered: its job id."""
    scene = json.loads((ROOT / "examples" / f"{ROOT_EXAMPLE}.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["render"]["spp"] = 16
    r = api.post("/api/jobs", json={"scene": scene, "spp_per_pass": 8, "tile_size": 16})
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    api_wait(api, job_id, "done")
    return job_id


def api_wait(api, job_id, status, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if api.get(f"/api/jobs/{job_id}").json()["status"] == status:
            return
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not reach {status}")


def test_job_page_shows_what_a_job_waits_for_and_its_blocklist(dashboard, page):
    """A job requiring a tag no worker has says what it waits for; a node blocklisted for it is
    listed with its failed passes; its tile legend counts the states. (The job is made in the
    store, not queued: it stays so.)"""
    import uuid

    from services.farm.planner import Plan

    store = dashboard.store()
    job_id = uuid.uuid4().hex
    store.create_job(job_id, "waits", 0, Plan(16, 16, 4, 8, 4), b"{}", tags=("gpu",))
    for _ in range(3):
        store.note_failure(job_id, "bad@host", 3)
    page.goto(f"{dashboard.url}/#/job/{job_id}")
    waiting = page.wait_for_selector("#job-errors li.job-waiting")
    assert waiting.inner_text() == "waiting for a worker with tags gpu"
    listed = page.wait_for_selector("#job-errors li.blocklisted[data-node='bad@host']")
    assert "bad@host (3 failed passes)" in listed.inner_text()
    # The legend names the states there are: a converged tile (a job with a target error that
    # has nothing to add for now) gets its own colour, and no entry while there is none
    assert "converged" not in page.inner_text("#tile-legend")
    store.set_tile_state(job_id, 1, "converged")
    page.wait_for_function("() => document.querySelector('#tile-legend').innerText"
                           ".includes('converged 1')")
    assert "queued 3" in page.inner_text("#tile-legend")
    store.cancel_job(job_id)
    no_page_errors(page)


def test_a_job_of_frames_shows_a_strip_and_plays_it(dashboard, page, api, artifacts):
    """A 3-frame job: the strip shows every frame with its progress; a click previews that
    frame (the frames route); Play runs through them."""
    scene = json.loads(
        (Path(__file__).resolve().parents[2] / "examples" / f"{ROOT_EXAMPLE}.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    scene["render"]["spp"] = 4
    frames = [[], [{"op": "replace", "path": "/camera/fov", "value": 60}],
              [{"op": "replace", "path": "/camera/fov", "value": 20}]]
    r = api.post("/api/jobs", json={"scene": scene, "frames": frames, "name": "frames"})
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    page.goto(f"{dashboard.url}/#/job/{job_id}")
    page.wait_for_selector("#job-status .badge.s-done", timeout=60_000)
    page.wait_for_function("document.querySelectorAll('#frame-strip .frame-thumb img').length"
                           " === 3")
    captions = page.locator("#frame-strip .frame-caption").all_inner_texts()
    assert captions == ["0 · 100 %", "1 · 100 %", "2 · 100 %"]
    # each frame's estimated error (the job's answer's frame_progress) in its title
    estimate = api.get(f"/api/jobs/{job_id}").json()["frame_progress"][2]["expected_error"]
    title = page.get_attribute("#frame-strip .frame-thumb[data-frame='2']", "title")
    assert title.startswith("frame 2, estimated relMSE "), title
    assert float(title.rsplit(" ", 1)[1]) == pytest.approx(estimate, rel=5e-3)
    with page.expect_response(lambda resp: f"/api/jobs/{job_id}/frames/2/image.png" in resp.url):
        page.click("#frame-strip .frame-thumb[data-frame='2']")
    assert "/frames/2/image.png" in page.get_attribute("#download-png", "href")
    shot(page, artifacts, "frames")
    page.click("#frames-play")
    page.wait_for_selector("#frame-strip .frame-thumb.selected[data-frame='1']")
    page.click("#frames-play")
    no_page_errors(page)
