"""``glsynth generate --executor ray``: the run's tasks on long-lived Ray actors.

Each actor holds one :class:`glsynth.pipeline.worker.Worker` (its own headless GL
context and loaded assets), created once per run. The driver first hands out the
per-body prepare tasks (paste + blend), then the view chunks, preferring the actor
that already holds a chunk's body (the views stage keeps the last body loaded).
Actors write samples straight into the output folder, which must therefore be shared
storage (the same POSIX path on every node, with atomic rename); ``generate()`` merges
the manifest, COCO file and params.csv at the end.

Fault tolerance: a sample is complete when its JSON exists and every file is written
by an atomic rename, so a task can be re-run safely. When an actor dies (node lost,
process killed, out of memory) its unfinished tasks go back to the queue and a new
actor takes its place; a task that was running on :data:`MAX_TRIES` dead actors is reported
as an error instead of being retried forever. An exception raised *inside* a task (bad
input, a bug) is not retried: it is raised here, as the local executor would.
"""
from __future__ import annotations

import logging
import math
import os
import uuid
from collections import OrderedDict, deque

from tqdm import tqdm

from ..errors import GlsynthError, MissingDependencyError
from ..io.images import remove_temporaries
from .ray_reaper import Reaper

try:
    import ray
    from ray.exceptions import RayActorError
    has_ray = True
except ImportError as _exc:  # optional dependency: fail on first use, naming the fix
    has_ray = False
    _RAY_IMPORT_ERROR = _exc

log = logging.getLogger(__name__)

ACTOR_PREFIX = "glsynth-worker"   # actors are named f"{ACTOR_PREFIX}-{run}-{n}"
MAX_TRIES = 3                     # actors a single task may take down before we give up
IN_FLIGHT = {"prepare": 1, "render": 2}  # tasks queued per actor (hides the round trip)
STALL_WARN_S = 60                 # say so when nothing finished for this long
ENV_PREFIXES = ("GLSYNTH_",)      # driver environment variables passed on to the actors


class RayExecutorError(GlsynthError, RuntimeError):
    """The Ray executor could not finish the run (actors fail to start, a task keeps
    killing its actor)."""


def _require_ray():
    if not has_ray:
        raise MissingDependencyError("--executor ray needs Ray: pip install 'glsynth[ray]' "
                                     f"(import failed: {_RAY_IMPORT_ERROR})") from _RAY_IMPORT_ERROR


if has_ray:
    @ray.remote
    class GlsynthWorker:
        """A Ray actor around one ``Worker``; every method returns the worker's report."""

        def __init__(self, cfg_dict, out):
            gpu_ids = ray.get_gpu_ids()
            if gpu_ids and str(gpu_ids[0]).isdigit():
                # EGL ignores CUDA_VISIBLE_DEVICES: render on the GPU Ray gave this actor
                # (glcontext reads the index; EGL lists NVIDIA's devices first)
                os.environ.setdefault("GLCONTEXT_DEVICE_INDEX", str(gpu_ids[0]))
            logging.basicConfig(level=logging.WARNING)
            from glsynth.config import from_dict
            from glsynth.pipeline.worker import Worker, share_cores
            cpus = int(ray.get_runtime_context().get_assigned_resources().get("CPU", 1) or 1)
            share_cores(cpus)  # before the GL context: llvmpipe reads LP_NUM_THREADS then
            self.worker = Worker(from_dict(cfg_dict), out, writer_threads=cpus)

        def ready(self):
            return {"pid": os.getpid(), "node": ray.get_runtime_context().get_node_id(),
                    "gl": self.worker.views.renderer.info}

        def ping(self):
            return None

        def prepare(self, body_id):
            return self.worker.prepare(body_id)

        def render(self, tasks):
            return self.worker.render([tuple(t) for t in tasks])


class _Slot:
    """One live actor and the tasks queued on it (oldest first)."""

    def __init__(self, actor, name):
        self.actor, self.name = actor, name
        self.inflight = deque()   # ObjectRefs, in submission order
        self.last_body = None     # body its views stage will hold after its queued tasks
        self.alive = True
        self.ready = False        # its worker (GL context, assets) is constructed


class _Pool:
    def __init__(self, cfg_dict, out, workers, run_id, actor_options):
        self.cfg_dict, self.out, self.run_id = cfg_dict, out, run_id
        self.options = actor_options
        # the stages' own per-body bars are silenced: the driver shows one per phase
        self.env = {"TQDM_DISABLE": "1",
                    **{k: v for k, v in os.environ.items() if k.startswith(ENV_PREFIXES)}}
        self.workers = workers
        self.slots, self.started, self.deaths, self.early_deaths = [], 0, 0, 0
        self.starting = {}        # ready() ObjectRef -> slot, until the actor is up
        self.info = None          # the first actor's ready() answer
        for _ in range(workers):
            self.spawn()

    def spawn(self):
        name = f"{ACTOR_PREFIX}-{self.run_id}-{self.started}"
        self.started += 1
        actor = GlsynthWorker.options(
            name=name, max_restarts=0, runtime_env={"env_vars": self.env}, **self.options,
        ).remote(self.cfg_dict, self.out)
        slot = _Slot(actor, name)
        self.slots.append(slot)
        self.starting[actor.ready.remote()] = slot
        return slot

    def live(self):
        return [s for s in self.slots if s.alive]

    def working(self):
        return [s for s in self.slots if s.alive and s.ready]

    def shutdown(self):
        for s in self.slots:
            try:
                ray.kill(s.actor, no_restart=True)
            except Exception:  # already gone
                pass
            s.alive = False


def _actor_options(workers):
    """An equal share of the cluster's CPUs per actor (at most one node's worth, so every
    actor fits on a node; its thread pools follow it, see ``share_cores``), and a GPU (or
    an equal share of the cluster's GPUs) when it has any."""
    gpus = float(ray.cluster_resources().get("GPU", 0))
    cpus = float(ray.cluster_resources().get("CPU", 1))
    node_cpus = [n["Resources"].get("CPU", 0) for n in ray.nodes() if n.get("Alive")]
    per_node = min((c for c in node_cpus if c >= 1), default=1)
    opts = {"num_cpus": max(1, int(min(cpus // workers, per_node)))}
    if gpus >= 1:
        per = 1.0 if gpus >= workers else 1.0 / math.ceil(workers / gpus)
        opts["num_gpus"] = per
    return opts


def run_ray(cfg, out, ids, chunks, workers, address=None):
    """Prepare every body in ``ids``, then render ``chunks`` (lists of (body id, view
    index)) on ``workers`` Ray actors; returns the reports, prepare reports first.

    ``address``: an existing cluster ("auto", "ray://host:10001", "host:6379"); None
    joins the cluster this process is already connected to, else starts a local one
    with this machine's CPUs. Only a cluster started here is shut down here.
    """
    _require_ray()
    out = os.path.abspath(os.fspath(out))
    started_here, reaper = False, None
    if not ray.is_initialized():
        if address:
            ray.init(address=address)
        else:
            # a local instance is ours: nothing of it may outlive this process
            reaper = Reaper()
            ray.init(num_cpus=max(os.cpu_count() or 1, workers), include_dashboard=False)
            reaper.watch()
        started_here = True
    pool = None
    try:
        run_id = uuid.uuid4().hex[:8]
        pool = _Pool(cfg.to_dict(), out, workers, run_id, _actor_options(workers))
        reports = _schedule(pool, [[b] for b in ids], "prepare", "paste + blend", "body",
                            affinity=False)
        if reaper is not None:
            reaper.watch()  # the actors' processes too
        reports += _schedule(pool, chunks, "render", "views", "img", affinity=True)
        if pool.deaths:
            # writes a killed actor never renamed into place; every task is finished now
            remove_temporaries(out)
            log.warning("ray: %d actor(s) died and were replaced; their tasks were re-run",
                        pool.deaths)
        return reports
    finally:
        if pool is not None:
            pool.shutdown()
        if started_here:
            ray.shutdown()
        if reaper is not None:
            reaper.close()


def _schedule(pool, jobs, method, desc, unit, affinity):
    """Run ``jobs`` (prepare: [body_id]; render: [(body, j), ...]) on the pool's actors;
    returns the reports in completion order."""
    # per-body queues of (job index, job), keyed by the body a job starts with
    queues = OrderedDict()
    for i, job in enumerate(jobs):
        queues.setdefault(_first_body(job, method), deque()).append((i, job))
    tries = [0] * len(jobs)
    pending = {}  # ObjectRef -> (slot, job index)
    reports = []
    total = len(jobs) if method == "prepare" else sum(len(j) for j in jobs)
    bar = tqdm(total=total, desc=desc, unit=unit)

    def pick(slot):
        if not affinity:
            for body, q in queues.items():
                if q:
                    return q.popleft()
            return None
        q = queues.get(slot.last_body)
        if q:
            return q.popleft()
        held = {s.last_body for s in pool.live() if s is not slot}
        for body, q in queues.items():  # a body nobody holds, in order
            if q and body not in held:
                return q.popleft()
        longest = max(queues.values(), key=len, default=None)  # steal from the tail
        return longest.pop() if longest else None

    def fill():
        for level in range(1, IN_FLIGHT[method] + 1):  # round robin: idle actors first
            for slot in pool.working():
                if len(slot.inflight) < level:
                    nxt = pick(slot)
                    if nxt is not None:
                        submit(slot, *nxt)

    def submit(slot, i, job):
        arg = job[0] if method == "prepare" else job
        ref = getattr(slot.actor, method).remote(arg)
        pending[ref] = (slot, i)
        slot.inflight.append(ref)
        if method == "render":
            slot.last_body = job[-1][0]

    def requeue(i):
        job = jobs[i]
        queues.setdefault(_first_body(job, method), deque()).appendleft((i, job))

    try:
        while pending or any(queues.values()):
            fill()
            watch = list(pending) + list(pool.starting)
            if not watch:  # cannot happen: every live actor is either starting or working
                raise RayExecutorError(f"{method}: tasks left but no Ray actor to run them")
            ready, _ = ray.wait(watch, num_returns=1, timeout=STALL_WARN_S)
            if not ready:
                _stalled(pool, len(pending))
                continue
            ref = ready[0]
            if ref in pool.starting:
                _actor_started(pool, ref, pending, tries, requeue, jobs, method)
                continue
            slot, i = pending[ref]
            try:
                report = ray.get(ref)
            except RayActorError as exc:
                _actor_died(pool, slot, pending, tries, requeue, exc, jobs, method)
                bar.set_postfix(restarts=pool.deaths)
                continue
            del pending[ref]
            slot.inflight.remove(ref)
            reports.append(report)
            bar.update(1 if method == "prepare" else report["done"])
    finally:
        bar.close()
    return reports


def _actor_started(pool, ref, pending, tries, requeue, jobs, method):
    slot = pool.starting.pop(ref)
    try:
        info = ray.get(ref)
    except RayActorError as exc:
        _actor_died(pool, slot, pending, tries, requeue, exc, jobs, method)
        return
    slot.ready = True
    if pool.info is None:
        pool.info = info
        log.info("ray: first actor up on node %s (GL_RENDERER %s)", info["node"],
                 info["gl"].get("GL_RENDERER"))


def _stalled(pool, n_pending):
    waiting = sum(1 for s in pool.live() if not s.ready)
    res = ray.cluster_resources()
    log.warning("ray: nothing finished for %ds; %d task(s) running, %d actor(s) still waiting "
                "to start (each needs %s; the cluster has %s CPU, %s GPU)", STALL_WARN_S,
                n_pending, waiting, pool.options, res.get("CPU", 0), res.get("GPU", 0))


def _first_body(job, method):
    return job[0] if method == "prepare" else job[0][0]


def _actor_died(pool, slot, pending, tries, requeue, exc, jobs, method):
    """Requeue everything queued on a dead actor and start a replacement."""
    if getattr(exc, "actor_init_failed", False):  # its constructor raised: no use retrying
        raise RayExecutorError(f"Ray actor {slot.name} could not start a glsynth worker: {exc}") from exc
    slot.alive = False
    pool.deaths += 1
    for r, s in list(pool.starting.items()):
        if s is slot:
            del pool.starting[r]
    if not slot.ready:
        pool.early_deaths += 1
        if pool.early_deaths > 3 * pool.workers:
            raise RayExecutorError(f"{pool.early_deaths} Ray actors died before they were up; "
                                   f"last error: {exc}") from exc
    try:
        ray.kill(slot.actor, no_restart=True)
    except Exception:
        pass
    lost = [pending.pop(r)[1] for r in slot.inflight if r in pending]
    slot.inflight.clear()
    if lost:
        tries[lost[0]] += 1  # the oldest task is the one that was running
        if tries[lost[0]] >= MAX_TRIES:
            raise RayExecutorError(
                f"{method} task {jobs[lost[0]]!r} was running on {tries[lost[0]]} actors that died; "
                f"last error: {exc}") from exc
    for i in reversed(lost):  # back to the head of their queues, in the same order
        requeue(i)
    log.warning("ray: actor %s died (%s); %d task(s) requeued, starting a replacement",
                slot.name, type(exc).__name__, len(lost))
    pool.spawn()
