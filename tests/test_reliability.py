"""Reliability (issue 21): one output folder holds one run, model files run no code,
writes are complete before they are renamed and get the umask's permissions, bad
numbers and degenerate inputs are refused early with a reason, and the command line
reports expected failures in one line."""
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import cv2
import numpy as np
import pytest

import glsynth as gs
from glsynth.cli import main
from glsynth.config import ConfigError, load_config

TINY = ["bodies.count=1", "bodies.texture_size=256", "views.per_body=2", "views.size=64",
        "views.supersample=1", "paste.view_size=128", "backgrounds.count=1", "seed=3",
        "blend.method=paste", "lesions.per_body=1"]


def tiny(*extra):
    return load_config(None, TINY + list(extra))


def _cli_args(out, sets):
    args = ["generate", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    return args


def _start_cli(out, sets):
    """`glsynth generate` in a subprocess; returns it once it has started on the bodies."""
    # Ctrl-C as in a terminal: a shell's background job (`pytest ... &`) ignores SIGINT,
    # and a child inherits that, so Python would never turn it into KeyboardInterrupt
    proc = subprocess.Popen([sys.executable, "-m", "glsynth.cli", *_cli_args(out, sets)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 300
    while not (out / "bodies").is_dir():
        if proc.poll() is not None or time.time() > deadline:
            proc.kill()
            pytest.fail(f"the run never started on its bodies: {proc.communicate()}")
        time.sleep(0.02)
    return proc


def _tree(out):
    return {os.path.relpath(os.path.join(r, n), out): open(os.path.join(r, n), "rb").read()
            for r, _, ns in os.walk(out) for n in ns}


# ---- the command line ------------------------------------------------------------------
def _run_main(argv):
    import io
    from contextlib import redirect_stderr
    buf = io.StringIO()
    with redirect_stderr(buf):
        rc = main(argv)
    return rc, buf.getvalue()


def _one_line_errors(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    latin = tmp_path / "latin1.yaml"
    latin.write_bytes("# réglages\n".encode("latin-1"))
    (tmp_path / "random.pt").write_bytes(np.random.default_rng(0).bytes(512))
    (tmp_path / "empty.pt").write_bytes(b"")
    out = str(tmp_path / "out")
    return {
        "config is a folder": (["generate", "--config", str(tmp_path), "--out", out], str(tmp_path)),
        "config not UTF-8": (["generate", "--config", str(latin), "--out", out], str(latin)),
        "out under a file": (["generate", "--out", str(a_file / "out")], str(a_file / "out")),
        "out is a file": (["generate", "--out", str(a_file)], f"{a_file}: exists and is not a folder"),
        "model of random bytes": (["evaluate", "--model", str(tmp_path / "random.pt"), "--real", out,
                                   "--layout", "pairs", "--out", out], "random.pt: not a torch"),
        "empty model": (["evaluate", "--model", str(tmp_path / "empty.pt"), "--real", out,
                         "--layout", "pairs", "--out", out], "empty.pt: not a readable torch"),
        "train without data": (["train", "--out", str(tmp_path / "m.pt")], "give --data"),
    }


@pytest.mark.parametrize("case", ["config is a folder", "config not UTF-8", "out under a file",
                                  "out is a file", "model of random bytes", "empty model",
                                  "train without data"])
def test_expected_failures_are_one_line(tmp_path, case):
    argv, named = _one_line_errors(tmp_path)[case]
    rc, err = _run_main(argv)
    assert rc == 2, err
    assert len(err.strip().splitlines()) == 1 and named in err, err


def test_os_errors_are_one_line_and_bugs_keep_their_traceback(monkeypatch):
    import glsynth.pipeline

    def read_only(*a, **k):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), "/mnt/ro/out")
    monkeypatch.setattr(glsynth.pipeline, "generate", read_only)
    rc, err = _run_main(["generate", "--out", "/mnt/ro/out"])
    assert rc == 2 and err.strip() == "glsynth generate: error: /mnt/ro/out: Read-only file system"

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(glsynth.pipeline, "generate", interrupted)
    rc, err = _run_main(["generate", "--out", "x"])
    assert rc == 130 and "interrupted" in err and "Traceback" not in err

    def bug(*a, **k):
        raise ValueError("a bug, not a user error")
    monkeypatch.setattr(glsynth.pipeline, "generate", bug)
    with pytest.raises(ValueError, match="a bug"):
        main(["generate", "--out", "x"])


def test_ctrl_c_ends_a_run_with_one_line_and_code_130(tmp_path):
    out = tmp_path / "run"
    proc = _start_cli(out, TINY + ["views.per_body=8"])
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == "glsynth generate: interrupted; continue with --resume"


def test_a_config_file_that_is_not_utf8_is_named(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("# réglages\nseed: 1\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin1\.yaml: not UTF-8"):
        load_config(path)


# ---- writes ----------------------------------------------------------------------------
def test_output_files_get_the_umask_permissions(tmp_path):
    from glsynth.io.images import write_bytes, write_png
    from glsynth.train.trainer import save_checkpoint
    old = os.umask(0o022)
    try:
        write_png(tmp_path / "a.png", np.zeros((4, 4), np.uint8))
        write_bytes(tmp_path / "b.json", b"{}")
        save_checkpoint(tmp_path / "c.pt", {"x": 1})
        os.umask(0o002)
        write_bytes(tmp_path / "d.json", b"{}")
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()}
    assert modes == {"a.png": 0o644, "b.json": 0o644, "c.pt": 0o644, "d.json": 0o664}


def test_a_full_disk_never_leaves_a_truncated_file(tmp_path):
    """A file-size limit makes the kernel refuse the last bytes of the PNG (EFBIG), as a
    full disk refuses them (ENOSPC): the write fails naming the file, and nothing is
    left under its name or as a temporary."""
    code = textwrap.dedent(f"""
        import os, resource, signal
        import cv2, numpy as np
        from glsynth.io.images import write_png
        img = np.random.default_rng(0).integers(0, 255, (128, 128), dtype=np.uint8)
        size = len(cv2.imencode(".png", img)[1])
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (size - 10, resource.RLIM_INFINITY))
        try:
            write_png({str(tmp_path / "x.png")!r}, img)
        except OSError as exc:
            print("error:", exc)
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert f"{tmp_path / 'x.png'}: could not write the file" in res.stdout, res.stdout
    assert os.listdir(tmp_path) == []


def test_no_space_left_is_one_clear_error(tmp_path, monkeypatch):
    """A file object that takes half the bytes, then reports ENOSPC."""
    from glsynth.errors import WriteError
    from glsynth.io.images import write_png, write_text
    real_write = os.write
    calls = []

    def half_then_full(fd, data):
        calls.append(len(data))
        if len(calls) == 1:
            return real_write(fd, bytes(data)[:len(data) // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "write", half_then_full)
    target = tmp_path / "targets" / "x_semantic.png"
    with pytest.raises(WriteError) as info:
        write_png(target, np.random.default_rng(1).integers(0, 255, (64, 64), dtype=np.uint8))
    assert str(info.value).startswith(f"{target}: could not write the file")
    assert "disk" in str(info.value) and info.value.errno == errno.ENOSPC
    assert len(calls) == 2 and os.listdir(target.parent) == []
    # a file system that accepts no bytes at all must not spin or pass
    monkeypatch.setattr(os, "write", lambda fd, data: 0)
    with pytest.raises(WriteError):
        write_text(tmp_path / "y.json", "{}")
    assert not (tmp_path / "y.json").exists()


# ---- model files -----------------------------------------------------------------------
class _Payload:
    """Unpickling this creates a file (an attacker's code would do worse)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_a_hostile_model_file_runs_no_code(tmp_path, capsys):
    import torch
    from glsynth.errors import ModelFileError
    from glsynth.train.trainer import FORMAT, init_weights, load_model, train
    from glsynth.train.model import SegNet
    marker = tmp_path / "pwned"
    evil = tmp_path / "model.pt"
    torch.save({"format": FORMAT, "arch": {}, "model": {}, "x": _Payload(marker)}, evil)
    for load in (lambda: load_model(evil), lambda: init_weights(SegNet(width=0.25), evil),
                 lambda: train(tmp_path / "no-data", evil, resume=True)):
        with pytest.raises(ModelFileError, match="model.pt: refused"):
            load()
        assert not marker.exists()
    rc = main(["evaluate", "--model", str(evil), "--real", str(tmp_path), "--layout", "pairs",
               "--out", str(tmp_path / "report")])
    err = capsys.readouterr().err
    assert rc == 2 and not marker.exists()
    assert len(err.strip().splitlines()) == 1 and str(evil) in err


# ---- validation ------------------------------------------------------------------------
@pytest.mark.parametrize("override,key", [
    ("views.w=[.nan, 1]", "views.w"), ("photo.exposure=[.nan, .nan]", "photo.exposure"),
    ("views.ambient=[0.2, .inf]", "views.ambient"), ("blend.lr=.nan", "blend.lr"),
    ("paste.max_depth_change=.inf", "paste.max_depth_change"),
    ("bodies.fitzpatrick=[1, .nan]", "bodies.fitzpatrick"),
])
def test_non_finite_numbers_are_rejected(override, key):
    with pytest.raises(ConfigError, match=rf"{key}.*finite"):
        load_config(None, [override])


def test_degenerate_lesions_are_rejected_with_a_reason(tmp_path):
    from glsynth.assets.lesions import LesionError, load_lesion, load_lesions
    rng = np.random.default_rng(0)
    photo = rng.integers(60, 200, (60, 80, 3), dtype=np.uint8)
    spot = np.zeros((60, 80), np.uint8)
    spot[20:40, 30:50] = 255
    for name, img, mask in (("tiny", photo[:1, :1], np.full((1, 1), 255, np.uint8)),
                            ("white", photo, np.full((60, 80), 255, np.uint8)),
                            ("good", photo, spot)):
        cv2.imwrite(str(tmp_path / f"{name}.png"), img)
        cv2.imwrite(str(tmp_path / f"{name}_mask.png"), mask)
    with pytest.raises(LesionError, match=r"tiny\.png: image is 1x1 pixels, below the minimum"):
        load_lesion(tmp_path / "tiny.png", tmp_path / "tiny_mask.png")
    with pytest.raises(LesionError, match=r"white_mask\.png: mask covers 100% of the image"):
        load_lesion(tmp_path / "white.png", tmp_path / "white_mask.png")
    lesions = load_lesions(tmp_path, layout="pairs")
    assert lesions.ids == ["good"]
    assert dict(lesions.skipped) == {"with images below the minimum size": 1,
                                     "with masks covering nearly the whole image": 1}
    # the thresholds are the config's
    assert load_lesions(tmp_path, layout="pairs", min_size=1, max_mask_fraction=1.0).ids == \
        ["good", "tiny", "white"]
    with pytest.raises(ConfigError, match="lesions.max_mask_fraction"):
        load_config(None, ["lesions.max_mask_fraction=0"])


def _write_scan(folder, scale):
    """A 3DBodyTex-layout folder: a person-sized textured box in ``scale`` units."""
    import trimesh
    folder.mkdir(parents=True)
    box = trimesh.creation.box(extents=(0.5, 1.7, 0.3))
    v = (box.vertices + [0, 0.85, 0]) * scale
    with open(folder / "model_highres_0_normalized.obj", "w") as fh:
        fh.writelines(f"v {x} {y} {z}\n" for x, y, z in v)
        fh.writelines(f"vt {x} {y}\n" for x, y in (v[:, :2] / v[:, :2].max()).clip(0, 1))
        fh.writelines(f"f {a}/{a} {b}/{b} {c}/{c}\n" for a, b, c in box.faces + 1)
    cv2.imwrite(str(folder / "model_highres_0_normalized.png"), np.full((16, 16, 3), 180, np.uint8))


def test_a_mesh_in_millimetres_is_named_as_such(tmp_path):
    from glsynth.assets.bodytex import BodyError
    from glsynth.pipeline.bodies import load_body
    _write_scan(tmp_path / "scans" / "mm", 1000.0)
    _write_scan(tmp_path / "scans" / "m", 1.0)
    cfg = tiny(f"bodies.source={tmp_path / 'scans'}", "bodies.count=2")
    assert load_body(cfg, "m").mesh.vertices.max() < 2
    with pytest.raises(BodyError, match=r"mm: the body is 1700 units across.*metres.*millimetres"):
        load_body(cfg, "mm")


# ---- the body cache --------------------------------------------------------------------
def test_a_swapped_or_cut_body_cache_file_is_rebuilt(tmp_path):
    from glsynth.assets.bodies import make_body
    cache = tmp_path / "cache"
    one, two = (make_body(seed=s, texture_size=128, cache_dir=cache) for s in (1, 2))
    (path1,), (path2,) = ((cache / "bodies").glob(f"body-{s}-*.npz") for s in (1, 2))
    shutil.copy(path1, path2)  # body 1's file under body 2's name
    again = make_body(seed=2, texture_size=128, cache_dir=cache)
    assert again.meta["seed"] == 2 and np.array_equal(again.mesh.vertices, two.mesh.vertices)
    with np.load(path2) as z:  # the bad file was replaced, not kept
        assert json.loads(str(z["meta"]))["seed"] == 2
    with np.load(path1) as z:  # body 1's file with its texture cut in half
        arrays = {k: z[k] for k in z.files}
    arrays["texture"] = arrays["texture"][:64]
    np.savez(path1, **arrays)
    again = make_body(seed=1, texture_size=128, cache_dir=cache)
    assert again.mesh.texture.shape == (128, 128, 3)
    assert np.array_equal(again.mesh.texture, one.mesh.texture)


# ---- one run per folder ----------------------------------------------------------------
def test_resume_with_another_seed_or_config_is_refused(tmp_path):
    out = tmp_path / "run"
    gs.pipeline.generate(tiny(), out)
    before = _tree(out)
    from glsynth.errors import GlsynthError
    with pytest.raises(GlsynthError, match=r"seed 3 -> 4.*views\.per_body 2 -> 3"):
        gs.pipeline.generate(tiny("seed=4", "views.per_body=3"), out, resume=True)
    assert _tree(out) == before  # nothing written, nothing mixed in
    # the stage commands continue the same run only
    err = _run_main(["views", "--out", str(out), *sum((["--set", s] for s in TINY + ["views.size=96"]), [])])
    assert err[0] == 2 and "views.size 64 -> 96" in err[1]
    gs.pipeline.generate(tiny(), out, resume=True)  # its own config continues it


def test_a_second_process_on_the_folder_is_refused(tmp_path, capsys):
    """Even one that would continue the very same run: two writers interleave their
    pastes, blends and samples (with other seeds, a body gets one run's paste and the
    other's blend)."""
    out = tmp_path / "shared"
    first = _start_cli(out, TINY + ["views.per_body=8"])
    try:
        rc = main(_cli_args(out, TINY + ["views.per_body=8"]) + ["--resume"])
        err = capsys.readouterr().err
    finally:
        stdout, stderr = first.communicate(timeout=600)
    assert rc == 2 and "another glsynth run is writing this folder" in err, err
    assert first.returncode == 0, stderr
    manifest = json.load(open(out / "manifest.json"))
    assert manifest["seed"] == 3 and manifest["counts"]["images"] == 8
    assert json.load(open(out / "fingerprint.json"))["seed"] == 3


def test_the_lock_of_a_killed_run_is_taken_over(tmp_path):
    out = tmp_path / "stale"
    out.mkdir()
    code = textwrap.dedent(f"""
        import os, signal
        from glsynth.pipeline.runlock import _locked
        with _locked({str(out)!r}):
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    subprocess.run([sys.executable, "-c", code])
    assert "pid" in (out / ".glsynth.lock").read_text()  # left behind by the dead holder
    gs.pipeline.generate(tiny("views.per_body=1"), out, resume=True)
    assert (out / "manifest.json").is_file() and not (out / ".glsynth.lock").exists()


# ---- inputs are checked before any stage works -----------------------------------------
def test_a_missing_background_folder_fails_before_any_body_is_pasted(tmp_path):
    from glsynth.assets.backgrounds import BackgroundError
    out = tmp_path / "run"
    with pytest.raises(BackgroundError, match="nowhere: background folder not found"):
        gs.pipeline.generate(tiny(f"backgrounds.source={tmp_path / 'nowhere'}"), out)
    assert not (out / "bodies").exists()
