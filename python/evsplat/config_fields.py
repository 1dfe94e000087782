"""The settings of a ``TrainConfig`` by dotted name (``loss.w_motion``, ``mover.enabled``):
their types, their one-line meanings, and values given as text on the command line
(``--set KEY=VALUE``).

Written over the dataclasses' fields, so a field added to ``evsplat.config`` is settable and
listed with no change here. A field's meaning is the comment beside it in config.py (on its
line, else the comment lines just above it, which also cover the fields that follow without
a blank line), read from the source with ``tokenize``: the comment stays the one place it is
written.
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import inspect
import io
import math
import re
import textwrap
import tokenize
import types
import typing
from functools import cache

from evsplat.config import TrainConfig
from evsplat.errors import EvsplatError

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")
_NONE = ("none", "null")


def _walk(cls: type, prefix: str = "") -> list[tuple[str, type, str, type]]:
    """(dotted key, owning dataclass, field name, type) of every leaf setting, in field order."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind):
            out += _walk(kind, f"{prefix}{f.name}.")
        else:
            out.append((f"{prefix}{f.name}", cls, f.name, kind))
    return out


@cache
def settings() -> dict[str, tuple[type, str, type]]:
    """Every leaf setting of TrainConfig: dotted key -> (owning dataclass, field name, type)."""
    return {key: (cls, name, kind) for key, cls, name, kind in _walk(TrainConfig)}


def _sentence(text: str) -> str:
    """The first sentence of a comment block (a period before a capital or a backtick ends it)."""
    return re.split(r"(?<=\.)\s+(?=[A-Z`])", text.strip(), maxsplit=1)[0]


@cache
def _class_meanings(cls: type) -> dict[str, str]:
    """Field name -> the first sentence of its comment in ``cls``'s source ('' without one):
    the comment lines just above it (or above the run of fields it ends), then its own."""
    source = textwrap.dedent(inspect.getsource(cls))
    comments: dict[int, str] = {}  # line -> comment text
    code: set[int] = set()  # lines that hold code (a comment beside code is not above a field)
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
        elif tok.type not in (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT):
            code.update(range(tok.start[0], tok.end[0] + 1))
    (body,) = ast.parse(source).body
    fields = [
        node
        for node in body.body  # type: ignore[attr-defined]
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
    ]
    meanings: dict[str, str] = {}
    block, previous_end = "", -1
    for node in fields:
        above, n = [], node.lineno - 1
        while n in comments and n not in code:
            above.insert(0, comments[n])
            n -= 1
        if above:
            block = " ".join(above)
        elif n != previous_end:  # a blank line or other code ends a comment's run of fields
            block = ""
        own = comments.get(node.lineno) or comments.get(node.end_lineno or node.lineno, "")
        texts = (block if above or not own else "", own)
        parts = [_sentence(text).rstrip(".") for text in texts if text]
        meanings[node.target.id] = "; ".join(parts)  # type: ignore[union-attr]
        previous_end = node.end_lineno or node.lineno
    return meanings


def meaning(key: str) -> str:
    """The one-line meaning of the setting ``key`` ('' where config.py gives none)."""
    cls, name, _ = settings()[key]
    return _class_meanings(cls).get(name, "")


def _unknown(key: str) -> EvsplatError:
    keys = list(settings())
    inside = [k for k in keys if k.startswith(f"{key}.")]
    if inside:
        return EvsplatError(f"--set {key}: a section; set one of its fields, e.g. {inside[0]}")
    close = difflib.get_close_matches(key, keys, n=4, cutoff=0.6)
    # A leaf name alone (``lambda_ssim``) or the paper's symbol (``lambda_m`` for λ_m).
    leaf = key.rsplit(".", 1)[-1]
    close += [k for k in keys if k.rsplit(".", 1)[-1] == leaf and k not in close]
    symbol = leaf.replace("lambda_", "λ_")
    if symbol != leaf:
        pattern = re.compile(rf"{re.escape(symbol)}\b")
        close += [k for k in keys if pattern.search(meaning(k)) and k not in close]
    hint = f"closest: {', '.join(close)}" if close else "`evsplat config show` lists them all"
    return EvsplatError(f"--set {key}: no such setting; {hint}")


def _parse(text: str, kind: object, key: str) -> object:
    """``text`` as a value of ``kind`` (bool, int, float, str, a tuple of them, or X | None)."""
    args = typing.get_args(kind)
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        if text.strip().lower() in _NONE:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _parse(text, inner, key)
    if typing.get_origin(kind) is tuple:
        parts = text.strip().strip("()").split(",")
        if len(parts) != len(args):
            raise EvsplatError(
                f"--set {key}={text}: expected {len(args)} comma-separated values, e.g. "
                f"{key}={','.join(_example(a) for a in args)}"
            )
        return tuple(_parse(p, a, key) for p, a in zip(parts, args))
    word = text.strip()
    if kind is bool:
        if word.lower() in _TRUE + _FALSE:
            return word.lower() in _TRUE
    elif kind is int:
        try:
            return int(word)
        except ValueError:
            pass
    elif kind is float:
        try:
            value = float(word)
        except ValueError:
            value = math.nan
        if math.isfinite(value):
            return value
    elif kind is str:
        return text
    raise EvsplatError(f"--set {key}={text}: expected {_name(kind)}, e.g. {key}={_example(kind)}")


def _name(kind: object) -> str:
    return {bool: "true or false", int: "an integer", float: "a finite number"}.get(kind, "text")


def _example(kind: object) -> str:
    inner = [a for a in typing.get_args(kind) if a is not type(None)]
    if typing.get_origin(kind) in (typing.Union, types.UnionType) and len(inner) == 1:
        return _example(inner[0])
    return {bool: "false", int: "3", float: "0.5"}.get(kind, "text")


def apply(cfg: TrainConfig, assignments: list[str]) -> TrainConfig:
    """``cfg`` with each ``KEY=VALUE`` of ``assignments`` set (in order; ``cfg`` is changed in
    place and returned). A key that is not a setting or a value of the wrong type is a one-line
    error: the first lists the closest names, the second the type and an example."""
    for item in assignments:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise EvsplatError(f"--set {item!r}: expected KEY=VALUE, e.g. --set loss.w_motion=0.2")
        if key not in settings():
            raise _unknown(key)
        _, name, kind = settings()[key]
        owner = cfg
        for part in key.split(".")[:-1]:
            owner = getattr(owner, part)
        setattr(owner, name, _parse(text, kind, key))
    return cfg


def describe(cfg: TrainConfig) -> str:
    """Every setting of ``cfg`` as ``key = value  # meaning``, one a line, in field order."""
    rows = []
    for key in settings():
        value = cfg
        for part in key.split("."):
            value = getattr(value, part)
        rows.append((f"{key} = {value!r}", meaning(key)))
    width = max(len(left) for left, _ in rows)
    return "\n".join(f"{left:<{width}}  # {text}" if text else left for left, text in rows)
