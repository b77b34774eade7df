"""The docs say what the code does: every `Class.member` that docs/architecture.md, the README or a docstring or
comment in the package names exists on that class (our classes only), and every hook the strategy is said to have
(`strategy.<hook>`) is one of Strategy's."""
import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "dc4gs_cl"


def class_members() -> dict[str, set[str]]:
    """Class name -> the names defined on it, its bases' included (methods, class attributes, fields, attributes
    set on self), read from the package's source."""
    members, bases = {}, {}
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ClassDef):
                continue
            names = members.setdefault(node.name, set())
            bases.setdefault(node.name, set()).update(b.id for b in node.bases if isinstance(b, ast.Name))
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    names.add(item.name)
                elif isinstance(item, ast.Assign):
                    names |= {t.id for t in item.targets if isinstance(t, ast.Name)}
                    names |= {e.id for t in item.targets if isinstance(t, ast.Tuple) for e in t.elts
                              if isinstance(e, ast.Name)}
                elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    names.add(item.target.id)
            for sub in ast.walk(node):
                if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and sub.value.id == "self" \
                        and isinstance(sub.ctx, ast.Store):
                    names.add(sub.attr)

    def closed(name, seen=()):
        out = set(members.get(name, ()))
        for base in bases.get(name, ()):
            if base not in seen:
                out |= closed(base, seen + (name,))
        return out
    return {name: closed(name) for name in members}


def documented_texts() -> dict[str, str]:
    texts = {str(p.relative_to(REPO)): p.read_text()
             for p in (REPO / "docs" / "architecture.md", REPO / "docs" / "dc4gs" / "studies.md", REPO / "README.md")}
    for path in PACKAGE.rglob("*.py"):   # docstrings and comments
        source = path.read_text()
        docs = [ast.get_docstring(n) or "" for n in ast.walk(ast.parse(source))
                if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef))]
        comments = [line.split("#", 1)[1] for line in source.splitlines() if "#" in line]
        texts[str(path.relative_to(REPO))] = "\n".join(docs + comments)
    return texts


def test_named_members_exist():
    members = class_members()
    missing = set()
    for where, text in documented_texts().items():
        for cls, name in re.findall(r"\b([A-Z][A-Za-z0-9]+)\.([a-z_][A-Za-z0-9_]*)\b", text):
            if cls in members and name not in members[cls]:
                missing.add(f"{where}: {cls}.{name}")
        for name in re.findall(r"\bstrategy\.([a-z_][A-Za-z0-9_]*)\(", text):
            if name not in members["Strategy"]:
                missing.add(f"{where}: strategy.{name}")
    assert not missing, sorted(missing)


def test_the_reader_finds_members():
    """The check above is only as good as its reader: methods, fields and attributes set in __init__ count."""
    members = class_members()
    assert {"attach", "gather", "apply", "actions", "window", "config"} <= members["Strategy"]
    assert {"attach", "gather", "name"} <= members["AbsGS"]          # inherited
    assert "fold" not in members["Strategy"]
