"""Per-user caches (issue 35 item 4): the model cache and the training datasets live in the
user's cache directory, not the working directory; `$SONARMAP_CACHE_DIR` and the config's
`training.directory` move them; no key depends on where they are."""

from __future__ import annotations

from pathlib import Path

import platformdirs
import pytest

from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.training.cache_dir import CACHE_ENV
from sonarmap.pipeline.training.model import training_simulations
from sonarmap.pipeline.training.model_cache import model_cache, planned_default_model

ROOT = Path(__file__).resolve().parent.parent


def _config(*overrides: str):  # type: ignore[no-untyped-def]
    return load_config(all_stages(), None, list(overrides), extra_sections())


def test_caches_default_to_the_user_cache_directory_whatever_the_working_directory(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))  # Linux: ~/.cache
    expected = Path(platformdirs.user_cache_dir("sonarmap", appauthor=False)) / "training"
    seen = set()
    for work in ("one", "two"):
        (tmp_path / work).mkdir()
        monkeypatch.chdir(tmp_path / work)
        cfg = _config()
        seen.add(cfg.training.directory)
        assert model_cache(cfg).root == expected / "store"
        assert all(s.out.parent == expected for s in training_simulations(cfg.training))
    assert seen == {str(expected)} and expected.is_absolute()
    assert str(tmp_path / "xdg") in str(expected)


def test_environment_then_config_move_the_caches(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(CACHE_ENV, "scratch/cache")  # relative: fixed when read, not later
    assert model_cache(_config()).root == tmp_path / "scratch/cache/training/store"
    chosen = tmp_path / "lab-disk"
    cfg = _config(f"training.directory={chosen}")
    assert model_cache(cfg).root == chosen / "store"
    monkeypatch.setenv(CACHE_ENV, "")  # empty: the user's cache directory again
    assert model_cache(_config()).root.parent.parent == Path(
        platformdirs.user_cache_dir("sonarmap", appauthor=False)
    )


def test_the_default_model_key_does_not_depend_on_the_cache_directory(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    keys = set()
    for name in ("a", "b"):
        monkeypatch.setenv(CACHE_ENV, str(tmp_path / name))
        key, at_hand = planned_default_model(ArtifactStore(tmp_path / "store"), _config())
        assert at_hand  # the shipped model, whatever the empty cache
        keys.add(key)
    assert len(keys) == 1
    assert (ROOT / "configs/model/train" / keys.pop()).is_dir()
