"""The API's schemas, one family per resource (FastAPI template style)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict

from services.farm.pools import MAX_JOB_TAGS, check_tag

JobStatus = Literal["queued", "running", "done", "failed", "cancelled"]

# As in the scene (renderer/scene/schema.py): a JSON string ("32") or a float (32.0) is not an
# integer.
StrictInt = Annotated[int, Strict()]
StrictBool = Annotated[bool, Strict()]
Tag = Annotated[str, Field(max_length=32), AfterValidator(check_tag)]


class JobCreate(BaseModel):
    # As the scene does: an unknown field (a typo such as "tilesize") is an error, not ignored.
    model_config = ConfigDict(extra="forbid")

    scene: dict[str, Any] = Field(description="a scene, format v1 (docs/scene-format.md)")
    name: str = Field(default="", max_length=200)
    tile_size: StrictInt | None = Field(
        default=None, ge=8, le=1024,
        description="tile edge in pixels (default 64, halved for a frame of fewer than 16 "
                    "tiles, down to 16)")
    spp_per_pass: StrictInt | None = Field(
        default=None, ge=1, le=65_536,
        description="samples per pixel of the first pass (default 8)")
    max_spp_per_pass: StrictInt | None = Field(
        default=None, ge=1, le=65_536,
        description="the largest pass: passes grow from spp_per_pass, each as many samples as "
                    "all before it, up to this (default 64; equal to spp_per_pass: equal passes)")
    priority: StrictInt = Field(default=0, ge=0, le=9, description="9 runs first")
    tags: list[Tag] = Field(default_factory=list, max_length=MAX_JOB_TAGS,
                            description="worker tags the job requires: only worker nodes with "
                                        "all of them (LUCENT_WORKER_TAGS) render it")
    frames: list[list[dict[str, Any]]] | None = Field(
        default=None, min_length=1, max_length=10_000,
        description="frame i is the scene with the i-th JSON Patch (RFC 6902) applied: a camera "
                    "path, a moving object, a sweep; every frame keeps the film size and spp")
    check_workers: StrictBool = Field(
        default=False, description="refuse the job (409) when no live worker has its tags; "
                                   "otherwise it waits for one")
    denoise: StrictBool = Field(
        default=False, description="once done, the image denoised with Intel Open Image Denoise "
                                   "(guided by albedo and normal AOVs); the undenoised image is "
                                   "image.exr's 'noisy' layer (docs/farm.md)")


class FramePublic(BaseModel):
    index: int
    progress: float = Field(description="samples merged / planned of this frame, 0–1")
    expected_error: float | None = Field(
        default=None, description="the frame's expected relMSE, its tiles' (each tile's "
                                  "expected_error over its pixels), once every tile has one, "
                                  "plus the job's expected_bias: with render.target_error, each "
                                  "frame is sampled to the target on its own")


class TilePublic(BaseModel):
    index: int
    frame: int = 0
    x0: int
    y0: int
    width: int
    height: int
    state: str
    samples: int = Field(description="samples per pixel merged")
    error: str | None = None
    expected_error: float | None = Field(
        default=None, description="the tile's expected relMSE from its merged samples (the mean "
                                  "of its pixels' error terms, docs/adaptive-sampling.md), once "
                                  "a merge has given its pixels 2 samples")


class JobPublic(BaseModel):
    id: str
    name: str
    status: JobStatus
    priority: int
    width: int
    height: int
    spp: int
    tile_size: int
    spp_per_pass: int
    max_spp_per_pass: int = Field(description="the largest pass allowed")
    passes: int = Field(description="passes per tile")
    pass_growth: int = Field(default=1, description="each pass after the first holds this many "
                             "times the samples before it, up to max_spp_per_pass")
    largest_pass: int = Field(description="samples of the job's largest pass (at most "
                                          "max_spp_per_pass)")
    tiles: int = Field(description="tiles of the whole job (tiles_per_frame x frames)")
    frames: int = 1
    tasks_total: int
    tasks_merged: int
    samples_planned: int
    samples_merged: int
    progress: float = Field(description="samples merged / samples planned, 0–1; for a running "
                                        "job with render.target_error, target / expected "
                                        "error (0 before every pixel has an estimate)")
    samples_per_second: float | None
    eta_seconds: float | None
    dropped_samples: int = Field(description="non-finite samples left out")
    created_at: float
    started_at: float | None
    finished_at: float | None
    error: str | None
    image_version: int = Field(description="merges so far: the preview's ETag")
    methods: dict[str, str] = Field(default_factory=dict,
                                    description="for translucent 'auto': the method chosen")
    submitter: str | None = Field(default=None, description="the name of the API token it was "
                                                            "submitted with (LUCENT_API_TOKENS)")
    tags: list[str] = Field(default_factory=list, description="worker tags it requires")
    denoise: bool = Field(default=False, description="its done image is denoised (the noisy "
                                                     "one kept as image.exr's noisy layer)")
    target_error: float | None = Field(
        default=None, description="the scene's render.target_error: the frame's expected relMSE "
                                  "asked for (docs/adaptive-sampling.md)")
    expected_error: float | None = Field(
        default=None, description="the frames' expected relMSE: the samples' noise estimated "
                                  "from the samples merged so far, once every pixel has 2, plus "
                                  "expected_bias (the quantity target_error bounds; any job has "
                                  "it)")
    expected_bias: float = Field(
        default=0.0, description="with render.target_error: the bias the models method auto "
                                 "chose may add to the frames' relMSE, at most (their measured "
                                 "error over their objects' pixels times the share of the frame "
                                 "those may cover); the samples' noise is aimed at the target "
                                 "less it (docs/adaptive-sampling.md)")
    waiting_for: str | None = Field(
        default=None, description="queued or running with no live worker that has its tags: "
                                  "'waiting for a worker with tags gpu'")


class JobDetail(JobPublic):
    frame_progress: list[FramePublic] = Field(default_factory=list)
    tile_states: list[TilePublic]
    errors: list[str]
    blocklist: dict[str, int] = Field(
        default_factory=dict, description="worker nodes that get none of this job's passes any "
                                          "more -> its passes that failed on each "
                                          "(LUCENT_BLOCKLIST_THRESHOLD)")


class JobsPublic(BaseModel):
    data: list[JobPublic]
    count: int
    offset: int
    limit: int


class WorkerPublic(BaseModel):
    id: str
    host: str | None = None
    pid: int | None = None
    state: str
    current_task: str | None = None
    tiles_done: int = 0
    paths_per_second: float = 0.0
    last_heartbeat: float | None = None
    node: str | None = Field(default=None, description="its Celery worker node (the blocklist's "
                                                       "unit)")
    tags: list[str] = Field(default_factory=list, description="its node's tags "
                                                              "(LUCENT_WORKER_TAGS)")
    version: str | None = Field(default=None, description="its Lucent release (None: a worker "
                                                          "from before workers said)")
    kernel: str | None = Field(default=None, description="the kernel it renders with "
                                                         "(LUCENT_WORKER_KERNEL; None: a worker "
                                                         "from before workers said)")
    protocol: int | None = Field(default=None, description=(
        "what its merge keeps: 2, a target job of frames' per-frame sums; 1, a worker from "
        "before; None once its heartbeat has expired (docs/farm.md, upgrading a farm)"))


class WorkersPublic(BaseModel):
    data: list[WorkerPublic]
    count: int
    server_time: float | None = Field(
        default=None, description="the service's clock: a heartbeat's age is server_time minus "
                                  "last_heartbeat, whatever the client's clock says")
    heartbeat_interval: float | None = Field(
        default=None, description="seconds between heartbeats; silent for 3 intervals = lost")
