"""eca as the face of a pipecat bot (docs/pipecat.md): `pip install 'eca-face[pipecat]'`.

- `EcaVideoService` (face.py): a processor placed after the TTS; the TTS audio becomes a streamed `say`,
  the user's turns `user_speech`, an interruption `interrupt`, and the face's pictures go downstream
  with the audio, in step on the transport's timeline. `EcaFaceParams` says which eca and how to draw.
- `EcaTools` (tools.py): `set_emotion` and `move_head` as LLM function schemas and their handlers.
- `EspeakTTSService` (tts.py): espeak-ng as a pipecat TTS service (local: no key, no network).
- `client_page()` (page.py): a small browser page for a bot on SmallWebRTC (face and voice in, microphone out).

Nothing outside this package imports pipecat; importing it without pipecat says how to install it.
"""

try:
    import pipecat.frames.frames  # noqa: F401
    import pipecat.processors.frame_processor  # noqa: F401
except ImportError as exc:  # pragma: no cover - depends on the install
    raise ImportError(f"eca's pipecat integration needs pipecat ({exc}): pip install 'eca-face[pipecat]'") from exc

from typing import Any

from eca.services.pipecat.face import EcaFaceParams, EcaVideoService, FaceNotReady
from eca.services.pipecat.page import client_page
from eca.services.pipecat.tools import EcaTools

__all__ = ["EcaFaceParams", "EcaTools", "EcaVideoService", "EspeakTTSService", "FaceNotReady", "client_page"]


def __getattr__(name: str) -> Any:
    # The TTS service is imported when first asked for: pipecat's TTS module is large, and a face that
    # follows another TTS does not need it.
    if name == "EspeakTTSService":
        from eca.services.pipecat.tts import EspeakTTSService

        return EspeakTTSService
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
