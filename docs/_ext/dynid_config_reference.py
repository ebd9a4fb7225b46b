"""The reference of ``dynid identify``'s configuration, generated from the schema at build time.

Nothing here lists a key by hand. The schema is asked through the public parser
:func:`dynid.config.parse_config`, as a user's file would ask it:

* the sections and keys: a table with one unknown key is refused with the list of the keys allowed
  there ("allowed keys in [processing] are [...]"), so every table the parser knows, nested tables
  included, is found by recursion from the top level;
* required keys: an empty table is refused with "missing required keys [...]";
* the type and the allowed values of a key: a value of the wrong type (the string ``"zz_probe"``) is
  refused with "expected a number", "must be one of [...]", ...; a key that applies only when another
  is set is refused first for that ("... is for method = 'iv' or 'didim'", "... set
  identification.physical_consistency = true"): the probe sets it as the message says and asks again,
  and the reference states the condition;
* the defaults: the values the parser fills in for a minimal config (``dynid.config.Config`` and its
  dataclasses), and else the default of the matching dataclass field;
* the description: the comment written beside that field in the dataclass's source, where there is
  one, and the dataclass's docstring for the section.

The directive ``.. dynid-config-reference::`` renders it (``docs/reference/config.rst``);
``tests/test_docs_config_reference.py`` checks that it covers every key the parser accepts.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib
import inspect
import io
import re
import tokenize
import typing
from pathlib import Path
from typing import Any

PROBE = "zz_probe"

# the smallest document the parser accepts: the probes change one table of it at a time (no file is read)
MINIMAL: dict[str, Any] = {
    "robot": {"model": "builtin:puma560"},
    "data": {"file": "train.csv", "time": {"column": "t"}, "position": {"columns": ["q1"]},
             "effort": {"columns": ["tau1"]}},
    "validation": {"file": "valid.csv"},
}

_ALLOWED = re.compile(r"allowed keys in (?:the top level|\[(?P<where>[^\]]+)\]) are \[(?P<keys>[^\]]*)\]")
_MISSING = re.compile(r"missing required keys \[(?P<keys>[^\]]*)\]")
_CHOICES = re.compile(r"must be one of \[(?P<keys>[^\]]*)\]")


@dataclasses.dataclass
class Key:
    name: str
    type: str = ""
    choices: tuple[str, ...] = ()
    default: str = ""
    required: bool = False
    description: str = ""
    condition: str = ""  # "is for covariance = 'hac'": when the key applies
    table: bool = False  # a nested table, documented as its own section


@dataclasses.dataclass
class Section:
    path: tuple[str, ...]  # () is the top level
    keys: list[Key]
    doc: str = ""

    @property
    def title(self) -> str:
        return "Top level" if not self.path else "[" + ".".join(self.path) + "]"


def _parse(doc: dict[str, Any]):
    from dynid.config import parse_config

    return parse_config(doc, Path("."))


def _error(doc: dict[str, Any]) -> str | None:
    from dynid.errors import ConfigError

    try:
        _parse(doc)
    except ConfigError as exc:
        return str(exc)
    return None


def _names(text: str) -> list[str]:
    return [k.strip().strip("'\"") for k in text.split(",") if k.strip()]


def _with(path: tuple[str, ...], value: Any, key: str | None = None) -> dict[str, Any]:
    """MINIMAL with the table at ``path`` given (created empty), and ``key = value`` in it (or the table
    replaced by ``value`` when ``key`` is None)."""
    doc = copy.deepcopy(MINIMAL)
    if not path:
        if key is not None:
            doc[key] = value
        return doc
    t = doc
    for p in path:
        if not isinstance(t.get(p), dict):
            t[p] = {}
        if p is not path[-1] or key is not None:
            t = t[p]
    if key is None:
        t[path[-1]] = value
    else:
        t[key] = value
    return doc


def allowed_keys(path: tuple[str, ...]) -> list[str] | None:
    """The keys the parser allows in the table at ``path`` (None: not a table the parser reads alone)."""
    msg = _error(_with(path, PROBE, PROBE) if path else {**copy.deepcopy(MINIMAL), PROBE: 1})
    m = _ALLOWED.search(msg or "")
    if not m or (m.group("where") or "") != ".".join(path):
        return None
    return _names(m.group("keys"))


def required_keys(path: tuple[str, ...]) -> set[str]:
    if not path:
        m = _MISSING.search(_error({}) or "")
    else:
        m = _MISSING.search(_error(_with(path, {})) or "")
    return set(_names(m.group("keys"))) if m else set()


_SET = re.compile(r"set (?P<key>[\w.]+) = (?P<value>\S+)$")
_FOR = re.compile(r" is for (?P<key>\w+) = (?P<value>'[^']*')")


def _set(doc: dict[str, Any], dotted: str, value: Any) -> None:
    *tables, key = dotted.split(".")
    t = doc
    for name in tables:
        t = t.setdefault(name, {})
    t[key] = value


def _kind(path: tuple[str, ...], key: str) -> tuple[str, tuple[str, ...], str]:
    """The type a wrong value's error names, the allowed values it lists, and the condition under which
    the key applies (when the parser first asked for another key: "is for method = 'iv' ...")."""
    doc = _with(path, PROBE, key)
    where = ".".join((*path, key))
    condition = ""
    for _ in range(3):  # a key that applies only with another key set: set it, as the message says, and ask again
        msg = _error(doc) or ""
        m = _CHOICES.search(msg)
        if m and where in msg:
            return "string", tuple(_names(m.group("keys"))), condition
        for pattern, name in (("expected a finite number", "number"), ("expected a number", "number"),
                              ("expected an integer", "integer"), ("expected true or false", "boolean"),
                              ("expected a list", "list"), ("expected a table", "table"),
                              ("give a number or one per", "number or list"), ("not found", "path")):
            if pattern in msg and where in msg:
                return name, (), condition
        needs = _SET.search(msg) if msg.startswith(where) else None
        if needs is None and msg.startswith(where):
            needs = _FOR.search(msg)
            if needs is not None:
                condition = "only with " + msg[len(where):].split(", not ")[0].strip().removeprefix("is for ")
        if needs is None:
            break
        import tomllib

        target = needs.group("key") if "." in needs.group("key") else ".".join((*path, needs.group("key")))
        _set(doc, target, tomllib.loads(f"v = {needs.group('value')}")["v"])
        if not condition:
            own = target.removeprefix(".".join(path) + ".") if path else target
            condition = f"only with {own} = {needs.group('value')}"
    return "", (), condition


# ---------------------------------------------------------------------- the dataclasses behind a table
def _field_comments(cls: type) -> dict[str, str]:
    """The comments of a dataclass's fields: the comment ending the line ``name: type = default  # ...``
    (with the comment lines below it at the same column), else the comment lines just above the field."""
    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    tokens = tokenize.generate_tokens(io.StringIO(source).readline)
    comments = {t.start[0]: (t.start[1], t.string.lstrip("#").strip()) for t in tokens if t.type == tokenize.COMMENT}
    out: dict[str, str] = {}
    pending: list[str] = []  # comment lines above the next field
    trailing: tuple[str, int] | None = None  # the field whose line ended in a comment, and that comment's column
    for i, line in enumerate(source.splitlines(), start=1):
        stripped = line.lstrip()
        c = comments.get(i)
        if stripped.startswith("#") and c:
            if trailing is not None and c[0] == trailing[1]:
                out[trailing[0]] += " " + c[1]
            else:
                trailing = None
                pending.append(c[1])
            continue
        m = re.match(r"\s+([A-Za-z_]\w*)\s*:(?!:)", line)
        if m and not stripped.startswith(("def ", "class ", "@", "return")):
            name = m.group(1)
            parts = ([c[1]] if c else []) or pending
            if parts:
                out[name] = " ".join(parts)
            trailing = (name, c[0]) if c else None
        else:
            trailing = None
        pending = []
    return out


def _dataclass_of(hint: Any) -> type | None:
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return hint
    for arg in typing.get_args(hint):
        cls = _dataclass_of(arg)
        if cls is not None:
            return cls
    return None


def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except Exception:  # an annotation that does not resolve at run time: the raw strings
        return {}


def _objects(path: tuple[str, ...]) -> tuple[Any, type | None]:
    """The parsed object of the table at ``path`` in MINIMAL (None when the minimal document leaves it out)
    and its dataclass (from the object, else from the parent's type hints)."""
    from dynid.config import Config

    parsed: Any = None
    for doc in [MINIMAL, _with(path, {})] if path else [MINIMAL]:
        try:
            parsed = _parse(doc)
        except Exception:
            continue
        obj: Any = parsed
        for p in path:
            obj = getattr(obj, p, None)
        if obj is not None:
            break
    obj, cls = parsed, Config
    for p in path:
        hint = _hints(cls).get(p) if cls is not None else None
        obj = getattr(obj, p, None) if obj is not None else None
        parent = cls
        cls = type(obj) if dataclasses.is_dataclass(obj) else _dataclass_of(hint)
        if cls is None and parent is not None:
            cls = _named_class(parent, p)
    return obj, cls


def _named_class(cls: type, name: str) -> type | None:
    """The dataclass that the comment of ``cls``'s field ``name`` names (``dynid.module.Class``): a field
    typed ``Any`` to keep an optional table's class out of the import graph (``Config.payload``)."""
    m = re.search(r"(dynid(?:\.\w+)+)\.([A-Z]\w*)", _field_comments(cls).get(name, ""))
    if m is None:
        return None
    try:
        found = getattr(importlib.import_module(m.group(1)), m.group(2), None)
    except ImportError:
        return None
    return found if dataclasses.is_dataclass(found) else None


_DESCRIPTION_ALIASES = {"lambda": "lam"}  # a key that is a Python keyword: its field's name


def _descriptions(cls: type | None, path: tuple[str, ...], parent: type | None) -> dict[str, str]:
    """The descriptions of a table's keys, by key: the comments of its dataclass's fields; the comments of a
    nested dataclass's fields that open with the key they read (``covariance_blocks (hac, ...): ...``, the
    fields of ``CovarianceConfig``); for a table without a dataclass of its own, its parent's fields named
    ``<table>_<key>`` (``[payload.origin] xyz``: ``PayloadConfig.origin_xyz``)."""
    out: dict[str, str] = {}
    if cls is not None:
        out.update(_field_comments(cls))
        for hint in _hints(cls).values():
            sub = _dataclass_of(hint)
            if sub is None or sub is cls:
                continue
            for text in _field_comments(sub).values():
                m = re.match(r"([a-z_]+) [(:]", text)
                if m and m.group(1) not in out:
                    out[m.group(1)] = text
        for key, field in _DESCRIPTION_ALIASES.items():
            if field in out and key not in out:
                out[key] = out[field]
        # a sub-table held as prefixed fields (origin -> origin_xyz, origin_rpy): its keys' descriptions joined
        prefixed: dict[str, list[str]] = {}
        for name, text in _field_comments(cls).items():
            head, _, tail = name.partition("_")
            if tail and head not in out:
                prefixed.setdefault(head, []).append(f"{tail}: {text}")
        out.update({head: "; ".join(parts) for head, parts in prefixed.items() if len(parts) > 1})
    elif parent is not None and path:
        out.update({name.removeprefix(path[-1] + "_"): text for name, text in _field_comments(parent).items()
                    if name.startswith(path[-1] + "_")})
    if not path:  # top-level keys read by a function of dynid.config of the same name (data_root)
        import dynid.config as package

        for name, fn in vars(package).items():
            if callable(fn) and not isinstance(fn, type) and (fn.__doc__ or "").strip() and name not in out:
                first = inspect.getdoc(fn).split("\n\n", 1)[0].replace("\n", " ")
                out[name] = re.sub(r"^``\w+``:\s*", "", first)
    return out


def _default(name: str, obj: Any, cls: type | None) -> str:
    fields = {f.name: f for f in dataclasses.fields(cls)} if cls is not None else {}
    aliases = [name, name.removeprefix("covariance_"), name[:3]]  # lambda -> lam (a keyword in Python)
    for attr in aliases:
        if obj is not None and hasattr(obj, attr):
            value = getattr(obj, attr)
            break
        f = fields.get(attr)
        if f is not None and f.default is not dataclasses.MISSING:
            value = f.default
            break
    else:
        return ""
    if dataclasses.is_dataclass(value) or isinstance(value, Path):
        return ""
    if value is None:
        return "not set"
    if isinstance(value, tuple):
        value = list(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def collect() -> list[Section]:
    """Every table of the identify config with its keys, top level first, depth first."""
    sections: list[Section] = []

    def visit(path: tuple[str, ...], parent: type | None) -> None:
        keys = allowed_keys(path)
        if keys is None:
            return
        required = required_keys(path)
        obj, cls = _objects(path)
        comments = _descriptions(cls, path, parent)
        doc = inspect.getdoc(cls) or "" if cls is not None and cls.__doc__ and "(" not in cls.__doc__[:len(cls.__name__) + 1] else ""
        section = Section(path, [], doc)
        sections.append(section)
        subtables = []
        for name in keys:
            key = Key(name, required=name in required)
            key.table = allowed_keys((*path, name)) is not None
            if key.table:
                key.type = "table"
                subtables.append(name)
            else:
                key.type, key.choices, key.condition = _kind(path, name)
                key.default = "" if key.required else _default(name, obj, cls)
            key.description = comments.get(name, comments.get(name.removeprefix("covariance_"), ""))
            if not key.type and cls is not None:
                hint = _hints(cls).get(name)
                key.type = _type_name(hint) if hint is not None else ""
            section.keys.append(key)
        for name in subtables:
            visit((*path, name), cls)

    visit((), None)
    return sections


_TYPE_WORDS = {"str": "string", "float": "number", "int": "integer", "bool": "boolean", "Path": "path"}


def _type_name(hint: Any) -> str:
    """A field's annotation in the words of a TOML file: ``tuple[float, ...] | None`` -> ``list of number``."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    origin = typing.get_origin(hint)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " or ".join(_type_name(a) for a in args)
    if origin is not None and isinstance(origin, type) and issubclass(origin, __import__("collections").abc.Mapping):
        return "table"
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return "list of " + _type_name(args[0])
        return "list of " + str(len(args)) + " " + " or ".join(sorted({_type_name(a) for a in args}))
    if isinstance(hint, type):
        return "table" if dataclasses.is_dataclass(hint) else _TYPE_WORDS.get(hint.__name__, hint.__name__)
    return str(hint).replace("typing.", "")


# ---------------------------------------------------------------------- rendering
def _rst_escape(text: str) -> str:
    return re.sub(r"([*`|_\\])", r"\\\1", text)


def to_rst(sections: list[Section]) -> str:
    lines: list[str] = []
    for s in sections:
        title = s.title
        lines += [title, "-" * len(title), ""]
        if s.doc:  # reStructuredText already (a docstring); its roles as literals, so it reads outside Sphinx too
            lines += [re.sub(r":[\w:]+:`~?([^`]+)`", r"``\1``", " ".join(s.doc.split())), ""]
        lines += [".. list-table::", "   :header-rows: 1", "   :widths: 18 16 16 50", "",
                  "   * - key", "     - type", "     - default", "     - description"]
        for k in s.keys:
            type_ = k.type or "see description"
            if k.choices:
                type_ += ": " + " | ".join(f"``{c}``" for c in k.choices)
            default = "**required**" if k.required else (f"``{k.default}``" if k.default else "")
            desc = _rst_escape(k.description)
            if k.condition:
                desc = f"*({_rst_escape(k.condition)})* " + desc
            if k.table:
                sub = "[" + ".".join((*s.path, k.name)) + "]"
                desc = (desc + " " if desc else "") + f"(a table: see `{sub}`_)"
            lines += [f"   * - ``{k.name}``", f"     - {type_}", f"     - {default}", f"     - {desc}"]
        lines.append("")
    return "\n".join(lines)


def setup(app):  # pragma: no cover - run by Sphinx
    from docutils import nodes
    from docutils.statemachine import StringList
    from sphinx.util.docutils import SphinxDirective
    from sphinx.util.nodes import nested_parse_with_titles

    class ConfigReference(SphinxDirective):
        """``.. dynid-config-reference::``: one section per table of the identify config."""

        has_content = False

        def run(self):
            holder = nodes.section()
            holder.document = self.state.document
            text = to_rst(collect())
            nested_parse_with_titles(self.state, StringList(text.splitlines(), source="<dynid config schema>"), holder)
            return holder.children

    app.add_directive("dynid-config-reference", ConfigReference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
