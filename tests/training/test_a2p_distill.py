"""a2p's guidance distillation: the student regresses onto the guided teacher, so a student that is
still the teacher's copy (its guidance input starts silent) is exact at scale 1 and off at any
other; its gradient reaches the guidance input."""

from __future__ import annotations

import pytest

from tests.conftest import require

pytestmark = require("torch")


def test_the_guidance_students_target_is_the_guided_teacher() -> None:
    import torch

    from convodrive.models.a2p import A2P
    from convodrive.models.a2p_config import FACE, LIP_OUTPUTS
    from convodrive.training.recipes.a2p_distill import guided_regression_loss
    from tests.models.test_a2p import BANDS, SPEAKERS, TINY

    torch.manual_seed(0)
    model = A2P(TINY, BANDS, SPEAKERS, "distill").eval()
    teacher, student = model.face, model.face_student
    assert teacher is not None and student is not None
    missing, unexpected = student.load_state_dict(teacher.state_dict(), strict=False)
    assert not unexpected and all(name.startswith("guidance.") for name in missing)
    b, t = 3, 40
    conditions = [torch.randn(b, t, 2 * BANDS), torch.randn(b, t, LIP_OUTPUTS)]
    keep = torch.ones(b, 2)
    speaker = torch.arange(b) % SPEAKERS
    both = torch.cat([keep, torch.zeros(b, 2)])
    with torch.no_grad():
        teacher_memory = teacher.memory([torch.cat([c, c]) for c in conditions], both, speaker.repeat(2))
    x0 = torch.randn(b, t, FACE.stop - FACE.start)
    mask = torch.ones(1, 1, FACE.stop - FACE.start)

    def loss(guidance_max: float) -> torch.Tensor:
        memory = student.memory(conditions, keep, speaker)
        generator = torch.Generator().manual_seed(1)
        return guided_regression_loss(
            teacher, student, (teacher_memory, memory), x0, mask, guidance_max, TINY, generator
        )

    assert float(loss(1.0).detach()) < 1e-10  # scale 1: the conditional pass, which the copy already gives
    guided = loss(4.0)
    assert float(guided.detach()) > 1e-4
    guided.backward()
    assert student.guidance is not None and student.guidance.weight.grad.abs().sum() > 0
    assert all(p.grad is None for p in teacher.parameters())


@pytest.mark.parametrize("value", ["progressive", ""])
def test_an_unknown_distillation_is_named(value: str) -> None:
    import dataclasses

    from tests.models.test_a2p import TINY

    with pytest.raises(ValueError, match="distillation"):
        dataclasses.replace(TINY, distillation=value).check()
