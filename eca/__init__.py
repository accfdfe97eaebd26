"""eca: a live face for conversational agents.

The distribution is `eca-face`; everything it installs lives under this one import name, so no folder of
a user's project can hide it:

- `eca.agent`: the behaviour models (gaze, face, lip-sync, scripts), pure numpy/stdlib on injected time;
- `eca.protocol`: the wire (messages, codec, topics, endpoints, the client);
- `eca.services`: the processes, the `eca` command line and the pipecat face;
- `eca.pipecat`: the pipecat face's public names, re-exported (`eca.services.pipecat`);
- `eca/configs`: the constants with their sources, shipped with the package (see `eca.agent.config`).
"""

from importlib import resources
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

try:
    __version__ = version("eca-face")
except PackageNotFoundError:  # a source tree used without installing it
    __version__ = "0+unknown"


def shipped_configs() -> Path:
    """The `configs/` folder shipped inside the package (read through importlib.resources, so it is found
    wherever pip put eca). A package installed as files is the only kind pip makes, so it is a real folder."""
    return Path(str(resources.files(__name__) / "configs"))
