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
import threading
import time

import numpy as np
from tqdm import tqdm

from ..config import Config
from ..dataformat import BLENDED, PASTED, view_record
from ..io.images import read_rgb, write_png, write_text
from . import views as V
from .bodies import TexelGeometry, body_ids, load_body
from .inputs import Inputs, background_source, lesion_source
from .paste import PasteError, PasteSettings, PastedTextures, paste_lesions
from .prefetch import Prefetcher
from .seeding import rng_for, torch_seed
from .writer import SampleWriter, sample_done, write_sample

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
        # a procedural bank is dealt out by each body's place in the whole run
        procedural = cfg.lesions.source == "procedural"
        run_bodies = body_ids(cfg) if procedural else None
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
            if procedural:
                # the bank holds per_body lesions for each body of the whole run (shards
                # included): dealt out by the body's index, none shared
                first = (cfg.bodies.first + run_bodies.index(body_id)) * cfg.lesions.per_body
                picks = (first + np.arange(cfg.lesions.per_body)) % len(lesions)
            else:
                picks = rng.choice(len(lesions), cfg.lesions.per_body,
                                   replace=len(lesions) < cfg.lesions.per_body)
            chosen = [lesions[int(i)] for i in picks]
            # the rest of the bank, in a seeded order, for a body that can hold none of these
            taken = set(picks.tolist())
            spares = (lesions[int(i)] for i in rng.permutation(len(lesions)) if i not in taken)
            eruption = _eruption(cfg.lesions, lesions, chosen, rng_for(cfg.seed, "eruption", body_id))
            renderer = self.renderer
            texels = TexelGeometry.of_body(renderer, body.mesh)
            result = paste_lesions(renderer, body, texels, chosen, settings, (body_id,), cfg.seed,
                                   spares, eruption)
            result.save(folder)
            self._time("paste", time.perf_counter() - t0)
            log.info("%s: %d of %d lesions placed", body_id, len(result.placements), len(chosen))


def _eruption(le, bank, chosen, rng):
    """paste_lesions' ``eruption`` (spread, radius in m) when the body's first placed
    procedural lesion of an eruptive preset spreads (probability ``lesions.eruption``),
    else None."""
    from ..assets.morphology import ERUPTIVE
    if le.eruption <= 0 or not hasattr(bank, "spread"):
        return None
    if not any(lesion.meta.get("preset") in ERUPTIVE for lesion in chosen) or rng.random() >= le.eruption:
        return None
    n = int(rng.integers(int(le.eruption_lesions[0]), int(le.eruption_lesions[1]) + 1))

    def spread(lesion):
        if lesion.meta.get("preset") not in ERUPTIVE:
            return []
        return [bank.spread(lesion, j) for j in range(1, n + 1)]
    return spread, float(rng.uniform(*le.eruption_radius))


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
                texels = TexelGeometry.of_body(renderer, body.mesh)
                blended = poisson_blend(renderer, body.mesh, pasted, texels, b.pad)
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
        TexelGeometry.forget()

    def _decals(self, body, pasted, blended, folder):
        """Each lesion at its own resolution (pipeline/decals.py), saved with the body."""
        from ..assets.lesions import lesion_from_meta
        from .decals import build_decals
        renderer = self.renderer
        texels = TexelGeometry.of_body(renderer, body.mesh)
        decals = build_decals(renderer, body.mesh, texels, pasted.original, pasted.pasted, blended,
                              pasted.placements,
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
        self._ahead = Prefetcher()
        if todo:  # the first body loads in the helper thread while the backgrounds are made
            self._ahead.start(("body", todo[0][0]), self._body_from_disk, todo[0][0])
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
            self._ahead.close()
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
        """Start the helper thread (prefetch.py) on what the coming views need: the
        next body, and (when the room tints the light, which needs the background
        before the scene) their backgrounds."""
        current = getattr(self, "_state", (None,))[0]
        following = next((b for b, _ in upcoming if b != (current or upcoming[0][0])), None)
        if following is not None:
            self._ahead.start(("body", following), self._body_from_disk, following)
        if self.cfg.views.ambient_tint <= 0:
            return  # without tint the background index is drawn after the scene
        size = self.cfg.views.size
        for body_id, j in upcoming:
            i, _ = self._tint_background_choice(body_id, j, len(self._backgrounds))
            self._ahead.start(("background", i), self._backgrounds.get, i, size, size)

    def _body_from_disk(self, body_id):
        """The part of a body's view state that needs no GL: the body, its textured mesh
        (staged for upload) and label maps."""
        body = load_body(self.cfg, body_id)
        textured, instances, placements = self._textures(body_id, body)
        from .decals import Decals
        decals = Decals.load(self.body_dir(body_id)) if placements else None
        occlusion = None
        if self._wants_occlusion():
            from ..gl.occlusion import stored_occlusion
            occlusion = stored_occlusion(body.mesh)
        mesh_b = body.mesh.copy_with(texture=textured, decals=decals, occlusion=occlusion)
        self.renderer.stage(mesh_b)
        return body, mesh_b, instances, placements

    def _wants_occlusion(self):
        v = self.cfg.views
        return v.occlusion and v.shading == "skin" and "rgb" in self.cfg.outputs

    def _body_state(self, body_id):
        """Everything views of one body share; the last body's is kept."""
        cached = getattr(self, "_state", None)
        if cached is not None and cached[0] == body_id:
            return cached[1]
        t0 = time.perf_counter()
        body, mesh_b, instances, placements = self._ahead.get(("body", body_id), self._body_from_disk,
                                                              body_id)
        if self._wants_occlusion() and mesh_b.occlusion is None:  # not baked yet: GL, so here
            from ..gl.occlusion import cached_occlusion
            mesh_b = mesh_b.copy_with(occlusion=cached_occlusion(self.renderer, body.mesh))
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
        """A views.LesionSite per placed lesion, an eruption's lesions making one: its
        texels' points, normals and area."""
        if not placements:
            return []
        h, w = instances.shape
        uv = mesh.uvs[mesh.face_uvs]
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * (w * h)
        texel_area = mesh.face_areas / np.maximum(uv_area, 1e-30)   # surface per texel, by face
        groups = {}         # site key -> (points, normals, area) of its lesions, in order
        for p in placements:  # only each lesion's texel box is rasterised (~10 ms, not 240)
            tx = TexelGeometry.of(renderer, mesh, only=np.isin(instances, p.ids), box=p.texel_box)
            if len(tx.rows):
                g = groups.setdefault(p.lesion_meta.get("eruption", ("alone", p.instance)), ([], [], []))
                g[0].append(tx.points), g[1].append(tx.normals)
                g[2].append(float(texel_area[tx.faces].sum()))
        return [V.LesionSite(np.concatenate(pts), np.concatenate(nrm), sum(area))
                for pts, nrm, area in groups.values()]

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
            background = self._ahead.get(("background", bg_index), backgrounds.get, bg_index, v.size, v.size)
            tint = V.ambient_tint_from(background, v.ambient_tint)
        for attempt in range(1, v.attempts + 1):
            try:
                scene = V.sample_scene(body, lesion_points, rng, v, renderer, ambient_tint=tint,
                                       drawn=mesh_b)
                layers = V.render_view(renderer, body, mesh_b, instances, nevi_map, scene, v,
                                       cfg.outputs)
                break
            except V.ViewRejected as exc:
                rejected[exc.reason.value] = rejected.get(exc.reason.value, 0) + 1
        else:
            log.warning("%s: no acceptable view in %d attempts; skipped", sid, v.attempts)
            return
        if tint is None:
            bg_index = int(rng.integers(len(backgrounds)))
            blur = float(rng.uniform(*cfg.backgrounds.blur))
        exposure = V.background_exposure(scene, backgrounds.meta[bg_index])
        cam = scene.camera
        focus = V.focus_distance(cam)
        occluder = None
        if scene.framing != "wild" and cfg.backgrounds.edges > 0:
            # gloved fingers, clothing or a drape at the frame's edge: its own generator
            edge_rng = rng_for(cfg.seed, "edge", body_id, j)
            if edge_rng.random() < cfg.backgrounds.edges:
                occluder = V.edge_occluder(scene, layers["semantic"].shape, edge_rng)
                occluder = occluder if V.occlude(layers, occluder, v, focus) else None
        if occluder is None and scene.framing != "wild" and cfg.backgrounds.hair > 0:
            # a lock of the patient's hair over a view of the head: its own generator
            occluder = V.hair_occluder(scene, body, layers, rng_for(cfg.seed, "hair", body_id, j),
                                       cfg.backgrounds.hair)
            occluder = occluder if occluder is not None and V.occlude(layers, occluder, v, focus) else None
        # camera model: its own generator, so switching it on changes no scene parameter
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
        meta = view_record(sid, v.size, scene, attempts=attempt, ambient_tint=tint, photo=photo_params,
                           body={"id": body_id, **_jsonable(body.meta)}, lesions=lesions,
                           nevi=[{"id": k, "box": b} for k, b in layers.get("nevi_boxes", {}).items()],
                           background={"index": bg_index, "source": cfg.backgrounds.source, "blur": blur,
                                       "exposure": exposure,
                                       "edge": occluder.meta if occluder is not None else None},
                           fractions=layers["fractions"])
        out, outputs = self.out, cfg.outputs

        def finish():
            t0 = time.perf_counter()
            if "rgb" in outputs:
                image = V.composite(layers["rgba"], V.expose(background, exposure), blur)
                if occluder is not None:
                    image = V.draw_occluder(image, occluder)
                # RGB only: every label layer stays the sharp geometric truth
                layers["image"] = photo.apply(image, photo_params, layers["depth"])
            write_sample(out, sid, layers, meta, outputs)
            self._time("finish", time.perf_counter() - t0)  # in the writer thread
        return finish


def _jsonable(obj):
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
