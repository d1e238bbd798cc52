"""The blocklist: a worker node that keeps failing one job's passes stops getting them.

Flamenco Manager's rule (its ``persistence`` keeps a job's blocklist of workers; a worker that
fails a job's tasks N times gets none of them any more): each pass of a job that raises on a node
is counted against that node (``JobStore.note_failure``); at ``LUCENT_BLOCKLIST_THRESHOLD`` (3)
failures the node is blocklisted for that job. Celery pushes tasks through shared queues, so a
blocklisted node still receives the job's passes: it hands each back (sends it again to the job's
queue, without counting a try) and pauses ``HAND_BACK_PAUSE`` before taking the next message, so
that the other nodes take it.

The failure that blocklists a node, and any after it, are charged to the node, not to the pass:
its try is taken back (``forgive_attempt``), so a pass that failed only on a bad node is not
failed for it. With ``blocklist_threshold <= max_attempts`` a bad node alone never spends all the
tries of a pass.

When no live, non-blocklisted node with the job's tags remains, the job fails with that reason
(checked when a node is blocklisted and when a blocklisted node is handed a pass), unless the
failure was its pass's last try: then the tile fails with it, as without a blocklist (a pass that
fails on the farm's only node is the pass's fault as much as the node's). A pass that
kills its process (a crash, not an exception) is not counted here: the redelivery cap fails it.
"""

from __future__ import annotations

from services.farm.pools import eligible
from services.farm.store import JobMeta, JobStore

# Seconds a blocklisted node's process waits after handing a pass back, so that the pass goes to
# another node rather than straight back to it.
HAND_BACK_PAUSE = 0.5


def eligible_nodes(store: JobStore, meta: JobMeta) -> list[str]:
    """The live worker nodes that may render the job: its tags, not blocklisted for it."""
    blocked = set(store.blocklist(meta.id))
    nodes = {w.get("node") or w["id"] for w in eligible(store.workers(), meta.tags)}
    return sorted(nodes - blocked)


def no_eligible_reason(store: JobStore, meta: JobMeta, threshold: int) -> str | None:
    """Why the job cannot go on (no eligible node remains), or None when one does."""
    if eligible_nodes(store, meta):
        return None
    blocked = store.blocklist(meta.id)
    listed = ", ".join(f"{node} ({n} failed passes)" for node, n in blocked.items())
    tags = f" with tags {','.join(meta.tags)}" if meta.tags else ""
    return (f"no eligible worker remains: every live worker node{tags} is blocklisted for this "
            f"job after {threshold} failed passes (LUCENT_BLOCKLIST_THRESHOLD): {listed}")
