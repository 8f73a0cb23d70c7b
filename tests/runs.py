"""Small end-to-end runs shared by the pipeline and Ray tests, and how to compare two
run folders byte for byte."""
import json
import os

from glsynth.config import load_config

SMALL = ["bodies.count=1", "bodies.texture_size=512", "lesions.per_body=2", "blend.method=deep", "blend.steps=4",
         "blend.features=filters", "views.per_body=4", "views.size=128", "views.supersample=1",
         "paste.view_size=256", "backgrounds.count=3", "seed=7"]

# what a run records about itself in manifest.json; everything else in the folder,
# bodies/ included, must be the same bytes for the same config and seed
RUN_FACTS = ("timings_seconds", "workers", "executor")


def small_config(*extra):
    return load_config(None, SMALL + list(extra))


def dataset_bytes(out, run_facts=RUN_FACTS):
    """Every file of a run folder, manifest.json without ``run_facts``."""
    files = {}
    for root, _, names in os.walk(out):
        for n in names:
            rel = os.path.relpath(os.path.join(root, n), out)
            data = open(os.path.join(root, n), "rb").read()
            if rel == "manifest.json":
                man = json.loads(data)
                data = json.dumps({k: v for k, v in man.items() if k not in run_facts}, sort_keys=True)
            files[rel] = data
    return files


def assert_same_folders(a, b, resumed=False):
    """Whole folders equal; a resumed run counts only the views it rejected itself."""
    facts = RUN_FACTS + (("rejected_views",) if resumed else ())
    a, b = dataset_bytes(a, facts), dataset_bytes(b, facts)
    assert sorted(a) == sorted(b), sorted(set(a) ^ set(b))[:10]
    assert [k for k in a if a[k] != b[k]] == []
