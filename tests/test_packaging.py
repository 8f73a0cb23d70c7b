"""The wheel: built with ``pip wheel``, installed (not editable) into a fresh virtual
environment, it holds every module, the shaders and the configs, and ``glsynth generate``
runs the embedded default from a folder outside the repository.

The fresh environment borrows the third-party packages of the environment running the
tests (a .pth file listing its import path; ``pip check`` confirms the wheel's
requirements are met) rather than downloading them again: the test needs no network, and pip never
gets to resolve a torch of its own.
"""
import os
import shutil
import subprocess
import sys
import zipfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _run(args, **kw):
    proc = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=900, **kw)
    assert proc.returncode == 0, f"{' '.join(map(str, args))} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


def test_a_missing_extra_fails_on_use_naming_the_extra():
    from glsynth.errors import MissingDependencyError
    from glsynth.optional import optional_import, require
    math = optional_import("math", extra="x", needed_by="y")
    require(math)
    assert math.sqrt(4) == 2
    gone = optional_import("glsynth_no_such_module", extra="preview", needed_by="glsynth preview")
    with pytest.raises(MissingDependencyError, match=r"glsynth preview needs glsynth_no_such_module.*"
                                                     r"pip install 'glsynth\[preview\]'") as info:
        gone.anything
    assert isinstance(info.value.__cause__, ImportError) and isinstance(info.value, ImportError)
    with pytest.raises(MissingDependencyError):
        require(gone)


def test_preview_without_glfw_says_which_extra_to_install(tmp_path):
    """A user without the preview extra gets one line naming it, before any work."""
    script = ("import sys\nsys.modules['glfw'] = None  # as if not installed\n"
              "from glsynth.cli import main\nsys.exit(main(['preview', '--screenshot', 'x.png']))\n")
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path, env=env)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "needs glfw" in proc.stderr and "pip install 'glsynth[preview]'" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """A wheel built from a copy of the sources (a stale build/ here cannot leak in)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in ("glsynth", "shaders", "configs"):
        shutil.copytree(os.path.join(ROOT, name), src / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(os.path.join(ROOT, name), src / name)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
          "-w", tmp / "dist", src])
    (path,) = (tmp / "dist").glob("glsynth-*.whl")
    return path


@pytest.mark.slow
def test_wheel_holds_every_module_shader_and_config(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for sub, pattern in (("glsynth", ".py"), ("shaders", ""), ("configs", ".yaml")):
        for root, _, files in os.walk(os.path.join(ROOT, sub)):
            for f in files:
                if f.endswith(pattern) and "__pycache__" not in root:
                    rel = os.path.relpath(os.path.join(root, f), ROOT).replace(os.sep, "/")
                    want = rel if sub == "glsynth" else f"glsynth/{rel}"
                    assert want in names, f"{want} is missing from the wheel"
    meta = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("METADATA"))).decode()
    requires = [l.split(":", 1)[1].strip() for l in meta.splitlines() if l.startswith("Requires-Dist:")]
    core = [r for r in requires if "extra ==" not in r]
    # window and cluster packages only with their extras; torch stays (anny needs it)
    assert not [r for r in core if r.startswith(("glfw", "ray"))], core
    assert any(r.startswith("torch") for r in core) and any(r.startswith("anny") for r in core)
    assert 'glfw>=2.6; extra == "preview"' in requires and 'ray>=2.9; extra == "ray"' in requires


@pytest.mark.slow
def test_installed_wheel_generates_the_embedded_default(wheel, tmp_path):
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv])
    py = venv / "bin" / "python"
    site = _run([py, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"]).stdout.strip()
    # third-party packages from the test environment: its import path without the
    # folders that hold a glsynth/ (the .pth files there, the editable glsynth's among
    # them, are not processed: a .pth line only appends a path)
    borrowed = [p for p in sys.path if p and os.path.isdir(p) and not os.path.isdir(os.path.join(p, "glsynth"))]
    with open(os.path.join(site, "_borrowed.pth"), "w") as fh:
        fh.write("\n".join(borrowed) + "\n")
    _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "-q", wheel])
    _run([sys.executable, "-m", "pip", "--python", py, "check"])
    work = tmp_path / "elsewhere"   # not the repository: nothing found by accident
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    where = _run([py, "-c", "import glsynth, glsynth.resources as r; "
                            "print(glsynth.__file__); print(r.shader_dir()); print(r.config_dir())"],
                 cwd=work, env=env).stdout.split()
    assert all(p.startswith(site) for p in where), where
    out = work / "out"
    _run([venv / "bin" / "glsynth", "generate", "--out", out, "--set", "bodies.count=1",
          "--set", "bodies.texture_size=256", "--set", "lesions.per_body=1", "--set", "views.per_body=1",
          "--set", "views.size=64", "--set", "paste.view_size=128", "--set", "backgrounds.count=1"],
         cwd=work, env=env)
    assert os.listdir(out / "images") and (out / "annotations.coco.json").is_file()
    shown = _run([venv / "bin" / "glsynth", "show", out, "--out", work / "sheet.png", "-n", "1"],
                 cwd=work, env=env)
    assert "wrote" in shown.stdout and (work / "sheet.png").is_file()
