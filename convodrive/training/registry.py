"""The trainable models, by name: ``convodrive train MODEL`` and ``python -m convodrive.training MODEL``.

A model issue adds one line to ``RECIPES``; a third-party package declares an entry point in the
group ``convodrive.recipes``, as generators do in ``convodrive.generators``. Recipes are imported
only when named, so listing them is cheap.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from convodrive.plumbing.errors import UserError
from convodrive.training.config import Preset
from convodrive.training.recipe import Recipe

RECIPES: dict[str, str] = {
    "fgd": "convodrive.training.recipes.fgd:FGDRecipe",
    "probtalk": "convodrive.training.recipes.probtalk:ProbTalkRecipe",
    "a2p": "convodrive.training.recipes.a2p:A2PRecipe",
}


RECIPE_GROUP = "convodrive.recipes"


def _targets() -> dict[str, str]:
    return {**{ep.name: ep.value for ep in entry_points(group=RECIPE_GROUP)}, **RECIPES}


def model_names() -> list[str]:
    return sorted(_targets())


def get_recipe(name: str) -> Recipe:
    targets = _targets()
    if name not in targets:
        raise UserError(f"unknown model '{name}' (available: {', '.join(sorted(targets))})")
    module, attr = targets[name].split(":")
    return getattr(importlib.import_module(module), attr)()


def get_preset(recipe: Recipe, name: str | None) -> tuple[str, Preset]:
    chosen = name or recipe.default_preset
    if chosen not in recipe.presets:
        raise UserError(
            f"model '{recipe.name}' has no preset '{chosen}' (available: {', '.join(sorted(recipe.presets))})"
        )
    return chosen, recipe.presets[chosen]
