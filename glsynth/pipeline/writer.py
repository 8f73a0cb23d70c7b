"""Writing a dataset: one atomic file per layer, the per-image JSON last (a sample is
complete exactly when its JSON exists, which is what --resume looks for), in background
threads (``SampleWriter``); then COCO, params.csv and the manifest gathered from the
JSONs."""
from __future__ import annotations

import csv
import io
import json
import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..dataformat import image_path, layer_path, record_path, sample_ids
from ..io.images import write_bytes, write_png, write_text


def sample_done(out_dir, sample_id) -> bool:
    return os.path.isfile(record_path(out_dir, sample_id))


def write_sample(out_dir, sample_id, layers: dict, meta: dict, outputs):
    def path(layer):
        return layer_path(out_dir, sample_id, layer)

    if "rgb" in outputs:
        write_png(image_path(out_dir, sample_id), layers["image"])
    if "semantic" in outputs:
        write_png(path("semantic"), layers["semantic"])
    if "instances" in outputs:
        write_png(path("instances"), layers["instances"])
    if "anatomy" in outputs and "anatomy" in layers:
        write_png(path("anatomy"), layers["anatomy"])
    if "depth" in outputs:
        write_depth(path("depth"), layers["depth"])
    if "nevi" in outputs:        # uint16 nevus ids (0 none; boxes in the JSON's "nevi")
        write_png(path("nevi"), layers["nevi"])
    # extra 3D outputs, as .npy (np.load reads them; no precision lost to PNG scaling)
    if "normals" in outputs:     # float16 H x W x 3, unit camera-space normals, 0 off the body
        write_npy(path("normals"), layers["normals"].astype(np.float16))
    if "uv" in outputs:          # float32 H x W x 2, texture (u, v), -1 off the body
        write_npy(path("uv"), layers["uv"].astype(np.float32))
    if "face_id" in outputs:     # int32 H x W, mesh face index, -1 off the body
        write_npy(path("face_id"), layers["face_id"].astype(np.int32))
    write_text(record_path(out_dir, sample_id), json.dumps(meta, indent=1, sort_keys=True))


def write_depth(path, depth):
    import tifffile
    buf = io.BytesIO()
    # Deflate (level 1) after TIFF's floating-point predictor (imagecodecs): half the size
    # of plain Deflate at a third of the time (512^2: 292 kB in 4.2 ms vs 584 kB in 12 ms
    # with Python's zlib), and still read by libtiff, OpenCV, GDAL and tifffile.
    tifffile.imwrite(buf, depth.astype(np.float32), compression="zlib", compressionargs={"level": 1},
                     predictor=3, metadata=None)
    write_bytes(path, buf.getvalue())


def write_npy(path, array):
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    write_bytes(path, buf.getvalue())


def rle_encode(mask: np.ndarray) -> dict:
    """COCO uncompressed RLE: run lengths over the column-major pixels, starting with
    a run of zeros (possibly empty)."""
    flat = np.asarray(mask, bool).ravel(order="F").astype(np.int8)
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    counts = np.diff(np.r_[0, changes, flat.size]).tolist()
    if flat.size and flat[0]:
        counts = [0] + counts
    return {"size": [int(mask.shape[0]), int(mask.shape[1])], "counts": [int(c) for c in counts]}


def read_json(path):
    with open(path) as fh:
        return json.load(fh)


def finalize(out_dir, manifest: dict):
    """COCO annotations, params.csv and manifest.json from every complete sample."""
    from concurrent.futures import ThreadPoolExecutor
    ids = sample_ids(out_dir)
    coco = {"info": {"description": "glsynth synthetic dermatology images",
                     "version": manifest.get("glsynth_version")},
            "categories": [{"id": 1, "name": "lesion", "supercategory": "skin condition"}],
            "images": [], "annotations": []}
    rows = []
    # decoding the instance PNGs is most of the work and releases the GIL: in threads
    with ThreadPoolExecutor(max(1, min(8, os.cpu_count() or 1))) as pool:
        samples = pool.map(lambda sid: _coco_entries(out_dir, sid), ids)
        for img_id, (sid, meta, anns) in enumerate(samples, 1):
            coco["images"].append({"id": img_id, "file_name": f"images/{sid}.png", "width": meta["width"],
                                   "height": meta["height"], "glsynth_id": sid})
            for ann in anns:
                coco["annotations"].append({"id": len(coco["annotations"]) + 1, "image_id": img_id, **ann})
            rows.append(_param_row(sid, meta))
    write_text(os.path.join(out_dir, "annotations.coco.json"), json.dumps(coco))
    if rows:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        write_text(os.path.join(out_dir, "params.csv"), buf.getvalue())
    manifest["counts"] = {"images": len(ids), "lesion_annotations": len(coco["annotations"])}
    write_text(os.path.join(out_dir, "manifest.json"), json.dumps(manifest, indent=1, sort_keys=True),
               durable=True)


def _coco_entries(out_dir, sid):
    """(sid, per-image JSON, its COCO annotations without ids)."""
    from ..io.images import read_image
    meta = read_json(record_path(out_dir, sid))
    inst_path = layer_path(out_dir, sid, "instances")
    inst = read_image(inst_path) if os.path.isfile(inst_path) else None
    anns = []
    for lesion in meta["lesions"]:
        x0, y0, x1, y1 = lesion["box"]
        ann = {"category_id": 1, "iscrowd": 0, "bbox": [x0, y0, x1 - x0, y1 - y0],
               "area": int(lesion["area"]), "glsynth_instance": lesion["instance"]}
        if inst is not None:
            ann["segmentation"] = rle_encode(inst == lesion["instance"])
        anns.append(ann)
    return sid, meta, anns


def _param_row(sid, meta) -> dict:
    cam, light, mat = meta["camera"], meta["light"], meta["material"]
    return {"id": sid, "body": meta["body"]["id"], "w": cam.get("w"), "fov_deg": cam["fov_deg"],
            "eye_x": cam["eye"][0], "eye_y": cam["eye"][1], "eye_z": cam["eye"][2],
            "light_x": light["position"][0], "light_y": light["position"][1],
            "light_z": light["position"][2],
            "ambient": float(np.mean(light["ambient"])), "diffuse": float(np.mean(light["diffuse"])),
            "specular": float(np.mean(light["specular"])),
            "material_specular": float(np.mean(mat["specular"])), "shininess": mat["shininess"],
            "background": meta["background"]["index"], "blur": meta["background"]["blur"],
            "skin_fraction": meta["fractions"]["skin"], "lesion_fraction": meta["fractions"]["lesion"],
            "lesions": len(meta["lesions"])}


class SampleWriter:
    """Runs each sample's finishing work (``submit(fn)``) in background threads, at
    most ``max_pending`` samples behind the renderer; leaving the ``with`` block waits
    for all of them and re-raises the first error. A sample's JSON is still its last
    file, so an interrupted run leaves only complete samples or temporaries."""

    def __init__(self, threads=2, max_pending=3):
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
