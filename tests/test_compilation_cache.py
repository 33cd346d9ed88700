"""The command line's persistent XLA compilation cache (``bezmotion._src.compilation_cache``)."""

from __future__ import annotations

import jax
import pytest

from bezmotion._src.compilation_cache import MIN_COMPILE_SECONDS, SWITCH_ENV, use_compilation_cache


@pytest.fixture
def no_cache_configured():
    """The process as a fresh command line finds it: no cache folder (restored afterwards,
    so the session's own cache, from conftest, stays in use)."""
    folder = jax.config.jax_compilation_cache_dir
    seconds = jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_compilation_cache_dir", None)
    yield
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", seconds)


def test_a_process_without_a_cache_gets_the_one_under_bezmotions_cache(no_cache_configured, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    monkeypatch.delenv(SWITCH_ENV, raising=False)
    assert use_compilation_cache() == tmp_path / "xla"
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
    assert jax.config.jax_persistent_cache_min_compile_time_secs == MIN_COMPILE_SECONDS


@pytest.mark.parametrize("switch", ["off", "0", "OFF "])
def test_the_switch_turns_it_off(no_cache_configured, tmp_path, monkeypatch, switch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    monkeypatch.setenv(SWITCH_ENV, switch)
    assert use_compilation_cache() is None
    assert jax.config.jax_compilation_cache_dir is None


def test_a_cache_the_process_configured_is_left_as_it_is(tmp_path, monkeypatch):
    """Here conftest's session cache: a caller's own choice wins."""
    before = jax.config.jax_compilation_cache_dir
    assert before  # conftest configured one
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    monkeypatch.delenv(SWITCH_ENV, raising=False)
    assert str(use_compilation_cache()) == before and jax.config.jax_compilation_cache_dir == before
