"""One process's share of a run: a GL context, the three stages on it, and the loaded
body and sources they keep between tasks. Both executors (local processes, Ray actors)
run their tasks on a :class:`Worker`; every task returns a report (timings, GL info,
rejected views) that ``generate`` adds up."""
from __future__ import annotations

import os
import sys

from ..config import Config
from .inputs import Inputs
from .stages import BlendLesions, Generate2DViews, SelectAndPaste


class Worker:
    """The stages of one process on one renderer (its own GL context)."""

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
        return self.report()

    def render(self, tasks, progress=False):
        """Render the (body id, view index) ``tasks``."""
        rejected = self.views.synthesize_views(tasks, progress=progress)
        return {**self.report(), "rejected": rejected, "done": len(tasks)}

    def report(self) -> dict:
        """The stages' timings since the last report, and the GL in use."""
        timings = {}
        for stage in (self.paste, self.blend, self.views):
            for k, t in stage.timings.items():
                timings[k] = timings.get(k, 0.0) + t
            stage.timings = {}
        return {"timings": timings, "gl": self.views.renderer.info}

    def close(self):
        self.views.renderer.close()


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
