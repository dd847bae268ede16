"""The XML layer of a Mitsuba 3 scene file, shared by the loader
(:mod:`core.loader`) and the reference store (:mod:`references.reference`):
parsing, ``<default>`` values and ``$name`` substitution, ``<include>`` and
``<path>``, file lookup and the upgrade of pre-2.0 files.  One set of rules,
so the scene the own algorithms read and the files a reference is keyed by
are found the same way (Mitsuba 3.9's ``parser.cpp`` is the model):

* ``$name`` (an identifier, ``[A-Za-z_][A-Za-z0-9_]*``) is replaced by the
  ``-D`` value or the ``<default>`` value; a name with neither is an error.
* ``<include>`` nests at most :data:`MAX_INCLUDE_DEPTH` files (Mitsuba's
  limit); gibench also caps the total number of included files at
  :data:`MAX_INCLUDES` (Mitsuba has no such cap), so a small file including
  another ten times per level cannot expand into millions of elements.
* Files are parsed without DTD loading, entity expansion or network access
  (no external or internal entities: Mitsuba's parser has none either), so an
  entity bomb or an external entity is an error, never an expansion.

Every error is a :class:`core.errors.SceneError` naming the file, the line,
the element and, inside an included file, the chain of includes.
"""

from __future__ import annotations

import re
from pathlib import Path

from lxml import etree

from .errors import SceneError

__all__ = ["Document", "resolve", "expanded", "parse_file", "substitute", "check_defines", "short",
           "IDENTIFIER", "MAX_INCLUDE_DEPTH", "MAX_INCLUDES"]

#: A ``<default>`` / ``-D`` name and what ``$name`` matches.
IDENTIFIER = r"[A-Za-z_][A-Za-z0-9_]*"

#: Private attribute marking the top element spliced in by an ``<include>`` (its
#: value indexes ``Document.sources``); namespaced so no plugin property can clash.
_SRC = "{urn:gibench:loader}source"

#: Mitsuba's limit on nested ``<include>`` files (parser.cpp ``max_include_depth``).
MAX_INCLUDE_DEPTH = 15

#: gibench's limit on the number of ``<include>`` expansions in one scene.
MAX_INCLUDES = 1000


def short(text, limit: int = 60) -> str:
    """``text`` for an error message: on one line, at most ``limit`` characters (a
    hostile value of thousands of digits is not echoed in full)."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def check_defines(defines) -> dict[str, str]:
    """``{name: value}`` as strings, each name an identifier (``-D name=value``)."""
    out = {}
    for k, v in (defines or {}).items():
        if not re.fullmatch(IDENTIFIER, str(k)):
            raise SceneError(f"-D: a define name must be an identifier, got {short(k)!r}")
        out[str(k)] = str(v)
    return out


def substitute(value: str, defaults: dict[str, str], fail) -> str:
    """``value`` with every ``$name`` replaced from ``defaults``; ``fail(name)`` returns
    the exception to raise for a name without a value."""
    def rep(m):
        name = m.group(1)
        if name not in defaults:
            raise fail(name)
        return defaults[name]
    return re.sub(r"\$(" + IDENTIFIER + ")", rep, value)


def _parser() -> etree.XMLParser:
    return etree.XMLParser(remove_comments=True, resolve_entities=False, load_dtd=False,
                           no_network=True, huge_tree=False)


def parse_file(path: Path, where: str = "") -> etree._ElementTree:
    """The parsed XML file (hardened parser, comments dropped); a :class:`SceneError`
    with file and line for malformed XML, an unreadable file or an entity."""
    try:
        tree = etree.parse(str(path), _parser())
    except etree.XMLSyntaxError as exc:
        line = exc.lineno if exc.lineno is not None else "?"
        raise SceneError(f"{path}:{line}: malformed XML: {short(exc.msg, 200)}{where}") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {short(exc, 200)}{where}") from None
    for node in tree.iter(etree.Entity):
        raise SceneError(f"{path}:{node.sourceline}: XML entities are not supported "
                         f"(&{node.name};){where}")
    if tree.docinfo.internalDTD is not None and tree.docinfo.internalDTD.entities():
        raise SceneError(f"{path}:1: XML entity declarations are not supported{where}")
    return tree


class Document:
    """A scene file with its includes expanded in place (:func:`resolve`): the root
    element, the ``<default>``/``-D`` values, the ``<path>`` directories, the
    included files (``includes``: ``(name as written, path)``) and where each
    element came from, for errors."""

    def __init__(self, path: Path, defines: dict[str, str] | None = None):
        self.path = path
        self.root = None
        self.defaults: dict[str, str] = check_defines(defines)
        self.files: list[Path] = []
        self.includes: list[tuple[str, Path]] = []
        # <include>d files: (file, "included from a.xml:3 <- ...") by index; see _expand_includes.
        self.sources: list[tuple[Path, str]] = []
        # <path> directories, most recent first (Mitsuba prepends them to its file resolver).
        self.search: list[Path] = []

    def where(self, el) -> tuple[Path, str]:
        """The file an element comes from and its include chain ("" for the scene file)."""
        node = el
        while node is not None:
            src = node.get(_SRC) if isinstance(node.tag, str) else None
            if src is not None:
                return self.sources[int(src)]
            node = node.getparent()
        return self.path, ""

    def error(self, el, msg: str) -> SceneError:
        line = getattr(el, "sourceline", None) or "?"
        tag = el.tag if isinstance(el.tag, str) else "?"
        typ = el.get("type")
        desc = f'<{tag} type="{typ}">' if typ else f"<{tag}>"
        path, chain = self.where(el)
        text = f"{path}:{line}: {desc}: {msg}{chain}"
        return SceneError(text.replace("\r", " ").replace("\n", " "))      # always one line

    def resolve(self, el, name: str, what: str = "file") -> Path:
        """A file named in the scene, found as Mitsuba's file resolver finds it: an
        absolute name as is; a relative one in the ``<path>`` directories (the latest
        declared first), then in the scene file's directory."""
        p = Path(name)
        if p.is_absolute():
            if p.is_file():
                return p
            raise self.error(el, f"{what} not found: {p}")
        dirs = [*self.search, self.path.parent]
        for d in dirs:
            if (d / p).is_file():
                return (d / p).resolve()
        raise self.error(el, f"{what} '{name}' not found (searched: {', '.join(str(d) for d in dirs)})")

    def attr(self, el, key: str, default=None):
        v = el.get(key)
        if v is None:
            return default
        return self.subst(el, v)

    def subst(self, el, v: str) -> str:
        return substitute(v, self.defaults,
                          lambda name: self.error(el, f"'${name}' has no <default> value"))


def _snake_case(name: str) -> str:
    """Mitsuba 3's camelCase -> snake_case rule (xml.cpp ``upgrade_tree``), kept
    exactly: at a lower-upper pair insert ``_`` and lower-case the run of capitals
    that follows (``intIOR`` -> ``int_ior``); the character after that run is
    skipped, as in Mitsuba's loop."""
    i = 0
    while i < len(name) - 1:
        if name[i].islower() and name[i + 1].isupper():
            name = name[:i + 1] + "_" + name[i + 1:]
            i += 2
            while i < len(name) and name[i].isupper():
                name = name[:i] + name[i].lower() + name[i + 1:]
                i += 1
        i += 1
    return name


def _upgrade_pre_v2(root) -> None:
    """In-memory upgrade of a Mitsuba 0.x/1.x scene, as Mitsuba 3 performs it
    (parameter names only; ``<lookAt>`` is not renamed, see the module docstring)."""
    for el in root.iter():
        if not isinstance(el.tag, str):
            continue
        if el.tag != "default" and el.get("name") is not None:
            el.set("name", _snake_case(el.get("name")))
    for el in root.iter("bsdf"):
        if el.get("type") == "diffuse":
            for c in el:
                if isinstance(c.tag, str) and c.get("name") == "diffuse_reflectance":
                    c.set("name", "reflectance")


# --------------------------------------------------------------- include ---

def _parse_xml(path: Path, where: str = "") -> etree._Element:
    return parse_file(path, where).getroot()


def _check_version(ctx, root, where: str = "") -> int:
    """The major version of a file's root ``version`` attribute; a file older
    than 2.0 is upgraded in memory (:func:`_upgrade_pre_v2`)."""
    version = root.get("version", "3.0.0")
    m = re.fullmatch(r"\s*(\d{1,4})\.(\d{1,4})(?:\.(\d{1,4}))?\s*", version)
    if m is None or int(m.group(1)) > 3:
        raise ctx.error(root, f"unsupported scene version '{short(version)}' (0.x to 3.x)")
    if int(m.group(1)) < 2:
        _upgrade_pre_v2(root)
    return int(m.group(1))


def _expand_includes(ctx, root, file: Path, chain: str, depth: int) -> None:
    """Replace every ``<include filename=...>`` under ``root`` by the file's content and
    record the ``<path value=...>`` directories, in document order, as Mitsuba 3's
    parser does (parser.cpp, ``TagType::Include`` / ``TagType::Resource``):

    * ``<path>`` may only be a child of the root; a relative directory is taken
      from the directory of the file that declares it, else looked up in the
      directories declared before; it must exist.  Later ones are searched first.
    * An included file is looked up in the including file's directory, then in
      the ``<path>`` directories, then in the scene file's directory.  It needs a
      ``version`` on its root (files older than 2.0 are upgraded on their own
      version); a ``<scene>`` root contributes its children, any other root
      element (e.g. a ``<bsdf>``) is inserted itself, named by the include's
      ``name``.  Nesting stops at depth 15.

    Errors inside an included file name that file and line and then the chain
    of includes that led to it.
    """
    for el in list(root.iter("include", "path")):
        if el.tag == "path":
            if el.getparent() is not root:
                raise ctx.error(el, "<path> can only be a child of the root <scene>")
            value = ctx.attr(el, "value")
            if not value:
                raise ctx.error(el, "<path> needs a 'value' attribute")
            d = Path(value)
            if not d.is_absolute():
                cands = [file.parent / d, *(s / d for s in ctx.search), ctx.path.parent / d]
                d = next((c for c in cands if c.is_dir()), file.parent / d)
            if not d.is_dir():
                raise ctx.error(el, f"<path>: folder '{short(value)}' not found")
            ctx.search.insert(0, d.resolve())
            el.getparent().remove(el)
            continue
        name = ctx.attr(el, "filename")
        if not name:
            raise ctx.error(el, "<include> needs a 'filename' attribute")
        dirs = [file.parent, *ctx.search, ctx.path.parent]
        found = Path(name) if Path(name).is_absolute() else next(
            (d / name for d in dirs if (d / name).is_file()), None)
        if found is None or not found.is_file():
            raise ctx.error(el, f"included file '{short(name)}' not found "
                                f"(searched: {', '.join(str(d) for d in dict.fromkeys(dirs))})")
        if depth + 1 > MAX_INCLUDE_DEPTH:
            raise ctx.error(el, f"more than {MAX_INCLUDE_DEPTH} nested <include> files")
        if len(ctx.includes) >= MAX_INCLUDES:
            raise ctx.error(el, f"more than {MAX_INCLUDES} <include> expansions in one scene "
                                "(gibench's limit on include fan-out)")
        found = found.resolve()
        ctx.files.append(found)
        ctx.includes.append((name, found))
        here = f"{file.name if file == ctx.path else file}:{el.sourceline}"
        sub_chain = f" (included from {here}" + (f", {chain[2:]}" if chain else ")")
        inc = _parse_xml(found, sub_chain)
        ctx.sources.append((found, sub_chain))
        mark = str(len(ctx.sources) - 1)
        inc.set(_SRC, mark)
        if inc.get("version") is None:
            raise ctx.error(inc, "an included file needs a 'version' attribute on its root element")
        _check_version(ctx, inc)
        if inc.tag == "scene":
            for c in inc:
                if isinstance(c.tag, str) and c.tag == "default":
                    if c.get("name") is None or c.get("value") is None:
                        raise ctx.error(c, "<default> needs 'name' and 'value'")
                    ctx.defaults.setdefault(c.get("name"), c.get("value"))
        _expand_includes(ctx, inc, found, sub_chain, depth + 1)
        parts = [c for c in inc if isinstance(c.tag, str)] if inc.tag == "scene" else [inc]
        parent, at = el.getparent(), el.getparent().index(el)
        for c in parts:
            if c.get(_SRC) is None:
                c.set(_SRC, mark)
        if inc.tag != "scene" and el.get("name") is not None:
            inc.set("name", el.get("name"))
        parent.remove(el)
        for k, c in enumerate(parts):
            parent.insert(at + k, c)




def resolve(path, defines: dict | None = None, *, cls=None) -> Document:
    """Parse a scene file and expand it: ``<default>`` values (``defines`` first, as
    Mitsuba's ``-D``), ``<include>`` and ``<path>`` in document order.

    ``cls`` is the :class:`Document` subclass to build (the loader's keeps ids).

    Raises
    ------
    SceneError
        Missing file, malformed XML, an entity, a root other than ``<scene>``, an
        unsupported version, a bad ``<default>``, an include or path not found, too
        deep or too many includes, ``$name`` without a value.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: scene file not found")
    doc = (cls or Document)(path, defines)
    root = _parse_xml(path)
    doc.root = root
    if root.tag != "scene":
        raise doc.error(root, "the root element must be <scene>")
    _check_version(doc, root)
    # Mitsuba resolves <default> before anything else; an included scene's
    # defaults join in document order.
    for c in root:
        if isinstance(c.tag, str) and c.tag == "default":
            name, value = c.get("name"), c.get("value")
            if name is None or value is None:
                raise doc.error(c, "<default> needs 'name' and 'value'")
            if not re.fullmatch(IDENTIFIER, name):
                raise doc.error(c, f"<default> name must be an identifier, got {short(name)!r}")
            doc.defaults.setdefault(name, value)
    _expand_includes(doc, root, path, "", 0)
    # Every $name must have a value, wherever it is used (Mitsuba substitutes all
    # attributes before reading any): the loader and the store refuse the same files.
    for el in root.iter():
        if isinstance(el.tag, str):
            for key, value in el.attrib.items():
                if "$" in value and key != _SRC:
                    doc.subst(el, value)
    return doc


def expanded(path, defines: dict | None = None) -> etree._Element:
    """The scene of ``path`` as one self-contained ``<scene>`` element that Mitsuba loads
    as it loads the file: every ``<include>`` replaced by its content (:func:`resolve`),
    the ``<path>`` directories given back as ``<path>`` elements with absolute
    folders at the top, in their declaration order (Mitsuba searches the latest
    first), and the scene file's own directory among them, so relative names resolve
    wherever the string is loaded.  ``<default>`` elements and ``$name`` stay as
    written (an included file's defaults follow the including file's, which win, as
    in Mitsuba).  Used where the scene's elements must be edited after the includes
    are expanded (a sensor or an integrator declared in an included file).
    """
    doc = resolve(path, defines)
    root = doc.root
    for el in root.iter():
        if isinstance(el.tag, str) and _SRC in el.attrib:
            del el.attrib[_SRC]
            if el is not root:
                # An included file's own root (e.g. a <bsdf>) carries the file's version,
                # which Mitsuba does not accept inside a scene.
                el.attrib.pop("version", None)
    etree.cleanup_namespaces(root)
    dirs = [doc.path.parent.resolve(), *reversed(doc.search)]   # searched last ... first
    for k, d in enumerate(dirs):
        el = etree.Element("path")
        el.set("value", str(d))
        root.insert(k, el)
    return root
