"""``glsynth sim2real`` end to end on a tiny budget, with real-layout images the test writes."""
import json
import os

import cv2
import numpy as np
import pytest
import torch

from glsynth.config import load_config
from glsynth.io.images import write_png
from glsynth.train.sim2real import sim2real

TINY = ["bodies.texture_size=512", "lesions.per_body=2", "blend.method=paste", "views.size=96",
        "paste.view_size=256", "backgrounds.count=2", "seed=11"]


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def fitz_folder(root, n=3, seed=0, bad_mask=None):
    rng = np.random.default_rng(seed)
    for k in range(n):
        h, w = 70 + 5 * k, 90
        img = np.clip(rng.normal([190, 140, 120], 10, (h, w, 3)), 0, 255).astype(np.uint8)
        les = np.zeros((h, w), np.uint8)
        cv2.circle(les, (40 + 3 * k, 35), 10 + k, 255, -1)
        img[les > 0] = (110, 60, 50)
        ns = np.zeros((h, w), np.uint8)
        ns[:, :15] = 255
        d = root / f"img{k}"
        d.mkdir(parents=True)
        cv2.imwrite(str(d / "image.jpg"), img[..., ::-1])
        write_png(d / "lesions.png", les if k != bad_mask else les[:-3])
        write_png(d / "nonskin.png", ns)
    (root / "metadata.csv").write_text("name,label,fitzpatrick\n" + "".join(
        f"img{k},cond{k % 2},{k + 2}\n" for k in range(n)))
    return root


@pytest.mark.slow
def test_sim2real_end_to_end_and_resume(tmp_path):
    real = fitz_folder(tmp_path / "real")
    val = fitz_folder(tmp_path / "val", n=2, seed=1)
    cfg = load_config(None, TINY)
    out = tmp_path / "run"
    s = sim2real(cfg, real, "fitz17k", 0.6, out, val=val, views_per_body=6, bodies_per_part=1,
                 size=64, progress=False)
    assert {"report.md", "summary.json", "per_image.csv", "grid.png", "model.pt"} <= set(os.listdir(out))
    saved = json.load(open(out / "summary.json"))
    for c in ("lesion", "skin", "nonskin"):
        assert 0 <= saved["jaccard"][c] <= 1
        assert saved["jaccard"][c] == pytest.approx(saved["classes"][c]["jaccard_mean"])
        assert c in saved["jaccard_nonempty"]
    r = saved["sim2real"]
    assert saved["n_images"] == 3 and r["images_generated"] >= 6 and r["device"] == "cpu"
    assert 1 <= r["training_steps"] <= r["planned_steps"] and r["training_seconds"] > 0
    assert r["checkpoint"] == "model.best.pt" and r["best"]["step"] >= 1
    assert saved["by_diagnosis"].keys() == {"cond0", "cond1"}
    assert "paper" in open(out / "report.md").read()
    # a finished run resumes to the same result without more training
    again = sim2real(cfg, real, "fitz17k", 0.6, out, val=val, resume=True, size=64, progress=False)
    assert again["sim2real"]["training_steps"] == r["training_steps"]
    assert again["jaccard"] == pytest.approx(saved["jaccard"])
    with pytest.raises(FileExistsError, match="--resume"):
        sim2real(cfg, real, "fitz17k", 0.6, out, progress=False)


def test_bad_real_folders_fail_before_any_work(tmp_path):
    cfg = load_config(None, TINY)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="empty"):
        sim2real(cfg, empty, "fitz17k", 1, tmp_path / "a", progress=False)
    bad = fitz_folder(tmp_path / "bad", bad_mask=1)
    with pytest.raises(ValueError, match=r"img1.*lesions\.png.*does not match"):
        sim2real(cfg, bad, "fitz17k", 1, tmp_path / "b", progress=False)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
