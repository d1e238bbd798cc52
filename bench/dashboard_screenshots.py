"""Screenshots of every dashboard page for the docs, from a real farm, in headless Chromium.

    .venv/bin/python -m bench.dashboard_screenshots [--out docs/images/dashboard]

Renders a few example jobs (two done, one cancelled, one running and one queued at the shots),
then saves jobs.png, job.png, job-done.png, job-target.png (a job with a target error, its tiles
coloured by their estimated error), workers.png, submit.png, submit-errors.png, methods.png and
phone-jobs.png / phone-job.png (390 px wide).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import httpx

from bench.dashboard_farm import CHROMIUM, CHROMIUM_ARGS, ROOT, DashboardFarm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "dashboard")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    from playwright.sync_api import sync_playwright

    with DashboardFarm(workers=2) as farm, httpx.Client(base_url=farm.url, timeout=60) as api, \
            sync_playwright() as pw:
        half = {"width": 160, "height": 120}
        done = farm.submit(api, "cornell_box", tile_size=32)  # the default passes: 8-64 spp
        farm.wait(api, done["id"])
        glass = farm.submit(api, "glass_sphere", film=half, spp=32, tile_size=32)
        farm.wait(api, glass["id"])
        # a job with a target error: its tiles coloured by their estimated error
        target = farm.submit(api, "caustic_floor", film=half, spp=4096, target_error=0.01,
                             tile_size=16)
        farm.wait(api, target["id"])
        cancelled = farm.submit(api, "mirror_phong", film=half, spp_per_pass=4, tile_size=32)
        time.sleep(1.0)
        api.delete(f"/api/jobs/{cancelled['id']}")
        running = farm.submit(api, "translucent_sphere", spp_per_pass=4, tile_size=32)
        queued = farm.submit(api, "backlit_slab", priority=0)
        time.sleep(3.0)

        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1366, "height": 860})

        def shot(hash_: str, name: str, wait: float = 1.5, full: bool = False) -> None:
            page.goto(f"{farm.url}/#/{hash_}")
            page.wait_for_timeout(int(wait * 1000))
            page.screenshot(path=str(args.out / f"{name}.png"), full_page=full)
            print(args.out / f"{name}.png")

        shot("jobs", "jobs")
        shot(f"job/{running['id']}", "job", wait=2.5, full=True)
        shot(f"job/{done['id']}", "job-done", full=True)
        page.goto(f"{farm.url}/#/job/{target['id']}")
        page.wait_for_timeout(1500)
        page.select_option("#colour-by", "error")
        page.wait_for_timeout(500)
        page.screenshot(path=str(args.out / "job-target.png"), full_page=True)
        print(args.out / "job-target.png")
        shot("workers", "workers")
        page.goto(f"{farm.url}/#/submit")
        page.select_option("#example", "cornell_box")
        page.wait_for_timeout(500)
        page.screenshot(path=str(args.out / "submit.png"))
        scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
        scene["render"]["spp"] = 0
        scene["objects"][0]["edge1"] = [2, 0]
        page.fill("#scene", json.dumps(scene, indent=2))
        page.click("#submit-job")
        page.wait_for_selector("#scene-errors li")
        page.screenshot(path=str(args.out / "submit-errors.png"))
        shot("methods", "methods", full=True)

        phone = browser.new_page(viewport={"width": 390, "height": 844}, device_scale_factor=2,
                                 is_mobile=True)
        for hash_, name in (("jobs", "phone-jobs"), (f"job/{running['id']}", "phone-job")):
            phone.goto(f"{farm.url}/#/{hash_}")
            phone.wait_for_timeout(1500)
            phone.screenshot(path=str(args.out / f"{name}.png"))
            print(args.out / f"{name}.png")
        browser.close()
        for job in (running, queued):
            api.delete(f"/api/jobs/{job['id']}")


if __name__ == "__main__":
    main()
