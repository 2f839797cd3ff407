"""The planner: decide hit or miss per stage, with the reason, without computing.

Every stage's key comes from its config section, version, input keys and (the stage
reading `DATASET`) the dataset fingerprint; no artifact's contents are read.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.config.load import section_dict
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.engine.hashing import recipe_key, stage_recipe
from sonarmap.pipeline.engine.run.planned import DatasetSpec, PlannedStage
from sonarmap.pipeline.engine.run.run_records import miss_reason, previous_recipes
from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef, ArtifactStore
from sonarmap.schemas import SCHEMA_VERSION
from sonarmap.stages.base import Stage

__all__ = ["plan"]


def plan(
    stages: Sequence[Stage],
    config: BaseModel,
    dataset: DatasetSpec,
    store: ArtifactStore,
    *,
    until: str | None = None,
    force: Sequence[str] = (),
    external: Mapping[str, tuple[Stage, ArtifactRef]] | None = None,
    content_keyed: Collection[str] = (),
) -> list[PlannedStage]:
    """Hit or miss, with the reason, for each stage up to and including `until`.

    `content_keyed` names external inputs (the model) whose files' sha256s enter the
    recipe of every stage reading them, so other content under the same key can never
    produce the same downstream keys.
    """
    names = [s.name for s in stages]
    for name in [until, *force]:
        if name is not None and name not in names:
            raise ConfigError(f"unknown stage '{name}' (stages: {', '.join(names)})")
    beyond = [f for f in force if until is not None and names.index(f) > names.index(until)]
    if beyond:  # said, not ignored: the user asked for a recomputation that would not happen
        raise ConfigError(f"--force {beyond[0]}: after --until {until}, so it would not run")
    external = dict(external or {})
    keys: dict[str, str] = {name: ref.key for name, (_, ref) in external.items()}
    contents = {
        name: recipe_key({k: v["sha256"] for k, v in external[name][1].manifest["files"].items()})
        for name in content_keyed
        if name in external
    }
    previous: dict[str, dict[str, Any]] | None = None  # read on the first miss only
    changed: set[str] = set()
    planned: list[PlannedStage] = []
    for stage in stages:
        input_keys = {}
        for item in stage.inputs:
            if item.is_dataset:
                continue
            if item.stage not in keys:
                raise ConfigError(
                    f"stage {stage.name}: input '{item.name}' has no producer in this run"
                )
            input_keys[item.name] = keys[item.stage]
        recipe = stage_recipe(
            stage=stage.name,
            version=stage.version,
            config=section_dict(
                config, stage.name, stage.key_excludes, stage.reads_sections, stage.draws
            ),
            input_keys=input_keys,
            schema_version=SCHEMA_VERSION,
            dataset_fingerprint=dataset.fingerprint if stage.reads_dataset else None,
        )
        read = {i.name: contents[i.stage] for i in stage.inputs if i.stage in contents}
        if read:
            recipe["input_content"] = dict(sorted(read.items()))
        key = recipe_key(recipe)
        keys[stage.name] = key
        if stage.name in force:  # what is there is replaced, even a corrupt artifact
            hit, reason = False, "forced"
        elif store.get(stage.name, key) is not None:
            hit, reason = True, "cached"
        else:
            hit = False
            if previous is None:
                previous = previous_recipes(store, dataset.path)
            reason = miss_reason(stage.name, recipe, previous.get(stage.name), changed)
        if not hit:
            changed.add(stage.name)
        planned.append(PlannedStage(stage, key, recipe, hit, reason))
        if stage.name == until:
            break
    return planned
