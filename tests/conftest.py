"""Shared fixtures: one GL context for the whole session (tests/gl_context.py), checked
for GL errors around every test (as moderngl's own test-suite does), and fresh random
seeds that a failure reports and GLSYNTH_TEST_SEED replays.

test_backends.py reruns the renderer tests under OSMesa in a subprocess.
"""
import os

import numpy as np
import pytest

from gl_context import GL_BACKEND, get_renderer

# pyrender, the independent reference, on the same kind of context as ours
os.environ.setdefault("PYOPENGL_PLATFORM", GL_BACKEND)

_seeds = {}  # node id (a test's or a module's) -> the seed drawn for it


def _fresh_rng(node):
    seed = int(os.environ.get("GLSYNTH_TEST_SEED") or int.from_bytes(os.urandom(4), "little"))
    _seeds[node.nodeid] = seed
    return np.random.default_rng(seed)


@pytest.fixture
def rng(request):
    """A generator with a fresh seed per test (reported on failure)."""
    return _fresh_rng(request.node)


@pytest.fixture(scope="module")
def module_rng(request):
    """A generator with a fresh seed per module, for module-scoped fixtures."""
    return _fresh_rng(request.node)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    if report.failed:
        seeds = {nid: s for nid, s in _seeds.items() if item.nodeid == nid or item.nodeid.startswith(nid + "::")}
        if seeds:
            lines = [f"{nid}: random seed {s}" for nid, s in seeds.items()]
            if len(set(seeds.values())) > 1:
                lines.append("GLSYNTH_TEST_SEED seeds every generator alike: replay one seed at a time")
            lines.append("replay: GLSYNTH_TEST_SEED=%d python -m pytest '%s'"
                         % (next(iter(seeds.values())), item.nodeid))
            report.sections.append(("random seed", "\n".join(lines)))


@pytest.fixture
def gl_backend():
    return GL_BACKEND


@pytest.fixture
def renderer(gl_backend):
    r = get_renderer(gl_backend)
    r.ctx.error  # clear any stale error flag
    yield r
    assert r.ctx.error == "GL_NO_ERROR"
