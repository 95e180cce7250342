"""Count three signs of untyped data crossing module boundaries in ``polarref/`` (issue 29).

* public functions annotated to return a dict (``-> dict``, ``-> dict[...]``, ``-> dict | None``),
  serialisers (``to_dict``, ``to_json``, ...) excepted;
* dataclass fields typed as a bare ``dict``, ``object`` or ``Any`` (anywhere in the annotation);
* subscripts by a string constant (``x["key"]``) outside JSON (de)serialisation, i.e. outside
  functions whose name says they convert to or from JSON (see ``SERIALISERS``).

AST only (nothing is imported). ``python scripts/layout_counts.py`` prints the three numbers;
``--list`` prints each occurrence. tests/test_layout.py keeps them from growing.
"""

from __future__ import annotations

import ast
import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Functions whose job is the JSON form of a record: their string keys ARE the file format.
SERIALISERS = re.compile(r"^_?(to_dict|from_dict|to_json|from_json|as_json|_?upgrade\w*|encode|decode|"
                         r"dumps|loads|read_\w*json|\w*_from_json|\w*_to_json)$")


@dataclass(frozen=True)
class Counts:
    dict_returning: list[str]   # "module:function"
    loose_fields: list[str]     # "module:Class.field"
    string_subscripts: list[str]  # "module:line"


def _returns_dict(ann: ast.expr | None) -> bool:
    if ann is None:
        return False
    if isinstance(ann, ast.Constant) and isinstance(ann.value, str):  # string annotation
        try:
            ann = ast.parse(ann.value, mode="eval").body
        except SyntaxError:
            return False
    if isinstance(ann, ast.BinOp):  # X | None
        return _returns_dict(ann.left) or _returns_dict(ann.right)
    if isinstance(ann, ast.Subscript):
        ann = ann.value
    return isinstance(ann, ast.Name) and ann.id in ("dict", "Dict")


def _loose(ann: ast.expr) -> bool:
    for node in ast.walk(ann):
        if isinstance(node, ast.Name) and node.id in ("object", "Any"):
            return True
        if isinstance(node, ast.Name) and node.id in ("dict", "Dict"):
            parent_is_subscript = any(isinstance(p, ast.Subscript) and p.value is node for p in ast.walk(ann))
            if not parent_is_subscript:
                return True
    return False


def _is_dataclass(cls: ast.ClassDef) -> bool:
    for d in cls.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name == "dataclass":
            return True
    return False


def _public(name: str) -> bool:
    return not name.startswith("_")


def _scan(mod: str, tree: ast.Module, out: Counts) -> None:
    def visit(node: ast.AST, public_scope: bool, serialiser: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                if _is_dataclass(child):
                    for stmt in child.body:
                        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) \
                                and not (isinstance(stmt.annotation, ast.Name) and stmt.annotation.id == "ClassVar") \
                                and "ClassVar" not in ast.unparse(stmt.annotation) and _loose(stmt.annotation):
                            out.loose_fields.append(f"{mod}:{child.name}.{stmt.target.id}")
                visit(child, public_scope and _public(child.name), serialiser)
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                is_ser = serialiser or bool(SERIALISERS.match(child.name))
                if public_scope and _public(child.name) and not is_ser \
                        and isinstance(node, (ast.Module, ast.ClassDef)) and _returns_dict(child.returns):
                    out.dict_returning.append(f"{mod}:{child.name}")
                visit(child, False, is_ser)
            else:
                if isinstance(child, ast.Subscript) and not serialiser and isinstance(child.slice, ast.Constant) \
                        and isinstance(child.slice.value, str) and not isinstance(child.ctx, ast.Del):
                    # annotations such as Literal["x"] are types, not lookups
                    if not (isinstance(child.value, ast.Name) and child.value.id in ("Literal", "Annotated")):
                        out.string_subscripts.append(f"{mod}:{child.lineno}")
                visit(child, public_scope, serialiser)

    visit(tree, True, False)


def count(root: Path = ROOT) -> Counts:
    out = Counts([], [], [])
    for path in sorted((root / "polarref").rglob("*.py")):
        mod = ".".join(path.relative_to(root).with_suffix("").parts)
        _scan(mod, ast.parse(path.read_text(encoding="utf-8"), filename=str(path)), out)
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    c = count()
    if "--list" in argv:
        for title, items in (("dict-returning public functions", c.dict_returning),
                             ("bare dict/object/Any dataclass fields", c.loose_fields),
                             ("string-key subscripts outside JSON (de)serialisation", c.string_subscripts)):
            print(f"# {title}: {len(items)}")
            print("\n".join(items))
    print(f"dict_returning_public_functions {len(c.dict_returning)}")
    print(f"bare_dict_object_any_dataclass_fields {len(c.loose_fields)}")
    print(f"string_key_subscripts_outside_json {len(c.string_subscripts)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
