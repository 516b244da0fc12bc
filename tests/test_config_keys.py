"""Each config key is declared once (runtime/config_keys.py); the parser, the model's recorded trigger
settings, deploy/handover.toml and docs/CONFIG.md all follow that declaration."""

from __future__ import annotations

import dataclasses
import tomllib

import pytest

from runtime.config import Config, ConfigError, config_from_dict
from runtime.config_keys import KEYS, SECTIONS, key, section_keys
from runtime.config_text import DEPLOY_FILE, DOCS_FILE, deploy_toml, docs_markdown
from runtime.trigger_settings import TriggerSettings, recorded_problems

CONFIG_KEYS = [k for k in KEYS if k.config]


def test_deploy_file_and_docs_are_written_from_the_declaration():
    assert DEPLOY_FILE.read_text() == deploy_toml(), "run: python -m runtime.config_text"
    assert DOCS_FILE.read_text() == docs_markdown(), "run: python -m runtime.config_text"


def test_the_deploy_file_names_every_key_with_its_default():
    """Set keys show their default (or a marked example); unset ones are named in a comment."""
    text = DEPLOY_FILE.read_text()
    data = tomllib.loads(text)
    for k in CONFIG_KEYS:
        table = data.get(k.section, {}) if k.section else data
        if k.short in table:
            expected = k.example if k.shown else k.default
            assert table[k.short] == (list(expected) if isinstance(expected, tuple) else expected), k.name
        else:
            assert k.optional, f"{k.name} is not optional, so the file sets it"
            assert f"# {k.short} = " in text, k.name
    assert "floor" not in data.get("trigger", {}), "recorded-only settings are not config keys"


def test_every_section_class_has_one_field_per_declared_key():
    cfg = config_from_dict({})
    for section in SECTIONS:
        target = getattr(cfg, section) if section else cfg
        names = {f.name for f in dataclasses.fields(target)}
        if not section:
            names -= {"source", "warnings"} | set(SECTIONS)
        assert names == {k.short for k in section_keys(section)}, section
        for k in section_keys(section):
            assert getattr(target, k.short) == k.config_default, k.name
    assert isinstance(cfg, Config)


@pytest.mark.parametrize("k", [k for k in CONFIG_KEYS if k.range is not None], ids=lambda k: k.name)
def test_every_number_outside_its_declared_range_is_refused_naming_the_key(k):
    lo, hi = k.range
    for bad in (hi + 1, lo - 1):
        data: dict = {k.short: k.type(bad)}
        with pytest.raises(ConfigError) as info:
            config_from_dict({k.section: data} if k.section else data)
        assert str(info.value).startswith(k.name + ":"), info.value


@pytest.mark.parametrize("k", [k for k in CONFIG_KEYS if k.choices], ids=lambda k: k.name)
def test_every_choice_key_takes_its_choices_and_refuses_others(k):
    def wrap(value):
        return {k.section: {k.short: value}} if k.section else {k.short: value}

    for choice in k.choices:
        cfg = config_from_dict(wrap(choice))
        assert getattr(getattr(cfg, k.section) if k.section else cfg, k.short) == choice
    with pytest.raises(ConfigError, match=f"^{k.name}: must be one of"):
        config_from_dict(wrap("nonsense"))


def test_the_recorded_trigger_settings_are_the_trigger_keys():
    """A model records every trigger setting; its defaults are the declared ones."""
    settings = TriggerSettings()
    assert set(settings.to_meta()) == {k.short for k in section_keys("trigger", config_only=False)}
    for k in section_keys("trigger", config_only=False):
        assert getattr(settings, k.short) == k.default, k.name
    assert settings.to_meta()["fraction"] == key("trigger.fraction").default


@pytest.mark.parametrize("name", [k.short for k in section_keys("trigger", config_only=False)
                                  if k.recorded and k.range and k.short != "fraction"])
def test_a_recorded_setting_outside_its_declared_range_is_a_problem(name):
    lo, hi = key(f"trigger.{name}").range
    assert recorded_problems({name: hi + 1}) and not recorded_problems({name: lo})
