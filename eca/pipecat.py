"""eca as the face of a pipecat bot: the public names of `eca.services.pipecat`, under a short path.

    from eca.pipecat import EcaFaceParams, EcaTools, EcaVideoService, EspeakTTSService

Importing it without pipecat installed raises an ImportError that says `pip install 'eca-face[pipecat]'`.
"""

from typing import Any

import eca.services.pipecat as _bridge
from eca.services.pipecat import EcaFaceParams, EcaTools, EcaVideoService, FaceNotReady, client_page

__all__ = ["EcaFaceParams", "EcaTools", "EcaVideoService", "EspeakTTSService", "FaceNotReady", "client_page"]  # noqa: F822 (lazy, below)


def __getattr__(name: str) -> Any:
    if name == "EspeakTTSService":  # imported when first asked for, as in the bridge
        return _bridge.EspeakTTSService
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
