"""Segmentation training and evaluation (glsynth.train): loss, training, checkpoints, metrics."""
import csv
import json
import os

import cv2
import numpy as np
import pytest
import torch

import glsynth as gs
from glsynth.config import load_config
from glsynth.io.images import read_rgb, write_png
from glsynth.train import metrics
from glsynth.train.evaluate import predict, score, truth_map
from glsynth.train.loss import (anatomy_jaccard_loss, fuzzy_jaccard_loss, nevi_ignore_mask,
                                seg_jaccard_loss)
from glsynth.train.model import SegNet
from glsynth.train.trainer import load_model, prefetched, train

TINY = ["bodies.count=1", "bodies.texture_size=512", "lesions.per_body=2", "blend.method=paste",
        "views.per_body=4", "views.size=96", "views.supersample=1", "paste.view_size=256",
        "backgrounds.count=2", "seed=11"]
FAST = dict(size=64, batch_size=4, lr=5e-3, progress=False, save_every=0)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny tensors: threads only add contention
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth")
    gs.pipeline.generate(load_config(None, TINY), out)
    return out


@pytest.fixture(scope="module")
def trained(synth, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "model.pt"
    ck = train(synth, path, epochs=12, augment=False, seed=3, **FAST)
    return path, ck


def onehot(target, n):
    return torch.nn.functional.one_hot(target.clamp(0, n - 1), n).permute(0, 3, 1, 2).float()


def fuzzy_j(p, g, w):
    """Independent reference: Crum's fuzzy Jaccard sum(min) / sum(max) over weighted pixels."""
    return (np.minimum(p, g) * w).sum() / (np.maximum(p, g) * w).sum()


# ---------------------------------------------------------------------------------------
# Loss


def _seg_example():
    t = torch.ones(2, 8, 8, dtype=torch.long)          # skin
    t[0, :3, :] = 2                                      # non-skin rows
    t[0, 4:6, 4:6] = 0                                   # a lesion in image 0 only
    t[1, :, :2] = 2
    return t


def test_loss_is_zero_for_a_perfect_prediction():
    t = _seg_example()
    assert seg_jaccard_loss(onehot(t, 3), t).item() == 0.0
    a = torch.zeros(2, 8, 8, dtype=torch.long)
    a[0, 2:6, 2:6], a[1, :4] = 3, 6
    assert anatomy_jaccard_loss(onehot(a, 8), a).item() == 0.0
    total, parts = fuzzy_jaccard_loss(onehot(t, 3) * 50, t, onehot(a, 8) * 50, a)
    assert total.item() < 1e-6 and parts["seg"] < 1e-6 and parts["anatomy"] < 1e-6
    # with nevus boxes and ignored (255) pixels too
    t2 = t.clone()
    t2[1, 7, :] = 255
    ign = torch.zeros(2, 8, 8, dtype=torch.bool)
    ign[0, 3:7, 3:7] = True
    assert seg_jaccard_loss(onehot(t2, 3), t2, ign).item() == 0.0


@pytest.mark.parametrize("skin_loss", ["paper", "exclusive"])
def test_seg_loss_matches_hand_computation_per_image_and_channel(skin_loss):
    t = _seg_example()
    g = torch.Generator().manual_seed(0)
    p = torch.softmax(torch.randn(2, 3, 8, 8, generator=g), 1)
    ign = torch.zeros(2, 8, 8, dtype=torch.bool)
    ign[0, 5:8, 5:8] = True                              # nevus box overlapping the lesion
    pn, tn, ig = p.numpy(), t.numpy(), ign.numpy()
    losses = []
    for b in range(2):
        for c in range(3):
            gc = (tn[b] == c).astype(float)
            w = np.ones((8, 8))
            if c in (0, 1):
                w[ig[b]] = 0                             # nevus boxes: lesion and skin channels
            if c == 1 and skin_loss == "paper":
                w[tn[b] == 0] = 0                        # lesion pixels: skin channel
            if (gc * w).sum() == 0:
                continue                                 # empty truth: ignored
            losses.append(1 - fuzzy_j(pn[b, c], gc, w))
    assert len(losses) == 5                              # image 1 has no lesion
    got, counted = seg_jaccard_loss(p, t, ign, return_parts=True, skin_loss=skin_loss)
    assert counted.tolist() == [[True, True, True], [False, True, True]]
    assert got.item() == pytest.approx(np.mean(losses), rel=1e-5)


def test_anatomy_loss_is_per_channel_over_the_batch():
    a = torch.zeros(2, 6, 6, dtype=torch.long)
    a[0, :3] = 2                                         # group 2 only in image 0
    a[1, 3:] = 5                                         # group 5 only in image 1
    g = torch.Generator().manual_seed(1)
    p = torch.softmax(torch.randn(2, 8, 6, 6, generator=g), 1)
    pn, an = p.numpy(), a.numpy()
    ref = [1 - fuzzy_j(pn[:, c], (an == c).astype(float), np.ones_like(pn[:, c]))
           for c in (0, 2, 5)]                           # channels 1, 3, 4, 6, 7 absent: ignored
    got, counted = anatomy_jaccard_loss(p, a, return_parts=True)
    assert counted.tolist() == [True, False, True, False, False, True, False, False]
    assert got.item() == pytest.approx(np.mean(ref), rel=1e-5)
    # batch-wide, not per image: differs from averaging per-image losses
    per_image = np.mean([anatomy_jaccard_loss(p[i:i + 1], a[i:i + 1]).item() for i in range(2)])
    assert abs(per_image - got.item()) > 1e-3


def test_loss_ignores_exactly_what_the_paper_ignores():
    t = _seg_example()
    ign = torch.zeros(2, 8, 8, dtype=torch.bool)
    ign[1, 5:8, 5:8] = True
    g = torch.Generator().manual_seed(2)
    p = torch.softmax(torch.randn(2, 3, 8, 8, generator=g), 1)
    base = seg_jaccard_loss(p, t, ign).item()

    def changed(channel, where):
        q = p.clone()
        q[:, channel][where] = torch.rand(int(where.sum()), generator=g)
        return seg_jaccard_loss(q, t, ign).item() != pytest.approx(base, abs=1e-7)

    lesion = t == 0
    everywhere = torch.ones_like(ign)
    # skin channel: lesion pixels and nevus boxes do not count, other pixels do
    assert not changed(1, lesion) and not changed(1, ign)
    assert changed(1, ~lesion & ~ign)
    # lesion channel: nevus boxes do not count; image 1 has no lesion, so its whole channel is ignored
    assert not changed(0, ign)
    img1 = everywhere.clone()
    img1[0] = False
    assert not changed(0, img1)
    img0 = everywhere.clone()
    img0[1] = False
    assert changed(0, img0)
    # non-skin channel: nothing ignored, nevus boxes and lesion pixels included
    assert changed(2, ign) and changed(2, lesion)
    # the exclusive skin loss counts skin predicted on a lesion, and costs more for more
    # of it; the nevus boxes stay ignored
    q = p.clone()
    q[:, 1][lesion] = 0.99
    worse = seg_jaccard_loss(q, t, ign, skin_loss="exclusive").item()
    assert worse > seg_jaccard_loss(p, t, ign, skin_loss="exclusive").item() + 1e-3
    assert seg_jaccard_loss(q, t, ign).item() == pytest.approx(base, abs=1e-7)
    q[:, 1][ign] = 0.5
    assert seg_jaccard_loss(q, t, ign, skin_loss="exclusive").item() == pytest.approx(worse, abs=1e-7)
    with pytest.raises(ValueError, match="skin_loss"):
        seg_jaccard_loss(p, t, ign, skin_loss="lesion")
    # no "nevi" in the JSON: nothing ignored
    assert not nevi_ignore_mask({}, (4, 4)).any()
    m = nevi_ignore_mask({"nevi": [{"id": 1, "box": [1, 0, 3, 2]}, {"id": 2, "box": [3.2, 3, 9, 9]}]}, (4, 5))
    ref = np.zeros((4, 5), bool)
    ref[0:2, 1:3] = True                                 # x1, y1 exclusive
    ref[3:4, 3:5] = True                                 # clipped to the image
    assert (m == ref).all()


@pytest.mark.parametrize("case", ["all_nonskin", "all_lesion", "all_ignored", "nevus_everywhere"])
def test_gradients_are_finite_for_empty_and_full_masks(case):
    t = torch.full((2, 8, 8), {"all_nonskin": 2, "all_lesion": 0, "all_ignored": 255,
                               "nevus_everywhere": 1}[case], dtype=torch.long)
    ign = torch.full((2, 8, 8), case == "nevus_everywhere")
    a = torch.zeros(2, 8, 8, dtype=torch.long) if case != "all_ignored" else torch.full((2, 8, 8), 255)
    for scale in (1.0, 1e4):  # also saturated softmax (probabilities exactly 0 and 1)
        seg = (torch.randn(2, 3, 8, 8) * scale).requires_grad_()
        anat = (torch.randn(2, 8, 8, 8) * scale).requires_grad_()
        loss, _ = fuzzy_jaccard_loss(seg, t, anat, a, ign)
        loss.backward()
        assert torch.isfinite(loss) and 0 <= loss.item() <= 2
        assert torch.isfinite(seg.grad).all() and torch.isfinite(anat.grad).all()
    if case in ("all_ignored", "nevus_everywhere"):
        seg = torch.zeros(2, 3, 8, 8, requires_grad=True)
        loss = seg_jaccard_loss(torch.softmax(seg, 1), t, ign)
        loss.backward()
        assert loss.item() == 0 and (seg.grad == 0).all()


# ---------------------------------------------------------------------------------------
# Training and checkpoints


def test_training_lowers_the_loss(trained):
    _, ck = trained
    losses = [h["loss"] for h in ck["history"]]
    assert len(losses) == 12 and all(np.isfinite(losses))
    assert np.mean(losses[-3:]) < np.mean(losses[:3]) - 0.02, losses


def test_checkpoint_reloads_and_predicts_the_same(trained, synth):
    path, ck = trained
    model, ck2 = load_model(path)
    assert ck2["step"] == ck["step"] and ck2["hparams"]["size"] == 64
    ref = SegNet(**{k: ck["arch"][k] for k in ("n_seg", "n_anatomy", "width")})
    ref.load_state_dict(ck["model"])
    ref.eval()
    img = read_rgb(next((synth / "images").iterdir()))
    a = predict(model, img, 64)
    b = predict(ref, img, 64)
    assert a.shape == img.shape[:2] and (a == b).all()
    x = torch.randn(1, 3, 64, 80)
    with torch.no_grad():
        assert torch.equal(model(x)["seg"], ref(x)["seg"])


def test_checkpoints_hold_only_tensors_and_plain_values(trained):
    """What train writes loads with torch's weights_only unpickler and nothing allowed
    beyond its defaults (glsynth never unpickles code from a model file)."""
    path, _ = trained
    ck = torch.load(path, map_location="cpu", weights_only=True)
    assert ck["format"] == "glsynth-segnet" and type(ck["torch"]) is str


def test_interrupted_training_resumes_to_the_same_weights(synth, tmp_path):
    kw = dict(FAST, size=48, epochs=2, seed=5, batch_size=2)  # 2 batches per epoch
    full = train(synth, tmp_path / "a.pt", **kw)
    part = train(synth, tmp_path / "b.pt", max_steps=1, **kw)   # stops inside epoch 1
    assert part["stopped"] == "max steps" and part["batch_in_epoch"] == 1
    with pytest.raises(FileExistsError):
        train(synth, tmp_path / "b.pt", **kw)
    done = train(synth, tmp_path / "b.pt", resume=True, **kw)
    assert done["step"] == full["step"] == 4
    for key in ("model", "train_model"):   # the weight average and the raw weights
        for k, v in full[key].items():
            assert torch.allclose(v.float(), done[key][k].float(), atol=1e-6), (key, k)
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".tmp-")]


def test_the_skin_loss_is_stored_kept_on_resume_and_checked(synth, tmp_path):
    kw = dict(FAST, size=48, epochs=1, seed=5, batch_size=2)
    part = train(synth, tmp_path / "x.pt", max_steps=1, skin_loss="exclusive", **kw)
    assert part["hparams"]["skin_loss"] == "exclusive"
    done = train(synth, tmp_path / "x.pt", resume=True, **kw)   # the stored choice wins
    assert done["hparams"]["skin_loss"] == "exclusive"
    from glsynth.errors import InputError
    with pytest.raises(InputError, match="skin_loss"):
        train(synth, tmp_path / "y.pt", skin_loss="lesion", **kw)


def test_prefetching_keeps_order_raises_errors_and_stops_its_thread():
    import threading
    import time

    def live():
        return [t for t in threading.enumerate() if t.name.startswith("glsynth-prefetch")]

    def slow(n):
        for i in range(n):
            time.sleep(0.002 * (i % 3))
            yield i
    assert list(prefetched(slow(50), depth=3)) == list(range(50))

    def broken():
        yield 1
        raise ValueError("bad sample file")
    got = []
    with pytest.raises(ValueError, match="bad sample file"):
        for b in prefetched(broken()):
            got.append(b)
    assert got == [1]

    before = set(live())                           # (other helpers may be alive)
    it = prefetched(iter(range(10**6)), depth=2)   # left after 3 of a million batches
    assert [next(it) for _ in range(3)] == [0, 1, 2]
    assert set(live()) - before                    # its thread runs...
    it.close()
    assert set(live()) <= before                   # ...and is gone


def test_planned_steps_are_fitted_to_the_time(synth, tmp_path):
    """A plan far too long for its minutes is cut, after two epochs, to what the time
    allows, and the run then ends at the fitted step with its schedule complete; a
    resumed run keeps the fitted length."""
    kw = dict(FAST, size=48, seed=5, batch_size=2)   # 2 batches per epoch
    ck = train(synth, tmp_path / "m.pt", steps=1_000_000, fit_minutes=0.05, time_limit=5, **kw)
    h = ck["hparams"]
    assert h["fitted"] and 4 < h["steps"] < 1_000_000
    assert ck["step"] == h["steps"] and ck["stopped"] is None
    again = train(synth, tmp_path / "m.pt", resume=True, steps=1_000_000, fit_minutes=10, **kw)
    assert again["hparams"]["steps"] == h["steps"] and again["step"] == h["steps"]
    plain = train(synth, tmp_path / "p.pt", steps=6, **kw)   # no fitting asked: the plan stands
    assert plain["step"] == 6 and not plain["hparams"]["fitted"]


def test_one_slow_epoch_does_not_shorten_the_fitted_plan(synth, tmp_path, monkeypatch):
    """The second epoch runs ~25x slower (as when another process takes the CPU), the
    later ones at full speed: the plan is fitted again from the epochs' median time, so
    the run goes on far past the at most 28 steps the slow epoch alone allows (12 s at
    0.5 s per step, after 4), and still ends with its schedule complete within the time.
    (12 s, not less: a first epoch slowed by imports would leave a shorter budget no
    epoch in the schedule's first half to fit again from.)"""
    import time
    from glsynth.train.trainer import TrainSet
    get = TrainSet.__getitem__

    def slow_in_epoch_2(self, key):
        if key[0] == 1:
            time.sleep(0.25)
        return get(self, key)
    monkeypatch.setattr(TrainSet, "__getitem__", slow_in_epoch_2)
    kw = dict(FAST, size=48, seed=5, batch_size=2)   # 2 batches per epoch
    t0 = time.time()
    ck = train(synth, tmp_path / "m.pt", steps=1_000_000, fit_minutes=0.2, time_limit=5, **kw)
    assert ck["hparams"]["fitted"] and ck["step"] == ck["hparams"]["steps"] > 60
    assert ck["stopped"] is None and time.time() - t0 < 0.2 * 60 * 1.5


def test_steps_that_slow_down_late_shorten_the_plan(synth, tmp_path, monkeypatch):
    """From the fifth epoch on every step takes ~0.1 s more: the plan fitted from the
    fast early epochs is cut at later epoch ends, so the run ends with its schedule
    complete before the time limit (set, as sim2real sets it, 5% past the minutes)."""
    import time
    from glsynth.train.trainer import TrainSet
    get = TrainSet.__getitem__

    def slow_from_epoch_4(self, key):
        if key[0] >= 4:
            time.sleep(0.05)
        return get(self, key)
    monkeypatch.setattr(TrainSet, "__getitem__", slow_from_epoch_4)
    kw = dict(FAST, size=48, seed=5, batch_size=2)   # 2 batches per epoch
    ck = train(synth, tmp_path / "m.pt", steps=1_000_000, fit_minutes=0.1,
               time_limit=0.1 * 1.05, **kw)
    assert ck["stopped"] is None and ck["step"] == ck["hparams"]["steps"] > 8


def test_weight_average_follows_its_recurrence_with_the_warm_up():
    from glsynth.train.trainer import WeightAverage
    net = torch.nn.Sequential(torch.nn.Linear(3, 2), torch.nn.BatchNorm1d(2))
    avg = WeightAverage(net, decay=0.9)
    rng = np.random.default_rng(7)
    ref = {k: v.double().clone() for k, v in net.state_dict().items()}
    for step in range(30):
        with torch.no_grad():
            for v in net.state_dict().values():
                if v.is_floating_point():
                    v.copy_(torch.from_numpy(rng.normal(size=tuple(v.shape))))
        net.train()(torch.randn(4, 3))                       # moves the batch counter
        avg.update(net, step)
        d = min(0.9, (1 + step) / (10 + step))
        for k, v in net.state_dict().items():
            ref[k] = d * ref[k] + (1 - d) * v.double() if v.is_floating_point() else v.double()
    for k, v in avg.state.items():
        assert torch.allclose(v.double(), ref[k], atol=1e-6), k
    assert int(avg.state["1.num_batches_tracked"]) == 30
    live = {k: v.clone() for k, v in net.state_dict().items()}
    avg.swap(net)
    for k, v in net.state_dict().items():                 # the model now holds the average
        assert torch.allclose(v.double(), ref[k], atol=1e-6), k
    avg.swap(net)
    assert all(torch.equal(net.state_dict()[k], v) for k, v in live.items())


def test_ema_zero_exports_the_last_weights(synth, tmp_path):
    kw = dict(FAST, size=48, epochs=1, seed=5, batch_size=2)
    last = train(synth, tmp_path / "a.pt", ema=0.0, **kw)
    avg = train(synth, tmp_path / "b.pt", **kw)
    assert "train_model" not in last and avg["hparams"]["ema"] == 0.999
    for k, v in last["model"].items():                  # same run, same raw weights
        assert torch.equal(v, avg["train_model"][k]), k
    assert any(not torch.equal(v, avg["model"][k]) for k, v in last["model"].items()
               if v.is_floating_point())
    with pytest.raises(gs.errors.InputError):
        train(synth, tmp_path / "c.pt", ema=1.0, **kw)


# ---------------------------------------------------------------------------------------
# Metrics and evaluation


def test_jaccard_and_dice_match_hand_computation():
    p = np.zeros((4, 5), bool)
    g = np.zeros((4, 5), bool)
    p[0, :3] = True                  # 3 px
    g[0, 1:5] = True                 # 4 px, overlap 2, union 5
    assert metrics.jaccard(p, g) == pytest.approx(2 / 5)
    assert metrics.dice(p, g) == pytest.approx(4 / 7)
    empty = np.zeros((4, 5), bool)
    assert metrics.jaccard(empty, empty) == 1.0 and metrics.dice(empty, empty) == 1.0
    assert metrics.jaccard(p, empty) == 0.0 and metrics.dice(p, empty) == 0.0
    assert metrics.jaccard(empty, g) == 0.0 and metrics.dice(empty, g) == 0.0
    # class maps: lesion / skin / non-skin scored one against the others
    truth = np.array([[0, 0, 1, 1], [1, 1, 2, 2]], np.uint8)
    pred = np.array([[0, 1, 1, 1], [1, 1, 1, 1]], np.uint8)
    s = score(pred, truth, ("lesion", "skin", "nonskin"))
    assert s["lesion_jaccard"] == pytest.approx(1 / 2) and s["lesion_dice"] == pytest.approx(2 / 3)
    assert s["skin_jaccard"] == pytest.approx(4 / 7) and s["skin_dice"] == pytest.approx(8 / 11)
    assert s["nonskin_jaccard"] == 0.0 and s["nonskin_truth_px"] == 2


def _fitz_fixture(root, rng):
    """Three fitz17k folders: lesion + non-skin, lesion without nonskin.png content, no lesion."""
    cases = {}
    for k, (les, ns) in enumerate([(True, True), (True, False), (False, False)]):
        h, w = 60 + 10 * k, 90
        img = np.clip(rng.normal([190, 140, 120], 8, (h, w, 3)), 0, 255).astype(np.uint8)
        lm = np.zeros((h, w), np.uint8)
        nm = np.zeros((h, w), np.uint8)
        if les:
            cv2.circle(lm, (45, 30), 12, 255, -1)
            img[lm > 0] = (90, 50, 40)
        if ns:
            nm[:, :20] = 255
            img[:, :20] = (40, 60, 160)
        d = root / f"img{k}"
        d.mkdir(parents=True)
        cv2.imwrite(str(d / "image.jpg"), img[..., ::-1])
        write_png(d / "lesions.png", lm)
        write_png(d / "nonskin.png", nm)
        cases[f"img{k}"] = (img, lm > 0, nm > 0)
    return cases


def test_evaluate_end_to_end_on_a_fitz17k_folder(trained, tmp_path):
    from glsynth.cli import main
    path, _ = trained
    real = tmp_path / "real"
    cases = _fitz_fixture(real, np.random.default_rng(0))
    out = tmp_path / "report"
    assert main(["evaluate", "--model", str(path), "--real", str(real), "--layout", "fitz17k",
                 "--out", str(out), "-q", "--threads", "1"]) == 0
    assert {"report.md", "per_image.csv", "grid.png", "summary.json"} <= set(os.listdir(out))
    rows = {r["id"]: r for r in csv.DictReader(open(out / "per_image.csv"))}
    assert set(rows) == set(cases)
    model, _ = load_model(path)
    js = {c: [] for c in ("lesion", "skin", "nonskin")}
    for sid, (_, les, ns) in cases.items():
        img = read_rgb(real / sid / "image.jpg")
        pred = predict(model, img, 64, tta="d4")    # the command's default
        truth = np.where(les, 0, np.where(ns, 2, 1))
        assert (truth_map(les.shape, {"lesion": real / sid / "lesions.png",
                                      "nonskin": real / sid / "nonskin.png"}) == truth).all()
        for k, c in enumerate(js):
            j = metrics.jaccard(pred == k, truth == k)
            assert float(rows[sid][f"{c}_jaccard"]) == pytest.approx(j, abs=1e-6)
            js[c].append(j)
    assert int(rows["img2"]["lesion_truth_px"]) == 0
    summary = json.load(open(out / "summary.json"))
    for c, v in js.items():
        assert summary["classes"][c]["jaccard_mean"] == pytest.approx(np.mean(v), abs=1e-6)
        assert summary["classes"][c]["jaccard_std"] == pytest.approx(np.std(v), abs=1e-6)
    assert summary["classes"]["nonskin"]["n_empty_truth"] == 2 and summary["tta"] == "d4"
    report = open(out / "report.md").read()
    assert "lesion" in report and "± " in report
    grid = read_rgb(out / "grid.png")
    assert grid.shape[0] > 3 * 160
    # pairs layout: lesion only
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    for sid, (img, les, _) in cases.items():
        if les.any():
            cv2.imwrite(str(pairs / f"{sid}.png"), img[..., ::-1])
            write_png(pairs / f"{sid}_segmentation.png", les.astype(np.uint8) * 255)
    out2 = tmp_path / "report2"
    assert main(["evaluate", "--model", str(path), "--real", str(pairs), "--layout", "pairs",
                 "--out", str(out2), "-q"]) == 0
    s2 = json.load(open(out2 / "summary.json"))
    assert list(s2["classes"]) == ["lesion"] and s2["n_images"] == 2


def test_test_time_views_are_turned_back_before_they_are_averaged(rng):
    """Averaged over all eight flips and quarter turns, the prediction of a turned or
    mirrored image is the same turn of the image's prediction (an untrained network is
    far from equivariant, so a view left unturned breaks this); with the mirror only,
    mirroring commutes; one view is the network itself."""
    from glsynth.errors import InputError
    from glsynth.train.evaluate import predict_probs
    torch.manual_seed(int(rng.integers(1 << 31)))
    model = SegNet(n_seg=3, n_anatomy=16, width=0.5).eval()
    img = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    p = predict_probs(model, img, 64, tta="d4")
    for turned, undo in ((np.rot90(img), lambda q: np.rot90(q, -1, (1, 2))),
                         (img[:, ::-1], lambda q: q[:, :, ::-1]), (img[::-1], lambda q: q[:, ::-1])):
        q = predict_probs(model, np.ascontiguousarray(turned), 64, tta="d4")
        np.testing.assert_allclose(undo(q), p, atol=1e-5)
    plain = predict_probs(model, img, 64, tta="none")
    assert np.abs(np.rot90(predict_probs(model, np.rot90(img).copy(), 64, tta="none"), -1, (1, 2))
                  - plain).max() > 1e-3      # the network alone is not equivariant
    q = predict_probs(model, img[:, ::-1].copy(), 64, tta="flip")
    np.testing.assert_allclose(q[:, :, ::-1], predict_probs(model, img, 64, tta="flip"), atol=1e-5)
    from glsynth.train.data import preprocess
    with torch.no_grad():
        ref = torch.softmax(model(torch.from_numpy(preprocess(img, 64))[None])["seg"], 1)[0].numpy()
    np.testing.assert_allclose(plain, ref, atol=1e-6)
    with pytest.raises(InputError, match="test-time augmentation 'd8'"):
        predict_probs(model, img, 64, tta="d8")


def test_train_cli(synth, tmp_path):
    from glsynth.cli import main
    out = tmp_path / "m.pt"
    args = ["train", "--data", str(synth), "--data", str(synth), "--out", str(out), "--size", "48",
            "--epochs", "1", "--batch-size", "8", "-q", "--threads", "1"]
    assert main(args) == 0
    _, ck = load_model(out)
    assert ck["n_samples"] == 8 and ck["step"] == 1
    assert main(args) == 2                      # exists, no --resume
    assert main(args + ["--resume"]) == 0       # already finished: nothing to do


def test_heldout_procedural_folder_is_consistent(tmp_path):
    from glsynth.train.evaluate import real_samples
    from glsynth.train.heldout import procedural_clinical
    ids = procedural_clinical(tmp_path, n=3, seed=5, size=96)
    samples = real_samples(tmp_path, "fitz17k")
    assert sorted(s[0] for s in samples) == ids
    for sid, img_path, masks in samples:
        img = read_rgb(img_path)
        t = truth_map(img.shape[:2], masks)
        assert (t == 0).any() and (t == 1).any()      # a lesion on some healthy skin
    assert (truth_map((96, 96), samples[1][2]) == 2).any()   # non-skin around the skin region


# ---------------------------------------------------------------------------------------
# Validation-based checkpoint selection, real images in training, augmentation


def test_mixed_batches_hold_the_requested_ratio():
    from glsynth.train.trainer import epoch_batches
    for n_synth, n_real, batch, ratio in [(50, 7, 8, 0.25), (33, 3, 6, 0.5), (10, 40, 4, 0.75)]:
        batches = epoch_batches(n_synth, n_real, batch, ratio, seed=5, epoch=2)
        k_real = round(ratio * batch)
        synth = [i for b in batches for s, i in b if s == 0]
        assert sorted(synth) == list(range(n_synth))           # one pass over the synthetic set
        for b in batches[:-1]:
            assert sum(s == 1 for s, _ in b) == k_real and len(b) == batch
        real = [i for b in batches for s, i in b if s == 1]
        # real samples are drawn without repeats until the set is used up
        for start in range(0, len(real) - n_real + 1, n_real):
            assert sorted(real[start:start + n_real]) == list(range(n_real))
        assert batches == epoch_batches(n_synth, n_real, batch, ratio, seed=5, epoch=2)
    # real images only (staged fine-tuning): one pass over them
    only = epoch_batches(0, 10, 4, 0.25, seed=1, epoch=0)
    assert sorted(i for b in only for _, i in b) == list(range(10)) and all(s == 1 for b in only for s, _ in b)


def test_checkpoint_selection_keeps_the_lowest_validation_loss(synth, tmp_path):
    from glsynth.train.trainer import best_path, Validator
    real = tmp_path / "val"
    _fitz_fixture(real, np.random.default_rng(1))
    ck = train(synth, tmp_path / "m.pt", epochs=6, seed=2, val=real, val_every=1, **FAST)
    hist = ck["val_history"]
    assert len(hist) >= ck["step"]                     # validated after every step
    best = min(hist, key=lambda r: r["loss"])
    assert ck["best"]["step"] == best["step"] and ck["best"]["loss"] == pytest.approx(best["loss"])
    model, saved = load_model(best_path(tmp_path / "m.pt"))
    assert saved["step"] == best["step"]
    again = Validator(real, "fitz17k", 64)(model)       # the saved weights score what was recorded
    assert again["loss"] == pytest.approx(best["loss"], abs=1e-5)
    assert again["lesion"] == pytest.approx(best["lesion"], abs=1e-6)
    assert not (np.diff([r["loss"] for r in hist]) == 0).all()   # it changed as it trained


def test_real_images_train_the_lesion_skin_head(tmp_path):
    real = tmp_path / "real"
    _fitz_fixture(real, np.random.default_rng(2))
    ck = train([], tmp_path / "r.pt", epochs=3, seed=0, real_train=real, **FAST)
    assert ck["n_real"] == 3 and ck["n_samples"] == 0 and ck["step"] == 3   # 3 images, batch 4
    assert np.isfinite(ck["history"][-1]["loss"])


def test_augmentation_is_seeded_and_degrades_like_a_camera():
    from glsynth.train import data as D
    rng = np.random.default_rng(0)
    img = np.clip(rng.normal(150, 30, (96, 128, 3)), 0, 255).astype(np.uint8)
    lab = {"seg": (rng.random((96, 128)) > 0.5).astype(np.uint8)}
    a1, l1 = D.augment(np.random.default_rng([4, 1]), img, lab, 64)
    a2, l2 = D.augment(np.random.default_rng([4, 1]), img, lab, 64)
    assert (a1 == a2).all() and (l1["seg"] == l2["seg"]).all()
    # the geometry is the same with and without the degradations: labels identical
    a3, l3 = D.augment(np.random.default_rng([4, 1]), img, lab, 64, degrade=False)
    assert (l3["seg"] == l1["seg"]).all()
    # zoom: at 3x a 64 px crop of a 96 px image spans ~21 source px
    sharp = np.zeros((96, 96, 3), np.uint8)
    sharp[:, ::2] = 255
    seen = []
    for k in range(40):
        out, _ = D.augment(np.random.default_rng([9, k]), sharp, {"s": np.zeros((96, 96), np.uint8)}, 64,
                           scale_range=(3.0, 3.0), degrade=False)
        seen.append(out.std())
    assert np.median(seen) > 30      # stripes stay resolved when magnified


def test_uneven_light_only_takes_light_away_smoothly_within_its_stops(rng, monkeypatch):
    """On a flat grey frame the light field keeps full light somewhere, takes at most
    UNEVEN_STOPS away (in linear light), varies smoothly (no step between neighbours
    larger than the field's span allows) and leaves hue alone; with p 0 it is off."""
    from glsynth.pipeline.photo import srgb_to_linear
    from glsynth.train import data as D
    monkeypatch.setattr(D, "UNEVEN_LIGHT", 1.0)
    img = np.full((64, 96, 3), (180, 140, 120), np.uint8)
    spans = []
    for seed in rng.integers(2 ** 31, size=20):
        out = D._uneven_light(np.random.default_rng(int(seed)), img)
        lin = srgb_to_linear(out).astype(np.float64) / srgb_to_linear(img)
        out = out.astype(np.float64)
        assert lin.max() <= 1.02 and lin.max() > 0.97
        assert lin.min() >= 2.0 ** -D.UNEVEN_STOPS - 0.02
        assert np.abs(np.diff(out, axis=1)).max() <= 4 and np.abs(np.diff(out, axis=0)).max() <= 4
        ratio = lin[..., 0] / lin[..., 2]
        assert np.abs(ratio - 1).max() < 0.1            # one gain for R, G and B
        spans.append(np.log2(lin.max() / lin.min()))
    assert max(spans) > 0.5                             # it does darken parts of the frame
    monkeypatch.setattr(D, "UNEVEN_LIGHT", 0.0)
    assert (D._uneven_light(np.random.default_rng(0), img) == img).all()


def test_normalise_is_shades_of_gray_then_imagenet_statistics(rng):
    from glsynth.assets.colour import shades_of_gray
    from glsynth.train import data as D
    img = (rng.random((37, 53, 3)) ** rng.uniform(0.5, 2, 3) * 255).astype(np.uint8)
    want = ((shades_of_gray(img).astype(np.float32) / 255 - D.MEAN) / D.STD).transpose(2, 0, 1)
    got = D.normalise(img)
    assert got.dtype == np.float32 and got.shape == (3, 37, 53)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)


def test_training_samples_are_the_same_from_the_cache(synth, rng):
    """Decoded samples kept in memory give the same tensors as decoding afresh, and the
    cache holds no more than its budget."""
    from glsynth.train.trainer import TrainSet
    seed = int(rng.integers(2**31))
    cached, fresh = TrainSet([synth], size=64, seed=seed), TrainSet([synth], size=64, seed=seed, cache_gb=0)
    for epoch in (0, 1):  # epoch 1 reads the cache filled in epoch 0
        for i in range(len(fresh)):
            for a, b in zip(cached[(epoch, 0, i)], fresh[(epoch, 0, i)]):
                assert torch.equal(a, b)
    assert len(cached.cache) == len(cached) and not fresh.cache
    one = sum(a.nbytes for a in cached.cache[0] if a is not None)
    small = TrainSet([synth], size=64, cache_gb=2.5 * one / 2**30)
    for i in range(len(small)):
        small.load(i)
    assert 1 <= len(small.cache) <= 2 and small.cache_left >= 0
