"""Safe arithmetic expressions from case files: parsed against a whitelist, evaluated with numpy."""

from __future__ import annotations

import ast
import functools
import math
from typing import NamedTuple

import numpy as np

FUNCTIONS = {
    "sin": np.sin, "cos": np.cos, "tan": np.tan,
    "asin": np.arcsin, "acos": np.arccos, "atan": np.arctan,
    "sinh": np.sinh, "cosh": np.cosh, "tanh": np.tanh,
    "exp": np.exp, "log": np.log, "sqrt": np.sqrt, "abs": np.abs,
    "min": np.minimum, "max": np.maximum,
}
VARIADIC = ("min", "max")
CONSTANTS = {"pi": math.pi}
# Names a case file's parameters may not take: the variables, the constants (with e, kept free
# for Euler's number) and the functions.
RESERVED = ("x", "y", "z", "t", "e", *CONSTANTS, *FUNCTIONS)
_BINARY = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
           ast.Div: np.true_divide, ast.Pow: np.power}
_UNARY = {ast.UAdd: np.positive, ast.USub: np.negative}
# Readable names for the constructs users most likely try; others fall back to the AST class name.
_KINDS = {
    ast.Attribute: "attribute access", ast.Subscript: "indexing", ast.Compare: "comparison",
    ast.BoolOp: "'and'/'or'", ast.IfExp: "conditional expression", ast.Lambda: "lambda",
    ast.BinOp: "this operator", ast.UnaryOp: "this operator", ast.List: "a list",
    ast.Tuple: "a tuple", ast.Dict: "a dict", ast.Set: "a set", ast.ListComp: "a comprehension",
    ast.SetComp: "a comprehension", ast.DictComp: "a comprehension",
    ast.GeneratorExp: "a comprehension", ast.NamedExpr: "assignment", ast.JoinedStr: "a string",
    ast.Starred: "unpacking",
}


class ExpressionError(ValueError):
    """An expression that is not plain arithmetic, or that cannot be evaluated."""


class Expression:
    """A parsed arithmetic expression, evaluated on scalars or numpy arrays.

    Attributes
    ----------
    source : str or float or int
        The expression as written (a string), or the number given.
    variables : frozenset of str
        Names of the variables used (``pi`` and named constants excluded).
    constants : frozenset of str
        Names of the named constants (case-file parameters) used; their values are part of
        the expression from parsing on.
    """

    def __init__(self, source, variables, function, constants=()):
        self.source = source
        self.variables = frozenset(variables)
        self.constants = frozenset(constants)
        self._function = function

    @property
    def is_constant(self) -> bool:
        """True when the expression uses no variables."""
        return not self.variables

    def evaluate(self, x=None, y=None, z=None, t=None, shape=None):
        """Evaluate the expression.

        Parameters
        ----------
        x, y, z : float or array_like, optional
            Coordinates (typically arrays of node coordinates).
        t : float, optional
            Time.
        shape : int or tuple of int, optional
            Shape the result is broadcast to, also for a constant expression.

        Returns
        -------
        float or numpy.ndarray
            A float when no argument has a shape, else a new float array broadcast
            against the given variables and `shape`.

        Raises
        ------
        ExpressionError
            If a variable the expression uses is not given, or shapes do not broadcast.
        """
        given = {name: np.asarray(value, dtype=float)
                 for name, value in (("x", x), ("y", y), ("z", z), ("t", t)) if value is not None}
        missing = self.variables - given.keys()
        if missing:
            raise ExpressionError(f"expression {self.source!r} needs {', '.join(sorted(missing))}")
        # Overflow to inf or nan (e.g. 9**9**9, sqrt(-1)) is a valid numpy result, not a warning.
        try:
            with np.errstate(all="ignore"):
                value = self._function(given)
        except RecursionError:
            raise ExpressionError(f"expression {_short(str(self.source))} is too deeply nested") from None
        shapes = [np.shape(value), *(v.shape for v in given.values())]
        try:
            target = np.broadcast_shapes(*shapes, *(() if shape is None else (shape,)))
        except ValueError:
            raise ExpressionError(f"expression {self.source!r}: arguments of shapes "
                                  f"{shapes[1:]} do not broadcast") from None
        if target == ():
            return float(value)
        return np.array(np.broadcast_to(value, target), dtype=float)

    __call__ = evaluate

    def at_time(self, t: float) -> float:
        """The value at time ``t`` of an expression in ``t`` alone: the scalar fast path that
        time loops call once per step (``evaluate`` costs tens of microseconds in checks)."""
        with np.errstate(all="ignore"):
            return float(self._function({"t": np.float64(t)}))

    def __repr__(self):
        return f"Expression({self.source!r})"


def parse_expression(source, allowed=("x", "y", "z", "t"), constants=None) -> Expression:
    """Parse a number or an arithmetic expression string, never executing it as code.

    Parameters
    ----------
    source : int, float or str
        A number, or an expression of numbers, the names in `allowed`, ``pi``, the names of
        `constants`, ``+ - * / **`` and calls of the functions in ``FUNCTIONS``.
    allowed : sequence of str
        Variable names the expression may use.
    constants : mapping of str to float, optional
        Named numbers (a case file's ``parameters``), replaced by their values when parsed.

    Returns
    -------
    Expression

    Raises
    ------
    ExpressionError
        If `source` is not a number or a string, or uses anything beyond the whitelist.
    """
    allowed = tuple(allowed)
    if isinstance(source, bool) or not isinstance(source, (int, float, str)):
        raise ExpressionError(f"expected a number or an arithmetic expression, got {source!r}")
    if not isinstance(source, str):
        value = _float(source)
        return Expression(source, (), lambda env: value)
    text = source.strip()  # eval mode rejects leading indentation
    try:
        tree = ast.parse(text, mode="eval")
    except (SyntaxError, ValueError) as exc:
        raise ExpressionError(f"invalid expression {_short(text)}: {getattr(exc, 'msg', exc)}") from None
    except (RecursionError, MemoryError):
        raise ExpressionError(f"expression {_short(text)} is too deeply nested") from None
    scope = _Scope(allowed, dict(constants or {}), set(), set())
    try:
        function = _build(tree.body, text, scope)
    except RecursionError:
        raise ExpressionError(f"expression {_short(text)} is too deeply nested") from None
    return Expression(source, scope.names, function, scope.used)


class _Scope(NamedTuple):
    """What a name may mean while building: variables, named constants; and what was used."""

    allowed: tuple
    constants: dict
    names: set      # variables used
    used: set       # named constants used


def _short(text, limit=60):
    """Quote `text` for a message, shortened so a huge input cannot flood the error."""
    return repr(text if len(text) <= limit else text[:limit] + "...")


def _float(number):
    """Convert a literal to float, so integer powers cannot build huge Python ints."""
    try:
        return float(number)
    except OverflowError:
        raise ExpressionError(f"number too large: {number}") from None


def _build(node, text, scope):
    """Return a closure ``env -> value`` for a whitelisted AST node, collecting the names used."""
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        value = _float(node.value)
        return lambda env: value
    if isinstance(node, ast.Constant):
        raise ExpressionError(f"{node.value!r} is not allowed (numbers only)")
    if isinstance(node, ast.Name):
        if node.id in CONSTANTS:
            value = CONSTANTS[node.id]
            return lambda env: value
        if node.id in scope.constants:
            value = _float(scope.constants[node.id])
            scope.used.add(node.id)
            return lambda env: value
        if node.id not in scope.allowed:
            known = scope.allowed + tuple(CONSTANTS) + tuple(scope.constants)
            raise ExpressionError(f"'{node.id}' is not an allowed name (allowed: {', '.join(known)})")
        scope.names.add(node.id)
        return lambda env: env[node.id]
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        op = _BINARY[type(node.op)]
        left, right = _build(node.left, text, scope), _build(node.right, text, scope)
        return lambda env: op(left(env), right(env))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        op, operand = _UNARY[type(node.op)], _build(node.operand, text, scope)
        return lambda env: op(operand(env))
    if isinstance(node, ast.Call):
        return _build_call(node, text, scope)
    kind = _KINDS.get(type(node), type(node).__name__)
    raise ExpressionError(f"{kind} is not allowed: {_short(ast.get_source_segment(text, node))}")


def _build_call(node, text, scope):
    """Return a closure for a call of a whitelisted function with positional arguments."""
    name = node.func.id if isinstance(node.func, ast.Name) else None
    if name not in FUNCTIONS:
        raise ExpressionError(f"function calls other than {', '.join(FUNCTIONS)} are not allowed: "
                              f"{_short(ast.get_source_segment(text, node))}")
    if node.keywords:
        raise ExpressionError(f"{name}() takes positional arguments only")
    variadic, count = name in VARIADIC, len(node.args)
    if (variadic and count < 2) or (not variadic and count != 1):
        wanted = "at least 2 arguments" if variadic else "exactly 1 argument"
        raise ExpressionError(f"{name}() takes {wanted}, got {count}")
    function = FUNCTIONS[name]
    args = [_build(arg, text, scope) for arg in node.args]
    if variadic:
        return lambda env: functools.reduce(function, [arg(env) for arg in args])
    (arg,) = args
    return lambda env: function(arg(env))
