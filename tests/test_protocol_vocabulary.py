"""The bus protocol spells the shared names (roles, eye modes, saccade kinds) as the models define them.

protocol/ imports nothing of the models, so this test, not an import, keeps the two vocabularies alike.
"""

from __future__ import annotations

from typing import get_args

from eca.agent import vocabulary
from eca.protocol import messages


def test_the_protocol_uses_the_models_names() -> None:
    assert get_args(messages.Role) == vocabulary.ROLES
    assert get_args(messages.EyeMode) == vocabulary.EYE_MODES
    assert get_args(messages.SaccadeKind) == vocabulary.SACCADE_KINDS


def test_the_gaze_model_and_the_scripts_read_the_one_vocabulary() -> None:
    from eca.agent.face import scene
    from eca.agent.gaze import params
    from eca.agent.script import vocab

    assert params.MODES == vocab.EYE_MODES == scene.EYE_MODES == vocabulary.EYE_MODES
    assert params.ROLES == vocab.ROLES == scene.ROLES == vocabulary.ROLES
    assert params.KINDS == vocabulary.SACCADE_KINDS


def test_the_rig_frame_s_list_lengths_are_the_rig_models_vocabularies() -> None:
    from eca.agent.rig import names

    assert (messages.RIG_ARKIT, messages.RIG_VISEMES, messages.RIG_VRM) == (
        len(names.ARKIT_NAMES), len(names.VISEME_NAMES), len(names.VRM_NAMES))
