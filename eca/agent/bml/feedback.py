"""The BML 1.0 standard's feedback elements as XML text, for a sender that speaks BML (OpenBMLParser's
BMLBlockProgressFeedback, BMLSyncPointProgressFeedback, BMLWarningFeedback, BMLPredictionFeedback).

Times are seconds, written with up to six decimals. Every attribute and text is escaped, and characters XML 1.0
cannot carry (control characters) become U+FFFD, so a warning quoting a hostile block is still well-formed.
"""

from __future__ import annotations

import math
import re
from xml.sax.saxutils import escape, quoteattr

BML_FEEDBACK_NS = "http://www.bml-initiative.org/bml/bml-1.0"
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff\ud800-\udfff]")


def block_progress_xml(block: str, sync: str, global_time_s: float, character: str) -> str:
    """<blockProgress id="block:start|end" globalTime characterId/>."""
    return _element("blockProgress", [("id", f"{block}:{sync}"), ("globalTime", _seconds(global_time_s)),
                                      ("characterId", character)])


def sync_point_progress_xml(block: str, behaviour: str, sync: str, time_s: float, global_time_s: float,
                            character: str) -> str:
    """<syncPointProgress id="block:behaviour:sync" time (from the block's start) globalTime characterId/>."""
    return _element("syncPointProgress", [("id", f"{block}:{behaviour}:{sync}"), ("time", _seconds(time_s)),
                                          ("globalTime", _seconds(global_time_s)), ("characterId", character)])


def warning_feedback_xml(block: str, behaviour: str, warning_type: str, text: str, character: str) -> str:
    """<warningFeedback id="block[:behaviour]" type characterId>text</warningFeedback>."""
    subject = f"{block}:{behaviour}" if behaviour else block
    return _element("warningFeedback", [("id", subject), ("type", warning_type), ("characterId", character)],
                    escape(_clean(text)))


def prediction_feedback_xml(block: str, global_start_s: float, global_end_s: float, character: str) -> str:
    """<predictionFeedback characterId><bml id globalStart globalEnd/></predictionFeedback>."""
    times = [("id", block), ("globalStart", _seconds(global_start_s)), ("globalEnd", _seconds(global_end_s))]
    inner = "<bml" + _attributes(times) + "/>"
    return _element("predictionFeedback", [("characterId", character)], inner)


def _element(tag: str, attributes: list[tuple[str, str]], content: str | None = None) -> str:
    head = f"<{tag} xmlns={quoteattr(BML_FEEDBACK_NS)}{_attributes(attributes)}"
    return f"{head}/>" if content is None else f"{head}>{content}</{tag}>"


def _attributes(attributes: list[tuple[str, str]]) -> str:
    # characterId is optional in the standard: an agent with no name sends none rather than an empty one
    return "".join(f" {name}={quoteattr(_clean(value))}" for name, value in attributes
                   if value or name != "characterId")


def _seconds(value: float) -> str:
    if not math.isfinite(value):
        raise ValueError(f"a feedback time must be finite, got {value!r}")
    text = f"{value:.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def _clean(text: str) -> str:
    return _NOT_XML.sub("\ufffd", text)
