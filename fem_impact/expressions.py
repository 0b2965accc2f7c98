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

    def __init__(self, source, variables, function, constants=(), tree=None, values=None):
        self.source = source
        self.variables = frozenset(variables)
        self.constants = frozenset(constants)
        self._function = function
        self._tree, self._values = tree, values   # for time_derivative (None: a number)
        self._jets: dict = {}
        self.what: str | None = None   # how an error names it (None: by its source)

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

    def at_times(self, t: np.ndarray) -> np.ndarray:
        """:meth:`at_time` on an array of times at once (a block of steps): a new float array of
        t's shape, the same numpy operations element by element; overflow gives inf or nan, as
        there (the caller decides what a non-finite value means)."""
        t = np.asarray(t, dtype=float)
        with np.errstate(all="ignore"):
            value = self._function({"t": t})
        if isinstance(value, np.ndarray) and value.shape == t.shape and value is not t:
            return value   # (a new array from numpy's operations)
        return np.array(np.broadcast_to(value, t.shape), dtype=float)

    def time_derivative(self, order: int) -> Expression:
        """The expression's ``order``-th derivative in t (0, 1 or 2), exact: evaluated by Taylor
        arithmetic (values and derivatives carried through each operation), never by differences.
        It takes t alone; a function not differentiable at a point (abs, min, max) takes the
        derivative of the branch it is on."""
        if order not in (0, 1, 2):
            raise ValueError(f"derivatives of order 0, 1 or 2, not {order}")
        if order == 0:
            return self
        if self.variables - {"t"}:
            raise ExpressionError(f"expression {self.source!r} may depend on t only")
        if order not in self._jets:
            if self._tree is None or "t" not in self.variables:
                function = _ZERO
            else:
                jet = _jet(self._tree, self._values)
                function = lambda env: jet(env)[order]  # noqa: E731
            name = "d/dt" if order == 1 else "d2/dt2"
            self._jets[order] = Expression(f"{name}({self.source})", self.variables & {"t"}, function)
        return self._jets[order]

    def __repr__(self):
        return f"Expression({self.source!r})"


def _ZERO(env):
    return 0.0 * env["t"] if "t" in env else 0.0


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
    values = {name: _float(value) for name, value in (constants or {}).items() if name in scope.used}
    return Expression(source, scope.names, function, scope.used, tree.body, values)


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


# Taylor arithmetic to second order: a value is a jet (f, f', f'') in t. For f(a):
# (f(a0), f'(a0) a1, f''(a0) a1^2 + f'(a0) a2).
def _chain(a, f0, f1, f2):
    return (f0, f1 * a[1], f2 * a[1] * a[1] + f1 * a[2])


def _jet_function(name, a):
    x = a[0]
    if name == "sin":
        return _chain(a, np.sin(x), np.cos(x), -np.sin(x))
    if name == "cos":
        return _chain(a, np.cos(x), -np.sin(x), -np.cos(x))
    if name == "tan":
        t = np.tan(x)
        return _chain(a, t, 1 + t * t, 2 * t * (1 + t * t))
    if name == "exp":
        e = np.exp(x)
        return _chain(a, e, e, e)
    if name == "log":
        return _chain(a, np.log(x), 1 / x, -1 / (x * x))
    if name == "sqrt":
        r = np.sqrt(x)
        return _chain(a, r, 0.5 / r, -0.25 / (r * x))
    if name == "abs":
        return _chain(a, np.abs(x), np.sign(x), 0.0 * x)
    if name == "sinh":
        return _chain(a, np.sinh(x), np.cosh(x), np.sinh(x))
    if name == "cosh":
        return _chain(a, np.cosh(x), np.sinh(x), np.cosh(x))
    if name == "tanh":
        t = np.tanh(x)
        return _chain(a, t, 1 - t * t, -2 * t * (1 - t * t))
    if name in ("asin", "acos"):
        d = 1 / np.sqrt(1 - x * x)
        sign = 1.0 if name == "asin" else -1.0
        return _chain(a, FUNCTIONS[name](x), sign * d, sign * x * d ** 3)
    if name == "atan":
        d = 1 / (1 + x * x)
        return _chain(a, np.arctan(x), d, -2 * x * d * d)
    raise ExpressionError(f"no derivative of {name}()")   # (every whitelisted function is above)


def _jet_binary(op, a, b):
    if op is ast.Add:
        return tuple(u + v for u, v in zip(a, b))
    if op is ast.Sub:
        return tuple(u - v for u, v in zip(a, b))
    if op is ast.Mult:
        return (a[0] * b[0], a[1] * b[0] + a[0] * b[1], a[2] * b[0] + 2 * a[1] * b[1] + a[0] * b[2])
    if op is ast.Div:
        c0 = a[0] / b[0]
        c1 = (a[1] - c0 * b[1]) / b[0]
        return (c0, c1, (a[2] - 2 * c1 * b[1] - c0 * b[2]) / b[0])
    # a ** b: the power rule for a constant exponent (negative bases allowed), else exp(b log a)
    if np.all(np.asarray(b[1]) == 0) and np.all(np.asarray(b[2]) == 0):
        n = b[0]
        return _chain(a, np.power(a[0], n), n * np.power(a[0], n - 1), n * (n - 1) * np.power(a[0], n - 2))
    return _jet_function("exp", _jet_binary(ast.Mult, b, _jet_function("log", a)))


def _jet(node, values):
    """A closure ``env -> (f, df/dt, d2f/dt2)`` for an expression tree that parse_expression accepted."""
    if isinstance(node, ast.Constant):
        value = _float(node.value)
        return lambda env: (value, 0.0, 0.0)
    if isinstance(node, ast.Name):
        if node.id == "t":
            return lambda env: (env["t"], 1.0, 0.0)
        value = CONSTANTS[node.id] if node.id in CONSTANTS else values[node.id]
        return lambda env: (value, 0.0, 0.0)
    if isinstance(node, ast.BinOp):
        op, left, right = type(node.op), _jet(node.left, values), _jet(node.right, values)
        return lambda env: _jet_binary(op, left(env), right(env))
    if isinstance(node, ast.UnaryOp):
        operand = _jet(node.operand, values)
        if isinstance(node.op, ast.USub):
            return lambda env: tuple(-u for u in operand(env))
        return operand
    name = node.func.id
    args = [_jet(arg, values) for arg in node.args]
    if name in VARIADIC:
        pick = np.less if name == "min" else np.greater

        def extreme(env):
            best = args[0](env)
            for arg in args[1:]:
                other = arg(env)
                take = pick(other[0], best[0])
                best = tuple(np.where(take, o, b) for o, b in zip(other, best))
            return best
        return extreme
    (arg,) = args
    return lambda env: _jet_function(name, arg(env))
