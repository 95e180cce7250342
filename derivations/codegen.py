"""Turn SymPy expressions into vectorized numpy functions returning (value, Jacobian).

The output is deterministic: no timestamps, stable ordering, common subexpressions numbered in
the order :func:`sympy.cse` returns them. Generation runs under a fixed ``PYTHONHASHSEED`` (see
:func:`derivations.generate.generate_files`) because SymPy's internal set iteration may depend
on string hashing.
"""

from __future__ import annotations

import dataclasses
import textwrap

import sympy as sp
from sympy.printing.numpy import NumPyPrinter


@dataclasses.dataclass(frozen=True)
class Arg:
    """One argument of a generated function."""

    name: str  # Python argument name
    symbols: tuple[sp.Symbol, ...]  # its components in row-major order
    trailing: tuple[int, ...]  # trailing shape: () scalar, (3,) vector, (3, 3) matrix
    doc: str  # one line for the docstring


@dataclasses.dataclass(frozen=True)
class FunctionSpec:
    """A scalar observation and its Jacobian w.r.t. ``wrt`` (evaluated at ``at``)."""

    name: str  # generated function name
    summary: str  # first docstring line
    args: tuple[Arg, ...]  # inputs, in signature order
    value: sp.Expr  # observation, may contain the ``at`` symbols (set to their values)
    wrt: tuple[sp.Symbol, ...]  # Jacobian columns, in order
    columns_doc: str  # docstring text naming the Jacobian columns
    at: tuple[tuple[sp.Symbol, float], ...] = ()  # e.g. rotation increment delta = 0
    singular: sp.Expr | None = None  # Jacobian rows where this is exactly 0 get ``singular_fill``
    singular_fill: str = "0.0"  # Python literal written into those rows
    singular_doc: str = ""  # docstring text documenting the singular set and fill
    singular_value: str | None = None  # if set, the value written where ``singular`` is 0
    wrap_pi: bool = False  # map -pi to +pi so the value lies in (-pi, pi]
    notes: str = ""  # extra docstring paragraph


def _printer() -> NumPyPrinter:
    return NumPyPrinter({"fully_qualified_modules": True})


def expressions(spec: FunctionSpec) -> tuple[sp.Expr, list[sp.Expr], sp.Expr | None]:
    """The value, Jacobian entries and singular indicator with ``at`` substituted."""
    at = dict(spec.at)
    value = spec.value.subs(at)
    jac = [sp.diff(spec.value, w).subs(at) for w in spec.wrt]
    singular = spec.singular.subs(at) if spec.singular is not None else None
    return value, jac, singular


def _unpack_lines(args: tuple[Arg, ...]) -> list[str]:
    names = ", ".join(a.name for a in args)
    trails = ", ".join(repr(a.trailing) for a in args)
    lines = [f"({names},), _shape = _broadcast(({names},), ({trails},))"]
    for a in args:
        if not a.trailing:
            continue
        for flat, sym in enumerate(a.symbols):
            if len(a.trailing) == 1:
                index = f"[..., {flat}]"
            else:
                index = f"[..., {flat // a.trailing[1]}, {flat % a.trailing[1]}]"
            lines.append(f"{sym.name} = {a.name}{index}")
    return lines


def _signature_names(args: tuple[Arg, ...]) -> dict[sp.Symbol, sp.Symbol]:
    """Scalar arguments keep their own name; component symbols are bound by unpacking."""
    return {a.symbols[0]: sp.Symbol(a.name, real=True) for a in args if not a.trailing}


def render_function(spec: FunctionSpec) -> str:
    value, jac, singular = expressions(spec)
    rename = _signature_names(spec.args)
    exprs = [value, *jac] + ([singular] if singular is not None else [])
    exprs = [sp.sympify(e).xreplace(rename) for e in exprs]
    replacements, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("_x"), order="canonical")
    printer = _printer()
    n = len(spec.wrt)
    body: list[str] = _unpack_lines(spec.args)
    body.append('with numpy.errstate(divide="ignore", invalid="ignore", over="ignore"):')
    inner = [f"{sym} = {printer.doprint(expr)}" for sym, expr in replacements]
    inner.append(f"value = numpy.broadcast_to({printer.doprint(reduced[0])}, _shape).astype(numpy.float64)")
    inner.append(f"jac = numpy.empty(_shape + ({n},), dtype=numpy.float64)")
    for k, expr in enumerate(reduced[1 : 1 + n]):
        inner.append(f"jac[..., {k}] = {printer.doprint(expr)}")
    if singular is not None:
        inner.append(f"singular = ({printer.doprint(reduced[1 + n])}) == 0.0")
    body += ["    " + line for line in inner]
    if singular is not None:
        body.append("singular &= ~numpy.isnan(value)")
        body.append(f"jac[singular] = {spec.singular_fill}")
        if spec.singular_value is not None:
            body.append(f"value = numpy.where(singular, {spec.singular_value}, value)")
    if spec.wrap_pi:
        body.append("value = numpy.where(value == -numpy.pi, numpy.pi, value)")
    body.append("return value, jac")

    params = ", ".join(a.name for a in spec.args)
    arg_doc = "\n".join(f"    {a.name}: {a.doc}" for a in spec.args)
    doc_parts = [spec.summary, ""]
    if spec.notes:
        doc_parts += [textwrap.fill(spec.notes, 92), ""]
    doc_parts += ["Args:", arg_doc, "", "Returns:",
                  f"    (value (...), jac (..., {n})); jac columns: {spec.columns_doc}."]
    if spec.singular_doc:
        doc_parts += ["", textwrap.fill(spec.singular_doc, 92)]
    doc = textwrap.indent("\n".join(doc_parts), "    ").strip()
    lines = [f"def {spec.name}({params}):", f'    """{doc}', '    """']
    lines += ["    " + line if line else "" for line in body]
    # Long generated lines are fine; strip trailing blanks so the file diffs cleanly.
    return "\n".join(line.rstrip() for line in lines) + "\n"


HELPERS = '''
def _broadcast(arrays, trailing):
    """float64 arrays broadcast over their leading axes (trailing shapes checked), and that shape."""
    out = [numpy.asarray(a, dtype=numpy.float64) for a in arrays]
    leading = []
    for a, t in zip(out, trailing):
        if a.ndim < len(t) or tuple(a.shape[a.ndim - len(t):]) != tuple(t):
            raise ValueError(f"expected an array of shape (..., {', '.join(map(str, t))}), got {a.shape}")
        leading.append(a.shape[: a.ndim - len(t)])
    shape = numpy.broadcast_shapes(*leading)
    return [numpy.broadcast_to(a, shape + tuple(t)) for a, t in zip(out, trailing)], shape
'''


def render_module(generator: str, sympy_version: str, doc: str, specs: list[FunctionSpec]) -> str:
    header = (
        f"# AUTOGENERATED by {generator} with SymPy {sympy_version} -- do not edit.\n"
        f"# Regenerate with `polarref derive`; `polarref derive --check` verifies this file.\n"
    )
    names = ", ".join(repr(s.name) for s in specs)
    top = header + f'"""{doc}"""\n\nimport numpy\n\n__all__ = [{names}]\n'
    return "\n\n".join([top, HELPERS.strip() + "\n"] + [render_function(s) for s in specs])
