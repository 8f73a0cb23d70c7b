"""The Ray executor on a small local cluster started here: the same bytes as the local
executor, for 1 and 2 actors (and two local worker processes), and a complete, identical
dataset when an actor is killed (ray.kill, or SIGKILL of its process) in the middle of
the run. Whole folders are compared, bodies/ included."""
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time

import pytest

ray = pytest.importorskip("ray")

import glsynth as gs  # noqa: E402
from glsynth.config import load_config  # noqa: E402
from glsynth.pipeline import ray_executor  # noqa: E402
from runs import SMALL, assert_same_folders  # noqa: E402  (the reduced end-to-end config)

pytestmark = pytest.mark.slow

# two bodies so that prepare runs in parallel and chunks have a body to stick to
OVERRIDES = SMALL + ["bodies.count=2", "views.per_body=6"]


def small_config():
    return load_config(None, OVERRIDES)


@pytest.fixture(scope="module")
def ray_cluster():
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    yield
    if started:
        ray.shutdown()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    gs.pipeline.generate(small_config(), out, workers=1)
    return out


def _assert_same(reference, out, resumed=False):
    """The whole folders, bodies/ included; manifest.json without its timings and the
    worker count and executor it records."""
    assert_same_folders(reference, out, resumed)


def _our_actors():
    return [n for n in ray.util.list_named_actors() if n.startswith(ray_executor.ACTOR_PREFIX)]


def _no_actors_left(timeout=10):
    """ray.kill is asynchronous: give the cluster a moment to forget the names."""
    deadline = time.time() + timeout
    while _our_actors() and time.time() < deadline:
        time.sleep(0.1)
    return _our_actors() == []


@pytest.mark.parametrize("workers", [1, 2])
def test_ray_matches_local_executor(ray_cluster, reference, tmp_path, workers):
    man = gs.pipeline.generate(small_config(), tmp_path / "ray", workers=workers, executor="ray")
    assert man["executor"] == "ray" and man["workers"] == workers
    assert man["counts"]["images"] == 12
    assert "blend" in man["timings_seconds"] and "views" in man["timings_seconds"]
    _assert_same(reference, tmp_path / "ray")
    assert ray.is_initialized(), "run_ray shut down a cluster it did not start"
    assert _no_actors_left(), "actors left behind"


def test_local_worker_processes_match_one_worker(reference, tmp_path):
    man = gs.pipeline.generate(small_config(), tmp_path / "two", workers=2)
    assert man["workers"] == 2 and man["executor"] == "local"
    _assert_same(reference, tmp_path / "two")


def _kill_when_first_sample_appears(out, how, killed):
    """Background thread: at the first sample JSON, kill one worker actor."""
    tgt = os.path.join(out, "targets")
    deadline = time.time() + 120
    while time.time() < deadline:
        if os.path.isdir(tgt) and any(n.endswith(".json") for n in os.listdir(tgt)):
            break
        time.sleep(0.01)
    else:
        return
    if how == "ray.kill":
        names = _our_actors()
        if names:
            ray.kill(ray.get_actor(names[0]))
            killed.append(names[0])
    else:  # SIGKILL the actor's worker process, as the OOM killer or a lost node would
        import psutil
        # only this cluster's processes (the local Ray cluster runs under this process)
        for p in psutil.Process().children(recursive=True):
            try:
                title = (p.cmdline() or [""])[0]
            except psutil.Error:
                continue
            if title.startswith("ray::GlsynthWorker"):
                os.kill(p.pid, signal.SIGKILL)
                killed.append(p.pid)
                break


@pytest.mark.parametrize("how", ["ray.kill", "sigkill"])
def test_killed_actor_is_replaced(ray_cluster, reference, tmp_path, caplog, how):
    out = tmp_path / "ray"
    os.makedirs(out)
    # bodies already pasted and blended: the kill lands in the views stage
    shutil.copytree(reference / "bodies", out / "bodies")
    shutil.copy(reference / "fingerprint.json", out)  # the same run, continued
    killed = []
    killer = threading.Thread(target=_kill_when_first_sample_appears, args=(str(out), how, killed))
    killer.start()
    with caplog.at_level(logging.WARNING, logger="glsynth.pipeline.ray_executor"):
        man = gs.pipeline.generate(small_config(), out, resume=True, workers=2, executor="ray")
    killer.join()
    assert killed, "no actor was killed"
    assert any("died" in r.getMessage() for r in caplog.records), "the kill went unnoticed"
    assert man["counts"]["images"] == 12
    _assert_same(reference, out, resumed=True)   # nothing missing, duplicated or half-written
    assert _no_actors_left()


def test_actor_start_failure_is_reported(ray_cluster, tmp_path, monkeypatch):
    monkeypatch.setenv("GLSYNTH_GL_BACKEND", "no-such-backend")  # passed on to the actors
    with pytest.raises(ray_executor.RayExecutorError, match="no-such-backend"):
        gs.pipeline.generate(small_config(), tmp_path / "bad", workers=1, executor="ray")
    assert _no_actors_left()


def test_a_killed_driver_leaves_no_ray_process(tmp_path):
    """SIGKILL of a `glsynth generate --executor ray` that started its own local Ray:
    every process below it (GCS, raylet, agents, actors) is gone within seconds. Ray's
    dashboard and runtime-env agents used to outlive the driver by a minute or more."""
    import psutil  # Ray ships it
    out = tmp_path / "run"
    args = [sys.executable, "-m", "glsynth.cli", "generate", "--out", str(out), "--executor", "ray",
            "--workers", "1"]
    for s in OVERRIDES:
        args += ["--set", s]
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}  # a Ray of its own
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    deadline = time.time() + 300
    while not (out / "bodies").is_dir():  # Ray is up and its actor at work
        assert proc.poll() is None and time.time() < deadline, "the run ended or never started"
        time.sleep(0.05)
    below = psutil.Process(proc.pid).children(recursive=True)
    assert any("raylet" in p.name() for p in below), [p.name() for p in below]
    proc.kill()
    proc.wait()

    def running():
        alive = []
        for p in below:
            try:
                if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                    alive.append(p.name())
            except psutil.NoSuchProcess:
                pass
        return alive
    deadline = time.time() + 20
    while running() and time.time() < deadline:
        time.sleep(0.2)
    assert running() == []
