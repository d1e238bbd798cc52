"""Per-job and farm-wide cost limits, checked when a job is submitted.

A scene within every per-field limit (``renderer.scene.Limits``) can still ask for far too much:
a 4096² film at 65 536 spp is 1.1e12 camera paths, weeks of this farm. The cost of a job is
counted in pixel-samples, ``width x height x spp``, the number of camera paths it traces:

- The integrator takes one light sample per path vertex whatever the number of lights (a light is
  picked from a CDF, ``renderer.lights``), and the BVH makes a ray's cost grow with the log of the
  triangle count, so neither lights nor triangles multiply the cost of a sample; both are bounded
  per scene by ``Limits`` instead.
- What a single path costs beyond that (very long random walks in a dense medium) cannot be told
  from the scene before it is rendered; the per-pass time limits (``task_soft_time_limit``) cap
  it, and a pass that exceeds them fails its job after ``max_attempts``.

==========================  ==================================  ===============================
Setting                     Environment variable                Refused with
==========================  ==================================  ===============================
``max_samples_per_job``     ``LUCENT_MAX_SAMPLES_PER_JOB``      422 on ``render.spp`` and
                                                                ``film``
``max_queued_samples``      ``LUCENT_MAX_QUEUED_SAMPLES``       429 (``Retry-After``)
==========================  ==================================  ===============================
"""

from __future__ import annotations

from dataclasses import dataclass

from services.farm.planner import Plan
from services.farm.settings import Settings
from services.farm.store import JobStore


@dataclass(frozen=True)
class CostError:
    """Why a job was refused: the HTTP status, the fields it names (``loc``) and a message."""

    status: int
    locs: tuple[tuple[str, ...], ...]
    msg: str


def job_samples(plan: Plan) -> int:
    """The pixel-samples (camera paths) of a job, every frame's."""
    return plan.width * plan.height * plan.spp * plan.frames


def queued_samples(store: JobStore) -> int:
    """Pixel-samples that the queued and running jobs have still to render (one status read per
    job, then four fields per active job: finished jobs cost next to nothing)."""
    return sum(store.active_samples_left())


def check_cost(plan: Plan, store: JobStore, settings: Settings) -> CostError | None:
    """None if the job may be queued, else why not.

    The farm-wide bound is read before the job is created, so concurrent submissions can each
    pass it: the backlog can exceed ``max_queued_samples`` by at most one ``max_samples_per_job``
    per submission in flight."""
    samples = job_samples(plan)
    if samples > settings.max_samples_per_job:
        return CostError(
            422, (("body", "scene", "render", "spp"), ("body", "scene", "film")),
            f"{plan.width} x {plan.height} pixels x {plan.spp} spp"
            f"{f' x {plan.frames} frames' if plan.frames > 1 else ''} = {samples} pixel-samples "
            f"exceed the limit {settings.max_samples_per_job} per job "
            "(LUCENT_MAX_SAMPLES_PER_JOB): lower spp or the film size")
    backlog = queued_samples(store)
    if backlog + samples > settings.max_queued_samples:
        return CostError(
            429, (("body", "scene"),),
            f"the farm has {backlog} pixel-samples queued; this job's {samples} would exceed the "
            f"limit {settings.max_queued_samples} (LUCENT_MAX_QUEUED_SAMPLES): retry later")
    return None
