"""BML files for `eca check` and `eca play`: read within the protocol's bound, parsed, voiced and scheduled as
the realizer would, so a file that checks is a file that plays."""

from __future__ import annotations

from pathlib import Path

from eca.agent.bml import MAX_BML_CHARS, Block, BmlError, SpeechParams, Timeline, parse_block, schedule
from eca.services.processes.audio.config import AudioConfig
from eca.services.processes.bml.speech import voice


def read_bml(path: str) -> str:
    """The file's text; ValueError naming the file when it cannot be read, is too long or is not UTF-8."""
    file = Path(path)
    try:
        size = file.stat().st_size
        if size > 4 * MAX_BML_CHARS:  # bounded before reading: a UTF-8 character is at most 4 bytes
            raise ValueError(f"{path}: {size} bytes, more than a BML block may hold ({MAX_BML_CHARS} characters)")
        data = file.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it ({exc.strerror})") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    if len(text) > MAX_BML_CHARS:
        raise ValueError(f"{path}: {len(text)} characters, more than a BML block may hold ({MAX_BML_CHARS})")
    return text


def check_bml(path: str) -> tuple[Block, Timeline]:
    """The file's block and its timeline from 0 s, its speech voiced with the configured engine; BmlError or
    ValueError naming the file and the line."""
    text = read_bml(path)
    block = parse_block(text, path)
    tts = AudioConfig.load().tts
    timings = {}
    for behaviour in block.behaviours:
        if isinstance(behaviour.params, SpeechParams):
            try:
                timings[behaviour.id] = voice(behaviour.params, tts).timing
            except ValueError as exc:
                raise ValueError(f"{path}:{behaviour.line}: block '{block.id}', speech '{behaviour.id}': {exc}") \
                    from None
    return block, schedule(block, 0.0, timings, {})


def describe(block: Block, timeline: Timeline) -> str:
    kinds = sorted({b.kind for b in block.behaviours})
    return (f"block '{block.id}' ({block.composition}), {len(block.behaviours)} behaviours ({', '.join(kinds)}), "
            f"{timeline.end_s - timeline.start_s:.2f} s, {len(block.warnings)} warnings")


__all__ = ["BmlError", "check_bml", "describe", "read_bml"]
