"""The FGD autoencoder at the papers' window (90 frames, not a multiple of its downsampling)."""

from __future__ import annotations

from tests.conftest import require

pytestmark = require("torch")

import torch  # noqa: E402

from convodrive.models.fgd import FGDConfig, FGDNetworks  # noqa: E402
from convodrive.motion import representation as rep  # noqa: E402
from convodrive.training.recipes.fgd import FGDRecipe, fgd_parts  # noqa: E402


def test_every_preset_builds_and_reconstructs_its_window() -> None:
    for name, preset in FGDRecipe.presets.items():
        config = FGDRecipe().model_config(preset.model)
        nets = FGDNetworks(fgd_parts(), config)
        motion = torch.randn(2, config.window, rep.FEATURE_DIM)
        mask = torch.ones(2, 1, rep.FEATURE_DIM)
        loss, figures = nets.reconstruction_loss(motion, mask)
        assert torch.isfinite(loss) and set(figures) == {"holistic_mse", "body_mse", "face_mse"}, name
        assert nets.nets["face"].encode(motion[:, :, fgd_parts()["face"]]).shape == (2, config.latent)
    assert FGDConfig().window == 90 and FGDConfig().latent == 128


def test_masked_channels_do_not_reach_the_features() -> None:
    nets = FGDNetworks(fgd_parts(), FGDConfig(window=16, channels=4, latent=8))
    motion = torch.randn(1, 16, rep.FEATURE_DIM)
    mask = torch.ones(1, 1, rep.FEATURE_DIM)
    mask[..., rep.PARTS["arkit"]] = 0
    changed = motion.clone()
    changed[..., rep.PARTS["arkit"]] += 5.0
    a, _ = nets.part_input("face", motion, mask)
    b, _ = nets.part_input("face", changed, mask)
    assert torch.equal(nets.nets["face"].encode(a), nets.nets["face"].encode(b))
