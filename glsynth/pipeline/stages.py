"""The three stages of the paper's listing, each usable alone, resumable and seeded:

    cfg = gs.load_config("configs/default.yaml")
    SelectAndPaste(cfg, out).paste_on_locations()
    BlendLesions(cfg, out).blend_lesions()
    Generate2DViews(cfg, out).synthesize_views()

Per body, ``OUT/bodies/<id>/`` keeps the pasted textures (T_p, T_m, T_d and the
placements) and the blended texture T_b, which view generation reuses.
"""
from __future__ import annotations

import contextlib
import gc
import json
import logging
import os
import sys
import threading
import time

import numpy as np
from tqdm import tqdm

from .. import __version__
from ..config import Config
from ..dataformat import BLENDED, BOX_CONVENTION, PASTED, camera_record, lights_record
from ..errors import InputError
from ..io.images import read_rgb, write_png, write_text
from . import views as V
from .bodies import TexelGeometry, body_ids, load_body
from .inputs import Inputs, background_source, lesion_source, open_inputs
from .paste import PasteError, PasteSettings, PastedTextures, paste_lesions
from .runlock import open_run
from .seeding import rng_for, torch_seed
from .writer import finalize, sample_done, write_sample

log = logging.getLogger(__name__)


class _Stage:
    """A pipeline stage. Given no ``renderer``, it makes one on first use and releases
    it (and its GL context) when the public call that made it returns, so the paper's
    one-line use, ``SelectAndPaste(cfg, out).paste_on_locations()``, leaves nothing
    behind (llvmpipe keeps ~0.2 GB of textures per body in a context). A renderer
    passed in is the caller's to close."""

    def __init__(self, config: Config, out, renderer=None, body_subset=None,
                 inputs: Inputs | None = None):
        self.cfg, self.out = config, os.fspath(out)
        inputs = inputs or Inputs()  # sources opened already (else each stage opens its own)
        self._lesions, self._backgrounds = inputs.lesions, inputs.backgrounds
        self._renderer = renderer
        self._owns_renderer = renderer is None
        self.body_ids = body_subset if body_subset is not None else body_ids(config)
        self.timings = {}
        self._timings_lock = threading.Lock()  # finishing threads add to the timings too

    @property
    def renderer(self):
        if self._renderer is None:
            from ..gl.renderer import Renderer
            size = max(self.cfg.paste.view_size, self.cfg.views.size)
            self._renderer = Renderer(size, size)
        return self._renderer

    @contextlib.contextmanager
    def _releasing_own_renderer(self):
        """Around a public call: release the renderer this stage made during it."""
        made_here = self._owns_renderer and self._renderer is None
        try:
            yield
        finally:
            if made_here and self._renderer is not None:
                self._renderer.close()
                self._renderer = None

    def body_dir(self, body_id):
        return os.path.join(self.out, "bodies", body_id)

    def _time(self, name, seconds):
        with self._timings_lock:
            self.timings[name] = self.timings.get(name, 0.0) + seconds


class SelectAndPaste(_Stage):
    """Place ``lesions.per_body`` lesions on every body (skipping bodies done before)."""

    def paste_on_locations(self):
        with self._releasing_own_renderer():
            self._paste_on_locations()

    def _paste_on_locations(self):
        cfg = self.cfg
        if cfg.lesions.per_body == 0:
            log.info("lesions.per_body is 0: nothing to paste")
            return
        lesions = self._lesions  # a worker keeps it across bodies
        settings = PasteSettings.from_config(cfg)
        for body_id in tqdm(self.body_ids, desc="paste", unit="body"):
            folder = self.body_dir(body_id)
            if PastedTextures.exists(folder):
                continue
            if lesions is None:
                lesions = self._lesions = lesion_source(cfg)
            if len(lesions) == 0:
                raise PasteError(f"lesions.source {cfg.lesions.source!r}: no usable lesions")
            t0 = time.perf_counter()
            body = load_body(cfg, body_id)
            self._time("load_body", time.perf_counter() - t0)
            t0 = time.perf_counter()
            rng = rng_for(cfg.seed, "lesion-choice", body_id)
            chosen = [lesions[int(i)] for i in rng.choice(len(lesions), cfg.lesions.per_body,
                                                             replace=len(lesions) < cfg.lesions.per_body)]
            renderer = self.renderer
            texels = TexelGeometry.of(renderer, body.mesh)
            result = paste_lesions(renderer, body, texels, chosen, settings, (body_id,), cfg.seed)
            result.save(folder)
            self._time("paste", time.perf_counter() - t0)
            log.info("%s: %d of %d lesions placed", body_id, len(result.placements), len(chosen))


class BlendLesions(_Stage):
    """Blend every pasted body's lesions (method from the config); writes blended.png."""

    def blend_lesions(self):
        with self._releasing_own_renderer():
            self._blend_lesions()

    def _blend_lesions(self):
        cfg, b = self.cfg, self.cfg.blend
        extractor = getattr(self, "_extractor", None)
        self.feature_description = getattr(self, "feature_description", "none")
        for body_id in tqdm(self.body_ids, desc=f"blend ({b.method})", unit="body"):
            folder = self.body_dir(body_id)
            if not PastedTextures.exists(folder) or os.path.isfile(os.path.join(folder, BLENDED)):
                continue
            body = load_body(cfg, body_id)
            pasted = PastedTextures.load(folder, body.mesh.texture)
            t0 = time.perf_counter()
            record = {"method": b.method, "lesions": {}}
            renderer = self.renderer
            if b.method == "paste" or not any(p.kind == "image" for p in pasted.placements):
                blended = pasted.pasted
            elif b.method == "poisson":
                from .poisson import poisson_blend
                blended = poisson_blend(renderer, body.mesh, pasted, TexelGeometry.of(renderer, body.mesh),
                                        b.pad)
            else:
                from .blend import BlendSettings, DeepBlender  # torch: imported only to blend deep
                settings = BlendSettings.from_config(b)
                if settings.needs_features and extractor is None:
                    from .features import make_extractor
                    extractor, self.feature_description = make_extractor(b.features, b.vgg_weights)
                    self._extractor = extractor
                blender = DeepBlender(renderer, body.mesh, pasted, settings, extractor)
                images = [p for p in pasted.placements if p.kind == "image"]  # fields need none
                for p in tqdm(images, desc=f"{body_id} lesions", unit="lesion", leave=False):
                    losses = blender.blend(p, rng_for(cfg.seed, "blend", body_id, p.instance),
                                           torch_seed(cfg.seed, "blend", body_id, p.instance))
                    record["lesions"][p.instance] = {
                        "first": losses[0] if losses else None, "last": losses[-1] if losses else None}
                blended = blender.result()
                record["features"] = self.feature_description
            if cfg.lesions.decal_size > 0 and pasted.placements:
                # before blended.png, which marks the body as done
                self._decals(body, pasted, blended, folder)
            write_png(os.path.join(folder, BLENDED), blended)
            # no timings here: every file but manifest.json is the same on every run
            write_text(os.path.join(folder, "blend.json"), json.dumps(record, indent=1, sort_keys=True))
            self._time("blend", time.perf_counter() - t0)


    def _decals(self, body, pasted, blended, folder):
        """Each lesion at its own resolution (pipeline/decals.py), saved with the body."""
        from ..assets.lesions import lesion_from_meta
        from .decals import build_decals
        renderer = self.renderer
        decals = build_decals(renderer, body.mesh, TexelGeometry.of(renderer, body.mesh), pasted.original,
                              pasted.pasted, blended, pasted.placements,
                              lambda p: lesion_from_meta(p.lesion_meta), self.cfg.lesions.decal_size)
        decals.save(folder)


class Generate2DViews(_Stage):
    """Render ``views.per_body`` annotated views per body and write the dataset."""

    writer_threads = 2  # finishing threads (composite, camera model, encoding)

    def synthesize_views(self, tasks=None, progress=True):
        """Render the (body id, view index) ``tasks`` (default: all of this run's) that
        are not written yet; returns {rejection reason: count}."""
        with self._releasing_own_renderer():
            return self._synthesize_views(tasks, progress)

    def _synthesize_views(self, tasks, progress):
        v = self.cfg.views
        if tasks is None:
            tasks = [(b, j) for b in self.body_ids for j in range(v.per_body)]
        todo = [(b, j) for b, j in tasks if not sample_done(self.out, f"{b}_{j:04d}")]
        bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), desc="views", unit="img",
                   disable=not progress)
        rejected = {}
        self.renderer  # made here, on the thread that renders (the helper thread stages)
        if todo:  # the first body loads in the helper thread while the backgrounds are made
            self._load_body_ahead(todo[0][0])
        if self._backgrounds is None:
            self._backgrounds = background_source(self.cfg)
        # Python's cyclic collector kept walking every object torch, the modules and the
        # loaded assets hold (~4% of a run's CPU in perf); frozen, it scans only what the
        # views themselves allocate. Unfrozen at the end, so that what this run leaves
        # behind can be collected.
        gc.freeze()
        try:
            # Compositing, the camera model and encoding run in background threads while
            # the next view renders (OpenCV, zlib and numpy release the GIL).
            with SampleWriter(threads=self.writer_threads) as writer:
                for t, (body_id, j) in enumerate(todo):
                    self._prefetch(todo[t:t + self.prefetch_views])
                    state = self._body_state(body_id)
                    t0 = time.perf_counter()
                    finish = self._one_view(self.renderer, body_id, *state, j, rejected)
                    if finish is not None:
                        writer.submit(finish)
                    self._time("views", time.perf_counter() - t0)
                    bar.update(1)
        finally:
            self._stop_prefetch()
            gc.unfreeze()
        bar.close()
        if rejected:
            log.info("rejected views: %s", ", ".join(f"{n}x {r}" for r, n in sorted(rejected.items())))
        return rejected

    prefetch_views = 6  # backgrounds made this many views ahead

    def _tint_background_choice(self, body_id, j, n_backgrounds):
        """(index, blur) of view j's background when the room tints the light: drawn
        from its own generator before the scene, so it can be known ahead."""
        rng = rng_for(self.cfg.seed, "background", body_id, j)
        return int(rng.integers(n_backgrounds)), float(rng.uniform(*self.cfg.backgrounds.blur))

    def _prefetch(self, upcoming):
        """In a helper thread, ahead of the coming views: load the next body from disk
        (~0.2 s each, which the render thread used to wait for at every body change)
        and make (or decode and resize) their backgrounds (a procedural room is ~50 ms
        of numpy and OpenCV)."""
        current = getattr(self, "_state", (None,))[0]
        following = next((b for b, _ in upcoming if b != (current or upcoming[0][0])), None)
        if following is not None:
            self._load_body_ahead(following)
        if self.cfg.views.ambient_tint <= 0:
            return  # without tint the background index is drawn after the scene
        size = self.cfg.views.size
        for body_id, j in upcoming:
            i, _ = self._tint_background_choice(body_id, j, len(self._backgrounds))
            if i not in self._bg_futures:
                self._bg_futures[i] = self._submit(self._backgrounds.get, i, size, size)

    def _submit(self, fn, *args):
        """Run ``fn(*args)`` in the helper thread (made on first use)."""
        from concurrent.futures import ThreadPoolExecutor
        if getattr(self, "_helper", None) is None:
            self._helper = ThreadPoolExecutor(1, thread_name_prefix="glsynth-prefetch")
            self._bg_futures, self._body_futures = {}, {}
        return self._helper.submit(fn, *args)

    def _load_body_ahead(self, body_id):
        """Start loading ``body_id`` in the helper thread; ``_body_state`` collects it."""
        if body_id not in getattr(self, "_body_futures", {}):
            future = self._submit(self._body_from_disk, body_id)
            self._body_futures[body_id] = future

    def _stop_prefetch(self):
        if getattr(self, "_helper", None) is not None:
            self._helper.shutdown(wait=True, cancel_futures=True)
            self._helper = None
            self._bg_futures, self._body_futures = {}, {}

    def _background(self, i):
        """Background ``i`` at the view size (waiting for its prefetch if one runs)."""
        future = getattr(self, "_bg_futures", {}).pop(i, None)
        if future is not None:
            return future.result()
        size = self.cfg.views.size
        return self._backgrounds.get(i, size, size)

    def _body_from_disk(self, body_id):
        """The part of a body's view state that needs no GL: the body, its textured mesh
        (staged for upload) and label maps."""
        body = load_body(self.cfg, body_id)
        textured, instances, placements = self._textures(body_id, body)
        from .decals import Decals
        decals = Decals.load(self.body_dir(body_id)) if placements else None
        mesh_b = body.mesh.copy_with(texture=textured, decals=decals)
        self.renderer.stage(mesh_b)
        return body, mesh_b, instances, placements

    def _body_state(self, body_id):
        """Everything views of one body share; the last body's is kept."""
        cached = getattr(self, "_state", None)
        if cached is not None and cached[0] == body_id:
            return cached[1]
        t0 = time.perf_counter()
        future = getattr(self, "_body_futures", {}).pop(body_id, None)
        body, mesh_b, instances, placements = (future.result() if future is not None
                                               else self._body_from_disk(body_id))
        # the textured mesh: it goes to the GPU for the views anyway (one upload)
        lesion_points = self._lesion_points(self.renderer, mesh_b, instances, placements)
        state = (body, mesh_b, instances, V.nevi_label_map(body), placements, lesion_points,
                 self._backgrounds)
        self._state = (body_id, state)
        self._time("load_body", time.perf_counter() - t0)
        return state

    def _textures(self, body_id, body):
        folder = self.body_dir(body_id)
        h, w = body.mesh.texture.shape[:2]
        if self.cfg.lesions.per_body == 0 or not PastedTextures.exists(folder):
            return body.mesh.texture, np.zeros((h, w), np.uint16), []
        instances, placements = PastedTextures.load_instances(folder)
        blended_path = os.path.join(folder, BLENDED)
        texture = read_rgb(blended_path if os.path.isfile(blended_path) else os.path.join(folder, PASTED))
        return texture, instances, placements

    def _lesion_points(self, renderer, mesh, instances, placements):
        """A views.LesionSite per placed lesion: its texels' points, normals and area."""
        if not placements:
            return []
        h, w = instances.shape
        uv = mesh.uvs[mesh.face_uvs]
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * (w * h)
        texel_area = mesh.face_areas / np.maximum(uv_area, 1e-30)   # surface per texel, by face
        sites = []
        for p in placements:  # only each lesion's texel box is rasterised (~10 ms, not 240)
            tx = TexelGeometry.of(renderer, mesh, only=np.isin(instances, p.ids), box=p.texel_box)
            if len(tx.rows):
                sites.append(V.LesionSite(tx.points, tx.normals, float(texel_area[tx.faces].sum())))
        return sites

    def _one_view(self, renderer, body_id, body, mesh_b, instances, nevi_map, placements,
                  lesion_points, backgrounds, j, rejected):
        """Sample and render view ``j``; returns the function that composites, applies
        the camera model and writes it (None when no acceptable view was found)."""
        from . import photo
        cfg, v = self.cfg, self.cfg.views
        sid = f"{body_id}_{j:04d}"
        rng = rng_for(cfg.seed, "view", body_id, j)
        tint, background = None, None
        if v.ambient_tint > 0:
            # the room's colour must be known before shading: the background is drawn
            # first, from its own generator (the view's stream stays as it was)
            bg_index, blur = self._tint_background_choice(body_id, j, len(backgrounds))
            background = self._background(bg_index)
            tint = V.ambient_tint_from(background, v.ambient_tint)
        for attempt in range(1, v.attempts + 1):
            try:
                scene = V.sample_scene(body, lesion_points, rng, v, renderer, ambient_tint=tint,
                                       drawn=mesh_b)
                layers = V.render_view(renderer, body, mesh_b, instances, nevi_map, scene, v,
                                       cfg.outputs)
                break
            except V.ViewRejected as exc:
                reason = str(exc).split(" ")[0] if "<" in str(exc) else str(exc)
                rejected[reason] = rejected.get(reason, 0) + 1
        else:
            log.warning("%s: no acceptable view in %d attempts; skipped", sid, v.attempts)
            return
        if tint is None:
            bg_index = int(rng.integers(len(backgrounds)))
            blur = float(rng.uniform(*cfg.backgrounds.blur))
        cam = scene.camera
        # camera model: its own generator, so switching it on changes no scene parameter
        focus = float(np.linalg.norm(np.subtract(cam.target, cam.eye)))
        photo_params = photo.sample_params(cfg.photo, rng_for(cfg.seed, "photo", body_id, j), focus,
                                           focal_px=float(cam.intrinsics()[1, 1]))
        if "rgb" in cfg.outputs and background is None:
            background = backgrounds.get(bg_index, v.size, v.size)
        by_instance = {k: p for p in placements for k in p.ids}
        lesions = []
        for k, region in layers["regions"].items():
            p = by_instance.get(k)
            lesions.append({"instance": k, "box": region["box"], "area": region["area"],
                            "lesion_id": p.lesion_id if p else None,
                            "source": p.lesion_meta if p else None})
        meta = {"id": sid, "width": v.size, "height": v.size, "attempts": attempt,
                "camera": camera_record(cam, centre=scene.centre, framing=scene.framing),
                "light": scene.light.to_dict(), "material": scene.material.to_dict(),
                "lights": lights_record(scene.lights),
                "ambient_tint": list(tint) if tint is not None else None,
                "photo": photo_params,
                "body": {"id": body_id, **_jsonable(body.meta)},
                "lesions": lesions,
                "nevi": [{"id": k, "box": b} for k, b in layers.get("nevi_boxes", {}).items()],
                "background": {"index": bg_index, "source": cfg.backgrounds.source, "blur": blur},
                "fractions": layers["fractions"],
                "box_convention": BOX_CONVENTION}
        out, outputs = self.out, cfg.outputs

        def finish():
            t0 = time.perf_counter()
            if "rgb" in outputs:
                image = V.composite(layers["rgba"], background, blur)
                # RGB only: every label layer stays the sharp geometric truth
                layers["image"] = photo.apply(image, photo_params, layers["depth"])
            write_sample(out, sid, layers, meta, outputs)
            self._time("finish", time.perf_counter() - t0)  # in the writer thread
        return finish


class SampleWriter:
    """Runs each sample's finishing work (``submit(fn)``) in background threads, at
    most ``max_pending`` samples behind the renderer; leaving the ``with`` block waits
    for all of them and re-raises the first error. A sample's JSON is still its last
    file, so an interrupted run leaves only complete samples or temporaries."""

    def __init__(self, threads=2, max_pending=3):
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor
        self._pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="glsynth-writer")
        self._pending, self.max_pending = deque(), max_pending

    def submit(self, fn):
        self._pending.append(self._pool.submit(fn))
        while len(self._pending) > self.max_pending:
            self._pending.popleft().result()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        try:
            while self._pending:
                future = self._pending.popleft()
                if exc[0] is None:
                    future.result()
                else:
                    future.cancel()
        finally:
            self._pool.shutdown(wait=True)
        return False


def _jsonable(obj):
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


class _Worker:
    """One process's share of a run: its own GL context, stages and loaded body."""

    def __init__(self, cfg: Config, out, writer_threads=None, inputs: Inputs | None = None):
        from ..gl.renderer import Renderer
        size = max(cfg.paste.view_size, cfg.views.size)
        renderer = Renderer(size, size)
        self.paste = SelectAndPaste(cfg, out, renderer=renderer, body_subset=[], inputs=inputs)
        self.blend = BlendLesions(cfg, out, renderer=renderer, body_subset=[])
        self.views = Generate2DViews(cfg, out, renderer=renderer, body_subset=[], inputs=inputs)
        if writer_threads is not None:  # a process's share of the cores caps the default
            self.views.writer_threads = min(Generate2DViews.writer_threads, writer_threads)
        self.cfg = cfg

    def prepare(self, body_id):
        """Paste and blend one body (skipped when done before)."""
        if self.cfg.lesions.per_body > 0:
            for stage, run in ((self.paste, self.paste.paste_on_locations),
                               (self.blend, self.blend.blend_lesions)):
                stage.body_ids = [body_id]
                run()
        return self._report()

    def close(self):
        self.views.renderer.close()

    def render(self, tasks, progress=False):
        rejected = self.views.synthesize_views(tasks, progress=progress)
        return {**self._report(), "rejected": rejected, "done": len(tasks)}

    def _report(self):
        timings = {}
        for stage in (self.paste, self.blend, self.views):
            for k, t in stage.timings.items():
                timings[k] = timings.get(k, 0.0) + t
            stage.timings = {}
        return {"timings": timings,
                "gl": self.views.renderer.info}


_PROCESS_WORKER = None


def share_cores(threads: int):
    """Limit this process's thread pools to ``threads``: llvmpipe's rasteriser threads
    (read when the GL context is made, so call this first; a user's LP_NUM_THREADS
    wins), OpenCV's and torch's. Each pool defaults to every core, so N worker
    processes oversubscribed the machine N-fold: 2 workers on 2 cores ran at 0.7x
    the samples/s of one, 8 on 16 cores at 0.75x. Torch is imported only by a deep
    blend: until then its share is passed on through OMP_NUM_THREADS."""
    import cv2
    threads = max(1, int(threads))
    os.environ.setdefault("LP_NUM_THREADS", str(threads))
    cv2.setNumThreads(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)
    else:
        os.environ["OMP_NUM_THREADS"] = str(threads)


def _worker_init(cfg_dict, out, threads):
    global _PROCESS_WORKER
    import signal
    from ..config import from_dict
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's to handle
    logging.basicConfig(level=logging.WARNING)
    share_cores(threads)
    _PROCESS_WORKER = _Worker(from_dict(cfg_dict), out, writer_threads=threads)


def _worker_prepare(body_id):
    return _PROCESS_WORKER.prepare(body_id)


def _worker_render(tasks):
    return _PROCESS_WORKER.render(tasks)


EXECUTORS = ("local", "ray")


def generate(cfg: Config, out, resume=False, workers=1, executor="local", address=None):
    """The whole pipeline into ``out``; returns the manifest.

    ``workers`` > 1 runs that many processes, each with its own GL context, started
    once: bodies are pasted and blended in parallel, then views are rendered in chunks.
    Every random choice is keyed by the task, so the files are the same for any
    number of workers. ``executor="ray"`` spreads the same tasks over Ray actors
    (``address``: an existing cluster; None starts a local one).

    ``out`` holds one run (``runlock``): a folder with a run in it needs ``resume``,
    which continues it only with the same config, seed and glsynth version, and no
    other process may write there meanwhile.
    """
    out = os.fspath(out)
    if workers < 1:
        raise InputError(f"workers must be >= 1, got {workers}")
    if executor not in EXECUTORS:
        raise InputError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    # one run per folder: locked, and its fingerprint written first or checked
    with open_run(out, cfg, resume):
        return _generate(cfg, out, resume, workers, executor, address)


def _generate(cfg, out, resume, workers, executor, address):
    if resume:
        _remove_partial_writes(out)
    inputs = open_inputs(cfg)  # every input file checked before any stage works
    t_start = time.perf_counter()
    ids = body_ids(cfg)
    tasks = [(b, j) for b in ids for j in range(cfg.views.per_body)]
    chunk = max(1, min(8, len(tasks) // (4 * workers) or 1))
    chunks = [tasks[i:i + chunk] for i in range(0, len(tasks), chunk)]
    reports = []
    if executor == "ray":
        from .ray_executor import run_ray
        reports = run_ray(cfg, out, ids, chunks, workers, address)
    elif workers == 1:
        worker = _Worker(cfg, out, inputs=inputs)
        try:
            reports += [worker.prepare(b) for b in tqdm(ids, desc="paste + blend", unit="body")]
            # one call for all views: the stage then loads each next body while rendering
            reports.append(worker.render(tasks, progress=True))
        finally:  # a process that calls generate again must not keep this run's GL memory
            worker.close()
    else:
        import multiprocessing as mp
        ctx = mp.get_context("spawn")  # GL contexts do not survive fork
        threads = max(1, (os.cpu_count() or 1) // workers)
        with ctx.Pool(workers, initializer=_worker_init, initargs=(cfg.to_dict(), out, threads)) as pool:
            reports += list(tqdm(pool.imap_unordered(_worker_prepare, ids), total=len(ids),
                                 desc="paste + blend", unit="body"))
            bar = tqdm(total=len(tasks), desc="views", unit="img")
            for r in pool.imap_unordered(_worker_render, chunks):
                reports.append(r)
                bar.update(r["done"])
            bar.close()
    timings, rejected = {}, {}
    for r in reports:
        for k, t in r["timings"].items():
            timings[k] = timings.get(k, 0.0) + t
        for k, n in r.get("rejected", {}).items():
            rejected[k] = rejected.get(k, 0) + n
    timings["total"] = time.perf_counter() - t_start
    features = _blend_features(out, ids)
    gl = reports[-1]["gl"] if reports else {}
    manifest = {"glsynth_version": __version__, "seed": cfg.seed, "config": cfg.to_dict(),
                "workers": workers, "executor": executor, "gl_renderer": gl.get("GL_RENDERER"),
                "gl_version": gl.get("GL_VERSION"), "versions": _versions(),
                "blend_features": ", ".join(features),
                "timings_seconds": {k: round(t, 3) for k, t in timings.items()},
                "rejected_views": rejected}
    finalize(out, manifest)
    return manifest


def _blend_features(out, ids) -> list:
    """The feature extractors the bodies' deep blends used, from their blend.json: the
    same for a resumed run, which blends nothing itself."""
    found = set()
    for body_id in ids:
        path = os.path.join(out, "bodies", body_id, "blend.json")
        if os.path.isfile(path):
            with open(path) as fh:
                found.add(json.load(fh).get("features", "none"))
    return sorted(found - {"none"}) or ["none"]


def _remove_partial_writes(out):
    """Temporary files of writes a killed run never renamed into place."""
    for root, _, names in os.walk(out):
        for n in names:
            if n.startswith(".tmp-"):
                os.unlink(os.path.join(root, n))


def _versions():
    import importlib.metadata as md
    out = {}
    for pkg in ("numpy", "torch", "moderngl", "anny", "opencv-contrib-python-headless"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out
