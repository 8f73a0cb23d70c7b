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
    proc = subprocess.Popen([sys.executable, "-m", "glsynth.cli", *_cli_args(out, sets)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
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
    out = str(tmp_path / "out")
    return {
        "config is a folder": (["generate", "--config", str(tmp_path), "--out", out], str(tmp_path)),
        "config not UTF-8": (["generate", "--config", str(latin), "--out", out], str(latin)),
        "out under a file": (["generate", "--out", str(a_file / "out")], str(a_file / "out")),
    }


@pytest.mark.parametrize("case", ["config is a folder", "config not UTF-8", "out under a file"])
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
