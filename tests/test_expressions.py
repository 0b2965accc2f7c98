"""Unit tests for fem_impact.expressions: parsing, vectorized evaluation and the whitelist."""

import math

import numpy as np
import pytest

from fem_impact.expressions import FUNCTIONS, ExpressionError, parse_expression


@pytest.mark.parametrize("source, expected", [
    ("1 + 2 * 3", 7.0),
    ("(1 + 2) * 3", 9.0),
    ("2 ** 3 ** 2", 512.0),
    ("-2 ** 2", -4.0),
    ("7 / 2", 3.5),
    ("+3 - -1", 4.0),
    ("2 * pi", 2 * math.pi),
    ("1e-3 * 2", 0.002),
])
def test_arithmetic_and_precedence(source, expected):
    expression = parse_expression(source)
    assert expression.is_constant
    assert expression.evaluate() == pytest.approx(expected)


def test_numbers_are_constants():
    expression = parse_expression(3)
    assert expression.source == 3 and expression.is_constant
    assert isinstance(expression.evaluate(), float) and expression.evaluate() == 3.0
    np.testing.assert_array_equal(parse_expression(-1.5).evaluate(shape=4), np.full(4, -1.5))


def test_vectorized_over_node_coordinates():
    x, y = np.array([0.0, 0.5, 1.0]), np.array([1.0, 2.0, 3.0])
    expression = parse_expression("(1 - x)/2 + y*t")
    assert expression.variables == {"x", "y", "t"} and not expression.is_constant
    np.testing.assert_allclose(expression.evaluate(x=x, y=y, t=2.0), (1 - x) / 2 + 2 * y)
    # A constant, or an expression of t only, is broadcast against the given coordinates.
    np.testing.assert_array_equal(parse_expression("2").evaluate(x=x, y=y), np.full(3, 2.0))
    np.testing.assert_array_equal(parse_expression("t")(x=x, t=1.0), np.ones(3))
    assert parse_expression("sin(t)")(t=0.5) == pytest.approx(math.sin(0.5))


@pytest.mark.parametrize("name, argument, expected", [
    ("sin", 0.5, math.sin(0.5)), ("cos", 0.5, math.cos(0.5)), ("tan", 0.5, math.tan(0.5)),
    ("asin", 0.5, math.asin(0.5)), ("acos", 0.5, math.acos(0.5)), ("atan", 0.5, math.atan(0.5)),
    ("sinh", 0.5, math.sinh(0.5)), ("cosh", 0.5, math.cosh(0.5)), ("tanh", 0.5, math.tanh(0.5)),
    ("exp", 0.5, math.exp(0.5)), ("log", 0.5, math.log(0.5)), ("sqrt", 0.5, math.sqrt(0.5)),
    ("abs", -0.5, 0.5),
])
def test_unary_functions(name, argument, expected):
    assert parse_expression(f"{name}(x)")(x=argument) == pytest.approx(expected)
    x = np.array([argument, argument])
    np.testing.assert_allclose(parse_expression(f"{name}(x)")(x=x), [expected, expected])


def test_min_max_reduce_over_arguments():
    x = np.array([0.0, 1.0, 2.0])
    np.testing.assert_array_equal(parse_expression("min(x, 1.5, 1)")(x=x), [0.0, 1.0, 1.0])
    np.testing.assert_array_equal(parse_expression("max(x, 1)")(x=x), [1.0, 1.0, 2.0])
    assert set(FUNCTIONS) >= {"sin", "cos", "exp", "sqrt", "abs", "min", "max"}


def test_huge_powers_overflow_to_inf_quietly():
    with np.errstate(all="raise"):  # evaluate() must not leak numpy warnings or errors
        assert parse_expression("9**9**9").evaluate() == math.inf


def test_missing_variable():
    with pytest.raises(ExpressionError, match="needs t"):
        parse_expression("x * t").evaluate(x=1.0)


@pytest.mark.parametrize("source, message", [
    ("__import__('os').system('touch X')", "function calls other than"),
    ("().__class__", "attribute access"),
    ("open('f')", "function calls other than"),
    ("x.real", "attribute access"),
    ("[1][0]", "indexing"),
    ("lambda: 1", "lambda"),
    ("1 if x else 2", "conditional"),
    ("x < 1", "comparison"),
    ("'a'", "numbers only"),
    ("True", "numbers only"),
    ("1j", "numbers only"),
    ("os", "'os' is not an allowed name"),
    ("__builtins__", "not an allowed name"),
    ("e", "not an allowed name"),
    ("x % 2", "not allowed"),
    ("x and 1", "not allowed"),
    ("[x for x in ()]", "not allowed"),
    ("(y := 1)", "not allowed"),
    ("sin(x=1)", "positional"),
    ("sin(1, 2)", "exactly 1 argument"),
    ("max(1)", "at least 2"),
    ("sin", "not an allowed name"),
    ("1 +", "invalid expression"),
    ("", "invalid expression"),
    ("(" * 500 + "1" + ")" * 500, ""),
    ("+".join(["1"] * 5000), ""),
])
def test_rejects_everything_but_arithmetic(source, message):
    with pytest.raises(ExpressionError, match=message):
        parse_expression(source)


@pytest.mark.parametrize("source", [True, None, [1.0], {"a": 1}, b"1"])
def test_rejects_non_numbers(source):
    with pytest.raises(ExpressionError, match="expected a number"):
        parse_expression(source)


def test_allowed_names_are_restricted():
    with pytest.raises(ExpressionError, match=r"'t' is not an allowed name \(allowed: x, y, z, pi\)"):
        parse_expression("x + t", allowed=("x", "y", "z"))
    assert parse_expression("2*pi*t", allowed=("t",)).variables == {"t"}


def test_malicious_expression_does_not_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    marker = tmp_path / "X"
    for source in (f"__import__('os').system('touch {marker}')",
                   f"[c for c in ().__class__.__base__.__subclasses__()][0]('{marker}')"):
        with pytest.raises(ExpressionError):
            parse_expression(source).evaluate(x=0.0, y=0.0, z=0.0, t=0.0)
    assert not marker.exists()


def test_named_constants_are_numbers_from_parsing_on():
    """Named constants (a case file's parameters) become numbers when parsed: they are not
    variables, the fast time path sees them, and the names used are reported."""
    expr = parse_expression("F0*sin(2*pi*f*t)", allowed=("t",), constants={"F0": 5.0, "f": 2000.0, "unused": 1.0})
    assert expr.variables == {"t"} and expr.constants == {"F0", "f"}
    assert expr.at_time(1.0 / 8000.0) == pytest.approx(5.0)       # sin(pi/2)
    assert expr(t=np.array([0.0, 1.0 / 8000.0])) == pytest.approx([0.0, 5.0])
    constant = parse_expression("2*F0", allowed=("t",), constants={"F0": 5.0})
    assert constant.is_constant and constant() == 10.0
    with pytest.raises(ExpressionError, match=r"'g' is not an allowed name \(allowed: t, pi, F0\)"):
        parse_expression("g*t", allowed=("t",), constants={"F0": 5.0})


@pytest.mark.parametrize("source, first, second", [
    ("A*sin(2*pi*f*t)", lambda t: 0.5 * np.pi * np.cos(np.pi * t), lambda t: -np.pi**2 * 0.5 * np.sin(np.pi * t)),
    ("v*t", lambda t: 0.25 + 0 * t, lambda t: 0 * t),
    ("t**3/(1 + t)", lambda t: (3 * t**2 * (1 + t) - t**3) / (1 + t) ** 2,
     lambda t: (6 * t + 6 * t**2 + 2 * t**3) / (1 + t) ** 3 - 0 * t),
    ("exp(-t)*cos(3*t)", lambda t: -np.exp(-t) * (np.cos(3 * t) + 3 * np.sin(3 * t)),
     lambda t: np.exp(-t) * (-8 * np.cos(3 * t) + 6 * np.sin(3 * t))),
    ("sqrt(1 + t*t) + 2**t", lambda t: t / np.sqrt(1 + t * t) + np.log(2) * 2**t,
     lambda t: (1 + t * t) ** -1.5 + np.log(2) ** 2 * 2**t),
    ("min(t, 0.3)**2", lambda t: np.where(t < 0.3, 2 * t, 0.0), lambda t: np.where(t < 0.3, 2.0, 0.0)),
])
def test_time_derivatives_are_exact(source, first, second):
    """A support's motion enters as loads with its first and second derivatives in t
    (fem/prescribed.py): carried exactly through every operation, not by differences."""
    e = parse_expression(source, allowed=("t",), constants={"A": 0.5, "f": 0.5, "v": 0.25})
    t = np.array([0.05, 0.2, 0.45, 0.8, 1.7])
    assert np.allclose(e.time_derivative(1)(t=t), first(t), rtol=1e-13, atol=1e-14)
    assert np.allclose(e.time_derivative(2)(t=t), second(t), rtol=1e-13, atol=1e-14)
    assert e.time_derivative(2).at_time(0.45) == pytest.approx(second(np.array(0.45)), rel=1e-13, abs=1e-14)
    assert e.time_derivative(0) is e
    assert parse_expression("3.5").time_derivative(2).at_time(1.0) == 0.0
