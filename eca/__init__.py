"""eca: a live face for conversational agents.

The distribution is `eca-face`; everything it installs lives under this one import name, so no folder of
a user's project can hide it:

- `eca.agent`: the behaviour models (gaze, face, lip-sync, scripts), pure numpy/stdlib on injected time;
- `eca.protocol`: the wire (messages, codec, topics, endpoints, the client);
- `eca.services`: the processes, the `eca` command line and the pipecat face;
- `eca.pipecat`: the pipecat face's public names, re-exported (`eca.services.pipecat`);
- `eca/configs`: the constants with their sources, shipped with the package (see `eca.agent.config`).
"""

from __future__ import annotations

from pathlib import Path

# Every process imports this package first: what it imports at the top, each of them holds. The version (read
# through importlib.metadata, which brings the email package along) is looked up when someone asks for it.


def __getattr__(name: str) -> str:
    if name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            found = version("eca-face")
        except PackageNotFoundError:  # a source tree used without installing it
            found = "0+unknown"
        globals()["__version__"] = found
        return found
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def shipped_configs() -> Path:
    """The `configs/` folder shipped inside the package. pip installs a package as files, so it is a real folder
    beside this file; importlib.resources finds it where a loader gives no file (it is imported only then)."""
    if __file__ is not None:
        return Path(__file__).resolve().parent / "configs"
    from importlib import resources

    return Path(str(resources.files(__name__) / "configs"))
