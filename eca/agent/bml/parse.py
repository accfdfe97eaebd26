"""Reading one BML block: XML in, a Block (behaviours, constraints, warnings) out, or a BmlError.

The XML is read with expat and no DTD at all (a DOCTYPE is refused, so no entity can expand: the "billion
laughs"), within bounds checked before any walking: size, depth, behaviours, constraints. Namespaces are resolved
here rather than by expat, because SmartBody's BML uses `sbm:` attributes and elements without declaring the
prefix: an undeclared `sbm:` or `eca:` means SmartBody's or eca's namespace; any other undeclared prefix is an
unknown namespace (a warning), not a malformed block.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal, NoReturn, cast
from xml.parsers import expat

from eca.agent.bml import mapping
from eca.agent.bml.errors import (
    BEHAVIOR_TYPE_NOT_SUPPORTED,
    CANNOT_CREATE_BEHAVIOR,
    CUSTOM_ATTRIBUTE_NOT_SUPPORTED,
    CUSTOM_BEHAVIOUR_NOT_SUPPORTED,
    PARSING_FAILURE,
    BmlError,
    BmlWarning,
)
from eca.agent.bml.model import (
    BML_NS,
    CORE_EXTENSIONS_NS,
    CORE_NAMESPACES,
    ECA_NS,
    MAX_BEHAVIOURS,
    MAX_BML_CHARS,
    MAX_CONSTRAINT_REFS,
    MAX_CONSTRAINTS,
    MAX_DEPTH,
    MAX_WARNINGS,
    SMARTBODY_NS,
    SYNC_NAMES,
    SYNC_POINTS,
    Behaviour,
    BlinkParams,
    Block,
    Constraint,
    HeadDirectionParams,
    Params,
    SyncRef,
    UnrealizedBehaviour,
    XmlElement,
    is_id,
    parse_sync_ref,
    sync_points,
)
from eca.agent.bml.speech_text import Fail, speech_params

XML_NS = "http://www.w3.org/XML/1998/namespace"
_DEFAULT_PREFIXES = {"xml": XML_NS, "sbm": SMARTBODY_NS, "eca": ECA_NS}
_QUIET_NAMESPACES = frozenset({XML_NS, SMARTBODY_NS})  # known dialects' attributes: ignored without a warning
_CORE_KINDS = frozenset({"speech", "gaze", "gazeShift", "faceLexeme", "faceFacs", "face", "faceShift", "head",
                         "headDirectionShift", "wait", "blink"})
_ECA_KINDS = frozenset({"emotion", "role", "blink"})
_RESERVED_IDS = frozenset({"bml", "self"})  # names that references give a meaning of their own
_PARAMETERS: Mapping[str, frozenset[str]] = {  # each kind's attributes besides id and its sync points
    "speech": frozenset({"type"}),  # SmartBody's content type (text/plain, application/ssml+xml)
    "gaze": frozenset({"target", "influence", "offsetAngle", "offsetDirection"}),
    "gazeShift": frozenset({"target", "influence", "offsetAngle", "offsetDirection"}),
    "faceLexeme": frozenset({"lexeme", "amount"}),
    "faceShift": frozenset({"lexeme", "amount"}),
    "faceFacs": frozenset({"au", "side", "amount"}),
    "face": frozenset({"type", "au", "side", "lexeme", "amount"}),
    "head": frozenset({"lexeme", "type", "repetition", "repeats", "amount", "target"}),
    "headDirectionShift": frozenset({"target"}),
    "wait": frozenset({"max-wait"}),
    "emotion": frozenset({"name", "intensity", "transition"}),
    "role": frozenset({"role"}),
}
_ECA_ATTRIBUTES: Mapping[str, frozenset[str]] = {"speech": frozenset({"audio"})}
MAX_AUDIO_PATH_CHARS = 1024


def parse_block(text: str | bytes, name: str = "bml") -> Block:
    """One <bml> block (BML 1.0 namespace, the older mindmakers one, none, or inside SmartBody's <act>)."""
    return _BlockReader(name).read(read_xml(text, name))


def read_xml(data: str | bytes, name: str) -> XmlElement:
    """The root element, namespaces resolved; BmlError (PARSING_FAILURE) with the position of any problem."""
    if isinstance(data, bytes):
        if len(data) > 4 * MAX_BML_CHARS:  # no UTF-8 text this long is short enough: refuse before decoding
            raise BmlError(f"block is {len(data)} bytes; at most {MAX_BML_CHARS} characters", name=name)
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = data[: exc.start].count(b"\n") + 1
            raise BmlError("bytes are not UTF-8 text", name=name, line=line) from None
    else:
        text = data
    text = text.removeprefix("\ufeff")
    if len(text) > MAX_BML_CHARS:
        raise BmlError(f"block is {len(text)} characters; at most {MAX_BML_CHARS}", name=name)
    if not text.strip():
        raise BmlError("empty block", name=name)
    try:
        encoded = text.encode("utf-8")
    except UnicodeEncodeError as exc:  # a lone surrogate in a str
        raise BmlError("not Unicode text (a lone surrogate)", name=name, line=text.count("\n", 0, exc.start) + 1
                       ) from None
    parser = expat.ParserCreate(encoding="UTF-8")  # the text is ours, encoded here: any declared encoding is moot
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    parser.buffer_text = True
    stack: list[tuple[XmlElement, dict[str, str]]] = []
    roots: list[XmlElement] = []

    def refuse(message: str) -> NoReturn:
        raise BmlError(message, name=name, line=parser.CurrentLineNumber, column=parser.CurrentColumnNumber + 1)

    def start(tag: str, attrs: dict[str, str]) -> None:
        if len(stack) >= MAX_DEPTH:
            refuse(f"elements nested deeper than {MAX_DEPTH}")
        scope = dict(stack[-1][1]) if stack else {"": "", **_DEFAULT_PREFIXES}
        for key, value in attrs.items():
            if key == "xmlns" or key.startswith("xmlns:"):
                scope[key[6:]] = value
        namespace, local = _resolve(tag, scope, default=True)
        resolved = {_resolve(key, scope, default=False): value for key, value in attrs.items()
                    if key != "xmlns" and not key.startswith("xmlns:")}
        element = XmlElement(namespace, local, tag, resolved, parser.CurrentLineNumber,
                             parser.CurrentColumnNumber + 1)
        (stack[-1][0].content if stack else roots).append(element)
        stack.append((element, scope))

    def end(tag: str) -> None:
        stack.pop()

    def characters(data: str) -> None:
        if stack:
            stack[-1][0].content.append(data)

    def doctype(*_: object) -> None:
        refuse("DOCTYPE declarations are not allowed (no entities in BML)")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = characters
    parser.StartDoctypeDeclHandler = doctype
    parser.EntityDeclHandler = lambda *_: refuse("entity declarations are not allowed")
    parser.ExternalEntityRefHandler = lambda *_: refuse("external entities are not allowed")
    try:
        parser.Parse(encoded, True)
    except expat.ExpatError as exc:
        raise BmlError(f"not well-formed XML: {expat.ErrorString(exc.code)}", name=name, line=exc.lineno,
                       column=exc.offset + 1) from None
    except (ValueError, RecursionError) as exc:
        raise BmlError(f"unreadable XML: {exc}", name=name) from None
    if not roots:
        raise BmlError("no root element", name=name)
    return roots[0]


def _resolve(qualified: str, scope: Mapping[str, str], *, default: bool) -> tuple[str, str]:
    """(namespace, local name); plain attributes have no namespace (not the default one: XML Namespaces 6.2)."""
    prefix, colon, local = qualified.rpartition(":")
    if not colon:
        return (scope.get("", "") if default else ""), qualified
    return scope.get(prefix, f"unbound:{prefix}"), local


class _BlockReader:
    def __init__(self, name: str) -> None:
        self.name = name
        self.tables = mapping.bml_tables()
        self.block_id = ""
        self.lines: dict[str, int] = {}  # behaviour id -> line, for duplicates
        self.behaviours: list[Behaviour] = []
        self.unrealized: list[UnrealizedBehaviour] = []
        self.constraints: list[Constraint] = []
        self.warnings: list[BmlWarning] = []

    def fail(self, element: XmlElement, message: str, behaviour: str = "") -> NoReturn:
        raise BmlError(message, name=self.name, line=element.line, column=element.column, block=self.block_id,
                       behaviour=behaviour, warning_type=PARSING_FAILURE)

    def warn(self, kind: str, element: XmlElement, behaviour: str, text: str) -> None:
        if len(self.warnings) < MAX_WARNINGS:
            subject = f"<{element.tag}> '{behaviour}'" if behaviour else f"<{element.tag}>"
            self.warnings.append(BmlWarning(kind, self.block_id, behaviour, element.line,
                                            f"{subject} (line {element.line}): {text}"))

    def read(self, root: XmlElement) -> Block:
        bml = self._find_bml(root)
        block_id = (bml.attr("id") or "").strip()
        if not block_id:
            self.fail(bml, "<bml> needs an 'id'")
        if not is_id(block_id):
            self.fail(bml, f"block id '{block_id[:64]}' is not an id (letters, digits, '_', '.', '-'; at most 64)")
        self.block_id = block_id
        character = (bml.attr("characterId") or "").strip()
        if character and not is_id(character):
            self.fail(bml, f"characterId '{character[:64]}' is not an id")
        composition = (bml.attr("composition") or "MERGE").strip()
        if composition not in ("MERGE", "APPEND", "REPLACE"):
            self.fail(bml, f"composition '{composition[:20]}' is not MERGE, APPEND or REPLACE")
        self._check_bounds(bml)
        for element in root.elements() if root is not bml else ():
            if element is not bml and element.name != "participant":  # SmartBody's <act> names its actor
                self.warn(CUSTOM_BEHAVIOUR_NOT_SUPPORTED, element, "", "ignored inside <act>")
        self._attribute_warnings(bml, frozenset({"id", "characterId", "composition"}), "", "bml")
        self._children(bml)
        return Block(block_id, character, cast(Literal["MERGE", "APPEND", "REPLACE"], composition),
                     tuple(self.behaviours), tuple(self.constraints), tuple(self.warnings), tuple(self.unrealized),
                     self.name)

    def _find_bml(self, root: XmlElement) -> XmlElement:
        if root.name == "bml" and root.namespace in CORE_NAMESPACES:
            return root
        if root.name == "act" and root.namespace in CORE_NAMESPACES:
            blocks = [e for e in root.elements() if e.name == "bml" and e.namespace in CORE_NAMESPACES]
            if len(blocks) != 1:
                self.fail(root, f"SmartBody's <act> must hold one <bml>, this one holds {len(blocks)}")
            return blocks[0]
        self.fail(root, f"the root is <{root.tag}>; a block is <bml> (namespace {BML_NS}, "
                        "the mindmakers one, or none) or SmartBody's <act>")

    def _check_bounds(self, bml: XmlElement) -> None:
        """Count what the block asks for before reading any of it."""
        behaviours = constraints = 0
        pending = [bml]
        while pending:
            for element in pending.pop().elements():
                if element.name == "required" and element.namespace in CORE_NAMESPACES:
                    pending.append(element)
                elif element.name == "constraint" and element.namespace in CORE_NAMESPACES:
                    constraints += len(element.elements())
                else:
                    behaviours += 1
        if behaviours > MAX_BEHAVIOURS:
            self.fail(bml, f"a block holds at most {MAX_BEHAVIOURS} behaviours, this one {behaviours}")
        if constraints > MAX_CONSTRAINTS:
            self.fail(bml, f"a block holds at most {MAX_CONSTRAINTS} constraints, this one {constraints}")

    def _children(self, holder: XmlElement) -> None:
        for element in holder.elements():
            core = element.namespace in CORE_NAMESPACES
            if core and element.name == "required":  # eca keeps every constraint: required ones read like the rest
                self._children(element)
            elif core and element.name == "constraint":
                for child in element.elements():
                    self.constraints.append(self._constraint(child))
            else:
                self._behaviour(element)

    def _constraint(self, element: XmlElement) -> Constraint:
        if element.namespace not in CORE_NAMESPACES or element.name not in ("synchronize", "before", "after"):
            self.fail(element, f"<{element.tag}> is not a constraint (synchronize, before, after)")
        refs: list[SyncRef] = []
        anchor = element.attr("ref")
        if anchor is not None and element.name != "synchronize":  # OpenBMLParser: <before ref="anchor">
            refs.append(self._ref(element, anchor, "ref", None))
        for sync in element.elements():
            if sync.name != "sync" or sync.attr("ref") is None:
                self.fail(sync, f"<{element.name}> holds <sync ref=\"...\"/> elements only")
            refs.append(self._ref(sync, sync.attr("ref") or "", "ref", None))
        if not 2 <= len(refs) <= MAX_CONSTRAINT_REFS:
            self.fail(element, f"<{element.name}> needs 2 to {MAX_CONSTRAINT_REFS} references, has {len(refs)}")
        kind = cast(Literal["synchronize", "before", "after"], element.name)
        return Constraint(kind, tuple(refs), element.line)

    def _ref(self, element: XmlElement, text: str, attribute: str, carrier: str | None) -> SyncRef:
        try:
            return parse_sync_ref(text, block_id=self.block_id, carrier=carrier)
        except ValueError as exc:
            self.fail(element, f"attribute '{attribute}': {exc}", carrier or "")

    def _behaviour(self, element: XmlElement) -> None:
        namespace, kind = element.namespace, element.name
        realizable = ((namespace in CORE_NAMESPACES and kind in _CORE_KINDS)
                      or (namespace == CORE_EXTENSIONS_NS and kind == "faceFacs")
                      or (namespace == ECA_NS and kind in _ECA_KINDS))
        behaviour_id = (element.attr("id") or "").strip()
        if not realizable and namespace not in CORE_NAMESPACES | {CORE_EXTENSIONS_NS}:
            self.warn(CUSTOM_BEHAVIOUR_NOT_SUPPORTED, element, behaviour_id,
                      f"namespace '{namespace[:80]}' is not one eca knows; ignored")
            return
        if not behaviour_id and not realizable:  # a gesture with no id: nothing can refer to it anyway
            self.warn(BEHAVIOR_TYPE_NOT_SUPPORTED, element, "", "not realizable on a face; ignored")
            return
        self._register(element, behaviour_id)
        if not realizable:
            self.warn(BEHAVIOR_TYPE_NOT_SUPPORTED, element, behaviour_id,
                      "not realizable on a face; ignored (its sync points still hold for references)")
            self._unrealized(element, behaviour_id, kind)
            return
        attrs = {local: value for (ns, local), value in element.attrs.items() if ns == ""}
        try:
            kind, params = self._params(element, kind, attrs)
        except ValueError as exc:
            self.fail(element, str(exc), behaviour_id)
        except mapping.Unrealizable as exc:
            self.warn(CANNOT_CREATE_BEHAVIOR, element, behaviour_id, f"{exc}; ignored")
            self._unrealized(element, behaviour_id, element.name)
            return
        known = _PARAMETERS.get(element.name, frozenset())
        self._attribute_warnings(element, known | {"id", *sync_points(element.name)}, behaviour_id, element.name)
        sync = self._sync_attributes(element, behaviour_id, kind)
        self.behaviours.append(Behaviour(behaviour_id, kind, element.line, sync, params))

    def _register(self, element: XmlElement, behaviour_id: str) -> None:
        if not behaviour_id:
            self.fail(element, f"<{element.tag}> needs an 'id'")
        if not is_id(behaviour_id) or behaviour_id in _RESERVED_IDS:
            self.fail(element, f"behaviour id '{behaviour_id[:64]}' is not an id (letters, digits, '_', '.', '-'; "
                               "at most 64; not 'bml' or 'self')")
        if behaviour_id in self.lines:
            self.fail(element, f"id '{behaviour_id}' is used twice: line {self.lines[behaviour_id]} and line "
                               f"{element.line}", behaviour_id)
        self.lines[behaviour_id] = element.line

    def _unrealized(self, element: XmlElement, behaviour_id: str, kind: str) -> None:
        sync = self._sync_attributes(element, behaviour_id, kind)
        self.unrealized.append(UnrealizedBehaviour(behaviour_id, kind, element.line, sync))

    def _params(self, element: XmlElement, kind: str, attrs: dict[str, str]) -> tuple[str, Params]:
        tables = self.tables
        if kind == "speech":
            audio = element.attrs.get((ECA_NS, "audio"))
            if audio is not None and (not audio.strip() or len(audio) > MAX_AUDIO_PATH_CHARS
                                      or not audio.isprintable()):
                raise ValueError(f"attribute 'eca:audio' must be a file path of 1 to {MAX_AUDIO_PATH_CHARS} "
                                 "printable characters")
            return kind, speech_params(element, audio.strip() if audio else None, self._fail_inside(element))
        if kind in ("gaze", "gazeShift"):
            return kind, mapping.gaze(attrs, tables, kind)
        if kind in ("faceLexeme", "faceShift"):
            return kind, mapping.face_lexeme(attrs, tables, kind)
        if kind == "faceFacs":
            return kind, mapping.face_facs(attrs, tables, kind)
        if kind == "face":
            return mapping.smartbody_face(attrs, tables)
        if kind == "head":
            params = mapping.head(attrs, tables)  # ORIENT with a target turns the head toward it
            return ("headDirectionShift" if isinstance(params, HeadDirectionParams) else kind), params
        if kind == "headDirectionShift":
            return kind, HeadDirectionParams(mapping.target(attrs, kind))
        if kind == "wait":
            return kind, mapping.wait(attrs)
        if kind == "emotion":
            return kind, mapping.emotion(attrs, tables)
        if kind == "role":
            return kind, mapping.role(attrs)
        return kind, BlinkParams()

    def _fail_inside(self, speech: XmlElement) -> Fail:
        behaviour_id = (speech.attr("id") or "").strip()

        def fail(element: XmlElement, message: str) -> NoReturn:
            self.fail(element, message, behaviour_id)

        return fail

    def _sync_attributes(self, element: XmlElement, behaviour_id: str, kind: str) -> dict[str, SyncRef]:
        points = sync_points(kind)
        sync: dict[str, SyncRef] = {}
        for (namespace, attribute), value in element.attrs.items():
            if namespace or attribute not in SYNC_NAMES:
                continue
            if attribute not in points and kind not in SYNC_POINTS:
                continue  # an element unknown to BML 1.0 (SmartBody's <animation>): its own phases are its own
            if attribute not in points:
                self.fail(element, f"<{element.tag}> has no sync point '{attribute}' (it has {', '.join(points)})",
                          behaviour_id)
            sync[attribute] = self._ref(element, value, attribute, behaviour_id)
        return sync

    def _attribute_warnings(self, element: XmlElement, known: frozenset[str], behaviour_id: str, kind: str) -> None:
        for namespace, attribute in element.attrs:
            if namespace in _QUIET_NAMESPACES or (not namespace and (attribute in known or attribute in SYNC_NAMES)):
                continue
            if namespace == ECA_NS and attribute in _ECA_ATTRIBUTES.get(kind, frozenset()):
                continue
            written = f"{namespace}:{attribute}" if namespace else attribute
            self.warn(CUSTOM_ATTRIBUTE_NOT_SUPPORTED, element, behaviour_id, f"attribute '{written[:120]}' ignored")
