"""The config's keys are declared once (glsynth/config.py): Config() is the default run,
configs/default.yaml and docs/config.md are generated from the declarations, validation
follows them, and the pipeline's settings take their defaults from them."""
import os

import pytest

from glsynth import configdoc
from glsynth.config import Config, ConfigError, Interval, PasteConfig, from_dict, keys, load_config
from glsynth.resources import config_dir

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_config_defaults_are_the_default_yaml():
    assert Config() == load_config(config_dir() / "default.yaml") == load_config(None)


@pytest.mark.parametrize("path,render", [("configs/default.yaml", configdoc.default_yaml),
                                         ("docs/config.md", configdoc.markdown)])
def test_generated_files_are_up_to_date(path, render):
    with open(os.path.join(ROOT, path), encoding="utf-8") as fh:
        committed = fh.read()
    assert committed == render(), (f"{path} is out of date: python -m glsynth.configdoc "
                                   f"--{'doc' if path.endswith('.md') else 'yaml'} > {path}")


def test_every_key_is_documented_and_in_the_table():
    table = configdoc.markdown()
    names = [name for name, _ in keys()]
    assert len(names) == len(set(names)) > 80
    for name, f in keys():
        assert f.metadata["doc"].strip(), name
        assert f"| `{name}` |" in table


def test_a_file_need_only_hold_what_it_changes(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text("views:\n  size: 256\n")
    cfg = load_config(path)
    assert cfg.views.size == 256
    cfg.views.size = Config().views.size
    assert cfg == Config()


def _bad_values(f):
    """Values just outside what a key's declaration accepts."""
    a = f.metadata["accepts"]
    bad = []
    for interval, wrap in ((a.within, lambda x: x), (a.pair, lambda x: [x, x])):
        if interval is None:
            continue
        if interval.lo is not None:
            bad.append(wrap(interval.lo if interval.lo_open else interval.lo - 1))
        if interval.hi is not None:
            bad.append(wrap(interval.hi if interval.hi_open else interval.hi + 1))
    if a.pair is not None:
        lo = a.pair.lo + 0.5 if a.pair.lo is not None else 0.5
        bad += [[lo + 0.25, lo], [lo]]          # low > high; not a pair
    if a.choices is not None:
        bad.append(max(a.choices) + 3 if isinstance(a.choices[0], int) else "nonsense")
    return bad


CHECKED = [(name, value) for name, f in keys() for value in _bad_values(f)]


@pytest.mark.parametrize("name,value", CHECKED, ids=[f"{n}={v}" for n, v in CHECKED])
def test_values_outside_a_declaration_are_rejected_naming_the_key(name, value):
    raw = Config().to_dict()
    *sections, leaf = name.split(".")
    node = raw
    for section in sections:
        node = node[section]
    node[leaf] = value
    with pytest.raises(ConfigError, match=rf"{name} must"):
        from_dict(raw)
    assert from_dict(Config().to_dict()) == Config()


def test_rules_beyond_intervals_and_choices():
    for override in ("lesions.decal_size=32", "lesions.kinds=[nevus, dragon]", "bodies.poses=[]",
                     "views.framing={wild: 0}", "views.framing={sideways: 1}", "photo.jpeg_quality=[0, 50]",
                     "photo.jpeg_quality=[50.5, 60]", "outputs=[]"):
        key = override.split("=")[0]
        with pytest.raises(ConfigError, match=rf"{key} must"):
            load_config(None, [override])
    assert load_config(None, ["lesions.decal_size=0", "lesions.kinds=[nevus]"]).lesions.decal_size == 0


def test_interval_text_and_membership():
    assert str(Interval(0, 170, lo_open=True, hi_open=True)) == "in (0, 170)"
    assert str(Interval(1)) == ">= 1" and str(Interval(0, lo_open=True)) == "> 0"
    assert 0 not in Interval(0, 1, lo_open=True) and 1 in Interval(0, 1, lo_open=True)


def test_pipeline_settings_default_to_the_config():
    from glsynth.pipeline.paste import PasteSettings
    assert PasteSettings() == PasteSettings.from_config(Config())
    custom = load_config(None, ["paste.dilation=3", "lesions.size=[0.2, 0.3]", "paste.w=[0.5, 0.7]"])
    s = PasteSettings.from_config(custom)
    assert (s.dilation, s.size, s.w) == (3, (0.2, 0.3), (0.5, 0.7))
    assert PasteSettings().dilation == PasteConfig().dilation


def test_blend_settings_default_to_the_config():
    pytest.importorskip("torch")
    from glsynth.pipeline.blend import BlendSettings
    assert BlendSettings() == BlendSettings.from_config(Config().blend)
    s = BlendSettings.from_config(load_config(None, ["blend.steps=7", "blend.threads=2"]).blend)
    assert (s.steps, s.threads, s.dtype) == (7, 2, "float32")
