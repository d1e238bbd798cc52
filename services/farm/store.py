"""The job store: what the farm has in flight lives in Redis, under ``{prefix}:`` keys (the jobs'
history, archived jobs included, is in SQL: ``services.farm.records``).

=================================  ======  =================================================
Key                                Type    What
=================================  ======  =================================================
``{p}:jobs``                       zset    job id -> submission time (the jobs in Redis)
``{p}:job:{id}``                   hash    the job: status, plan, counters, times, ``version``,
                                           ``active_at``, ``stalls`` (the stall re-queues)
``{p}:job:{id}:scene``             string  the scene JSON as submitted (workers re-fetch it)
``{p}:job:{id}:frames``            string  its frames' JSON Patches (a job of frames only)
``{p}:job:{id}:tile_state``        hash    tile -> queued / running (a pass renders) / converged
                                           (a target job's tile, nothing to add for now) / done /
                                           failed
``{p}:job:{id}:tile_samples``      hash    tile -> samples per pixel merged
``{p}:job:{id}:tile_error``        hash    tile -> the last error of a pass of that tile
``{p}:job:{id}:tile_err``          hash    tile -> its error summary (``tile_summary``)
``{p}:job:{id}:frame_sums``        hash    ``{sum}:{frame}`` -> a target job of frames' sums of
                                           each frame's tiles (``FRAME_SUMS``)
``{p}:job:{id}:attempts``          hash    ``tile:pass`` -> deliveries (the redelivery cap)
``{p}:job:{id}:merged``            set     ``tile:pass`` merged into the accumulation
``{p}:job:{id}:acc:{tile}``        string  the tile's accumulated ``SampleBuffer`` (``to_bytes``)
``{p}:job:{id}:pass:{tile}:{pass}`` string a rendered pass, deleted once merged
``{p}:job:{id}:failures``          hash    worker node -> passes of the job that failed on it
``{p}:job:{id}:blocklist``         set     nodes that get none of the job's passes any more
``{p}:pending``                    set     pass keys written and not merged (the sweeper's)
``{p}:finished``                   zset    job id -> finished time, for done/failed/cancelled
``{p}:to_archive``                 set     done jobs whose image is not in the blob store yet
``{p}:workers``                    zset    worker id -> last heartbeat time
``{p}:worker:{id}``                hash    the last heartbeat (expires after 3 intervals)
``{p}:holding``                    hash    worker id -> ``job tile pass attempt`` it renders
``{p}:metrics``                    hash    farm-wide counters for ``/metrics``
=================================  ======  =================================================

Memory is bounded by what is in flight: one accumulation per tile of each job not archived, plus
at most one pass buffer per task in flight. Once a job is done, the sweeper writes its image to the
blob store and its last state to its record (``services.farm.archive``), then deletes every key of
it (``delete_job``): a done job leaves Redis. Failed and cancelled jobs keep theirs (a retry goes
on from them) until they are deleted. ``version`` counts merges and is the preview image's ETag.
Hashes that a farm from before the job records archived keep ``images`` and ``tiles_final``: the
first sweep moves them to the records.
"""

from __future__ import annotations

import dataclasses
import json
import re
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import redis

from renderer.film.adaptive import PILOT, first_look_bound, tile_summary
from renderer.film.buffer import SampleBuffer
from services.farm.planner import Plan, frame_tiles_count

STATUSES = ("queued", "running", "done", "failed", "cancelled")
ACTIVE = ("queued", "running")
FINAL = ("done", "failed", "cancelled")

# Move a job to a new status only from one of the listed ones (atomically, in Redis); a final
# status lists the job in ``finished`` (retention's clock), a done one in ``to_archive`` too.
# KEYS[1] job hash, KEYS[2] finished zset, KEYS[3] to_archive set; ARGV[1] new status, ARGV[2]
# time, ARGV[3] time field or "", ARGV[4] error or "", ARGV[5] job id, ARGV[6..] from.
_TRANSITION = """
local status = redis.call('HGET', KEYS[1], 'status')
if not status then return 0 end
for i = 6, #ARGV do
  if status == ARGV[i] then
    redis.call('HSET', KEYS[1], 'status', ARGV[1])
    if ARGV[3] ~= '' then redis.call('HSET', KEYS[1], ARGV[3], ARGV[2]) end
    if ARGV[4] ~= '' then redis.call('HSET', KEYS[1], 'error', ARGV[4]) end
    redis.call('HINCRBY', KEYS[1], 'status_version', 1)
    if ARGV[1] == 'done' or ARGV[1] == 'failed' or ARGV[1] == 'cancelled' then
      redis.call('ZADD', KEYS[2], ARGV[2], ARGV[5])
    else
      redis.call('ZREM', KEYS[2], ARGV[5])
    end
    if ARGV[1] == 'done' then redis.call('SADD', KEYS[3], ARGV[5]) end
    return 1
  end
end
return 0
"""

# Delete a job whose status is one of those given. KEYS[1] job hash, KEYS[2] jobs, KEYS[3]
# finished, KEYS[4] to_archive, KEYS[5] pending, KEYS[6..] the job's other keys; ARGV[1] job id,
# ARGV[2..] the statuses it may have. Returns 1, or 0 (nothing deleted) when the job is gone or
# has another status.
_DELETE = """
local status = redis.call('HGET', KEYS[1], 'status')
local allowed = false
for i = 2, #ARGV do if status == ARGV[i] then allowed = true end end
if not allowed then return 0 end
redis.call('DEL', KEYS[1])
redis.call('ZREM', KEYS[2], ARGV[1])
redis.call('ZREM', KEYS[3], ARGV[1])
redis.call('SREM', KEYS[4], ARGV[1])
for i = 6, #KEYS do
  redis.call('DEL', KEYS[i])
  redis.call('SREM', KEYS[5], KEYS[i])
end
return 1
"""

# Claim a stall re-queue of a job (atomic, so that two sweepers never re-queue it twice).
# KEYS[1] job hash; ARGV[1] now, ARGV[2] stall timeout. A job is stalled when it is queued or
# running and nothing of it happened (a pass started or merged: ``active_at``; a re-queue:
# ``requeued_at``; its creation) for the timeout. The count of stalls in a row starts again once
# a pass of the job has started or merged since the last re-queue. Returns the count, or 0.
_CLAIM_STALL = """
local h = redis.call('HMGET', KEYS[1], 'status', 'created_at', 'active_at', 'requeued_at',
                     'stalls')
if h[1] ~= 'queued' and h[1] ~= 'running' then return 0 end
local active = tonumber(h[3]) or 0
local requeued = tonumber(h[4]) or 0
local since = math.max(tonumber(h[2]) or 0, active, requeued)
if tonumber(ARGV[1]) - since < tonumber(ARGV[2]) then return 0 end
local stalls = tonumber(h[5]) or 0
if active > requeued then stalls = 0 end
stalls = stalls + 1
redis.call('HSET', KEYS[1], 'stalls', stalls, 'requeued_at', ARGV[1])
return stalls
"""


# Count a delivery of a pass (KEYS[1] attempts hash, ARGV[1] tile:pass) and note the job alive
# (KEYS[2] job hash, ARGV[2] now). With a holder (ARGV[3], a worker id), record in the same step
# that it holds the pass (KEYS[3] the holding hash, value ``ARGV[4] attempt``), so that no worker
# can die holding a pass unseen. With a tile (ARGV[5]), the tile becomes running if it is queued
# (KEYS[4] the tile states): a done tile stays done when a late duplicate runs. ARGV[6]: 1 to
# count the delivery, 0 for the same delivery begun again. Returns the tries so far. (A Lua
# function the two scripts below begin with, on their KEYS and ARGV.)
_COUNT_ATTEMPT = """
local function count_attempt()
  local n = redis.call('HINCRBY', KEYS[1], ARGV[1], tonumber(ARGV[6]))
  redis.call('HSET', KEYS[2], 'active_at', ARGV[2])
  if ARGV[3] ~= '' then redis.call('HSET', KEYS[3], ARGV[3], ARGV[4] .. ' ' .. n) end
  if ARGV[5] ~= '' then
    local state = redis.call('HGET', KEYS[4], ARGV[5])
    if state == 'queued' or state == 'converged' then
      redis.call('HSET', KEYS[4], ARGV[5], 'running')
    end
  end
  return n
end
"""

# ``_COUNT_ATTEMPT`` unless the job's hash is gone: a deleted job is not brought back (0: the
# pass renders, and its merge drops it).
_ADD_ATTEMPT = _COUNT_ATTEMPT + """
if redis.call('EXISTS', KEYS[2]) == 0 then return 0 end
return count_attempt()
"""

# What a worker reads before it renders a pass, and the delivery counted when it will render, in
# one step: ``_COUNT_ATTEMPT`` (its KEYS and ARGV, with the tile) behind the checks of
# ``passes.begin_pass`` (KEYS[5] the job's blocklist, KEYS[6] its merged set; ARGV[7] the node,
# ARGV[8] the pass). Counted only for a queued or running job, a node not blocklisted, a pass
# not merged and in the plan: its tile has a state and its index is below tasks_total / tiles.
# Returns the job's hash (empty: no such job), blocked, merged, and the tries so far (-1: not
# counted).
_BEGIN_PASS = _COUNT_ATTEMPT + """
local h = redis.call('HGETALL', KEYS[2])
if #h == 0 then return {h, 0, 0, -1} end
local blocked = 0
if ARGV[7] ~= '' then blocked = redis.call('SISMEMBER', KEYS[5], ARGV[7]) end
local merged = redis.call('SISMEMBER', KEYS[6], ARGV[1])
local f = redis.call('HMGET', KEYS[2], 'status', 'tasks_total')
local tiles = redis.call('HLEN', KEYS[4])
if blocked == 1 or merged == 1 or (f[1] ~= 'queued' and f[1] ~= 'running') or tiles == 0
   or redis.call('HEXISTS', KEYS[4], ARGV[5]) == 0
   or tonumber(ARGV[8]) >= (tonumber(f[2]) or 0) / tiles then
  return {h, blocked, merged, -1}
end
return {h, blocked, merged, count_attempt()}
"""

# A converged tile of a job with a target error (KEYS[1] the merged set, KEYS[2] the job hash,
# KEYS[3] the tile states; ARGV[1] the tile, ARGV[2] its first pass to skip, ARGV[3] the passes
# of a tile): its passes from ARGV[2] on count as merged, empty, and the tile is done. Only for
# a queued or running job. Returns the passes newly counted.
_SKIP_PASSES = """
local status = redis.call('HGET', KEYS[2], 'status')
if status ~= 'queued' and status ~= 'running' then return 0 end
local n = 0
for p = tonumber(ARGV[2]), tonumber(ARGV[3]) - 1 do
  n = n + redis.call('SADD', KEYS[1], ARGV[1] .. ':' .. p)
end
if n > 0 then
  redis.call('HINCRBY', KEYS[2], 'tasks_merged', n)
  redis.call('HINCRBY', KEYS[2], 'version', 1)
end
redis.call('HSET', KEYS[3], ARGV[1], 'done')
return n
"""

# A converged tile of a job with a target error asked again (``services.farm.targets``): back to
# queued for its next pass, only while it is still converged and that pass still unmerged
# (KEYS[1] the tile states, KEYS[2] the merged set; ARGV[1] the tile, ARGV[2] the pass's
# member): 1 if so, and its caller sends the pass; 0 if another caller has it or a merge moved
# the tile on since the rule read it. A tile marked queued for a pass that had merged meanwhile
# waited with nothing in flight: the pass was dropped as a duplicate, and nothing sent the next.
_REQUEUE_CONVERGED = """
if redis.call('HGET', KEYS[1], ARGV[1]) ~= 'converged' then return 0 end
if redis.call('SISMEMBER', KEYS[2], ARGV[2]) == 1 then return 0 end
redis.call('HSET', KEYS[1], ARGV[1], 'queued')
return 1
"""

# A target job of frames pools its frames' sums from now on (KEYS[1] the job hash, KEYS[2] its
# frames' sums): 1 if it kept them until now, else 0 (``JobStore.pool_frame_sums``)
_POOL_FRAME_SUMS = """
if redis.call('HGET', KEYS[1], 'frame_sums') ~= '1' then return 0 end
redis.call('HSET', KEYS[1], 'frame_sums', '')
redis.call('DEL', KEYS[2])
return 1
"""

# What a merge reads, under its WATCH, in one round trip (KEYS: the merged set, the pass buffer,
# the job hash, the tile's accumulation, tile_samples, tile_state, tile_err, the pending set;
# ARGV: the pass's member of the merged set, the tile, '1' when the caller has the pass's bytes,
# and to store them first as ``put_pass`` does, their time to live in ms and the bytes, else
# ''): whether the pass is merged, the pass buffer (or only whether it exists: 1 or 0), the
# job's status, spp, tasks_total and frame size (width, height, frames), the accumulation, and
# the tile's samples, state and error summary. The buffer is stored only for a pass not merged
# of a job not done: for the sweeper, should this process die before its EXEC.
_MERGE_READ = """
local merged = redis.call('SISMEMBER', KEYS[1], ARGV[1])
local job = redis.call('HMGET', KEYS[3], 'status', 'spp', 'tasks_total', 'width', 'height',
                      'frames', 'tile_size', 'frame_sums')
if ARGV[4] ~= '' and merged == 0 and job[1] and job[1] ~= 'done' then
  redis.call('SET', KEYS[2], ARGV[5], 'PX', ARGV[4])
  redis.call('SADD', KEYS[8], KEYS[2])
end
local pass
if ARGV[3] == '1' then
  pass = redis.call('EXISTS', KEYS[2])
else
  pass = redis.call('GET', KEYS[2])
end
return {merged, pass, job, redis.call('GET', KEYS[4]), redis.call('HGET', KEYS[5], ARGV[2]),
        redis.call('HGET', KEYS[6], ARGV[2]), redis.call('HGET', KEYS[7], ARGV[2])}
"""

# Take a lost worker's holding (KEYS[1] the holding hash, ARGV[1] worker id, ARGV[2] the value
# read) if it is still that one: of several sweepers, one re-queues the pass.
_CLAIM_HOLDING = """
if redis.call('HGET', KEYS[1], ARGV[1]) == ARGV[2] then
  return redis.call('HDEL', KEYS[1], ARGV[1])
end
return 0
"""


# Count a failed pass of a job on a worker node (KEYS[1] failures hash, KEYS[2] blocklist set,
# ARGV[1] node, ARGV[2] threshold); at the threshold the node joins the job's blocklist. Returns
# the node's failures.
_NOTE_FAILURE = """
local n = redis.call('HINCRBY', KEYS[1], ARGV[1], 1)
if n >= tonumber(ARGV[2]) then redis.call('SADD', KEYS[2], ARGV[1]) end
return n
"""


def _plan_fields(plan: Plan) -> dict[str, Any]:
    """A job's plan as its hash holds it (``JobMeta.from_hash`` reads it back), for a job
    stored new (``create_job``) and one restored from its snapshot (``restore_job``)."""
    return {"width": plan.width, "height": plan.height, "spp": plan.spp,
            "tile_size": plan.tile_size, "spp_per_pass": plan.spp_per_pass,
            "max_spp_per_pass": plan.max_spp_per_pass, "pass_growth": plan.pass_growth,
            "frames": plan.frames, "tasks_total": plan.n_tasks}


# The job-hash fields that sum its tiles' error summaries, in the order of
# ``renderer.film.adaptive.tile_summary``'s tuple, and a summary as its ``tile_err`` entry
ERROR_SUMS = ("err_sum", "weight_sum", "err_pixels", "err_sq_sum")
# The job-hash fields that sum its tiles' first looks, each tile's once, at the merge of its first
# pass (``JobMeta.first_look_bound``): Σ e_p and Σ e_p² of that pass's error terms and the tile's
# pixels
LOOK_SUMS = ("look_sum", "look_sq_sum", "look_pixels")
# ... and their pilots, each tile's once, at the merge that gives its every pixel the pilot's
# samples (``renderer.film.adaptive.PILOT``, at most render.spp; ``JobMeta.pilot_error``): Σ e_p
# of the tile's error terms then and its pixels
PILOT_SUMS = ("pilot_sum", "pilot_pixels")
# What this code's merge keeps, which each worker's heartbeat gives as ``protocol`` (a worker
# from before gives none: 1): 2, a target job of frames' per-frame sums (``FRAME_SUMS``). A farm
# upgraded worker by worker has old workers merging beside new ones; a job is stored with
# per-frame sums only when every live worker's merge keeps them (``services.farm.pools.
# merge_protocol``), else it pools its frames' sums as every worker's merge can
MERGE_PROTOCOL = 2
FRAME_SUMS_PROTOCOL = 2
# A target job of frames keeps each of these sums for each frame too, as "{name}:{frame}" in its
# ``frame_sums`` hash (its job hash's ``frame_sums`` set; ``JobStore.frame_meta``): each frame
# is sampled to the target on its own, as its own render would be, not on the frames' mean error
# (the Cornell box and the glass sphere as the frames of one job, pooled, ended at 0.10-0.29x
# and 1.06-1.44x the target: python -m bench.target_error --farm-frames). Not in the job hash,
# which every pass reads whole: a job may have 10 000 frames.
FRAME_SUMS = (*ERROR_SUMS, *LOOK_SUMS, *PILOT_SUMS)


def frame_field(name: str, frame: int) -> str:
    """The job-hash field of one frame's ``name`` (one of ``FRAME_SUMS``)."""
    return f"{name}:{frame}"


def _summary_text(summary: tuple[float, float, int, float]) -> str:
    return " ".join(repr(float(x)) for x in summary)


def _summary_values(text: str | None) -> list[float]:
    """A tile's stored summary as numbers (zeros for none). A summary of three numbers is the
    previous rule's, without the squares of the error terms (a worker from before the pilot's
    first look merged it into a job that is still running): their sum is taken as 0, which
    only the first look's bound reads, and such a tile is past its first look. (The rule before
    that, whose summaries were four other numbers, Σ e with a small-sample correction, Σ √v,
    Σ v^¼ and pixels, is no longer read: a job running since then is read as this rule's.)"""
    if not text:
        return [0.0] * len(ERROR_SUMS)
    values = [float(x) for x in text.split()]
    if len(values) == 3:
        return [*values, 0.0]
    return values


def _estimates(summaries: dict) -> dict[int, float]:
    """``JobStore.tile_estimates`` from the ``tile_err`` hash as read."""
    out = {}
    for tile, text in summaries.items():
        err_sum, _, pixels, _ = _summary_values(_s(text))
        if pixels > 0:
            out[int(tile)] = err_sum / pixels
    return out


# ``merge_pass_buffer``'s answer when its merge counted the job's last task
MERGED_LAST = 2
# ... a flag added to it (1 | FRAME_LOOKED, MERGED_LAST | FRAME_LOOKED) when its merge completed
# the frames' first look or their pilot (the job's ``LOOK_SUMS`` or ``PILOT_SUMS`` then hold
# every tile's): the tiles that stopped before it, on their own, are to be asked again on the
# frames' (``services.farm.targets.wake_converged``)
FRAME_LOOKED = 4

# A job id as ``submit_job`` makes it (``uuid4().hex``). The API refuses any other form before it
# becomes part of a key: ``<id>:scene`` would otherwise name the job's other keys.
JOB_ID = re.compile(r"[0-9a-f]{32}")


def is_job_id(text: str) -> bool:
    return JOB_ID.fullmatch(text) is not None


def _s(value: bytes | str | None) -> str | None:
    return value.decode() if isinstance(value, bytes) else value


def pass_member(tile: int, pass_index: int) -> str:
    return f"{tile}:{pass_index}"


def _unmerged(pairs: list[tuple[int, int]], merged: Iterable[Any]) -> list[tuple[int, int]]:
    """Of ``pairs``, those whose flag in ``merged`` (one a pair, in order) is false."""
    return [pair for pair, flag in zip(pairs, merged, strict=True) if not flag]


def _states(read: Iterable[tuple[int, bytes | None]]) -> dict[int, str]:
    """Tile states as Redis gave them, ``(tile, value)``: those that have one."""
    return {t: v.decode() for t, v in read if v is not None}


@dataclass
class JobMeta:
    """A job's hash, typed."""

    id: str
    name: str
    status: str
    priority: int
    plan: Plan
    tasks_merged: int
    samples_merged: int
    dropped: int
    version: int
    created_at: float
    started_at: float | None
    finished_at: float | None
    error: str | None
    methods: dict[str, str]
    images: dict[str, str]  # format -> blob key, once the image is in the blob store
    tiles_final: dict[str, Any]  # {"samples": [per tile], "errors": {tile: error}}, archived
    submitter: str | None = None  # the name of the API token it was submitted with
    image_removed: bool = False  # its image removed by the cap on stored images (a record's)
    parked: str | None = None  # a record's: the blob of a failed or cancelled job's tiles
    tags: tuple[str, ...] = ()  # the worker tags it requires (services.farm.pools)
    denoise: bool = False  # its done image denoised (services.farm.archive.frame_exr)
    # a record's (services.farm.records): the frames' expected relMSE its row keeps, which
    # ``expected_error`` gives where the meta holds no sums (a job out of Redis)
    recorded_error: float | None = None
    # render.target_error, and the sums of its tiles' summaries (renderer.film.adaptive
    # tile_summary, kept by every merge): a target job's scale, and every job's expected error
    target_error: float | None = None
    # the bias auto's models may add to the frames' relMSE (renderer.materials.auto.frame_bias,
    # the largest over the frames): the target less it is the samples' noise's share
    expected_bias: float = 0.0
    err_sum: float = 0.0
    weight_sum: float = 0.0
    err_pixels: int = 0
    err_sq_sum: float = 0.0
    # the sums of its tiles' first looks (LOOK_SUMS), added once a tile at its first merge
    look_sum: float = 0.0
    look_sq_sum: float = 0.0
    look_pixels: int = 0
    # the sums of its tiles' pilots (PILOT_SUMS), added once a tile at the merge that ends it
    pilot_sum: float = 0.0
    pilot_pixels: int = 0
    # a target job of frames stored since each frame keeps its own sums (FRAME_SUMS; one stored
    # before pools its frames'), and those of them read ("{name}:{frame}": value; what
    # JobStore.frame_meta reads of one frame, a snapshot of all)
    frame_sums: bool = False
    frame_fields: dict[str, float] = field(default_factory=dict)
    # the frame whose sums the sum fields above hold (``for_frame``); None: all its frames'
    sums_frame: int | None = None

    @property
    def frame_pixels(self) -> int:
        """The pixels the error, first-look and pilot sums must each count before the estimate
        from them is known: one frame's (``for_frame``), else all its frames'."""
        frames = 1 if self.sums_frame is not None else self.plan.frames
        return self.plan.width * self.plan.height * frames

    def for_frame(self, frame: int) -> JobMeta:
        """The job as the rule of a tile of ``frame`` sees it: that frame's sums (of
        ``frame_fields``: ``JobStore.frame_meta`` reads them) in place of the job's, each frame
        sampled to the target on its own (``FRAME_SUMS``); or the job itself where its frames
        pool theirs (one frame, no target, or stored before frames kept their own)."""
        if self.plan.frames == 1 or not self.frame_sums:
            return self
        values: dict[str, Any] = {}
        for name in FRAME_SUMS:
            value = self.frame_fields.get(frame_field(name, frame), 0.0)
            values[name] = int(value) if name.endswith("_pixels") else value
        return dataclasses.replace(self, sums_frame=frame, **values)

    def _all_counted(self, counted: int) -> bool:
        """Whether sums over ``counted`` pixels hold every pixel of the frames (none: never)."""
        pixels = self.frame_pixels
        return pixels > 0 and counted >= pixels

    @property
    def expected_error(self) -> float | None:
        """The frames' expected relMSE from their merged samples' noise (with ``expected_bias``
        the quantity target_error bounds; every job's merges keep it), once every pixel has an
        estimate (2 samples); else None. A record's meta, which holds no sums, gives the error its
        row keeps (``recorded_error``)."""
        if not self._all_counted(self.err_pixels):
            return self.recorded_error
        return self.err_sum / self.err_pixels

    @property
    def first_look_bound(self) -> float | None:
        """The frames' first-look bound (``renderer.film.adaptive.first_look_bound``: the
        estimated error plus a multiple of its standard error over the pixels) on their first
        looks, each tile's first merged pass (``LOOK_SUMS``), once every tile has merged one;
        else None. The local loop's verdict on the frame at ``FIRST_LOOK`` samples a pixel,
        whatever the tiles have merged since: on the job's sums now, tiles that went on would
        lower the estimate below what the frame's first look showed, and a tile stopped at its
        first look on its own bound, whose few samples had not yet met the rare bright paths
        around it, would stay stopped (tests/farm/test_farm_state.py)."""
        if not self._all_counted(self.look_pixels):
            return None
        return first_look_bound(self.look_sum, self.look_sq_sum, self.look_pixels)

    @property
    def pilot_error(self) -> float | None:
        """The frames' estimated error at the end of the pilot (``PILOT_SUMS``: every tile's
        terms as they were at the merge that gave its pixels the pilot's samples), once every
        tile has ended its pilot; else None. The local loop's estimate of the frame at
        ``PILOT`` samples a pixel, on which it stops or takes its first, even, round
        (``renderer.film.adaptive.pass_counts``), whatever the tiles have merged since: the
        job's running estimate falls as the first tiles take that round, and the caustic
        floor's tiles that ended their pilot later stopped on it at 8 samples a pixel, their
        rare bright paths unmet (a job at 1.97x the target 0.1, its estimate 0.0836 where its
        tiles' pilots had estimated 0.159)."""
        if not self._all_counted(self.pilot_pixels):
            return None
        return self.pilot_sum / self.pilot_pixels

    @classmethod
    def new(cls, job_id: str, name: str, priority: int, plan: Plan, methods: dict[str, str],
            created_at: float, submitter: str | None = None,
            tags: tuple[str, ...] = (), denoise: bool = False,
            target_error: float | None = None, expected_bias: float = 0.0) -> JobMeta:
        """A job just submitted: queued, nothing merged (what ``create_job`` stores)."""
        return cls(id=job_id, name=name, status="queued", priority=priority, plan=plan,
                   tasks_merged=0, samples_merged=0, dropped=0, version=0,
                   created_at=created_at, started_at=None, finished_at=None, error=None,
                   methods=methods, images={}, tiles_final={}, submitter=submitter, tags=tags,
                   denoise=denoise, target_error=target_error, expected_bias=expected_bias)

    @property
    def samples_planned(self) -> int:
        return self.plan.width * self.plan.height * self.plan.spp * self.plan.frames

    @classmethod
    def from_hash(cls, h: dict[bytes, bytes]) -> JobMeta:
        d = {k.decode(): v.decode() for k, v in h.items()}

        def opt_float(name: str) -> float | None:
            return float(d[name]) if d.get(name) else None

        return cls(
            id=d["id"],
            name=d.get("name", ""),
            status=d["status"],
            priority=int(d.get("priority", 0)),
            # max_spp_per_pass: absent in jobs stored before passes grew (equal passes);
            # pass_growth: before it was a field (1)
            plan=Plan(int(d["width"]), int(d["height"]), int(d["spp"]), int(d["tile_size"]),
                      int(d["spp_per_pass"]), int(d.get("max_spp_per_pass", 0)),
                      int(d.get("frames", 1)), int(d.get("pass_growth", 1))),
            tasks_merged=int(d.get("tasks_merged", 0)),
            samples_merged=int(d.get("samples_merged", 0)),
            dropped=int(d.get("dropped", 0)),
            version=int(d.get("version", 0)),
            created_at=float(d["created_at"]),
            started_at=opt_float("started_at"),
            finished_at=opt_float("finished_at"),
            error=d.get("error") or None,
            methods=json.loads(d.get("methods") or "{}"),
            images=json.loads(d.get("images") or "{}"),
            tiles_final=json.loads(d.get("tiles_final") or "{}"),
            submitter=d.get("submitter") or None,
            tags=tuple(t for t in d.get("tags", "").split(",") if t),
            denoise=d.get("denoise") == "1",
            target_error=opt_float("target_error"),
            expected_bias=float(d.get("expected_bias") or 0.0),
            err_sum=float(d.get("err_sum") or 0.0),
            weight_sum=float(d.get("weight_sum") or 0.0),
            err_pixels=int(float(d.get("err_pixels") or 0)),
            err_sq_sum=float(d.get("err_sq_sum") or 0.0),
            look_sum=float(d.get("look_sum") or 0.0),
            look_sq_sum=float(d.get("look_sq_sum") or 0.0),
            look_pixels=int(float(d.get("look_pixels") or 0)),
            pilot_sum=float(d.get("pilot_sum") or 0.0),
            pilot_pixels=int(float(d.get("pilot_pixels") or 0)),
            frame_sums=d.get("frame_sums") == "1",
        )


@dataclass(frozen=True)
class JobSnapshot:
    """A job as Redis holds it at one instant (``JobStore.snapshot``)."""

    meta: JobMeta
    scene_json: bytes
    tile_states: dict[int, str]
    tile_samples: dict[int, int]
    tile_errors: dict[int, str]
    merged: list[str]  # ``tile:pass``
    tile_buffers: list[bytes | None]  # by tile; None before its first merge
    frames_json: bytes | None = None  # a job of frames: their patches

    def to_bytes(self) -> bytes:
        """The snapshot as one blob: a JSON line (the job, its scene, its tiles), then the
        tiles' buffers one after the other."""
        m = self.meta
        head = {"meta": {**{k: getattr(m, k) for k in (
                    "id", "name", "status", "priority", "tasks_merged", "samples_merged",
                    "dropped", "version", "created_at", "started_at", "finished_at", "error",
                    "methods", "submitter", "tags", "denoise", "target_error",
                    "expected_bias", *LOOK_SUMS, *PILOT_SUMS, "frame_sums")},
                    # (a job of frames' own look and pilot sums; its error sums are computed
                    # again from the buffers, as the job's)
                    "frame_fields": {k: v for k, v in m.frame_fields.items()
                                     if k.partition(":")[0] in (*LOOK_SUMS, *PILOT_SUMS)},
                    "plan": [m.plan.width, m.plan.height, m.plan.spp, m.plan.tile_size,
                             m.plan.spp_per_pass, m.plan.max_spp_per_pass, m.plan.frames,
                             m.plan.pass_growth]},
                "scene": self.scene_json.decode(),
                "frames": self.frames_json.decode() if self.frames_json else None,
                "tile_states": self.tile_states, "tile_samples": self.tile_samples,
                "tile_errors": self.tile_errors, "merged": self.merged,
                "buffers": [-1 if b is None else len(b) for b in self.tile_buffers]}
        return json.dumps(head).encode() + b"\n" + b"".join(
            b for b in self.tile_buffers if b is not None)

    @classmethod
    def from_bytes(cls, data: bytes) -> JobSnapshot:
        line, _, rest = data.partition(b"\n")
        head = json.loads(line)
        d = head["meta"]
        d["tags"] = tuple(d.get("tags", ()))
        meta = JobMeta(plan=Plan(*d.pop("plan")), images={}, tiles_final={}, **d)
        buffers: list[bytes | None] = []
        pos = 0
        for n in head["buffers"]:
            buffers.append(None if n < 0 else rest[pos:pos + n])
            pos += max(n, 0)
        return cls(meta, head["scene"].encode(),
                   {int(k): v for k, v in head["tile_states"].items()},
                   {int(k): v for k, v in head["tile_samples"].items()},
                   {int(k): v for k, v in head["tile_errors"].items()}, head["merged"], buffers,
                   head["frames"].encode() if head.get("frames") else None)


class JobStore:
    """Typed access to the keys above. Thread-safe (redis-py clients are)."""

    def __init__(self, client: redis.Redis, prefix: str = "lucent"):
        # redis-py types every reply as bytes | str, whatever decode_responses says; this
        # client has it off, so replies are bytes (and the store decodes them)
        self.r: Any = client
        self.prefix = prefix
        self._transition = client.register_script(_TRANSITION)
        self._claim_stall = client.register_script(_CLAIM_STALL)
        self._add_attempt = client.register_script(_ADD_ATTEMPT)
        self._begin_pass = client.register_script(_BEGIN_PASS)
        self._skip_passes = client.register_script(_SKIP_PASSES)
        self._requeue_converged = client.register_script(_REQUEUE_CONVERGED)
        self._pool_frame_sums = client.register_script(_POOL_FRAME_SUMS)
        self._claim_holding = client.register_script(_CLAIM_HOLDING)
        self._delete = client.register_script(_DELETE)
        self._note_failure = client.register_script(_NOTE_FAILURE)

    @classmethod
    def from_url(cls, url: str, prefix: str = "lucent") -> JobStore:
        return cls(redis.Redis.from_url(url, health_check_interval=30), prefix)

    # --- keys -----------------------------------------------------------------------------------
    def k(self, *parts: object) -> str:
        return ":".join([self.prefix, *map(str, parts)])

    def job_key(self, job_id: str) -> str:
        return self.k("job", job_id)

    def acc_key(self, job_id: str, tile: int) -> str:
        return self.k("job", job_id, "acc", tile)

    def pass_key(self, job_id: str, tile: int, pass_index: int) -> str:
        return self.k("job", job_id, "pass", tile, pass_index)

    def tile_keys(self, job_id: str, n_tiles: int) -> list[str]:
        """The job's keys that hold its tiles: what archiving deletes."""
        return [self.k("job", job_id, name)
                for name in ("tile_state", "tile_samples", "tile_error", "tile_err", "attempts",
                             "merged", "failures", "blocklist", "frame_sums")] + \
            [self.acc_key(job_id, t) for t in range(n_tiles)]

    def pending_passes_of(self, job_id: str) -> list[str]:
        """Pass buffers of the job written and not merged (a late duplicate, a cancelled job's)."""
        head = self.k("job", job_id, "pass") + ":"
        return [k for k in self.pending_passes() if k.startswith(head)]

    # --- jobs -----------------------------------------------------------------------------------
    def create_job(self, job_id: str, name: str, priority: int, plan: Plan,
                   scene_json: str | bytes, methods: dict[str, str] | None = None,
                   created_at: float | None = None, submitter: str | None = None,
                   tags: tuple[str, ...] = (), frames_json: bytes | None = None,
                   target_error: float | None = None, denoise: bool = False,
                   expected_bias: float = 0.0, frame_sums: bool = True) -> JobMeta:
        """Store a job, queued; ``frames_json``: the patches of a job of ``plan.frames``
        frames; ``target_error``: the scene's ``render.target_error`` (its merges then keep the
        tiles' error summaries), ``expected_bias`` the share of it auto's models may take;
        ``frame_sums``: a target job of frames keeps each frame's sums (``FRAME_SUMS``; False
        where a live worker's merge would not keep them, ``FRAME_SUMS_PROTOCOL``)."""
        now = time.time() if created_at is None else created_at
        fields: dict[str, Any] = {
            "id": job_id, "name": name, "status": "queued", "priority": priority,
            **_plan_fields(plan), "tasks_merged": 0, "samples_merged": 0, "dropped": 0,
            "version": 0, "status_version": 0, "created_at": now, "started_at": "",
            "finished_at": "", "error": "", "methods": json.dumps(methods or {}),
            "submitter": submitter or "", "tags": ",".join(tags),
            "target_error": "" if target_error is None else target_error,
            "expected_bias": expected_bias,
            "denoise": "1" if denoise else "",
            # (a target job of frames: each frame's own sums, FRAME_SUMS)
            "frame_sums": ("1" if frame_sums and plan.frames > 1 and target_error is not None
                           else ""),
        }
        pipe = self.r.pipeline()
        pipe.hset(self.job_key(job_id), mapping=fields)
        pipe.set(self.k("job", job_id, "scene"), scene_json)
        if frames_json is not None:
            pipe.set(self.k("job", job_id, "frames"), frames_json)
        pipe.hset(self.k("job", job_id, "tile_state"),
                  mapping={str(t): "queued" for t in range(plan.n_tiles)})
        pipe.zadd(self.k("jobs"), {job_id: now})
        pipe.execute()
        meta = self.get_job(job_id)
        assert meta is not None
        return meta

    def get_job(self, job_id: str) -> JobMeta | None:
        h = self.r.hgetall(self.job_key(job_id))
        return JobMeta.from_hash(h) if h else None

    def pool_frame_sums(self, job_id: str) -> bool:
        """A target job of frames that kept each frame's sums pools them from now on (its job
        hash's ``frame_sums`` cleared, their hash deleted): a worker whose merge does not keep
        them takes its passes (``services.farm.queue.pool_frames_beside_old_workers``). A merge
        under way that read the mark before may still add its change to the frames' hash:
        nothing reads it any more, and it is deleted with the job (``tile_keys``). True if this
        call changed the mark."""
        return bool(self._pool_frame_sums(
            keys=[self.job_key(job_id), self.k("job", job_id, "frame_sums")]))

    def frame_meta(self, meta: JobMeta, frame: int) -> JobMeta:
        """``meta`` as the rule of a tile of ``frame`` sees it (``JobMeta.for_frame``), that
        frame's sums read from the job's ``frame_sums`` hash (one round trip, where the job keeps
        them: a target job of frames; none where ``meta`` holds that frame's already)."""
        if meta.plan.frames == 1 or not meta.frame_sums or meta.sums_frame == frame:
            return meta
        names = [frame_field(name, frame) for name in FRAME_SUMS]
        values = self.r.hmget(self.k("job", meta.id, "frame_sums"), names)
        read = {n: float(v) for n, v in zip(names, values, strict=True) if v}
        return dataclasses.replace(meta, frame_fields=read).for_frame(frame)

    def get_status(self, job_id: str) -> str | None:
        return _s(self.r.hget(self.job_key(job_id), "status"))

    def get_scene(self, job_id: str) -> dict | None:
        raw = self.r.get(self.k("job", job_id, "scene"))
        return json.loads(raw) if raw is not None else None

    def get_frames(self, job_id: str) -> list | None:
        """The patches of a job of frames (one a frame), None for a job of one frame."""
        raw = self.r.get(self.k("job", job_id, "frames"))
        return json.loads(raw) if raw is not None else None

    def get_jobs(self, job_ids: list[str]) -> dict[str, JobMeta]:
        """Those of the jobs that Redis holds, by id (one round trip)."""
        pipe = self.r.pipeline()
        for job_id in job_ids:
            pipe.hgetall(self.job_key(job_id))
        return {j: JobMeta.from_hash(h)
                for j, h in zip(job_ids, pipe.execute(), strict=True) if h}

    def jobs_in_flight(self) -> list[JobMeta]:
        """Every job Redis holds: queued, running, done and not archived yet, failed or
        cancelled (kept for a retry until deleted). Archived jobs are in the job records only."""
        return list(self.get_jobs([i.decode() for i in self.r.zrange(self.k("jobs"), 0, -1)])
                    .values())

    def active_samples_left(self) -> list[int]:
        """Pixel-samples that each queued or running job has still to render."""
        pipe = self.r.pipeline()
        for job_id in self.active_job_ids():
            pipe.hmget(self.job_key(job_id), "width", "height", "spp", "samples_merged", "frames")
        return [max(int(w) * int(h) * int(spp) * int(frames or 1) - int(merged or 0), 0)
                for w, h, spp, merged, frames in pipe.execute() if w is not None]

    def active_job_ids(self) -> list[str]:
        ids = [i.decode() for i in self.r.zrange(self.k("jobs"), 0, -1)]
        pipe = self.r.pipeline()
        for job_id in ids:
            pipe.hget(self.job_key(job_id), "status")
        return [j for j, s in zip(ids, pipe.execute(), strict=True) if _s(s) in ACTIVE]

    def transition(self, job_id: str, to: str, from_: tuple[str, ...],
                   time_field: str = "", error: str = "") -> bool:
        """Set the status to ``to`` if it is one of ``from_`` (atomic, with the time field and
        the error when given, so no reader sees the new status without them); True if it
        changed."""
        return bool(self._transition(
            keys=[self.job_key(job_id), self.k("finished"), self.k("to_archive")],
            args=[to, time.time(), time_field, error, job_id, *from_]))

    def mark_started(self, job_id: str) -> None:
        self.transition(job_id, "running", ("queued",), "started_at")

    def fail_job(self, job_id: str, reason: str) -> bool:
        return self.transition(job_id, "failed", ACTIVE, "finished_at", error=reason)

    def cancel_job(self, job_id: str) -> bool:
        return self.transition(job_id, "cancelled", ACTIVE, "finished_at")

    def finish_if_complete(self, job_id: str) -> bool:
        """Once every task has been merged, mark the job done; or failed, with the reason, when
        every sample of it was dropped as non-finite (its image would be black, and "done"
        would hide why). True if the status changed."""
        h = self.r.hmget(self.job_key(job_id), "tasks_merged", "tasks_total", "samples_merged",
                         "dropped")
        if h[0] is None or int(h[0]) < int(h[1]):
            return False
        dropped = int(h[3] or 0)
        if dropped and not int(h[2] or 0):
            return self.fail_job(job_id, f"every sample ({dropped}) was dropped: its radiance "
                                 "was not a finite number (NaN or infinite). The scene's numbers "
                                 "overflow where the renderer computes with them: scale down "
                                 "those near the largest float, 1.8e308 (background, emission, "
                                 "lights)")
        return self.transition(job_id, "done", ACTIVE, "finished_at")

    def unmerged(self, job_id: str, plan: Plan,
                 frame: int | None = None) -> list[tuple[int, int]]:
        """The job's (tile, pass) pairs not merged yet, in the plan's order; ``frame``: of that
        frame only, asked of Redis pair by pair (``SMISMEMBER``) rather than by reading the
        job's whole merged set."""
        if frame is not None:
            pairs = plan.frame_order(frame)
            if not pairs:
                return []
            return _unmerged(pairs, self.r.smismember(self.k("job", job_id, "merged"),
                                                      [pass_member(t, p) for t, p in pairs]))
        members = {m.decode() for m in self.r.smembers(self.k("job", job_id, "merged"))}
        pairs = plan.order()
        return _unmerged(pairs, (pass_member(t, p) in members for t, p in pairs))

    def chain_view(self, job_id: str, plan: Plan, frame: int | None = None
                   ) -> tuple[list[tuple[int, int]], dict[int, str]]:
        """``unmerged`` and ``tile_states`` (``frame``: that frame's pairs and tiles) read in one
        MULTI/EXEC, so that they agree: a tile's state and its next pass as of one moment.
        Read apart, a tile that merged a pass and converged between the two reads showed as
        converged at the pass it had just merged (``services.farm.targets``)."""
        pipe = self.r.pipeline(transaction=True)
        merged_key = self.k("job", job_id, "merged")
        state_key = self.k("job", job_id, "tile_state")
        if frame is not None:
            pairs = plan.frame_order(frame)
            tiles = list(plan.frame_tiles(frame))
            if not pairs:  # (a plan of no passes: SMISMEMBER takes at least one member)
                return [], self.tile_states(job_id, tiles)
            pipe.smismember(merged_key, [pass_member(t, p) for t, p in pairs])
            pipe.hmget(state_key, [str(t) for t in tiles])
            flags, values = pipe.execute()
            return _unmerged(pairs, flags), _states(zip(tiles, values, strict=True))
        pipe.smembers(merged_key)
        pipe.hgetall(state_key)
        members, states = pipe.execute()
        done = {m.decode() for m in members}
        pairs = plan.order()
        return (_unmerged(pairs, (pass_member(t, p) in done for t, p in pairs)),
                _states((int(k), v) for k, v in states.items()))

    def requeue_converged(self, job_id: str, tile: int, pass_index: int) -> bool:
        """A converged tile back to queued for its next pass ``pass_index``, in one step and only
        while it is still converged and that pass unmerged: True if so (the caller sends the
        pass), False if another caller has requeued it or a merge has moved it on since."""
        return bool(self._requeue_converged(
            keys=[self.k("job", job_id, "tile_state"), self.k("job", job_id, "merged")],
            args=[str(tile), pass_member(tile, pass_index)]))

    def reopen_job(self, job_id: str) -> list[tuple[int, int]]:
        """For a retry: the job back to running, attempts, tile errors and stalls cleared;
        returns the (tile, pass) pairs not merged yet, which the caller enqueues again."""
        meta = self.get_job(job_id)
        if meta is None:
            return []
        todo = self.unmerged(job_id, meta.plan)
        states = self.tile_states(job_id)
        pipe = self.r.pipeline()
        pipe.delete(self.k("job", job_id, "attempts"), self.k("job", job_id, "tile_error"))
        for t in {t for t, _ in todo}:
            if states.get(t) != "done":
                pipe.hset(self.k("job", job_id, "tile_state"), str(t), "queued")
        pipe.hset(self.job_key(job_id), mapping={"error": "", "finished_at": "", "stalls": 0,
                                                 "active_at": time.time()})
        pipe.execute()
        self.transition(job_id, "running", ("failed", "cancelled"))
        return todo

    def stall_clock(self, job_id: str) -> tuple[int, float, tuple[str, ...]] | None:
        """(priority, when anything of the job last happened, its tags) for a queued or running
        job, else None: the stall rule's inputs."""
        h = self.r.hmget(self.job_key(job_id), "status", "priority", "tags", "created_at",
                         "active_at", "requeued_at")
        if h[0] is None or h[0].decode() not in ACTIVE:
            return None
        tags = tuple(t for t in (h[2] or b"").decode().split(",") if t)
        return int(h[1] or 0), max(float(v) for v in h[3:] if v), tags

    def claim_stall(self, job_id: str, stall_timeout: float, now: float | None = None) -> int:
        """If the job is queued or running and nothing of it happened for ``stall_timeout``
        seconds, record a stall re-queue now and return how many stalls in a row this makes
        (no pass started or merged in between); else 0. Atomic: of several sweepers that see
        the same stall, one claims it."""
        now = time.time() if now is None else now
        return int(self._claim_stall(keys=[self.job_key(job_id)], args=[now, stall_timeout]))

    # --- finished jobs --------------------------------------------------------------------------
    def jobs_to_archive(self) -> list[str]:
        """Done jobs whose image is not in the blob store yet."""
        return [i.decode() for i in self.r.smembers(self.k("to_archive"))]

    def finished_in_redis(self, before: float, limit: int = 100) -> list[str]:
        """Up to ``limit`` jobs Redis holds that finished (done, failed, cancelled) before
        ``before``, oldest first."""
        return [i.decode() for i in self.r.zrangebyscore(self.k("finished"), "-inf",
                                                          f"({before}", start=0, num=limit)]

    def snapshot(self, job_id: str) -> JobSnapshot | None:
        """What Redis holds of a job, read in one MULTI/EXEC (no merge lands between its parts):
        what a failed or cancelled job needs to go on after a retry."""
        meta = self.get_job(job_id)
        if meta is None:
            return None
        pipe = self.r.pipeline(transaction=True)
        pipe.hgetall(self.job_key(job_id))
        pipe.get(self.k("job", job_id, "scene"))
        pipe.get(self.k("job", job_id, "frames"))
        for name in ("tile_state", "tile_samples", "tile_error"):
            pipe.hgetall(self.k("job", job_id, name))
        pipe.smembers(self.k("job", job_id, "merged"))
        pipe.hgetall(self.k("job", job_id, "frame_sums"))
        for t in range(meta.plan.n_tiles):
            pipe.get(self.acc_key(job_id, t))
        h, scene, frames, states, samples, errors, merged, sums, *buffers = pipe.execute()
        if not h or scene is None:
            return None
        return JobSnapshot(
            dataclasses.replace(JobMeta.from_hash(h),
                                frame_fields={k.decode(): float(v) for k, v in sums.items()}),
            scene, {int(k): v.decode() for k, v in states.items()},
            {int(k): int(v) for k, v in samples.items()},
            {int(k): v.decode() for k, v in errors.items()}, sorted(m.decode() for m in merged),
            buffers, frames)

    def restore_job(self, snap: JobSnapshot) -> None:
        """Put a parked job back in Redis as it was when it was parked (its status, counters,
        scene, tiles and accumulations), ready for ``reopen_job``."""
        meta = snap.meta
        plan = meta.plan
        fields: dict[str, Any] = {
            "id": meta.id, "name": meta.name, "status": meta.status, "priority": meta.priority,
            **_plan_fields(plan), "tasks_merged": meta.tasks_merged,
            "samples_merged": meta.samples_merged,
            "dropped": meta.dropped, "version": meta.version, "status_version": 0,
            "created_at": meta.created_at, "started_at": meta.started_at or "",
            "finished_at": meta.finished_at or "", "error": meta.error or "",
            "methods": json.dumps(meta.methods), "submitter": meta.submitter or "",
            "tags": ",".join(meta.tags),
            "denoise": "1" if meta.denoise else "",
            "target_error": "" if meta.target_error is None else meta.target_error,
            "expected_bias": meta.expected_bias,
            # (the tiles' first looks: their first passes, which the merged buffers no longer
            # tell apart, kept by the snapshot as they were summed)
            **{name: getattr(meta, name) for name in (*LOOK_SUMS, *PILOT_SUMS)},
            "frame_sums": "1" if meta.frame_sums else "",
        }
        # (a target job of frames' own look and pilot sums, as the snapshot kept them; their
        # error sums computed again below, as the job's)
        frame_fields = {k: v for k, v in meta.frame_fields.items()
                        if k.partition(":")[0] in (*LOOK_SUMS, *PILOT_SUMS)}
        # The tiles' error summaries and the job's sums of them, as the merges kept them: each a
        # pure function of the tile's merged buffer, so computed again here rather than carried
        # in the snapshot (the next merge of a tile replaces its summary and adds the change;
        # without them a target job's scale, and any job's estimate, would start from nothing)
        summaries: dict[str, str] = {}
        sums = [0.0] * len(ERROR_SUMS)
        plan = meta.plan
        frame_sums = [[0.0] * len(ERROR_SUMS) for _ in range(plan.frames)]
        for t, data in enumerate(snap.tile_buffers):
            if data is not None:
                summary = tile_summary(SampleBuffer.from_bytes(data))
                summaries[str(t)] = _summary_text(summary)
                sums = [a + b for a, b in zip(sums, summary, strict=True)]
                f = plan.frame_of(t)
                frame_sums[f] = [a + b for a, b in zip(frame_sums[f], summary, strict=True)]
        fields.update(zip(ERROR_SUMS, sums, strict=True))
        if plan.frames > 1 and meta.frame_sums:
            for f, values in enumerate(frame_sums):
                frame_fields.update((frame_field(name, f), value)
                                    for name, value in zip(ERROR_SUMS, values, strict=True))
        pipe = self.r.pipeline()
        pipe.hset(self.job_key(meta.id), mapping=fields)
        if frame_fields:
            pipe.hset(self.k("job", meta.id, "frame_sums"), mapping=frame_fields)
        if summaries:
            pipe.hset(self.k("job", meta.id, "tile_err"), mapping=summaries)
        pipe.set(self.k("job", meta.id, "scene"), snap.scene_json)
        if snap.frames_json is not None:
            pipe.set(self.k("job", meta.id, "frames"), snap.frames_json)
        pipe.hset(self.k("job", meta.id, "tile_state"),
                  mapping={str(t): snap.tile_states.get(t, "queued")
                           for t in range(plan.n_tiles)})
        if snap.tile_samples:
            pipe.hset(self.k("job", meta.id, "tile_samples"),
                      mapping={str(t): n for t, n in snap.tile_samples.items()})
        if snap.tile_errors:
            pipe.hset(self.k("job", meta.id, "tile_error"),
                      mapping={str(t): e for t, e in snap.tile_errors.items()})
        for t, data in enumerate(snap.tile_buffers):
            if data is not None:
                pipe.set(self.acc_key(meta.id, t), data)
        if snap.merged:
            pipe.sadd(self.k("job", meta.id, "merged"), *snap.merged)
        # not back in ``finished``: the sweeper would park it again before the retry reopens it
        pipe.zadd(self.k("jobs"), {meta.id: meta.created_at})
        pipe.execute()

    def forget_archive(self, job_id: str) -> None:
        """Take the job off the list of those to archive."""
        self.r.srem(self.k("to_archive"), job_id)

    def tiles_final(self, job_id: str, n_tiles: int) -> dict[str, Any]:
        """The tiles' summary a job's record keeps once it is archived: samples per pixel of
        each tile, and the last error of those that had one."""
        samples = self.tile_samples(job_id)
        out: dict[str, Any] = {
            "samples": [samples.get(t, 0) for t in range(n_tiles)],
            "errors": {str(t): e for t, e in self.tile_errors(job_id).items()}}
        meta = self.get_job(job_id)
        if meta is not None and meta.denoise:
            out["denoise"] = True
        if meta is not None and meta.target_error is not None:
            out["target_error"] = meta.target_error
            if meta.expected_bias:
                out["expected_bias"] = meta.expected_bias
        if meta is not None and meta.expected_error is not None:
            out["expected_error"] = meta.expected_error
        estimates = self.tile_estimates(job_id)
        if estimates:
            out["estimates"] = {str(t): e for t, e in estimates.items()}
        blocklist = self.blocklist(job_id)
        if blocklist:
            out["blocklist"] = blocklist
        return out

    def delete_job(self, job_id: str, statuses: tuple[str, ...] = FINAL) -> bool:
        """Delete every key of the job, atomically, if its status is one of ``statuses`` (by
        default a finished job: done, failed, cancelled); False (nothing deleted) when it is gone
        or has another status. A done job archived leaves Redis this way."""
        meta = self.get_job(job_id)
        if meta is None:
            return False
        keys = [self.k("job", job_id, "scene"), self.k("job", job_id, "frames"),
                *self.tile_keys(job_id, meta.plan.n_tiles),
                *self.pending_passes_of(job_id)]
        return bool(self._delete(
            keys=[self.job_key(job_id), self.k("jobs"), self.k("finished"),
                  self.k("to_archive"), self.k("pending"), *keys],
            args=[job_id, *statuses]))

    # --- tiles ----------------------------------------------------------------------------------
    def job_view(self, job_id: str) -> tuple[JobMeta, dict[int, str], dict[int, int],
                                             dict[int, str], dict[str, int],
                                             dict[int, float]] | None:
        """The job, its tiles' states, samples and errors, its blocklist (node -> failed
        passes), and its tiles' estimated errors (``tile_estimates``),
        as one snapshot in one round trip (what a status answer shows); None for an unknown
        job."""
        pipe = self.r.pipeline()
        for part in ("tile_state", "tile_samples", "tile_error", "failures", "tile_err"):
            pipe.hgetall(self.k("job", job_id, part))
        pipe.smembers(self.k("job", job_id, "blocklist"))
        pipe.hgetall(self.job_key(job_id))
        states, samples, errors, failures, summaries, blocked, h = pipe.execute()
        if not h:
            return None
        return (JobMeta.from_hash(h), {int(k): v.decode() for k, v in states.items()},
                {int(k): int(v) for k, v in samples.items()},
                {int(k): v.decode() for k, v in errors.items()},
                {n.decode(): int(failures.get(n, 0)) for n in sorted(blocked)},
                _estimates(summaries))

    def tile_estimates(self, job_id: str) -> dict[int, float]:
        """Each tile's expected relMSE from its merged samples, the mean of
        its pixels' error terms (its ``tile_err`` summary: Σ e_p over the pixels with 2 samples
        or more, over their number), for the tiles whose summary counts a pixel."""
        return self.tile_estimates_of([job_id])[job_id]

    def tile_estimates_of(self, job_ids: list[str]) -> dict[str, dict[int, float]]:
        """``tile_estimates`` of each job, in one round trip."""
        pipe = self.r.pipeline(transaction=False)
        for job_id in job_ids:
            pipe.hgetall(self.k("job", job_id, "tile_err"))
        return {j: _estimates(h) for j, h in zip(job_ids, pipe.execute(), strict=True)}

    # --- the blocklist --------------------------------------------------------------------------
    def note_failure(self, job_id: str, node: str, threshold: int) -> int:
        """Count a pass of the job that failed on ``node``; at ``threshold`` failures the node
        is blocklisted for the job. Returns the node's failures."""
        return int(self._note_failure(
            keys=[self.k("job", job_id, "failures"), self.k("job", job_id, "blocklist")],
            args=[node, threshold]))

    def is_blocklisted(self, job_id: str, node: str) -> bool:
        return bool(self.r.sismember(self.k("job", job_id, "blocklist"), node))

    def blocklist(self, job_id: str) -> dict[str, int]:
        """Node -> failed passes, of the nodes blocklisted for the job."""
        pipe = self.r.pipeline()
        pipe.smembers(self.k("job", job_id, "blocklist"))
        pipe.hgetall(self.k("job", job_id, "failures"))
        blocked, failures = pipe.execute()
        return {n.decode(): int(failures.get(n, 0)) for n in sorted(blocked)}

    def forgive_attempt(self, job_id: str, tile: int, pass_index: int) -> None:
        """Take back a counted try of the pass (it failed through its worker, not itself)."""
        self.r.hincrby(self.k("job", job_id, "attempts"), pass_member(tile, pass_index), -1)

    def tile_states(self, job_id: str, tiles: list[int] | None = None) -> dict[int, str]:
        """Each tile's state (``tiles``: of those only, those that have one)."""
        if tiles is not None:
            if not tiles:
                return {}
            values = self.r.hmget(self.k("job", job_id, "tile_state"), [str(t) for t in tiles])
            return _states(zip(tiles, values, strict=True))
        h = self.r.hgetall(self.k("job", job_id, "tile_state"))
        return _states((int(k), v) for k, v in h.items())

    def tile_samples(self, job_id: str) -> dict[int, int]:
        h = self.r.hgetall(self.k("job", job_id, "tile_samples"))
        return {int(k): int(v) for k, v in h.items()}

    def tile_errors(self, job_id: str) -> dict[int, str]:
        h = self.r.hgetall(self.k("job", job_id, "tile_error"))
        return {int(k): v.decode() for k, v in h.items()}

    def set_tile_state(self, job_id: str, tile: int, state: str) -> None:
        self.r.hset(self.k("job", job_id, "tile_state"), str(tile), state)

    def fail_tile(self, job_id: str, tile: int, reason: str) -> None:
        pipe = self.r.pipeline()
        pipe.hset(self.k("job", job_id, "tile_state"), str(tile), "failed")
        pipe.hset(self.k("job", job_id, "tile_error"), str(tile), reason)
        pipe.execute()
        self.fail_job(job_id, f"tile {tile}: {reason}")

    def note_tile_error(self, job_id: str, tile: int, reason: str) -> None:
        self.r.hset(self.k("job", job_id, "tile_error"), str(tile), reason)

    def add_attempt(self, job_id: str, tile: int, pass_index: int, holder: str = "",
                    running: bool = False, count: bool = True) -> int:
        """Count a delivery of the pass that is about to run; it is also a sign of life of the
        job (``active_at``: the sweeper's stall clock starts again). ``holder``: the worker
        process that runs it, recorded as holding the pass until ``release_pass``. ``running``:
        in the same step, the tile becomes running if it is queued or converged (a done or
        failed tile stays as it is: a late duplicate does not reopen it). ``count=False``: the
        same delivery begun again (after a Redis outage), not counted; returns the tries so
        far."""
        return int(self._add_attempt(
            keys=[self.k("job", job_id, "attempts"), self.job_key(job_id), self.k("holding"),
                  self.k("job", job_id, "tile_state")],
            args=[pass_member(tile, pass_index), time.time(), holder,
                  f"{job_id} {tile} {pass_index}", str(tile) if running else "",
                  1 if count else 0]))

    def skip_passes(self, job_id: str, tile: int, first: int, n_passes: int) -> int:
        """A converged tile of a job with a target error: its passes ``first`` … ``n_passes - 1``
        count as merged (nothing to add: pass_member's set, ``tasks_merged``, ``version``) and the
        tile is done, in one step; a pass already merged is not counted twice (the merged set
        decides, as for every merge). Returns the passes newly counted."""
        return int(self._skip_passes(
            keys=[self.k("job", job_id, "merged"), self.job_key(job_id),
                  self.k("job", job_id, "tile_state")],
            args=[str(tile), first, n_passes]))

    def begin_view(self, job_id: str, tile: int, pass_index: int, node: str = "",
                   holder: str = "", count: bool = True
                   ) -> tuple[JobMeta | None, bool, bool, int | None]:
        """What a worker checks before it renders a pass, and ``add_attempt`` (with ``running``),
        in one round trip: the job (None if unknown), whether ``node`` is blocklisted for it,
        whether the pass is merged, and the tries so far with this delivery counted, or None
        when it was not counted (no such job, not queued or running, blocklisted, merged, or a
        pass its tile states and ``tasks_total`` do not have)."""
        member = pass_member(tile, pass_index)
        h, blocked, merged, n = self._begin_pass(
            keys=[self.k("job", job_id, "attempts"), self.job_key(job_id), self.k("holding"),
                  self.k("job", job_id, "tile_state"), self.k("job", job_id, "blocklist"),
                  self.k("job", job_id, "merged")],
            args=[member, time.time(), holder, f"{job_id} {tile} {pass_index}", str(tile),
                  1 if count else 0, node, pass_index])
        meta = JobMeta.from_hash(dict(zip(h[::2], h[1::2], strict=True))) if h else None
        return (meta, bool(node) and bool(blocked), bool(merged),
                None if int(n) < 0 else int(n))

    def attempts(self, job_id: str, tile: int, pass_index: int) -> int:
        return int(self.r.hget(self.k("job", job_id, "attempts"),
                               pass_member(tile, pass_index)) or 0)

    def is_merged(self, job_id: str, tile: int, pass_index: int) -> bool:
        return bool(self.r.sismember(self.k("job", job_id, "merged"),
                                     pass_member(tile, pass_index)))

    # --- sample buffers -------------------------------------------------------------------------
    def put_pass(self, job_id: str, tile: int, pass_index: int, data: bytes, ttl: float) -> str:
        """Store a rendered pass (deterministic key: a second delivery overwrites it with the same
        bytes) and list it as pending for the sweeper. A worker no longer calls this: its merge
        writes the same two keys in its first read (``merge_pass_buffer`` with ``ttl``); the
        tests use it to leave a pass behind for ``merge_pass`` and the sweeper."""
        key = self.pass_key(job_id, tile, pass_index)
        pipe = self.r.pipeline()
        pipe.set(key, data, px=int(ttl * 1000))
        pipe.sadd(self.k("pending"), key)
        pipe.execute()
        return key

    def merge_pass_buffer(self, job_id: str, tile: int, pass_index: int,
                          data: bytes | None = None, ttl: float | None = None) -> int:
        """Add the pass buffer of (tile, pass_index) into its tile's merged buffer, mark it
        merged, update the tile's samples and state and the job's counters, in one transaction
        (WATCH on the tile's buffer and the merged set, retried on a conflict). 0 (false) if it
        was merged already, there is no buffer, or the job is gone (the pass buffer is then
        dropped); else 1, or ``MERGED_LAST`` when this merge counted the job's last task,
        either with ``FRAME_LOOKED`` added when it completed the frames' first look or pilot.
        ``data``: the pass buffer's bytes as stored (``put_pass``), when the caller has them,
        so that the merge does not read them back (it still requires the stored buffer).
        ``ttl`` with ``data``: the caller has not stored them; the merge stores them first as
        ``put_pass`` would (in its first read: one round trip for both)."""
        r = self.r
        pass_key = self.pass_key(job_id, tile, pass_index)
        acc_key = self.acc_key(job_id, tile)
        merged_key = self.k("job", job_id, "merged")
        member = pass_member(tile, pass_index)
        job_key = self.job_key(job_id)
        samples_key = self.k("job", job_id, "tile_samples")
        err_key = self.k("job", job_id, "tile_err")
        state_key = self.k("job", job_id, "tile_state")
        with r.pipeline() as pipe:
            while True:
                try:
                    # and the scene, written once and deleted with the job: a job deleted or
                    # archived between the status read below and EXEC aborts the merge, which
                    # would otherwise write its keys (its hash too) back
                    pipe.watch(acc_key, merged_key, self.k("job", job_id, "scene"))
                    put = ("", b"") if data is None or ttl is None else (int(ttl * 1000), data)
                    ttl = None  # stored by the first read; a retry after a conflict need not
                    (is_merged, stored,
                     (status, spp, total, width, height, frames, tile_size, by_frame),
                     acc_bytes, tile_samples, tile_state, old_summary) = pipe.eval(
                        _MERGE_READ, 8, merged_key, pass_key, job_key, acc_key, samples_key,
                        state_key, err_key, self.k("pending"), member, str(tile),
                        "1" if data is not None else "", *put)
                    if data is None:
                        data = stored
                    elif not stored:
                        data = None  # expired, or merged and deleted by another call
                    # Merged already, no buffer (dropped or merged and deleted), or the job was
                    # deleted or is done: every pass of a done job was merged (this is a late
                    # duplicate) and its tile keys may be archived already.
                    if is_merged or data is None or _s(status) in (None, "done"):
                        pipe.unwatch()
                        if data is not None:
                            r.delete(pass_key)
                        r.srem(self.k("pending"), pass_key)
                        return 0
                    buf = SampleBuffer.from_bytes(data)
                    if acc_bytes is None:
                        acc = buf
                        had = 0
                    else:
                        acc = SampleBuffer.from_bytes(acc_bytes)
                        had = int(acc.drawn.min()) if acc.count.size else 0
                        acc.add(buf)
                    # (this merge ends the tile's pilot: its every pixel has drawn the pilot's
                    # samples, kept or dropped as non-finite, which before it one had not:
                    # pass_counts' end of the pilot)
                    pilot = min(PILOT, int(spp or 0))
                    ends_pilot = bool(acc.count.size) and had < pilot <= int(acc.drawn.min())
                    # Samples per pixel this pass planned: drawn ones, added or dropped as
                    # non-finite.
                    spp_added = int(buf.drawn.max()) if buf.count.size else 0
                    # tile_samples changes only in this transaction, under the same WATCH: the
                    # tile becomes done in the same EXEC that gives it its last samples, so no
                    # process killed in between can leave a complete tile shown as running.
                    tile_spp = int(tile_samples or 0) + spp_added
                    tile_done = tile_spp >= int(spp or 0)
                    # "running" means a pass of the tile is rendering now: a tile that has more
                    # passes to come goes back to queued (not a failed tile: that stays failed)
                    requeue = not tile_done and _s(tile_state) == "running"
                    # The tile's error summary, and the change to the job's sums (its old
                    # summary read under the same WATCH of the tile's buffer): a job with a
                    # target allocates by them, and every job reports its estimated error
                    summary = tile_summary(acc)
                    before = _summary_values(_s(old_summary))
                    delta = [new - was for new, was in zip(summary, before, strict=True)]
                    pipe.multi()
                    pipe.set(acc_key, acc.to_bytes())
                    pipe.sadd(merged_key, member)
                    pipe.delete(pass_key)
                    pipe.srem(self.k("pending"), pass_key)
                    pipe.hincrby(samples_key, str(tile), spp_added)
                    if tile_done:
                        pipe.hset(state_key, str(tile), "done")
                    elif requeue:
                        pipe.hset(state_key, str(tile), "queued")
                    merged_at = len(pipe.command_stack)  # its reply's index in EXEC's
                    pipe.hincrby(job_key, "tasks_merged", 1)
                    pipe.hincrby(job_key, "samples_merged", int(buf.count.sum()))
                    pipe.hincrby(job_key, "dropped", int(buf.dropped.sum()))
                    pipe.hincrby(job_key, "version", 1)
                    pipe.hset(job_key, "active_at", time.time())  # the stall clock restarts
                    pipe.hset(err_key, str(tile), _summary_text(summary))
                    # The job's sums, and for a target job of frames its tile's frame's
                    # (FRAME_SUMS): each the key and field suffix, and the pixels it sums over
                    n_frames = int(frames or 1)
                    frame_pixels = int(width or 0) * int(height or 0)
                    sums = [(job_key, "", frame_pixels * n_frames)]
                    if n_frames > 1 and _s(by_frame) == "1":
                        # (the tile's frame: Plan.frame_of)
                        per_frame = frame_tiles_count(int(width or 0), int(height or 0),
                                                      int(tile_size or 1))
                        sums.append((self.k("job", job_id, "frame_sums"),
                                     frame_field("", tile // max(per_frame, 1)), frame_pixels))
                    for name, d in zip(ERROR_SUMS, delta, strict=True):
                        for key, suffix, _ in sums:
                            pipe.hincrbyfloat(key, name + suffix, d)
                    # (the replies' indices of the new look and pilot pixel counts, what each
                    # adds, and the pixels it completes at)
                    counted = []
                    for key, suffix, pixels in sums:
                        if acc_bytes is None:
                            # the tile's first merged pass, its first look: its terms once
                            # (JobMeta.first_look_bound; the sums over the tile's every pixel,
                            # as the local loop's over the frame's, a pixel below 2 samples
                            # adding 0)
                            pipe.hincrbyfloat(key, "look_sum" + suffix, summary[0])
                            pipe.hincrbyfloat(key, "look_sq_sum" + suffix, summary[3])
                            counted.append((len(pipe.command_stack), buf.count.size, pixels))
                            pipe.hincrby(key, "look_pixels" + suffix, int(buf.count.size))
                        if ends_pilot:
                            # (JobMeta.pilot_error: the tile's terms at the end of its pilot,
                            # once)
                            pipe.hincrbyfloat(key, "pilot_sum" + suffix, summary[0])
                            counted.append((len(pipe.command_stack), acc.count.size, pixels))
                            pipe.hincrby(key, "pilot_pixels" + suffix, int(acc.count.size))
                    replies = pipe.execute()
                    break
                except redis.WatchError:
                    continue
        answer = MERGED_LAST if int(replies[merged_at]) >= int(total or 0) else 1
        # (this merge's pixels took the frames' look or pilot sums, or a frame's, to every
        # pixel of them)
        if any(int(replies[i]) >= pixels > int(replies[i]) - n for i, n, pixels in counted):
            answer |= FRAME_LOOKED
        return answer

    def tile_buffer(self, job_id: str, tile: int) -> bytes | None:
        """The tile's merged buffer (``SampleBuffer.to_bytes``); None before its first merge."""
        return self.r.get(self.acc_key(job_id, tile))

    def tile_buffers(self, job_id: str, n_tiles: int, first: int = 0
                     ) -> list[bytes | None] | None:
        """The merged buffers of tiles ``first`` to ``first + n_tiles - 1``, read in one
        transaction with the job's hash; None when the job is no longer in Redis (archived,
        parked or deleted: its buffers may be gone)."""
        pipe = self.r.pipeline()
        pipe.exists(self.job_key(job_id))
        for t in range(first, first + n_tiles):
            pipe.get(self.acc_key(job_id, t))
        exists, *buffers = pipe.execute()
        return buffers if exists else None

    def pending_passes(self) -> list[str]:
        """The keys of the pass buffers written and not merged yet."""
        return [raw.decode() for raw in self.r.smembers(self.k("pending"))]

    def forget_pending(self, key: str) -> None:
        self.r.srem(self.k("pending"), key)

    def broker_messages(self, queues: list[str]) -> int:
        """Messages waiting in these Celery queues (kombu keeps a Redis list per queue and
        priority level, in the Redis this store uses when it is also the broker)."""
        pipe = self.r.pipeline()
        for name in queues:
            pipe.llen(name)
        return sum(pipe.execute())

    def pending_count(self) -> int:
        """Pass buffers written and not merged yet (the sweeper's set)."""
        return int(self.r.scard(self.k("pending")))

    # --- the connection -------------------------------------------------------------------------
    def ping(self) -> None:
        """Raises ``redis.RedisError`` when Redis does not answer."""
        self.r.ping()

    def close(self) -> None:
        self.r.close()

    # --- workers --------------------------------------------------------------------------------
    def heartbeat(self, worker_id: str, fields: dict[str, Any], ttl: float) -> None:
        now = time.time()
        key = self.k("worker", worker_id)
        pipe = self.r.pipeline()
        pipe.hset(key, mapping={**fields, "last_heartbeat": now})
        pipe.pexpire(key, int(ttl * 1000))
        pipe.zadd(self.k("workers"), {worker_id: now})
        pipe.execute()

    def remove_worker(self, worker_id: str) -> None:
        self.r.delete(self.k("worker", worker_id))
        self.r.zrem(self.k("workers"), worker_id)
        self.release_pass(worker_id)

    def release_pass(self, worker_id: str, **increments: float) -> None:
        """The worker process holds no pass any more (it ended, whichever way); ``increments``:
        ``count``'s, in the same round trip."""
        pipe = self.r.pipeline(transaction=False)
        pipe.hdel(self.k("holding"), worker_id)
        self._add_counts(pipe, increments)
        pipe.execute()

    def _holdings(self) -> list[tuple[str, str, bool]]:
        """(worker id, ``job tile pass attempt``, whether its heartbeat lives) of every pass held
        (the heartbeat's hash is gone once the process died, or cannot reach Redis)."""
        held = {k.decode(): v.decode() for k, v in self.r.hgetall(self.k("holding")).items()}
        pipe = self.r.pipeline()
        for worker_id in held:
            pipe.exists(self.k("worker", worker_id))
        return [(w, v, bool(alive))
                for (w, v), alive in zip(held.items(), pipe.execute(), strict=True)]

    def lost_holdings(self) -> dict[str, str]:
        """worker id -> ``job tile pass attempt`` of each pass held by a worker process whose
        heartbeat has expired."""
        return {w: v for w, v, alive in self._holdings() if not alive}

    def job_held(self, job_id: str) -> bool:
        """Whether a worker process whose heartbeat has not expired holds a pass of the job (it
        is rendering it, or about to: ``add_attempt`` records the holding)."""
        prefix = f"{job_id} "
        return any(alive and v.startswith(prefix) for _, v, alive in self._holdings())

    def claim_holding(self, worker_id: str, value: str) -> bool:
        """Take the lost worker's holding if it is still ``value``; True for one caller only."""
        return bool(self._claim_holding(keys=[self.k("holding")], args=[worker_id, value]))

    def workers(self, forget_after: float = 300.0) -> list[dict[str, str]]:
        """Workers seen in the last ``forget_after`` seconds; those whose heartbeat expired come
        back with ``state = lost``."""
        now = time.time()
        self.r.zremrangebyscore(self.k("workers"), 0, now - forget_after)
        entries = self.r.zrevrange(self.k("workers"), 0, -1, withscores=True)
        pipe = self.r.pipeline()
        for worker_id, _ in entries:
            pipe.hgetall(self.k("worker", worker_id.decode()))
        out = []
        for (worker_id, seen), h in zip(entries, pipe.execute(), strict=True):
            d = {k.decode(): v.decode() for k, v in h.items()}
            if not d:
                d = {"state": "lost", "last_heartbeat": str(seen)}
            d["id"] = worker_id.decode()
            out.append(d)
        return out

    # --- metrics --------------------------------------------------------------------------------
    def count(self, **increments: float) -> None:
        pipe = self.r.pipeline()
        self._add_counts(pipe, increments)
        pipe.execute()

    def _add_counts(self, pipe, increments: dict[str, float]) -> None:
        for name, value in increments.items():
            pipe.hincrbyfloat(self.k("metrics"), name, value)

    def metrics(self) -> dict[str, float]:
        return {k.decode(): float(v) for k, v in self.r.hgetall(self.k("metrics")).items()}
